"""Human drivers beside connected vehicles: the envelope a human may take through the
junction (pure), the green the ICA gives it (pure), and mixed runs in real SUMO, where
an audit that trusts none of it checks every human against its light and its bounds."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica, padded
from dica.ica.core.dtot import Dtot
from dica.ica.core.envelope import (
    KRAUSS_DECEL_MPS2,
    KRAUSS_TAU_S,
    DriverLimits,
    bounds,
    bounds_from,
    bounds_rolling,
    bounds_seen,
    envelope_dtot,
    follow_delay,
    follow_delay_numpy,
    human_limits,
    path_s,
    profile,
)
from dica.ica.core.occupancy import footprints, overlap_matrix
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Reason, RequestError
from dica.ica.core.zones import Shape
from dica.tools.loopback import free_port
from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
STEP = 0.05
LIMITS = DriverLimits()


def _lane_with_turns(inter):
    """An approach lane with more than one route for cars (a human may take any)."""
    for r in inter.routes:
        if len([x for x in inter.routes_from(r.in_lane) if x.cars]) > 1:
            return r.in_lane
    raise AssertionError("no lane with several routes")


# -- the envelope (pure) -------------------------------------------------------------
def test_the_fast_bound_is_ahead_of_the_slow_one_and_both_leave(ch45):
    for route in ch45.routes:
        fast, slow = bounds(route, 5.0, 10.0, STEP, LIMITS)
        t = np.arange(10.0, fast.t_s[-1], STEP)  # until the fast one is out (then held)
        ahead = np.array([path_s(fast, x) - path_s(slow, x) for x in t])
        assert (ahead >= -1e-9).all()
        # both from the head; the fast one a step ahead (SUMO's Euler step), the slow one
        # standing through the reaction time, and the fast one never beats its type
        assert slow.s_m[0] == pytest.approx(-0.5) and -0.5 < fast.s_m[0] < -0.49
        end = route.cross_length_m + 5.0
        assert fast.s_m[-1] >= end and slow.s_m[-1] >= end  # both until the rear is out
        assert path_s(slow, 10.0 + LIMITS.react_s - 1e-6) == pytest.approx(-0.5)
        assert np.diff(fast.s_m).max() / STEP <= LIMITS.top_mps + 1e-9


def _covered(env: Dtot, route, t: float, s: float, shape: Shape) -> bool:
    """Is the body of a car with its front at ``s`` at ``t`` inside the union of the
    envelope's footprints whose intervals hold ``t``? (corners and centre, body without
    margin, footprints with it)."""
    body = footprints(route, np.array([s]), shape.length_m, shape.width_m)
    pts = np.vstack([body.corners()[0], body.centre])
    live = (env.lb_s <= t + 1e-9) & (t - 1e-9 <= env.ub_s)
    r = env.rects.take(np.flatnonzero(live))
    if len(r) == 0:
        return False
    d = pts[:, None, :] - r.centre[None, :, :]
    along = np.abs((d * r.heading[None]).sum(-1))
    normal = np.stack([-r.heading[:, 1], r.heading[:, 0]], -1)
    across = np.abs((d * normal[None]).sum(-1))
    inside = (along <= r.half_length + 1e-6) & (across <= r.half_width + 1e-6)
    return bool(inside.any(axis=1).all())


@pytest.mark.parametrize("seed", [1, 2])
def test_every_crossing_between_the_bounds_stays_inside_the_envelope(ch45, seed):
    """Drivers who move at any moment up to the reaction time, accelerate anywhere
    between the dawdler's and the full rate and cruise anywhere between the lowest and
    the highest speed: at every moment in continuous time (a quarter step apart), the
    body is inside footprints the envelope holds at that moment."""
    rng = np.random.default_rng(seed)
    cfg = IcaConfig()
    shape = Shape.of(4.5, 1.8)
    slow_a = (1.0 - LIMITS.sigma) * LIMITS.accel_mps2
    for route in ch45.routes:
        fast, slow = bounds(route, shape.length_m, 0.0, STEP, LIMITS)
        env = envelope_dtot(route, shape, fast, slow, cfg.margin_m)
        end = route.cross_length_m + shape.length_m
        for _ in range(6):
            wait = rng.uniform(-STEP, LIMITS.react_s)
            accel = rng.uniform(slow_a, LIMITS.accel_mps2)
            top = rng.uniform(LIMITS.slow_mps(route, STEP), LIMITS.top_mps)
            drv = profile(0.0, STEP, -0.5, end, wait, accel, top)
            for t in np.arange(0.0, drv.t_s[-1], STEP / 4):
                s = path_s(drv, t)
                if s <= 0.0 or s - shape.length_m >= route.cross_length_m:
                    continue  # not in the junction
                assert path_s(slow, t) - 1e-9 <= s <= path_s(fast, t) + 1e-9
                assert _covered(env, route, t, s, shape), (route.id, t, s)


def _krauss(rng, t0: float, s0: float, v0: float, n: int, accel: float, sigma: float,
            vmax: float, wait: int = 0) -> np.ndarray:  # fmt: skip
    """SUMO's Krauss on a clear road, step by step: the speed gains ``accel * step`` up
    to ``vmax``, less a dawdle of up to ``sigma * accel * step`` (of ``sigma * speed *
    step`` below ``accel``), the new speed carrying it over the step. Positions."""
    s, v, out = s0, v0, [s0]
    for k in range(n):
        if k < wait:
            out.append(s)
            continue
        want = min(v + accel * STEP, vmax)
        cut = sigma * (want if want < accel else accel) * STEP * rng.random()
        v = max(0.0, want - cut)
        s += v * STEP
        out.append(s)
    return np.array(out)


def test_krauss_drivers_stay_between_the_bounds_from_where_they_are_seen(ch45):
    """Drivers simulated the way SUMO's Krauss moves them (each with its own speed
    factor and random dawdling), seen at some moment at some speed: from there on each
    is never ahead of the fast bound nor behind the slow one."""
    rng = np.random.default_rng(5)
    for route in ch45.routes:
        cap = min(route.road_mps, route.exit_mps, route.via_mps)
        for _ in range(8):
            f = rng.uniform(LIMITS.speed_factor_min, LIMITS.speed_factor_max)
            v0 = rng.uniform(0.0, f * cap)
            s0 = rng.uniform(-0.5, route.cross_length_m)
            fast, slow = bounds_from(route, 4.5, 3.0, s0, v0, STEP, LIMITS)
            n = len(slow) + 5
            drv = _krauss(rng, 3.0, s0, v0, n, LIMITS.accel_mps2, LIMITS.sigma, f * cap)
            t = 3.0 + STEP * np.arange(len(drv))
            keep = t <= min(fast.t_s[-1], slow.t_s[-1])
            s_fast = np.interp(t[keep], fast.t_s, fast.s_m)
            s_slow = np.interp(t[keep], slow.t_s, slow.s_m)
            assert (drv[keep] <= s_fast + 1e-9).all()
            assert (drv[keep] >= s_slow - 1e-9).all()
        # and one standing at the line, not yet moving, waits at most the reaction time
        fast, slow = bounds_from(route, 4.5, 0.0, -0.5, 0.0, STEP, LIMITS, LIMITS.react_s)
        assert path_s(slow, LIMITS.react_s) == pytest.approx(-0.5)
        assert path_s(slow, LIMITS.react_s + 0.5) > -0.5 and path_s(fast, STEP) > -0.5


def _rolling_driver(rng, route, f: float, s0: float, v0: float, brake: int, n: int):
    """A driver given its green rolling at ``v0``, ``-s0`` short of its line: it brakes on
    (at up to 4.5 m/s^2) for ``brake`` steps, as a human may before it reacts, then
    drives as SUMO's Krauss, dawdling at random, at its speed factor ``f`` of each
    lane's limit, slowing for the junction's limit (a turn) at no more than 4.5 m/s^2
    (as it was slowing for its line). Positions, a step apart."""
    turn = f * min(route.via_mps, route.exit_mps)
    s, v, out = s0, v0, [s0]
    for k in range(n):
        if k < brake:
            v = max(v - rng.uniform(0.0, 4.5) * STEP, 0.0)
        else:
            cap = turn if s >= 0.0 else min(f * route.road_mps, math.sqrt(turn**2 - 9.0 * s))
            want = min(v + LIMITS.accel_mps2 * STEP, cap)
            a = want if want < LIMITS.accel_mps2 else LIMITS.accel_mps2
            v = max(0.0, want - LIMITS.sigma * a * STEP * rng.random())
        s += v * STEP
        out.append(s)
    return np.array(out)


def test_drivers_given_their_green_rolling_stay_between_its_bounds(ch45):
    """A driver seen rolling towards its line, slowing for its red head (it could still
    stop at it at 4.5 m/s^2), given its green now: whether it brakes on for anything up
    to its reaction time (a human's) or goes at once (SUMO's Krauss, dawdling at
    random), it is never ahead of the fast bound nor behind the slow one; nor of the
    bounds from where it is seen on its way (the ICA's shrinking)."""
    rng = np.random.default_rng(8)
    for route in ch45.routes:
        for _ in range(8):
            f = rng.uniform(LIMITS.speed_factor_min, LIMITS.speed_factor_max)
            dist = rng.uniform(0.6, 60.0)
            v0 = rng.uniform(0.5, min(f * route.road_mps, math.sqrt(9.0 * dist)))
            fast, slow = bounds_rolling(route, 4.5, 2.0, STEP, LIMITS, dist, v0)
            brake = int(rng.integers(0, round(LIMITS.react_s / STEP) + 1))
            drv = _rolling_driver(rng, route, f, -dist, v0, brake, len(slow) + 5)
            t = 2.0 + STEP * np.arange(len(drv))
            keep = t <= min(fast.t_s[-1], slow.t_s[-1])
            assert (drv[keep] <= np.interp(t[keep], fast.t_s, fast.s_m) + 1e-9).all()
            assert (drv[keep] >= np.interp(t[keep], slow.t_s, slow.s_m) - 1e-9).all()
            # seen half a second on, inside its reaction time: it may still be braking
            k = round(0.5 / STEP)
            v_seen = (drv[k] - drv[k - 1]) / STEP
            f2, s2 = bounds_seen(route, 4.5, t[k], drv[k], v_seen, STEP, LIMITS, 2.0)
            on = (t >= t[k]) & (t <= min(f2.t_s[-1], s2.t_s[-1]))
            assert (drv[on] >= np.interp(t[on], s2.t_s, s2.s_m) - 1e-9).all()
            assert (drv[on] <= np.interp(t[on], f2.t_s, f2.s_m) + 1e-9).all()


def test_a_head_lit_late_keeps_its_driver_between_bounds_that_allow_for_it(ch45):
    """A head may turn green up to ``late_s`` after its green's time (the LIT's way to a
    real roadside): a driver that moves only then, and reacts after that, standing at
    its line or rolling towards it and braking all the while, stays between the bounds
    of a green given with that allowance. The bounds without it would have lost some of
    them: the allowance is what keeps them."""
    late = dataclasses.replace(LIMITS, late_s=0.4)
    moves = round(late.moves_s / STEP)  # steps until it surely moves: the worst case
    rng = np.random.default_rng(13)
    lost = 0
    for route in ch45.routes:
        cap = min(route.road_mps, route.exit_mps, route.via_mps)
        for _ in range(4):
            f = rng.uniform(LIMITS.speed_factor_min, LIMITS.speed_factor_max)
            dist = rng.uniform(0.6, 60.0)
            v0 = rng.uniform(0.5, min(f * route.road_mps, math.sqrt(9.0 * dist)))
            fast, slow = bounds_rolling(route, 4.5, 2.0, STEP, late, dist, v0)
            drv = _rolling_driver(rng, route, f, -dist, v0, moves, len(slow) + 5)
            standing = _krauss(rng, 2.0, -0.5, 0.0, len(slow) + moves, LIMITS.accel_mps2,
                               LIMITS.sigma, f * cap, moves)  # fmt: skip
            sfast, sslow = bounds(route, 4.5, 2.0, STEP, late)
            for (lo, hi), way, unlate in (
                ((slow, fast), drv, bounds_rolling(route, 4.5, 2.0, STEP, LIMITS, dist, v0)[1]),
                ((sslow, sfast), standing, bounds(route, 4.5, 2.0, STEP, LIMITS)[1]),
            ):
                t = 2.0 + STEP * np.arange(len(way))
                keep = t <= min(lo.t_s[-1], hi.t_s[-1])
                assert (way[keep] <= np.interp(t[keep], hi.t_s, hi.s_m) + 1e-9).all()
                assert (way[keep] >= np.interp(t[keep], lo.t_s, lo.s_m) - 1e-9).all()
                keep = t <= unlate.t_s[-1]
                lost += bool((way[keep] < np.interp(t[keep], unlate.t_s, unlate.s_m) - 1e-6).any())
    assert lost > 0


def test_a_rolling_green_is_now_or_none_and_never_behind_a_slow_leader(ch45):
    """A driver rolling towards its line is given its green at once if every envelope
    fits now, else refused (it stops and asks standing, when it may be given a later
    one); and refused while it would catch up with the vehicle ahead in its lane."""
    lane = _lane_with_turns(ch45)
    shape = Shape.of(4.5, 1.8)
    ica = Dica(ch45, IcaConfig())
    ica.detect("h", lane, 0.0)
    g = ica.green("h", 0.0, shape.length_m, shape.width_m, LIMITS, 30.0, 12.0)
    assert g.green_s == 0.0 and g.speed_mps == 12.0 and g.near_m == 30.0
    # the reservations are the rolling bounds': the driver enters sooner than from a stop
    standing = Dica(ch45, IcaConfig())
    standing.detect("h", lane, 0.0)
    g0 = standing.green("h", 0.0, shape.length_m, shape.width_m, LIMITS, 0.5)
    assert ica.confirmed["h"].confirmation.exit_time_s < 10.0
    assert g0.speed_mps == 0.0
    # in the way of a connected vehicle: refused now (not a later green), given standing
    busy, _other = _cav_in_the_way(ch45, lane, shape)
    busy.detect("h", lane, 0.0)
    with pytest.raises(RequestError) as e:
        busy.green("h", 0.0, shape.length_m, shape.width_m, LIMITS, 5.0, 6.0)
    assert e.value.reason == Reason.INFEASIBLE and "h" not in busy.greens
    assert busy.green("h", 0.0, shape.length_m, shape.width_m, LIMITS).green_s > 0.0
    # behind a human in its lane that has just started from the line: refused at speed,
    # and given once that one is far enough ahead
    lead = Dica(ch45, IcaConfig())
    lead.detect("a", lane, 0.0)
    lead.detect("b", lane, 0.1)
    lead.green("a", 0.0, shape.length_m, shape.width_m, LIMITS)
    lead.advance(0.5)
    with pytest.raises(RequestError):
        lead.green("b", 0.5, shape.length_m, shape.width_m, LIMITS, 25.0, 14.0)
    later = 16.0  # gone out well ahead by then (the ICA remembers it: it may still catch it)
    lead.advance(later)
    assert lead.green("b", later, shape.length_m, shape.width_m, LIMITS, 25.0, 14.0)
    ica.detect("x", ch45.routes[-1].in_lane, 0.0)
    with pytest.raises(RequestError) as e:
        ica.green("x", 0.0, 4.5, 1.8, LIMITS, 80.0, 12.0)  # farther than a rolling ask
    assert e.value.reason == Reason.BAD_STATE
    with pytest.raises(RequestError) as e:  # too fast to stop at its line at 4.5 m/s^2
        ica.green("x", 0.0, 4.5, 1.8, LIMITS, 10.0, 12.0)
    assert e.value.reason == Reason.INFEASIBLE
    # each limit, and one past it: 60 m out, and as fast as still stops at 4.5 m/s^2
    for dist, v, ok in (
        (60.0, 12.0, True),
        (60.01, 12.0, False),
        (10.0, math.sqrt(90.0) - 1e-9, True),
        (10.0, math.sqrt(90.0) + 0.01, False),
    ):
        edge = Dica(ch45, IcaConfig())
        edge.detect("y", lane, 0.0)
        if ok:
            assert edge.green("y", 0.0, 4.5, 1.8, LIMITS, dist, v).speed_mps == v
        else:
            with pytest.raises(RequestError):
                edge.green("y", 0.0, 4.5, 1.8, LIMITS, dist, v)


def test_a_follower_let_go_after_its_follow_delay_never_brakes_inside(ch45):
    """A human behind a slow one on the same route: at once it would catch up inside
    the junction; given the delay :func:`follow_delay` asks, a Krauss driver at full
    acceleration (the fastest it can be) behind the leader at its slowest never has
    its safe speed below its own."""
    route = next(r for r in ch45.routes if r.turn.value == "through")
    _, lead = bounds(route, 4.5, 0.0, STEP, LIMITS)
    fast, _ = bounds(route, 4.5, 0.0, STEP, LIMITS)
    assert follow_delay(fast, route.cross_length_m, 4.5, lead, route.cross_length_m, 4.5) > 1.0
    late = 0.0
    for _ in range(200):  # as the green's search does: shift by what it asks, again
        f, _ = bounds(route, 4.5, late, STEP, LIMITS)
        d = follow_delay(f, route.cross_length_m, 4.5, lead, route.cross_length_m, 4.5)
        if d == 0.0:
            break
        late += d
    assert d == 0.0
    f, _ = bounds(route, 4.5, late, STEP, LIMITS)
    t = f.t_s
    u_f = f.s_m - route.cross_length_m
    inside = u_f - 4.5 < 0.0
    rear = np.interp(t, lead.t_s, lead.s_m) - route.cross_length_m - 4.5
    after = t > lead.t_s[-1]
    v_end = (lead.s_m[-1] - lead.s_m[-2]) / STEP
    rear = np.where(after, lead.s_m[-1] - route.cross_length_m - 4.5
                    + v_end * (t - lead.t_s[-1]), rear)  # fmt: skip
    assert (rear[inside] - u_f[inside] >= 2.5 - 1e-9).all()  # never closer than SUMO's minGap


def test_the_compiled_follow_delay_is_numpys(ch45):
    """The kernel the searches call against the numpy reference (to within 1e-9 s): real
    bounds of every pair of routes onto one exit lane at staggered greens, and random
    trajectories (rising, falling behind, one sample long), watched from the start or
    the line."""
    from dica.ica.core.trajectory import Trajectory

    cases = []
    for a in ch45.routes:
        for b in ch45.routes:
            if a.cars and b.cars and a.out_lane == b.out_lane:
                for g in (0.0, 1.3, 2.7):
                    fast, _ = bounds(a, 4.5, g, STEP, LIMITS)
                    _, slow = bounds(b, 5.0, 0.0, STEP, LIMITS)
                    cases.append((fast, a.cross_length_m, 4.5, slow, b.cross_length_m, 5.0))
    rng = np.random.default_rng(27)
    for _ in range(400):
        nf, nl = int(rng.integers(2, 300)), int(rng.integers(1, 200))
        f = Trajectory(
            float(rng.uniform(0, 20)),
            STEP,
            np.cumsum(np.abs(rng.normal(0.6, 0.4, nf))) + rng.uniform(-60, 10),
        )
        lead = Trajectory(
            float(rng.uniform(0, 20)),
            STEP,
            np.cumsum(np.abs(rng.normal(0.4, 0.4, nl))) + rng.uniform(-20, 40),
        )
        cases.append((f, float(rng.uniform(10, 40)), float(rng.uniform(3, 12)), lead,
                      float(rng.uniform(10, 40)), float(rng.uniform(3, 12))))  # fmt: skip
    nonzero = 0
    for case in cases:
        for from_m in (-np.inf, 0.0):
            want = follow_delay_numpy(*case, from_m)
            # the same arithmetic in the same order (bit for bit here); another CPU's numpy
            # may round a last bit otherwise, far below a step's 0.05 s
            assert follow_delay(*case, from_m) == pytest.approx(want, rel=0.0, abs=1e-9)
            nonzero += want > 0.0
    assert nonzero > len(cases) // 2


def _merging_lanes(inter) -> tuple[str, str, str]:
    """Two approach lanes with car routes onto one exit lane: (lane a, lane b, exit)."""
    for a in inter.routes:
        for b in inter.routes:
            if a.cars and b.cars and a.in_lane != b.in_lane and a.out_lane == b.out_lane:
                return a.in_lane, b.in_lane, a.out_lane
    raise AssertionError("no two lanes lead onto one exit lane")


def _never_brakes_behind(follower, f_route, lead, l_route, length_m: float = 4.5) -> bool:
    """By SUMO's safe speed, step by step (not by the ICA's function): ``follower``
    (a trajectory on ``f_route``) never comes closer than the standstill gap behind
    ``lead`` (on ``l_route``, carried on at its last speed) nor faster than its safe
    speed behind it while inside the junction (from its entry line until its rear is
    out). Both measured from the exit line."""
    tb = KRAUSS_TAU_S * KRAUSS_DECEL_MPS2
    u = follower.s_m - f_route.cross_length_m
    inside = (u - length_m < 0.0) & (follower.s_m >= 0.0)  # past its line, rear not out
    rear = np.interp(follower.t_s, lead.t_s, lead.s_m) - l_route.cross_length_m - length_m
    v_lead = (lead.s_m[-1] - lead.s_m[-2]) / STEP
    late = follower.t_s > lead.t_s[-1]
    rear[late] = (lead.s_m[-1] - l_route.cross_length_m - length_m
                  + v_lead * (follower.t_s[late] - lead.t_s[-1]))  # fmt: skip
    gap = rear - u - 2.5
    v = np.append(np.diff(follower.s_m) / STEP, 0.0)
    safe = -tb + np.sqrt(tb * tb + v_lead * v_lead + 2 * KRAUSS_DECEL_MPS2 * np.maximum(gap, 0))
    return bool((gap[inside] >= 0.0).all() and (v[inside] <= safe[inside] + 1e-9).all())


@pytest.mark.parametrize("later", ["human", "plan", "plan-sooner"])
def test_a_human_may_go_ahead_of_a_later_vehicle_onto_its_exit_lane(ch45, later):
    """Human b holds a green 20 s from now (or a connected vehicle a plan that enters
    about 22 s from now) onto the exit lane of human a, who asks now: a goes at once,
    ahead of it (it used to wait until it had gone), because at its fastest it never
    comes close enough behind a at its slowest to brake inside the junction (by SUMO's
    safe speed, step by step), and their reservations meet nowhere (brute force). A
    plan that enters about 12 s from now would catch a up inside: a waits for it."""
    lane_a, lane_b, out = _merging_lanes(ch45)
    shape = Shape.of(4.5, 1.8)
    rb = next(r for r in ch45.routes_from(lane_b) if r.out_lane == out)
    ica = Dica(ch45, IcaConfig())
    ica.detect("b", lane_b, 0.0)
    ica.detect("a", lane_a, 0.0)
    if later == "human":
        gb = ica.green("b", 20.0, shape.length_m, shape.width_m, LIMITS)
        held = _envelopes(ica, gb, ch45, shape)
        fast_b, _ = bounds(rb, 4.5, gb.green_s, STEP, LIMITS)
        soonest = gb.green_s
    else:
        t0 = 20.0 if later == "plan" else 10.0
        req = propose(rb, vin="b", seq=0, t0_s=t0, dist_to_entry_m=30.0, speed_mps=10.0)
        assert isinstance(ica.handle(req, t0), Confirmation)
        held, fast_b = [ica.confirmed["b"].dtot], ica.confirmed["b"].dtot.trajectory
        soonest = ica.confirmed["b"].confirmation.entry_time_s
    ga = ica.green("a", 0.0, shape.length_m, shape.width_m, LIMITS)
    if later == "plan-sooner":  # it meets nothing, but the plan would catch it inside
        assert not any(_clash(held[0], e) for e in _envelopes(ica, ga, ch45, shape))
        assert ga.green_s > soonest
        return
    assert ga.green_s < 1.0 < 20.0 <= soonest
    for ea in _envelopes(ica, ga, ch45, shape):
        assert not any(_clash(eb, ea) for eb in held)
    for ra in (r for r in ch45.routes_from(lane_a) if r.out_lane == out):
        _, slow_a = bounds(ra, 4.5, ga.green_s, STEP, LIMITS)
        assert _never_brakes_behind(fast_b, rb, slow_a, ra, 4.5 if later == "human" else 5.0)


def test_a_plan_onto_a_humans_exit_lane_never_has_either_brake_inside(ch45):
    """Human a holds a green at 0 onto an exit lane; a connected vehicle from the other
    lane onto it asks for a plan from t0: whether it goes ahead of a or behind, by
    SUMO's safe speed step by step the one behind never brakes inside the junction (a
    at its fastest behind the plan, or the plan behind a at its slowest). The rule
    binds: at some t0 it is planned later than on an empty junction."""
    later = []
    for t0 in (0.0, 2.0, 4.0, 8.0):
        req, done = _plan_behind_a_green(ch45, t0, 30.0, 10.0)
        assert isinstance(done, Confirmation)
        bare = Dica(ch45, IcaConfig())
        bare.detect("b", req.in_lane, 0.0)
        free = bare.handle(req, t0).entry_time_s
        later.append(done.entry_time_s - free)
    assert max(later) > 1.0


def _plan_behind_a_green(ch45, t0: float, dist_m: float, speed_mps: float | None = None):
    """Human a holds a green at 0 onto an exit lane; connected vehicle b, from another
    lane onto it, asks at ``t0``, ``dist_m`` out at ``speed_mps`` (default: the road's
    speed): b's request and the ICA's answer. If b was confirmed, it is checked first
    by SUMO's safe speed step by step: whether b goes ahead of a or behind, the one
    behind never brakes inside the junction (a at its fastest behind the plan, or the
    plan behind a at its slowest)."""
    lane_a, lane_b, out = _merging_lanes(ch45)
    shape = Shape.of(4.5, 1.8)
    rb = next(r for r in ch45.routes_from(lane_b) if r.out_lane == out)
    ica = Dica(ch45, IcaConfig())
    ica.detect("a", lane_a, 0.0)
    ica.detect("b", lane_b, 0.0)
    ga = ica.green("a", 0.0, shape.length_m, shape.width_m, LIMITS)
    v = rb.road_mps if speed_mps is None else speed_mps
    req = propose(rb, vin="b", seq=0, t0_s=t0, dist_to_entry_m=dist_m, speed_mps=v)
    done = ica.handle(req, t0)
    if isinstance(done, Confirmation):
        plan = ica.confirmed["b"].dtot.trajectory
        for ra in (r for r in ch45.routes_from(lane_a) if r.out_lane == out):
            fast_a, slow_a = bounds(ra, 4.5, ga.green_s, STEP, LIMITS)
            assert _never_brakes_behind(fast_a, ra, plan, rb) or _never_brakes_behind(
                plan, rb, slow_a, ra, 5.0
            )
    return req, done


@pytest.mark.parametrize("t0", [1.0, 2.0, 3.0, 4.0, 5.0])
def test_a_fast_approach_behind_a_crossing_human_is_planned_in_a_few_rounds(ch45, t0):
    """A connected vehicle 50 m out at the road's speed while a human crosses onto its
    exit lane: its plan is found in a few rounds, and neither brakes inside behind the
    other. (Watching the plan's samples on its approach as if it followed the human
    there asked the same delay round after round, since a delay cannot move where the
    vehicle already is: the search crawled for hundreds of rounds.)"""
    _, done = _plan_behind_a_green(ch45, t0, 50.0)
    assert isinstance(done, Confirmation), done
    assert done.iterations <= 10


def _clash(stored: Dtot, new: Dtot) -> bool:
    """The ICA's rule, by brute force: an occupancy of ``new`` overlaps one of
    ``stored`` (padded as stored) in space while their intervals overlap in time."""
    space = overlap_matrix(new.rects, stored.rects)
    time = (new.lb_s[:, None] <= stored.ub_s[None]) & (stored.lb_s[None] <= new.ub_s[:, None])
    return bool((space & time).any())


def _envelopes(ica: Dica, green, inter, shape: Shape) -> list[Dtot]:
    """The green's envelope DTOTs, rebuilt from its figures (unpadded)."""
    out = []
    for rid in green.routes:
        r = next(x for x in inter.routes if x.id == rid)
        fast, slow = bounds(r, shape.length_m, green.green_s, STEP, LIMITS)
        out.append(envelope_dtot(r, shape, fast, slow, ica.config.margin_m))
    return out


# -- the green (pure) ----------------------------------------------------------------
def test_a_green_reserves_every_route_of_the_lane_and_is_asked_again_alike(ch45):
    ica = Dica(ch45, IcaConfig())
    lane = _lane_with_turns(ch45)
    with pytest.raises(RequestError) as e:
        ica.green("h", 0.0, 4.5, 1.8, LIMITS)
    assert e.value.reason == Reason.NOT_DETECTED
    ica.detect("h", lane, 0.0)
    ica.detect("h2", lane, 0.0)
    with pytest.raises(RequestError) as e:
        ica.green("h2", 0.0, 4.5, 1.8, LIMITS)
    assert e.value.reason == Reason.NOT_HEAD
    with pytest.raises(RequestError) as e:
        ica.green("h", 0.0, 4.5, 1.8, LIMITS, dist_m=-1.0)
    assert e.value.reason == Reason.BAD_STATE
    g = ica.green("h", 3.0, 4.5, 1.8, LIMITS)
    routes = {r.id for r in ch45.routes_from(lane) if r.cars}
    assert g.green_s == 3.0 and set(g.routes) == routes and len(g.keys) == len(routes)
    assert all(k in ica.confirmed for k in g.keys) and "h" in g.keys
    assert ica.green("h", 4.0, 4.5, 1.8, LIMITS) is g  # a repeat: the same green
    assert len(ica.confirmed) == len(routes)


def test_a_journal_replays_rolling_and_late_greens_and_the_dropped_ones(ch45, tmp_path):
    """Journalled greens come back as given: one given rolling (its speed and distance),
    one under a late-head allowance (wider at its slow end), and a dropped one stays
    dropped: the restarted core holds the same reservations, occupancy for occupancy."""
    from dica.ica.journal import Journal, replay
    from dica.schemas.codec import now_ns
    from dica.schemas.messages import Lit

    cfg = IcaConfig(green_late_s=0.4)
    limits = human_limits(cfg.caps.road_mps, cfg.green_late_s)
    lanes = []
    for r in ch45.routes:
        if r.cars and r.in_lane not in lanes:
            lanes.append(r.in_lane)
    ica, path = Dica(ch45, cfg), tmp_path / "j.msgpack"
    j = Journal(path, sync=False)
    given = {}
    for vin, lane, dist, v in (("roll", lanes[0], 30.0, 12.0), ("stand", lanes[1], 0.5, 0.0),
                               ("gone", lanes[2], 0.5, 0.0)):  # fmt: skip
        ica.detect(vin, lane, 0.0)
        j.detect(vin, lane, 0.0)
        j.human(vin)
        g = ica.green(vin, 1.0, 4.5, 1.8, limits, dist, v)
        j.green(Lit(vin, g.green_s, g.asked_s, g.near_m, 4.5, 1.8, g.routes, now_ns(),
                    limits.top_mps, cfg.step_s, g.speed_mps, limits.late_s))  # fmt: skip
        given[vin] = g
    assert ica.unlight("gone", given["gone"].green_s)
    j.unlit("gone", given["gone"].green_s)
    j.close()
    back = Dica(ch45, cfg)
    done = replay(path, back)
    assert done.greens == 3 and done.skipped == 0
    assert set(back.greens) == {"roll", "stand"} and back.greens["roll"].speed_mps == 12.0
    assert set(back.confirmed) == set(ica.confirmed)
    for k, c in ica.confirmed.items():
        d = back.confirmed[k].dtot
        assert np.array_equal(d.lb_s, c.dtot.lb_s) and np.array_equal(d.ub_s, c.dtot.ub_s), k
    # the allowance is in them: the same greens without it end sooner at the slow end
    plain = Dica(ch45, IcaConfig())
    plain.detect("stand", lanes[1], 0.0)
    g0 = plain.green("stand", 1.0, 4.5, 1.8, human_limits(cfg.caps.road_mps), 0.5)
    ends = [back.confirmed[k].dtot.ub_s.max() for k in back.greens["stand"].keys]
    ends0 = [plain.confirmed[k].dtot.ub_s.max() for k in g0.keys]
    assert max(ends) > max(ends0) + 0.3


def test_a_green_dropped_late_frees_its_reservations_and_is_given_anew(ch45):
    """The roadside kept the head red (the LIT came too late): the green of that time
    goes with its reservations, a connected vehicle may be planned through them, and
    the driver's next ask is a new green, not the stale one. Told of a green it no
    longer holds (a repeated UNLIT), the ICA changes nothing."""
    ica = Dica(ch45, IcaConfig())
    lane = _lane_with_turns(ch45)
    ica.detect("h", lane, 0.0)
    g = ica.green("h", 3.0, 4.5, 1.8, LIMITS)
    assert not ica.unlight("h", 2.0) and ica.greens["h"] is g  # not that green
    # its UNLIT lost: asked again, the stale green comes back (the roadside drops it again)
    assert ica.green("h", 3.5, 4.5, 1.8, LIMITS) is g
    assert ica.unlight("h", 3.0)
    assert "h" not in ica.greens and not any(k in ica.confirmed for k in g.keys)
    assert not ica.unlight("h", 3.0) and ica.unlit == 1
    again = ica.green("h", 4.0, 4.5, 1.8, LIMITS)
    assert again is not g and again.green_s == 4.0
    assert all(k in ica.confirmed for k in again.keys)


def _cav_in_the_way(inter, lane: str, shape: Shape):
    """A connected vehicle's confirmation that a green given at once to a human at the
    head of ``lane`` would meet: (the ICA holding it, the route)."""
    mine = {r.out_lane for r in inter.routes_from(lane)}
    for other in inter.routes:
        if other.in_lane == lane or other.out_lane in mine:
            continue
        for dist in (10.0, 20.0, 30.0):
            ica = Dica(inter, IcaConfig())
            ica.detect("cav", other.in_lane, 0.0)
            req = propose(other, vin="cav", seq=0, t0_s=0.0, dist_to_entry_m=dist,
                          speed_mps=12.0)  # fmt: skip
            assert isinstance(ica.handle(req, 0.0), Confirmation)
            alone = Dica(inter, IcaConfig())
            alone.detect("h", lane, 0.0)
            g0 = alone.green("h", 0.0, shape.length_m, shape.width_m, LIMITS)
            assert g0.green_s == 0.0  # alone: at once
            cav = ica.confirmed["cav"].dtot
            if any(_clash(cav, e) for e in _envelopes(alone, g0, inter, shape)):
                return ica, other
    raise AssertionError("no connected vehicle crosses the lane's routes")


def test_a_green_waits_for_a_confirmed_vehicle_and_later_plans_keep_clear(ch45):
    """A connected vehicle confirmed across the lane's routes, which a green at once
    would meet, delays the green until no envelope meets it; one planned after the
    green is planned around the envelope. Both checked pairwise by brute force, not by
    the ICA's own search."""
    lane = _lane_with_turns(ch45)
    shape = Shape.of(4.5, 1.8)
    ica, other = _cav_in_the_way(ch45, lane, shape)
    ica.detect("h", lane, 0.0)
    g = ica.green("h", 0.0, shape.length_m, shape.width_m, LIMITS)
    assert g.green_s > 0.0 and g.rounds > 1
    cav = ica.confirmed["cav"].dtot
    assert not any(_clash(cav, e) for e in _envelopes(ica, g, ch45, shape))
    # a second connected vehicle, planned after the green, keeps clear of every envelope
    t = ica.confirmed["cav"].confirmation.entry_time_s + 0.1
    ica.detect("cav2", other.in_lane, 0.0)
    ica.advance(t)
    req2 = propose(other, vin="cav2", seq=0, t0_s=t, dist_to_entry_m=20.0, speed_mps=12.0)
    assert isinstance(ica.handle(req2, t), Confirmation)
    new = padded(ica.confirmed["cav2"].dtot, -2.0 * ica.config.time_pad_s)  # as asked
    assert not any(_clash(ica.confirmed[k].dtot, new) for k in g.keys)
    # and without the envelope it would have gone earlier, through it
    bare = Dica(ch45, IcaConfig())
    bare.detect("cav2", other.in_lane, 0.0)
    c2 = bare.handle(req2, t)
    assert c2.entry_time_s < ica.confirmed["cav2"].confirmation.entry_time_s


def test_a_crossing_human_seen_ahead_frees_what_it_no_longer_needs(ch45):
    """Seen on the lane of its turn, ahead of its slowest, a human's reservations shrink
    to that one route and end sooner, and a human waiting behind its envelope on a
    crossing lane, asking again, gets a sooner green that meets none of them."""
    shape = Shape.of(4.5, 1.8)
    lane = _lane_with_turns(ch45)
    mine = [r for r in ch45.routes_from(lane) if r.cars]
    took = next(r for r in mine if r.turn.value == "through")
    fast, _ = bounds(took, 4.5, 0.0, STEP, LIMITS)
    t = 2.0
    v_now = (path_s(fast, t) - path_s(fast, t - STEP)) / STEP * 0.9
    sooner = 0
    for other in sorted({r.in_lane for r in ch45.routes} - {lane}):
        ica = Dica(ch45, IcaConfig())
        ica.detect("h", lane, 0.0)
        g = ica.green("h", 0.0, 4.5, 1.8, LIMITS)
        assert len(g.keys) == len(mine) > 1
        out_before = ica.confirmed["h"].out_s
        ica.detect("w", other, 0.0)
        wg = ica.green("w", 0.0, 4.5, 1.8, LIMITS)
        # seen on its lane: all its routes still; then on the lane of its turn: that one
        assert ica.tighten("h", t, path_s(fast, t) - 0.3, v_now, lane, LIMITS) is not None
        paths = ica.tighten("h", t + 0.5, path_s(fast, t + 0.5) - 0.3, v_now + 1.1,
                            took.via_lanes[0], LIMITS)  # fmt: skip
        assert paths is not None and set(paths) == {took.id}
        assert ica.greens["h"].routes == (took.id,) and ica.greens["h"].keys == ("h",)
        assert not any(k in ica.confirmed for k in g.keys if k != "h")
        assert ica.confirmed["h"].out_s < out_before
        new = ica.regreen("w", t + 0.5, 4.5, 1.8, LIMITS)
        if new is not None:
            assert new.green_s < wg.green_s
            sooner += 1
        assert ica.greens["w"].green_s <= wg.green_s
        for e in _envelopes(ica, ica.greens["w"], ch45, shape):
            assert not _clash(ica.confirmed["h"].dtot, e)
    assert sooner >= 3


# -- mixed runs in SUMO --------------------------------------------------------------
def _run(out: Path, *args: str, code: int = 0) -> dict:
    p = dica_run([*DICA, "run", "--out", str(out), "--quiet", *args],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)  # fmt: skip
    assert p.returncode == code, p.stderr
    return json.loads((out / "metrics.json").read_text())


def _rows_csv(out: Path) -> list[dict]:
    return list(csv.DictReader((out / "vehicles.csv").open()))


@pytest.mark.sumo
def test_half_human_traffic_is_safe_and_every_human_kept_its_light(tmp_path):
    """Half the demand human drivers at the chapter 4-5 junction: zero collisions by
    both checks, no human on red or outside its envelope, everyone accounted for, and
    the demand is the one the all-connected run sees (the same vehicles at the same
    times), whose results are unchanged by naming share 1."""
    base = ("--layout", "ch45", "--volume", "300", "--seed", "21", "--duration", "300")
    m = _run(tmp_path / "mixed", *base, "--cav-share", "0.5")
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert m["unconfirmed_entries"] == 0 and m["stood_inside"] == 0
    h = m["humans"]
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert h["count"] > 40 and h["given_green"] > 30
    assert h["max_wait_for_green_s"] > 1.0  # some stood at a red head
    d = m["by_driver"]
    assert d["human"]["generated"] + d["connected"]["generated"] == m["generated"]
    assert d["human"]["crossed"] + d["connected"]["crossed"] == m["crossed"]
    a = m["accounted"]
    assert (
        a["lost"] == 0 and a["crossed"] + a["in_region"] + a["not_yet_in_region"] == a["generated"]
    )
    one = _run(tmp_path / "one", *base)
    named = _run(tmp_path / "named", *base, "--cav-share", "1")
    assert (tmp_path / "one" / "vehicles.csv").read_bytes() == (
        tmp_path / "named" / "vehicles.csv"
    ).read_bytes()
    assert one["mean_trip_time_s"] == named["mean_trip_time_s"]
    mixed, conn = _rows_csv(tmp_path / "mixed"), _rows_csv(tmp_path / "one")
    assert [(r["vin"], r["route"], r["depart_s"]) for r in mixed] == [
        (r["vin"], r["route"], r["depart_s"]) for r in conn
    ]
    humans = [r for r in mixed if r["human"] == "1"]
    assert 0.3 < len(humans) / len(mixed) < 0.7
    # one that never stopped was given its green rolling towards its line; the rest stood
    assert 0 < h["rolling_greens"] < h["given_green"]
    assert sum(r["stopped"] == "0" for r in humans if r["exited_s"]) <= h["rolling_greens"]


@pytest.mark.sumo
def test_the_recording_shows_humans_their_envelopes_and_heads(tmp_path):
    """Human drivers are drawn as such in the top view, each green's envelope holds
    conflict points in the chart and draws its fastest and slowest crossing on the lane
    chart, and the heads show red and green at the lines."""
    from dica.sim_gateway.recording.style import HEAD_GREEN_RGB, HEAD_RED_RGB, HUMAN_RGBA, rgba
    from tests.test_recording import _read, _rows

    out = tmp_path / "rec"
    _run(out, "--layout", "ch45", "--volume", "300", "--seed", "21", "--duration", "120",
         "--cav-share", "0.5", "--record")  # fmt: skip
    humans = {r["vin"] for r in _rows_csv(out) if r["human"] == "1"}
    data = _read(out / "spacetime.rrd")
    outlines = {c for _, row in _rows(data["/junction/vehicles"], "LineStrips2D:colors")
                for c in row or ()}  # fmt: skip
    assert HUMAN_RGBA in outlines and len(outlines) > 2  # connected ones in their states
    heads = {c for _, row in _rows(data["/junction/heads"], "Points2D:colors") for c in row}
    assert {rgba(HEAD_RED_RGB), rgba(HEAD_GREEN_RGB)} <= heads
    boxes = [lb.split()[0] for _, row in _rows(data["/charts/data/zones/reserved"],
             "Boxes2D:labels") for lb in row]  # fmt: skip
    assert humans & set(boxes) and set(boxes) - humans
    lines = [lb for lane in {r["route"].split("_")[0] for r in _rows_csv(out)}
             for key in data if key.startswith(f"/charts/data/lanes/{lane}_")
             and key.endswith("/plans")
             for _, row in _rows(data[key], "LineStrips2D:labels") for lb in row]  # fmt: skip
    assert any("slowest" in lb and lb.split()[0] in humans for lb in lines)


@pytest.mark.sumo
def test_human_drivers_on_a_users_net_of_other_limits(tmp_path):
    """A user's net: 40 km/h, two lanes, 150 m blocks, tighter turns than ours (its own
    turn speeds bound the slowest human): half the drivers human, nothing collides and
    no human leaves its envelope."""
    from tests.user_nets import make, tool

    net = tmp_path / "grid.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "150",
          "--default.lanenumber", "2", "--default.speed", "11.11", "--no-turnarounds", "true",
          "--default.junctions.radius", "3", "-o", str(net)])  # fmt: skip
    m = _run(tmp_path / "r", "--net", str(net), "--junction", "B1", "--volume", "250",
             "--cav-share", "0.5", "--duration", "300", "--seed", "21")  # fmt: skip
    h = m["humans"]
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert h["given_green"] > 20 and m["crossed"] > 60


