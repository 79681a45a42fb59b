"""Exit spacing: a vehicle may leave the junction faster than a slower vehicle
ahead on its exit lane, late enough that the road's driver never brakes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dica.ica.core.controller import ControllerSpec, build_controller
from dica.ica.core.dica import Dica
from dica.ica.core.handover import Handover, separation_reference
from dica.ica.core.kernels.handover import separation
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation
from dica.ica.core.search import Search
from tests.test_run_sumo import dica

ROAD_MPS = 70.0 / 3.6
RIGHT = "W_in_0", "S_out_0"  # right turn from the west: 25 km/h
THROUGH = "N_in_0", "S_out_0"  # through from the north, onto the same exit lane


def krauss_run(h: Handover, v_lead: float, v_follow: float, length: float, sep_s: float):
    """SUMO's Krauss driver (no dawdling), stepped at 0.1 s, for a follower released
    ``sep_s`` after its leader; both start with the rear at the exit line. Returns
    the follower's speeds and the speeds of a free run from its release."""
    dt = 0.1
    x_l, vl = 0.0, v_lead
    for _ in range(round(sep_s / dt)):  # the leader runs alone until the follower's release
        vl = min(vl + h.accel_mps2 * dt, ROAD_MPS)
        x_l += vl * dt
    x_f, vf, free, speeds, frees = -length, v_follow, v_follow, [], []
    for _ in range(400):
        g = x_l - x_f - length - h.min_gap_m  # SUMO's gap excludes minGap
        b, tau = h.decel_mps2, h.tau_s
        v_safe = -tau * b + math.sqrt((tau * b) ** 2 + vl * vl + 2.0 * b * max(g, 0.0))
        vf = min(vf + h.accel_mps2 * dt, ROAD_MPS, v_safe)
        free = min(free + h.accel_mps2 * dt, ROAD_MPS)
        vl = min(vl + h.accel_mps2 * dt, ROAD_MPS)
        x_l += vl * dt
        x_f += vf * dt
        speeds.append(vf)
        frees.append(free)
    return np.array(speeds), np.array(frees)


@pytest.mark.parametrize(
    "v_lead,v_follow", [(25 / 3.6, 65 / 3.6), (35 / 3.6, 65 / 3.6), (2.0, 65 / 3.6), (8.0, 12.0)]
)
def test_at_the_separation_the_driver_never_brakes_and_a_little_earlier_it_does(v_lead, v_follow):
    h = Handover(ROAD_MPS)
    sep = h.separation_s(v_lead, v_follow, 5.0)
    assert 0.0 < sep < 10.0
    speeds, free = krauss_run(h, v_lead, v_follow, 5.0, sep)
    assert np.all(speeds >= free - 1e-9), "released at the separation, the driver braked"
    # the bound is not idle: a follower released well before it has to brake
    speeds, free = krauss_run(h, v_lead, v_follow, 5.0, 0.5 * sep)
    assert np.any(speeds < free - 0.1)


def test_the_separation_grows_with_the_follower_s_speed_and_shrinks_with_the_leader_s():
    h = Handover(ROAD_MPS)
    by_follower = [h.separation_s(7.0, v, 5.0) for v in (9.0, 12.0, 15.0, 18.0)]
    assert by_follower == sorted(by_follower) and by_follower[0] < by_follower[-1]
    by_leader = [h.separation_s(v, 18.0, 5.0) for v in (3.0, 7.0, 11.0, 15.0)]
    assert by_leader == sorted(by_leader, reverse=True) and by_leader[0] > by_leader[-1]
    assert h.separation_s(7.0, 18.0, 12.0) > h.separation_s(7.0, 18.0, 5.0)  # a longer follower


def test_the_compiled_separation_is_the_numpy_search_bit_for_bit():
    """The compiled search (what a request runs) against the numpy one it replaces, on
    the lookup grid (1 cm/s, 10 cm) and off it, both drivers, and the edges: a leader
    standing, both at or above the road speed, equal speeds, a follower standing."""
    rng = np.random.default_rng(5)
    cases = [(0.0, ROAD_MPS, 5.0), (ROAD_MPS, ROAD_MPS, 5.0), (25.0, 30.0, 5.0),
             (8.0, 8.0, 5.0), (12.0, 0.0, 5.0), (0.0, 0.0, 12.0)]  # fmt: skip
    for _ in range(1500):
        v_lead, v_follow = rng.uniform(0.0, 1.2 * ROAD_MPS, 2)
        length = rng.uniform(3.0, 12.0)
        if rng.uniform() < 0.5:
            v_lead, v_follow = math.floor(v_lead * 100) / 100, math.ceil(v_follow * 100) / 100
            length = math.ceil(length * 10) / 10
        cases.append((float(v_lead), float(v_follow), float(length)))
    for h in (Handover(ROAD_MPS), Handover(50.0 / 3.6, 1.5, 3.0, 1.5, 2.0, 0.5, 0.1)):
        found = [separation(tuple(h.driver), *c) for c in cases]
        assert found == [separation_reference(h, *c) for c in cases]
        assert all(0.0 <= x < 120.0 for x in found)


