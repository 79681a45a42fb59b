"""Emergency vehicles in the demand and the metrics, the reactive light's program and
pre-emption, and the vehicle machine's revocation hook; no SUMO."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Tss
from dica.sim_gateway.demand import DemandSpec, make_arrivals
from dica.sim_gateway.metrics import Trip, TripLog, summarize_ev
from dica.sim_gateway.signals import (
    HOLD,
    REACTIVE_GREEN_S,
    REACTIVE_RED_S,
    REACTIVE_YELLOW_S,
    Preemption,
    phases_of,
    reactive_phases,
)
from dica.vehicle_agent.machine import Phase, Vehicle

# netconvert's plan for the chapter 4-5 junction: through and right for N-S, N-S left,
# the same for E-W (links 3, 7, 11, 15 are the left turns)
PLAN = [
    "GGGgrrrrGGGgrrrr",
    "yyygrrrryyygrrrr",
    "rrrGrrrrrrrGrrrr",
    "rrryrrrrrrryrrrr",
    "rrrrGGGgrrrrGGGg",
    "rrrryyygrrrryyyg",
    "rrrrrrrGrrrrrrrG",
    "rrrrrrryrrrrrrry",
]


def test_ev_candidates_leave_the_rest_of_the_demand_unchanged(ch45):
    plain = make_arrivals(ch45, DemandSpec(volume_per_10min=400, n_vehicles=500, seed=21), 0.05)
    with_ev = make_arrivals(
        ch45, DemandSpec(volume_per_10min=400, n_vehicles=500, seed=21, ev_prob=0.2), 0.05
    )
    assert not any(a.ev for a in plain)
    key = [(a.vin, a.route.id, a.arrival_s, a.speed_mps) for a in plain]
    assert key == [(a.vin, a.route.id, a.arrival_s, a.speed_mps) for a in with_ev]
    share = np.mean([a.ev for a in with_ev])
    assert 0.14 < share < 0.26


def test_the_ev_probability_is_checked():
    with pytest.raises(ValueError, match="not in"):
        DemandSpec(ev_prob=-0.1)


def test_evs_and_the_others_are_summarised_apart():
    log = TripLog()
    log.trips["a"] = Trip("a", "r", "through", 0.0, 1.0, 9.0, 6.0, ev=True)
    log.trips["b"] = Trip("b", "r", "through", 0.0, 1.0, 5.0, 4.0, ev=False)
    log.trips["c"] = Trip("c", "r", "through", 2.0, 3.0, 11.0, 4.0, stopped=True)
    log.trips["d"] = Trip("d", "r", "left", 5.0, ev=True)  # never left
    s = summarize_ev(log, 100.0)
    assert s["ev"]["generated"] == 2 and s["ev"]["crossed"] == 1
    assert s["ev"]["mean_trip_time_s"] == 8.0 and s["ev"]["mean_delay_s"] == 2.0
    assert s["ev"]["mean_trip_time_from_arrival_s"] == 9.0
    assert s["normal"]["mean_trip_time_s"] == 6.0 and s["normal"]["max_trip_time_s"] == 8.0
    assert s["normal"]["stopped_rate"] == 0.5


def _program(states: list[str], durations: list[float] | None = None):
    return phases_of(durations or [30.0 if "y" not in s else 3.0 for s in states], states)


def test_the_reactive_program_is_31_green_13_yellow_83_red_for_the_main_movements():
    d = [ph.duration_s for ph in reactive_phases(_program(PLAN))]
    assert d == [31.0, 13.0, 6.5, 13.0, 31.0, 13.0, 6.5, 13.0]
    through = 0  # link 0: north approach, green in phase 0 only
    green = sum(x for x, s in zip(d, PLAN, strict=True) if s[through] in "Gg")
    yellow = sum(x for x, s in zip(d, PLAN, strict=True) if s[through] == "y")
    assert (green, yellow, sum(d) - green - yellow) == (
        REACTIVE_GREEN_S,
        REACTIVE_YELLOW_S,
        REACTIVE_RED_S,
    )


def test_pre_emption_extends_returns_or_cuts_and_keeps_clearances():
    pre = Preemption(reactive_phases(_program(PLAN)))
    north_through, east_through = [0], [4]
    assert pre.steps(0, 10.0, north_through) == [(0, HOLD)]  # extend the green
    assert pre.steps(1, 5.0, north_through) == [(0, HOLD)]  # back from yellow to green
    # red for the EV: every green not green in the EV's phase, the permissive left
    # included, goes to the full yellow, then the EV's green
    yellow = "yyyyrrrryyyyrrrr"
    assert pre.steps(0, 20.0, east_through) == [(yellow, REACTIVE_YELLOW_S), (4, HOLD)]
    # a yellow already running finishes (what is left of it), then the EV's green
    assert pre.steps(3, 4.0, east_through) == [("rrryrrrrrrryrrrr", 4.0), (4, HOLD)]
    # the protected left gets its 'G' phase, not the permissive one
    assert pre.target([3]) == 2


def test_all_red_phases_are_kept_when_cutting():
    plan = ["GGrr", "yyrr", "rrrr", "rrGG", "rryy", "rrrr"]
    pre = Preemption(_program(plan, [30.0, 3.0, 2.0, 30.0, 3.0, 2.0]))
    assert pre.steps(0, 12.0, [2]) == [("yyrr", 3.0), ("rrrr", 2.0), (3, HOLD)]
    assert pre.steps(2, 1.0, [2]) == [("rrrr", 1.0), (3, HOLD)]  # an all-red running finishes


# the chapter 4-5 junction's reactive program (protected lefts keep a permissive 'g'
# through the main yellow and its all-red, into their own green)
CH45 = [
    (31.0, "GGGgrrrrGGGgrrrr"), (13.0, "yyygrrrryyygrrrr"), (2.286, "rrrgrrrrrrrgrrrr"),
    (5.0, "rrrGrrrrrrrGrrrr"), (13.0, "rrryrrrrrrryrrrr"), (2.856, "rrrrrrrrrrrrrrrr"),
    (31.0, "rrrrGGGgrrrrGGGg"), (13.0, "rrrryyygrrrryyyg"), (2.286, "rrrrrrrgrrrrrrrg"),
    (5.0, "rrrrrrrGrrrrrrrG"), (13.0, "rrrrrrryrrrrrrry"), (2.856, "rrrrrrrrrrrrrrrr"),
]  # fmt: skip


@pytest.mark.parametrize("program", [CH45, [(30.0 if "y" not in s else 3.0, s) for s in PLAN]])
def test_no_cut_turns_a_green_red_without_its_full_yellow_and_all_red(program):
    """From every phase, with any time left, for every movement an EV may need: no
    movement goes from green to red without the full yellow, and none gets green
    before the longest all-red has passed since the last yellow ended."""
    phases = _program([s for _, s in program], [d for d, _ in program])
    pre = Preemption(phases)
    for phase in range(len(program)):
        for link in range(len(program[0][1])):
            for left in (0.05, 1.0, 40.0):
                seq = pre.steps(phase, left, [link])
                shown = [(program[phase][1], left)]
                shown += [(k if isinstance(k, str) else program[k][1], d) for k, d in seq]
                for (a, _), (b, _) in itertools.pairwise(shown):
                    for i, (x, y) in enumerate(zip(a, b, strict=True)):
                        assert not (x in "Gg" and y == "r"), (phase, link, i, seq)
                start, end = shown[0][0], shown[-1][0]
                for i in range(len(start)):
                    if start[i] in "Gg" and end[i] == "r":  # it is stopped: a full yellow
                        assert any(st[i] == "y" and d >= pre.yellow_s for st, d in shown[1:])
                assert seq[-1][1] is HOLD and program[seq[-1][0]][1][link] in "Gg"


def test_the_machine_flies_a_replacement_and_drops_the_plan_without_one(ch45):
    cfg = IcaConfig()
    route = ch45.route("W_in_1", "E_out_1")
    v = Vehicle("w1", route, 5.0, 1.8, 12.0, cfg, phase=Phase.CONFIRMED, last_seq=0)
    old = _confirmation(route, cfg, t0=0.0, d=40.0, speed=12.0)
    v.confirmation = old
    new = _confirmation(route, cfg, t0=1.0, d=28.0, speed=12.0, seq=1)
    cmd = v.revoked(new, 1.0)
    # the new plan goes to the actuator under its own (next) seq, like any answer
    assert v.held is cmd and v.phase is Phase.REQUESTING and v.last_seq == 1
    assert cmd.seq == 1 and cmd.t0_s == 1.0 and cmd.has_plan and not cmd.drop
    # a replacement that starts later: the old plan is flown until then, as one plan
    later = _confirmation(route, cfg, t0=1.5, d=22.0, speed=12.0, seq=1)
    v.confirmation = old
    cmd = v.revoked(later, 1.0)
    assert cmd.t0_s == 1.0 and len(cmd.s_m) == len(later.tss.t_s) + 10
    s_old, _ = route.project(np.stack([old.tss.x_m, old.tss.y_m], -1))
    assert np.allclose(cmd.s_m[:10], s_old[20:30])  # where the old plan has it from t = 1 s
    s_new, _ = route.project(np.stack([later.tss.x_m, later.tss.y_m], -1))
    assert np.allclose(cmd.s_m[10:], np.maximum.accumulate(s_new))  # then the new plan
    v.confirmation, v.held = old, None
    stop = v.revoked(None, 2.0)
    assert v.confirmation is None and v.phase is Phase.REQUESTING and v.next_request_s == 2.0
    assert stop.drop and not stop.has_plan  # the actuator stops it short of the line


def _confirmation(route, cfg, t0, d, speed, seq=0) -> Confirmation:
    req = propose(route, vin="w1", seq=seq, t0_s=t0, dist_to_entry_m=d, speed_mps=speed, config=cfg)
    tss = Tss(req.tss.t_s, req.tss.x_m, req.tss.y_m, req.tss.heading_rad)
    return Confirmation("w1", seq, route.id, tss, t0 + 2.0, t0 + 4.0, 0.0, 1)