FAST_ROUTES = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" width="1.8" sigma="0.5"/>
  <vType id="truck" accel="2.0" decel="4.5" length="11.0" width="2.5" maxSpeed="25"/>
  <flow id="ew" type="car" begin="0" end="300" vehsPerHour="400" from="A1B1" to="B1C1"
        departSpeed="max"/>
  <flow id="we" type="truck" begin="0" end="300" vehsPerHour="100" from="C1B1" to="B1A1"
        departSpeed="max"/>
  <flow id="ns" type="car" begin="0" end="300" vehsPerHour="300" from="B2B1" to="B1B0"
        departSpeed="max"/>
  <flow id="sn" type="car" begin="0" end="300" vehsPerHour="200" from="B0B1" to="B1A1"
        departSpeed="max"/>
</routes>
"""


@pytest.mark.sumo
def test_a_route_files_vehicles_drawn_human_keep_their_envelopes_on_a_fast_net(tmp_path):
    """A user's net at 80 km/h (above the speeds the ICA plans with) and its own route
    file with trucks: half its vehicles drawn human as they depart (the same ones in
    every run), SUMO's driver from there, their own size kept; each meets its head at
    the region and keeps its envelope (drawn at the region instead, one came faster
    than a human's top speed and braked behind its slowest bound). Nothing collides,
    every vehicle is accounted for, and
    share 1 runs the file as before, every vehicle connected."""
    from tests.user_nets import make, tool

    net = tmp_path / "fast.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "300",
          "--default.lanenumber", "2", "--default.speed", "22.22", "--no-turnarounds", "true",
          "-o", str(net)])  # fmt: skip
    routes = tmp_path / "fast.rou.xml"
    routes.write_text(FAST_ROUTES)
    scen = ("--net", str(net), "--junction", "B1", "--routes", str(routes), "--duration", "300")
    m = _run(tmp_path / "h", *scen, "--cav-share", "0.5")
    h = m["humans"]
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert 0.3 < h["count"] / m["accounted"]["generated"] < 0.7 and h["given_green"] > 30
    assert m["accounted"]["lost"] == 0
    humans = {r["vin"] for r in _rows_csv(tmp_path / "h") if r["human"] == "1"}
    assert any(v.startswith("we.") for v in humans)  # trucks among them, at their size
    again = _run(tmp_path / "h2", *scen, "--cav-share", "0.5")
    assert again["humans"]["count"] == h["count"]  # the same draw
    m1 = _run(tmp_path / "c", *scen)
    assert "humans" not in m1 and m1["collisions"] == 0


@pytest.mark.sumo
def test_a_net_whose_turns_are_longer_than_drawn_keeps_every_human_in_its_envelope(tmp_path):
    """A spider net, whose internal lanes SUMO drives up to 4 % longer than their drawn
    shapes: route positions follow SUMO's lengths, so no human drifts ahead of its
    fastest crossing near the exit (seven did when positions followed the drawing)."""
    from tests.user_nets import make, tool

    net = tmp_path / "spider.net.xml"
    make([tool("netgenerate"), "--spider", "--spider.arm-number", "5",
          "--spider.circle-number", "2", "--spider.space-radius", "120",
          "--default.lanenumber", "2", "--default.speed", "13.89", "--no-turnarounds", "true",
          "-o", str(net)])  # fmt: skip
    stretch = 0.0
    for lane in ET.parse(net).getroot().iter("lane"):
        if lane.get("id", "").startswith(":A1_"):
            pts = np.array([p.split(",") for p in lane.get("shape").split()], dtype=float)
            drawn = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
            stretch = max(stretch, float(lane.get("length")) / drawn - 1.0)
    assert stretch > 0.03
    m = _run(tmp_path / "r", "--net", str(net), "--junction", "A1", "--volume", "150",
             "--cav-share", "0.5", "--duration", "300", "--seed", "21")  # fmt: skip
    h = m["humans"]
    assert h["count"] > 30 and h["outside_envelope"] == 0 and h["entered_on_red"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0


def _patched_run(out: Path, patch: str, volume: str) -> dict:
    """A half-human run at the chapter 4-5 junction in a process whose roadside is
    changed by ``patch`` (Python run after ``import dica.sim_gateway.humans as h``):
    the run's ``humans`` figures (collisions may follow: exit 1 is taken)."""
    code = f"import sys\nimport dica.sim_gateway.humans as h\n{patch}" + (
        "from dica.tools.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, "run", "--layout", "ch45", "--volume", volume, "--seed",
         "12", "--duration", "200", "--cav-share", "0.5", "--out", str(out), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode in (0, 1), p.stderr
    return json.loads((out / "metrics.json").read_text())["humans"]


@pytest.mark.sumo
def test_the_audit_sees_a_human_released_before_its_green(tmp_path):
    """The audit is not blind: heads that turn green three seconds before the ICA's
    green send humans over the line on red."""
    patch = (
        "orig = h.SignalHeads.release\n"
        "h.SignalHeads.release = lambda self, t: orig(self, t + 3.0)\n"
    )
    assert _patched_run(tmp_path / "early", patch, "300")["entered_on_red"] > 0


@pytest.mark.sumo
def test_the_audit_sees_a_human_outside_bounds_narrower_than_its_own(tmp_path):
    """Nor blind to the envelope: held to bounds that assume a driver with no reaction
    time and no dawdling (and never to the ICA's shrunk ones), SUMO's drivers fall
    behind the slowest of them."""
    patch = (
        "import dataclasses\n"
        "orig = h.green_bounds\n"
        "h.green_bounds = lambda r, n, g, st, lim, d, v: orig(r, n, g, st,\n"
        "    dataclasses.replace(lim, sigma=0.0, react_s=0.0, speed_factor_min=1.1), d, v)\n"
        "h.SignalHeads.tightened = lambda self, *seen: None\n"
    )
    h = _patched_run(tmp_path / "narrow", patch, "200")
    assert h["outside_envelope"] > 0 and h["worst_behind_slowest_m"] > 0.1


@pytest.mark.sumo
def test_the_all_way_stop_baseline(tmp_path):
    """SUMO's all-way stop (every driver stops, then goes in turn) at the chapter 4-5
    junction, all drivers human: the net's junction is an all-way stop and nothing
    collides."""
    out = tmp_path / "stop"
    m = _run(out, "--layout", "ch45", "--algorithm", "allway-stop", "--volume", "200",
             "--seed", "12", "--duration", "300", "--cav-share", "0")  # fmt: skip
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["crossed"] > 60
    (net,) = out.glob("*-allway-stop.net.xml")
    kinds = {j.get("type") for j in ET.parse(net).getroot().iter("junction")}
    assert "allway_stop" in kinds
    assert m["by_driver"]["human"]["generated"] == m["generated"]


@pytest.mark.sumo
def test_human_drivers_and_people_on_foot_keep_clear_of_each_other(tmp_path):
    """Every driver human at the chapter 4-5 junction with its crossings, 600 people an
    hour at each: no vehicle touches a person or another vehicle by either check, no
    human leaves its envelope or goes on red, and every walker is given its start
    within the bound."""
    m = _run(tmp_path / "both", "--layout", "ch45-walk", "--volume", "300", "--seed", "12",
             "--duration", "300", "--cav-share", "0", "--peds", "600")  # fmt: skip
    h, w = m["humans"], m["walkers"]
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["stood_inside"] == 0
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0
    assert h["outside_envelope"] == 0 and h["entered_on_red"] == 0
    assert h["given_green"] > 40 and w["crossed"] > 50
    assert w["max_ask_to_go_s"] <= 90.0 + 0.1  # the walkers' bound, and SUMO's step
    assert m["requests"]["greens_refused"].get("walkers", 0) > 0  # it came to that


@pytest.mark.sumo
def test_a_lockstep_cluster_with_human_drivers_and_people_makes_the_embedded_decisions(
    tmp_path,
):
    """Walkers' asks and human drivers' greens over Zenoh, in the embedded order: the
    same crossings, byte for byte."""
    from tests.test_cluster import _cluster

    common = ["--layout", "ch45-walk", "--volume", "300", "--seed", "21", "--duration", "90",
              "--cav-share", "0.5", "--peds", "300"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "1", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    m = _run(tmp_path / "emb", *common)
    for name in ("vehicles.csv", "timeseries.csv"):
        assert (tmp_path / "cl" / name).read_bytes() == (tmp_path / "emb" / name).read_bytes()
    assert m["humans"]["given_green"] > 10 and m["walkers"]["generated"] > 10
    assert m["walkers"]["crossed"] > 0
    assert m["walkers"]["person_hits"] == 0 and m["collisions"] == 0


@pytest.mark.sumo
def test_all_human_traffic_waits_less_than_at_the_all_way_stop(tmp_path):
    """Every driver human, volume 300: many are given their green rolling towards the
    line and need not stop, so the signal-free junction delays them less than SUMO's
    all-way stop does the same vehicles, with zero collisions by both checks and every
    human inside its envelope."""
    base = ("--layout", "ch45", "--volume", "300", "--seed", "21", "--duration", "300",
            "--cav-share", "0")  # fmt: skip
    m = _run(tmp_path / "dica", *base)
    stop = _run(tmp_path / "stop", *base, "--algorithm", "allway-stop")
    h = m["humans"]
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["stood_inside"] == 0
    assert h["outside_envelope"] == 0 and h["entered_on_red"] == 0
    assert h["rolling_greens"] > h["given_green"] / 3
    assert m["crossed"] >= stop["crossed"]
    assert m["mean_system_delay_s"] < stop["mean_system_delay_s"]


@pytest.mark.parametrize(
    "args",
    [
        ("--algorithm", "rdica"),
        ("--algorithm", "fifo"),
        ("--window", "4"),
    ],
)
def test_mixed_traffic_it_cannot_serve_is_refused_in_one_line(tmp_path, args):
    p = dica_run([*DICA, "run", "--layout", "ch45", "--cav-share", "0.5", *args,
                        "--out", str(tmp_path / "x"), "--duration", "10"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr and "cav-share" in p.stderr


@pytest.mark.sumo
def test_human_drivers_under_a_light_keep_its_right_of_way(tmp_path):
    """Under the lights human drivers ignore no foe (the head's green is the ICA's, not
    the light's): all drivers human, nothing collides at the actuated light."""
    m = _run(tmp_path / "act", "--layout", "ch45", "--algorithm", "actuated", "--volume", "300",
             "--seed", "12", "--duration", "400", "--cav-share", "0")  # fmt: skip
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["crossed"] > 100


@pytest.mark.cluster
def test_a_lockstep_cluster_with_human_drivers_makes_the_embedded_decisions(tmp_path):
    """Over Zenoh the gateway tells the ICA process of each human driver (SPOTTED), asks
    for its green (ASKGREEN -> LIT) and shrinks its reservations (SIGHTING -> SHRUNK)
    before the step's clock: every vehicle, connected or not, crosses as in one process,
    byte for byte. The observer draws what the embedded recording does: the humans as
    such, their envelopes from the greens the ICA publishes, and the heads."""
    from tests.test_cluster import _cluster
    from tests.test_recording import _read, _rows

    common = ["--layout", "ch45", "--volume", "300", "--seed", "21", "--duration", "120",
              "--cav-share", "0.5"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "1", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _run(tmp_path / "emb", *common, "--record")
    for name in ("vehicles.csv", "timeseries.csv"):
        assert (tmp_path / "cl" / name).read_bytes() == (tmp_path / "emb" / name).read_bytes()
    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    h = m["humans"]
    assert h["given_green"] > 10 and h["reservations_shrunk"] > 50
    assert 0 < h["rolling_greens"] < h["given_green"]  # some on the move (ASKGREEN's speed)
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert m["humans_unanswered"] == 0 and m["collisions"] == 0
    assert m == {**m, "humans": json.loads((tmp_path / "emb" / "metrics.json").read_text())[
        "humans"]}  # fmt: skip
    ica = json.loads((tmp_path / "cl" / "ica.json").read_text())
    assert ica["humans"] == h["count"] and ica["greens"] >= h["given_green"]
    assert ica["shrunk"] == h["reservations_shrunk"]
    humans = {r["vin"] for r in _rows_csv(tmp_path / "cl") if r["human"] == "1"}
    drawn = {}
    for run in ("cl", "emb"):
        data = _read(tmp_path / run / "spacetime.rrd")
        boxes = _rows(data["/charts/data/zones/reserved"], "Boxes2D:labels")
        lines = [row for key in data if key.startswith("/charts/data/lanes/")
                 and key.endswith("/plans")
                 for _, row in _rows(data[key], "LineStrips2D:labels")]  # fmt: skip
        drawn[run] = {
            "envelopes": sorted(lb for _, row in boxes for lb in row if lb.split()[0] in humans),
            "bounds": sorted(lb for row in lines for lb in row if lb.split()[0] in humans),
            "heads": [
                (round(t, 3), row)
                for t, row in _rows(data["/junction/heads"], "Points2D:colors")
                if len(row)
            ],
        }
    assert len(drawn["cl"]["envelopes"]) > 50 and len(drawn["cl"]["heads"]) > 50
    assert drawn["cl"] == drawn["emb"]


@pytest.mark.cluster
@pytest.mark.timing
def test_a_real_time_roadside_lights_a_head_late_within_its_allowance_or_keeps_it_red(tmp_path):
    """Real time, every driver human, the gateway's link late by 5 to 45 ms each way (at
    speed 2, up to 0.18 s of sim time a round trip), heads allowed to turn green 0.1 s
    late. The gateway does not wait for the ICA's answers about human drivers: it steps
    on, at the speed asked for; a LIT taken at a later step lights its head then, and
    one taken later than 0.1 s after its green is dropped, the head kept red and the
    ICA told (UNLIT), and the driver asks again. Nobody enters on red or leaves its
    envelope, which allows for the lateness, and nothing collides. (A walker's GO is
    given late or dropped alike, the stepping waiting for it; walkers mostly start with a
    phase still to come, so few GOs are ever late: that path is tested on the ICA
    process, test_crosswalk.py.)"""
    from tests.test_timing import _run_safe

    out = tmp_path / "rt"
    m = _run_safe(
        out,
        *("--clock", "realtime", "--speed", "2", "--agents", "1", "--port", str(free_port())),
        *("--volume", "400", "--duration", "45", "--seed", "21", "--cav-share", "0"),
        *("--delay", "5", "--jitter", "40", "--faulty", "gateway", "--green-late", "0.1"),
        "--no-record",
    )
    h = m["humans"]
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert h["given_green"] >= 8  # dropped greens were asked for again, and given
    assert h["heads_lit_late"] >= 1 and 0.05 - 1e-9 <= h["most_late_head_s"] <= 0.1 + 1e-9
    assert m["greens_dropped_late"] >= 1
    ica = json.loads((out / "ica.json").read_text())
    assert 1 <= ica["unlit"] <= m["greens_dropped_late"]  # a stale green is dropped again


def _ask(session, key: str, msg):
    """One query, its one answer decoded."""
    from dica.schemas.codec import decode, encode

    (r,) = [r for r in session.get(key, payload=encode(msg), timeout=5.0) if r.ok]
    return decode(r.ok.payload.to_bytes())


def _clock(session, j: str, lane: str, k: int, end: bool = False) -> None:
    """CLOCK k, and (a publication) wait until the ICA has taken it: a SIGHTING of no
    one at its time is refused as ahead of the clock until then."""
    from dica.schemas import keys
    from dica.schemas.codec import encode, now_ns
    from dica.schemas.messages import Clock, Reject, Sighting

    t = 0.05 * k
    session.put(keys.clock(j), encode(Clock(k, t, "lockstep", 1.0, end, now_ns())))
    if end:
        return
    deadline = time.monotonic() + 30.0
    gw = keys.human(j, "gateway")
    while isinstance(_ask(session, gw, Sighting("nobody", t, lane, 0.0, 0.0, now_ns())), Reject):
        assert time.monotonic() < deadline, "the ICA never took the clock"
        time.sleep(0.05)


@pytest.mark.cluster
def test_a_lockstep_cluster_with_a_route_files_human_drivers_makes_the_embedded_decisions(
    tmp_path,
):
    """A user's net and route file, half its vehicles drawn human: over Zenoh the same
    vehicles are drawn, told, given their greens and sent on as in one process, byte for
    byte."""
    from tests.test_cluster import _cluster
    from tests.user_nets import ROUTES, build_nets

    net = build_nets(tmp_path)["grid"]
    routes = tmp_path / "demand.rou.xml"
    routes.write_text(ROUTES)
    common = ["--net", str(net), "--junction", "B1", "--routes", str(routes), "--duration",
              "150", "--cav-share", "0.5"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "1", "--no-record", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _run(tmp_path / "emb", *common)
    for name in ("vehicles.csv", "timeseries.csv"):
        assert (tmp_path / "cl" / name).read_bytes() == (tmp_path / "emb" / name).read_bytes()
    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    assert m["humans"]["given_green"] > 10 and m["humans"]["outside_envelope"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0


def _a_car_a_green_delays(inter, lane: str, late_s: float):
    """A car's request from another approach (at 0.05 s, 30 m out) that a human's green at
    the head of ``lane`` at 0.05 s delays by more than a second: (the request, its route,
    its entry time without that green)."""
    limits = human_limits(IcaConfig().caps.road_mps, late_s)
    for route in (r for r in inter.routes if r.in_lane != lane and r.cars):
        req = propose(route, vin="car", seq=0, t0_s=0.05, dist_to_entry_m=30.0, speed_mps=10.0)
        alone, held = Dica(inter), Dica(inter)
        alone.detect("car", route.in_lane, 0.0)
        free = alone.handle(req, 0.05).entry_time_s
        held.detect("h1", lane, 0.0)
        held.detect("car", route.in_lane, 0.0)
        held.advance(0.05)
        held.green("h1", 0.05, 5.0, 1.8, limits, 0.5)
        if held.handle(req, 0.05).entry_time_s > free + 1.0:
            return req, route, free
    raise AssertionError("no car crosses the human's envelope")


def test_the_ica_process_serves_the_roadside_alone_and_keeps_greens_over_a_restart(
    ch45_net, ch45, tmp_path
):
    """On dica/<j>/human/gateway: a human driver SPOTTED, its green (LIT, published once
    for observers), asked at this step's time only; the same asked through an agent's key
    refused, and no agent may detect or ask for a human driver's VIN. The green is
    journalled: the restarted ICA still delays a car through its envelope."""
    from dica.ica.convert import request_from_core
    from dica.schemas import keys
    from dica.schemas.codec import decode, now_ns
    from dica.schemas.messages import (
        Ack,
        AskGreen,
        Detect,
        Lit,
        Reject,
        Response,
        Sighting,
        Spotted,
    )
    from dica.tools.loopback import router_and_ica

    j = ch45_net.junction_id
    lane = _lane_with_turns(ch45)
    # in process: a car from another approach that the human's green delays
    ica = Dica(ch45)
    ica.detect("h1", lane, 0.0)
    ica.advance(0.05)
    g = ica.green("h1", 0.05, 5.0, 1.8, human_limits(ica.config.caps.road_mps), 0.5)
    req, route, free = _a_car_a_green_delays(ch45, lane, 0.0)

    def ask(session, key, msg):
        return _ask(session, key, msg)

    def clock(session, k, end=False):
        _clock(session, j, lane, k, end)

    args = ("--net", str(ch45_net.net_path), "--junction", j, "--out", str(tmp_path))
    gw = keys.human(j, "gateway")
    with router_and_ica(j, args) as (session, proc):
        heard = []
        sub = session.declare_subscriber(keys.greens(j), lambda s: heard.append(s))
        for asker in ("agent-1", "*"):  # another's key, or all of them at once
            no = ask(session, keys.human(j, asker), Spotted("h1", lane, 0.0, now_ns()))
            assert isinstance(no, Reject) and "only the roadside" in no.detail
        for _ in range(2):  # told twice (a lost ACK): one human driver
            assert isinstance(ask(session, gw, Spotted("h1", lane, 0.0, now_ns())), Ack)
        no = ask(session, keys.detect(j, "agent-1"), Detect("h1", lane, 0.0, False, 9.0, now_ns()))
        assert isinstance(no, Reject) and "another agent" in no.detail
        clock(session, 1)
        for t in (1.1, 0.0):  # a step past the second ahead it may be, or behind the clock
            no = ask(session, gw, AskGreen("h1", t, 5.0, 1.8, 0.5, False, now_ns()))
            assert isinstance(no, Reject) and no.reason == "bad_time"
        no = ask(session, gw, AskGreen("h1", 0.05, 5.0, 1.8, 10.5, False, now_ns()))
        assert isinstance(no, Reject) and no.reason == "bad_state"  # 10 m short at most
        no = ask(session, keys.human(j, "agent-1"),
                 Sighting("h1", 0.05, lane, 0.0, 0.0, now_ns()))  # fmt: skip
        assert isinstance(no, Reject) and "only the roadside" in no.detail
        lit = ask(session, gw, AskGreen("h1", 0.05, 5.0, 1.8, 0.5, False, now_ns()))
        assert isinstance(lit, Lit) and lit.green_s == pytest.approx(g.green_s)
        assert set(lit.routes) == set(g.routes) and len(lit.routes) > 1
        again = ask(session, gw, AskGreen("h1", 0.05, 5.0, 1.8, 0.5, False, now_ns()))
        assert again.green_s == lit.green_s
        deadline = time.monotonic() + 30.0
        while not heard:
            assert time.monotonic() < deadline, "the green was never published"
            time.sleep(0.05)
        ask(session, gw, Spotted("h1", lane, 0.0, now_ns()))  # a round trip after both
        (pub,) = [decode(s.payload.to_bytes(), Lit) for s in heard]
        assert str(heard[0].key_expr) == keys.greens(j, "h1") and pub.routes == lit.routes
        sub.undeclare()
        clock(session, 2, end=True)
        assert proc.wait(15) == 0
    with router_and_ica(j, args) as (session, proc):  # the same journal
        clock(session, 1)
        det = Detect("car", route.in_lane, 0.0, False, 10.0, now_ns())
        assert isinstance(ask(session, keys.detect(j, "a"), det), Ack)
        got = ask(session, keys.request(j, "a"), request_from_core(req))
        assert isinstance(got, Response) and got.entry_time_s > free + 1.0
        no = ask(session, keys.request(j, "a"), request_from_core(dataclasses.replace(
            req, vin="h1")))  # fmt: skip
        assert isinstance(no, Reject) and "another agent" in no.detail
        clock(session, 2, end=True)
        assert proc.wait(15) == 0
    stats = json.loads((tmp_path / "ica.json").read_text())
    first, second = stats["incarnations"]
    assert first["humans"] == 1 and first["greens"] == 1
    assert second["journal_replayed"]["greens"] == 1


def test_a_green_dropped_late_is_freed_over_zenoh_and_over_a_restart(ch45_net, ch45, tmp_path):
    """An ICA told that heads may turn green up to 0.4 s late (--green-late): its LIT says
    so (an observer draws the same envelope); the roadside's UNLIT frees that green, once
    however often told, and the driver's next ask is a new green; an agent's UNLIT is
    refused. Journalled: the restarted ICA plans a car straight through where the
    dropped greens were."""
    from dica.ica.convert import request_from_core
    from dica.schemas import keys
    from dica.schemas.codec import now_ns
    from dica.schemas.messages import Ack, AskGreen, Detect, Lit, Reject, Response, Spotted, Unlit
    from dica.tools.loopback import router_and_ica

    j = ch45_net.junction_id
    lane = _lane_with_turns(ch45)
    req, route, free = _a_car_a_green_delays(ch45, lane, 0.4)
    args = ("--net", str(ch45_net.net_path), "--junction", j, "--out", str(tmp_path),
            "--green-late", "0.4")  # fmt: skip
    gw = keys.human(j, "gateway")
    with router_and_ica(j, args) as (session, proc):
        assert isinstance(_ask(session, gw, Spotted("h1", lane, 0.0, now_ns())), Ack)
        _clock(session, j, lane, 1)
        lit = _ask(session, gw, AskGreen("h1", 0.05, 5.0, 1.8, 0.5, False, now_ns()))
        assert isinstance(lit, Lit) and lit.late_s == pytest.approx(0.4)
        no = _ask(session, keys.human(j, "agent-1"), Unlit("h1", 0.05, lit.green_s, now_ns()))
        assert isinstance(no, Reject) and "only the roadside" in no.detail
        for _ in range(2):  # told twice (a lost ACK): dropped once
            assert isinstance(_ask(session, gw, Unlit("h1", 0.05, lit.green_s, now_ns())), Ack)
        _clock(session, j, lane, 2)
        new = _ask(session, gw, AskGreen("h1", 0.1, 5.0, 1.8, 0.5, False, now_ns()))
        assert isinstance(new, Lit) and new.green_s == pytest.approx(0.1)  # not the stale one
        _clock(session, j, lane, 3)  # an UNLIT from a step behind the clock is still taken
        assert isinstance(_ask(session, gw, Unlit("h1", 0.1, new.green_s, now_ns())), Ack)
        _clock(session, j, lane, 4, end=True)
        assert proc.wait(15) == 0
    with router_and_ica(j, args) as (session, proc):  # the same journal
        _clock(session, j, lane, 1)
        det = Detect("car", route.in_lane, 0.0, False, 10.0, now_ns())
        assert isinstance(_ask(session, keys.detect(j, "a"), det), Ack)
        got = _ask(session, keys.request(j, "a"), request_from_core(req))
        assert isinstance(got, Response) and got.entry_time_s < free + 1.0
        _clock(session, j, lane, 2, end=True)
        assert proc.wait(15) == 0
    first, second = json.loads((tmp_path / "ica.json").read_text())["incarnations"]
    assert first["greens"] == 2 and first["unlit"] == 2
    assert second["journal_replayed"]["greens"] == 2


@pytest.mark.cluster
def test_a_roadside_message_ahead_of_the_icas_clock_waits_for_it(ch45_net, ch45, tmp_path):
    """The ICA's session may hand the roadside's query over before the CLOCKs sent ahead
    of it: a SPOTTED a step past the 1 s window is held, not refused, and answered once
    the CLOCK comes; one whose CLOCK never comes is refused as ahead of the clock after
    the hold (2 s), and one behind the clock at once."""
    from dica.schemas import keys
    from dica.schemas.codec import decode, encode, now_ns
    from dica.schemas.messages import Ack, AskGreen, Clock, Reject, Spotted
    from dica.tools.loopback import router_and_ica

    j = ch45_net.junction_id
    lane = _lane_with_turns(ch45)
    gw = keys.human(j, "gateway")
    args = ("--net", str(ch45_net.net_path), "--junction", j, "--out", str(tmp_path))

    def answers(session, msg):
        return session.get(gw, payload=encode(msg), timeout=10.0)

    def answer(replies):
        (r,) = [r for r in replies if r.ok]
        return decode(r.ok.payload.to_bytes())

    with router_and_ica(j, args) as (session, proc):
        session.put(keys.clock(j), encode(Clock(1, 0.05, "lockstep", 1.0, False, now_ns())))
        late = 1.12  # past the 1 s window of the clock at 0.05 s, within that of 0.15 s
        deadline = time.monotonic() + 30.0
        while isinstance(answer(answers(session, Spotted("h0", lane, 0.05, now_ns()))), Reject):
            assert time.monotonic() < deadline, "the ICA never took the clock"
            time.sleep(0.05)
        held = answers(session, Spotted("h1", lane, late, now_ns()))
        # a query after it is answered at once; the one ahead of the clock is not
        assert isinstance(answer(answers(session, Spotted("h0", lane, 0.05, now_ns()))), Ack)
        assert held.try_recv() is None
        session.put(keys.clock(j), encode(Clock(2, 0.15, "lockstep", 1.0, False, now_ns())))
        assert isinstance(answer(held), Ack)  # on the CLOCK (refused had it been held out)
        t0 = time.monotonic()
        far = answer(answers(session, Spotted("h2", lane, 60.0, now_ns())))
        assert isinstance(far, Reject) and far.reason == "bad_time"
        assert time.monotonic() - t0 >= 1.5  # held, then refused
        behind = answer(answers(session, AskGreen("h1", 0.05, 5.0, 1.8, 0.5, False, now_ns())))
        assert isinstance(behind, Reject) and behind.reason == "bad_time"
        session.put(keys.clock(j), encode(Clock(3, 0.2, "lockstep", 1.0, True, now_ns())))
        assert proc.wait(15) == 0
    stats = json.loads((tmp_path / "ica.json").read_text())
    assert stats["incarnations"][0]["humans"] == 2  # h0 and h1; h2 never


def test_a_rolling_green_never_catches_a_vehicle_gone_out_ahead(ch45):
    """A human given its green standing leaves by an exit lane slowly (its slowest, from
    the line); its reservation ends and the ICA forgets it. A driver rolling up fast
    behind it on the same lane, asking moments later, is refused: at its fastest it
    would have to brake behind the one gone out (carried on at its last speed) while
    still inside. Once that one is far enough ahead, the same ask is given."""
    lane = _lane_with_turns(ch45)
    ica = Dica(ch45, IcaConfig())
    ica.detect("a", lane, 0.0)
    g = ica.green("a", 0.0, 4.5, 1.8, LIMITS)
    end = max(ica.confirmed[k].dtot.end_s for k in g.keys)
    ica.detect("b", lane, end)
    ica.advance(end + 0.1)
    assert not any(k in ica.confirmed for k in g.keys)  # gone, and forgotten
    with pytest.raises(RequestError) as e:
        ica.green("b", end + 0.1, 4.5, 1.8, LIMITS, 20.0, 13.0)
    assert e.value.reason == Reason.INFEASIBLE
    ica._ended.clear()  # without the memory of it, the same ask would have been given
    assert ica.green("b", end + 0.1, 4.5, 1.8, LIMITS, 20.0, 13.0).green_s == end + 0.1
    later = Dica(ch45, IcaConfig())
    later.detect("a", lane, 0.0)
    later.green("a", 0.0, 4.5, 1.8, LIMITS)
    later.detect("b", lane, end)
    later.advance(end + 12.0)
    assert later.green("b", end + 12.0, 4.5, 1.8, LIMITS, 20.0, 13.0)