def confirm_pair(inter, exit_spacing: bool) -> Dica:
    """A right-turner near the line, then a through vehicle onto the same exit lane."""
    cfg = ControllerSpec.of(
        "enhanced", 0.25, platoon=True, headway_s=0.3, exit_spacing=exit_spacing
    )
    ica = build_controller(cfg, inter)
    ica.advance(0.0)
    for vin, lanes, d, v in (("a", RIGHT, 10.0, 25 / 3.6), ("b", THROUGH, 50.0, 15.0)):
        ica.detect(vin, lanes[0], 0.0)
        req = propose(
            inter.route(*lanes), vin=vin, seq=0, t0_s=0.0, dist_to_entry_m=d, speed_mps=v,
            config=ica.config,
        )  # fmt: skip
        assert isinstance(ica.handle(req, 0.0), Confirmation)
    return ica


def test_a_through_vehicle_leaves_fast_behind_a_right_turner_at_the_separation(ch45):
    capped = confirm_pair(ch45, exit_spacing=False).confirmed
    ica = confirm_pair(ch45, exit_spacing=True)
    a, b = ica.confirmed["a"].dtot, ica.confirmed["b"].dtot
    tol = ica.config.speed_tol_mps
    # checkFV's cap alone: no faster than the right-turner, over the whole crossing
    assert capped["b"].dtot.exit_speed_mps <= a.exit_speed_mps + tol
    # with exit spacing it leaves faster, and no sooner than the separation allows
    assert b.exit_speed_mps > a.exit_speed_mps + 5.0
    sep = ica.handover(a.route.exit_mps).separation_s(a.exit_speed_mps, b.exit_speed_mps, 5.0)
    assert b.t_s[-1] >= a.t_s[-1] + sep - 1e-9
    # it takes the fast plan because it leaves earlier, and it holds the junction less long
    assert b.t_s[-1] < capped["b"].dtot.t_s[-1]
    assert b.t_s[-1] - b.trajectory.entry_time_s() < (
        capped["b"].dtot.t_s[-1] - capped["b"].dtot.trajectory.entry_time_s()
    )


def ask_right_turner(ica: Dica, inter) -> Confirmation:
    """A right-turner 10 m before the line at its 25 km/h cap, asking at t = 0."""
    ica.advance(0.0)
    ica.detect("a", RIGHT[0], 0.0)
    req = propose(
        inter.route(*RIGHT), vin="a", seq=0, t0_s=0.0, dist_to_entry_m=10.0, speed_mps=25 / 3.6,
        config=ica.config,
    )  # fmt: skip
    conf = ica.handle(req, 0.0)
    assert isinstance(conf, Confirmation)
    return conf


def ask_through(ica: Dica, inter, t: float) -> Confirmation:
    """A through vehicle onto the right-turner's exit lane, 30 m out at 15 m/s at ``t``."""
    ica.detect("c", THROUGH[0], t)
    req = propose(
        inter.route(*THROUGH), vin="c", seq=0, t0_s=t, dist_to_entry_m=30.0, speed_mps=15.0,
        config=ica.config,
    )  # fmt: skip
    conf = ica.handle(req, t)
    assert isinstance(conf, Confirmation)
    return conf


@pytest.mark.parametrize("pad", [0.0, 0.2])
def test_a_vehicle_that_has_left_still_spaces_the_next(ch45, pad):
    """The right-turner's reservation ends (its rear is out); a through vehicle
    asking just after still leaves late enough behind it: the ICA remembers
    recent exits, as the road's driver will still be closing in. With a time
    pad each may be that far off its plan, and the separation grows by twice it."""
    cfg = ControllerSpec.of("enhanced", 0.25, pad, platoon=True, headway_s=0.3)
    ica = build_controller(cfg, ch45)
    ask_right_turner(ica, ch45)
    a = ica.confirmed["a"].dtot
    t = float(a.end_s) + 0.01
    assert ica.advance(t) == ["a"] and "a" not in ica.confirmed
    assert ask_through(ica, ch45, t).delay_s > 0.2  # held back for the spacing
    c = ica.confirmed["c"].dtot
    assert c.exit_speed_mps > a.exit_speed_mps + 5.0
    sep = ica.handover(a.route.exit_mps).separation_s(a.exit_speed_mps, c.exit_speed_mps, 5.0)
    assert c.t_s[-1] >= a.t_s[-1] + sep + 2.0 * pad - 1e-9


@pytest.mark.sumo
def test_heavy_traffic_with_exit_spacing_is_safe_and_waits_less(tmp_path):
    """Volume 800 on the chapter 4-5 layout: zero collisions by both checks with
    and without exit spacing, and less delay from the schedule with it."""
    out = {}
    for name, extra in (("spaced", []), ("capped", ["--no-exit-spacing"])):
        rc = dica("run", "--volume", "800", "--duration", "240", "--seed", "21", "--quiet",
                  "--out", str(tmp_path / name), *extra)  # fmt: skip
        assert rc.returncode == 0, rc.stderr
        m = json.loads((tmp_path / name / "metrics.json").read_text())
        assert m["collisions"] == 0 and m["sumo_collisions"] == 0
        cfg = json.loads((tmp_path / name / "config.json").read_text())
        assert cfg["run"]["exit_spacing"] is (name == "spaced")
        out[name] = m["mean_system_delay_s"]
    assert out["spaced"] < out["capped"], out


