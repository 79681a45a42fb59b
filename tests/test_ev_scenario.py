"""Emergency vehicles in the demand and the metrics, the reactive light's program and
pre-emption, and the vehicle machine's revocation hook; no SUMO."""

from __future__ import annotations

import numpy as np
import pytest

from ica.core.config import IcaConfig
from ica.core.proposal import propose
from ica.core.request import Confirmation, Tss
from sim_gateway.demand import DemandSpec, make_arrivals
from sim_gateway.metrics import Trip, TripLog, summarize_ev
from sim_gateway.signals import (
    HOLD,
    REACTIVE_GREEN_S,
    REACTIVE_RED_S,
    REACTIVE_YELLOW_S,
    Preemption,
    reactive_durations,
)
from vehicle_agent.machine import MODE_CONFIRMED, MODE_DEFAULT, Phase, Vehicle

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


def test_the_reactive_program_is_31_green_13_yellow_83_red_for_the_main_movements():
    d = reactive_durations(PLAN)
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
    d = reactive_durations(PLAN)
    pre = Preemption(PLAN, d)
    north_through, east_through = [0], [4]
    assert pre.steps(0, 10.0, north_through) == [(0, HOLD)]  # extend the green
    assert pre.steps(1, 5.0, north_through) == [(0, HOLD)]  # back from yellow to green
    # red for the EV: the running green goes to its full yellow, then the EV's green
    assert pre.steps(0, 20.0, east_through) == [(1, REACTIVE_YELLOW_S), (4, HOLD)]
    # a yellow already running finishes (what is left of it), then the EV's green
    assert pre.steps(3, 4.0, east_through) == [(3, 4.0), (4, HOLD)]
    # the protected left gets its 'G' phase, not the permissive one
    assert pre.target([3]) == 2


def test_all_red_phases_are_kept_when_cutting():
    plan = ["GGrr", "yyrr", "rrrr", "rrGG", "rryy", "rrrr"]
    pre = Preemption(plan, [30.0, 3.0, 2.0, 30.0, 3.0, 2.0])
    assert pre.steps(0, 12.0, [2]) == [(1, 3.0), (2, 2.0), (3, HOLD)]


def test_the_machine_flies_a_replacement_and_brakes_without_one(ch45):
    cfg = IcaConfig()
    route = ch45.route("W_in_1", "E_out_1")
    v = Vehicle("w1", route, 5.0, 1.8, 12.0, cfg, phase=Phase.CONFIRMED)
    old = _confirmation(route, cfg, t0=0.0, d=40.0, speed=12.0)
    v.confirmation = old
    new = _confirmation(route, cfg, t0=1.0, d=28.0, speed=12.0)
    cmd = v.replace(new, 1.0)
    assert v.confirmation is new and v.phase is Phase.CONFIRMED
    assert cmd.t0_s == 1.0 and cmd.speed_mode == MODE_CONFIRMED
    # a replacement that starts later: the old plan is flown until then
    later = _confirmation(route, cfg, t0=1.5, d=22.0, speed=12.0)
    v.confirmation = old
    cmd = v.replace(later, 1.0)
    assert cmd.t0_s == 1.0 and len(cmd.speeds) == len(later.tss.t_s) - 1 + 10
    v.confirmation = old
    stop = v.replace(None, 2.0)
    assert v.confirmation is None and v.phase is Phase.REQUESTING and v.next_request_s == 2.0
    assert stop.speed_mode == MODE_DEFAULT  # SUMO's own braking limits again
    s, _ = route.project(np.stack([old.tss.x_m, old.tss.y_m], -1))
    room = -s[40] - cfg.kinematics.stop_gap_m  # where the old plan had it at t = 2 s
    assert stop.speeds[0] ** 2 <= 2 * 4.0 * room + 1e-6  # slow enough to stop before the line


def _confirmation(route, cfg, t0, d, speed) -> Confirmation:
    req = propose(route, vin="w1", seq=0, t0_s=t0, dist_to_entry_m=d, speed_mps=speed, config=cfg)
    tss = Tss(req.tss.t_s, req.tss.x_m, req.tss.y_m, req.tss.heading_rad)
    return Confirmation("w1", 0, route.id, tss, t0 + 2.0, t0 + 4.0, 0.0, 1)