@pytest.mark.parametrize("case", ["restarted", "remembered", "forgotten"])
def test_exits_are_remembered_across_a_restart_and_for_the_memory_s_length(ch45, tmp_path, case):
    """An ICA restarted from its journal still spaces a through vehicle behind the
    right-turner that left just before (the first advance files it among the exits);
    the memory keeps a vehicle LEFT_MEMORY_S after it left, and no longer."""
    from dica.ica.core.dica import LEFT_MEMORY_S
    from dica.ica.journal import Journal, replay

    cfg = ControllerSpec.of("enhanced", 0.25, platoon=True, headway_s=0.3)
    ica = build_controller(cfg, ch45)
    journal = Journal(tmp_path / "ica.journal")
    conf_a = ask_right_turner(ica, ch45)
    journal.detect("a", RIGHT[0], 0.0)
    journal.confirm(conf_a, 5.0, 1.8, RIGHT[0])
    journal.close()
    a = ica.confirmed["a"].dtot
    out_s = float(a.t_s[-1])
    if case == "restarted":
        ica = build_controller(cfg, ch45)
        assert replay(tmp_path / "ica.journal", ica).confirmations == 1
        t = float(a.end_s) + 0.01
    elif case == "remembered":
        ica.advance(float(a.end_s) + 0.01)
        t = out_s + LEFT_MEMORY_S - 0.05
    else:
        ica.advance(float(a.end_s) + 0.01)
        t = out_s + LEFT_MEMORY_S + 0.05
    ica.advance(t)
    assert "a" not in ica.confirmed
    remembered = ica._left.get(RIGHT[1], [])
    assert [r[2] for r in remembered] == ([] if case == "forgotten" else ["a"])
    if case == "restarted":
        ask_through(ica, ch45, t)
        c = ica.confirmed["c"].dtot
        sep = ica.handover(a.route.exit_mps).separation_s(a.exit_speed_mps, c.exit_speed_mps, 5.0)
        assert c.exit_speed_mps > a.exit_speed_mps + 5.0
        assert c.t_s[-1] >= out_s + sep - 1e-9


def test_an_exit_at_the_route_s_cap_up_to_rounding_does_not_bind_the_cap(ch45, monkeypatch):
    """A right-turner leaves at its 25 km/h cap as its samples give it (a hair under).
    For another right-turner onto that exit lane the cap does not bind, and it is
    planned once; for a through vehicle the right-turner's speed does, and it is
    planned twice (capped, and fast with exit spacing)."""
    ica = build_controller(ControllerSpec.of("enhanced", 0.25, exit_spacing=True), ch45)
    ask_right_turner(ica, ch45)
    right, through = ch45.route(*RIGHT), ch45.route(*THROUGH)
    out = ica.confirmed["a"].out_mps
    assert 0.0 < right.speed_cap_mps - out < 1e-9  # the rounding case
    assert ica.front_cap_mps(right) == right.speed_cap_mps
    assert ica.front_cap_mps(through) == out  # a slower vehicle ahead binds

    caps: list[float] = []
    rounds = Search.rounds

    def counted(self: Search, cap: float, *args, **kw):
        caps.append(cap)
        return rounds(self, cap, *args, **kw)

    monkeypatch.setattr(Search, "rounds", counted)
    ica.detect("d", RIGHT[0], 0.5)  # behind "a", which has begun to enter by t = 2
    req = propose(
        right, vin="d", seq=0, t0_s=2.0, dist_to_entry_m=40.0, speed_mps=25 / 3.6,
        config=ica.config,
    )  # fmt: skip
    assert isinstance(ica.handle(req, 2.0), Confirmation)
    assert caps == [right.speed_cap_mps]
    caps.clear()
    ask_through(ica, ch45, 2.0)
    assert caps == [out, through.speed_cap_mps]


@pytest.mark.parametrize(("under_cap", "binds"), [(1e-10, False), (1e-8, True)])
def test_the_rounding_allowance_is_1e_9_m_s_and_no_more(ch45, monkeypatch, under_cap, binds):
    """Either side of the allowance: an exit 1e-10 m/s under the route's cap does not
    bind the cap, one 1e-8 m/s under does."""
    ica = build_controller(ControllerSpec.of("enhanced", 0.25, exit_spacing=True), ch45)
    right = ch45.route(*RIGHT)
    v_out = right.speed_cap_mps - under_cap
    monkeypatch.setattr(Dica, "_exits", lambda self, lane: [(5.0, v_out, "a")])
    assert ica.front_cap_mps(right) == (v_out if binds else right.speed_cap_mps)
