"""Plans a vehicle can fly: limits, entry times, continuity, stopping."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dica.ica.core.planner import Kinematics, Planner
from dica.ica.core.trajectory import sample

KIN = Kinematics()
ROAD = 70 / 3.6


def check_flyable(p, planner: Planner, step=0.05):
    traj = sample(p, 0.0, step, planner.s_end_m)
    v = traj.speeds()
    assert v.min() >= -1e-9
    assert v.max() <= ROAD + 1e-9
    inside = traj.s_m[:-1] >= 0
    assert v[inside].max(initial=0) <= planner.cap_mps + 1e-9
    acc = np.diff(np.concatenate([[planner.v0_mps], v])) / step
    assert acc[1:].max(initial=0) <= KIN.accel_mps2 + 1e-6
    assert acc[1:].min(initial=0) >= -KIN.decel_mps2 - 1e-6
    assert abs(traj.s_m[0] + planner.d_m) < 1e-6
    assert traj.s_m[-1] >= planner.s_end_m - 1e-9
    return traj


states = st.tuples(
    st.floats(0.0, 50.0), st.floats(0.0, ROAD), st.sampled_from([25 / 3.6, 35 / 3.6, 65 / 3.6])
)


@settings(max_examples=200, derandomize=True, deadline=None)
@given(states, st.floats(0.0, 40.0))
def test_plans_respect_limits_and_enter_no_earlier_than_asked(state, extra):
    d, v0, cap = state
    pl = Planner(d, v0, ROAD, cap, 30.0, KIN)
    if not pl.feasible():
        # then even full braking cannot reach the cap at the line
        assert v0**2 - 2 * KIN.decel_mps2 * d > cap**2 - 1e-6
        return
    fast = pl.fastest()
    check_flyable(fast, pl)
    target = pl.earliest_entry_s() + extra
    p = pl.at_or_after(target)
    if p is None:
        assert not pl.can_stop()
        return
    traj = check_flyable(p, pl)
    assert p.entry_time_s >= target - 1e-6
    # the flown (sampled) motion enters within one step of the plan
    assert traj.entry_time_s() == pytest.approx(p.entry_time_s, abs=0.05)
    # and no later than needed: exactly on time, or the earliest stop-and-go plan
    assert p.entry_time_s == pytest.approx(target, abs=1e-4) or p.entry_time_s == pytest.approx(
        pl.stop_entry_s(), abs=1e-6
    )


def test_fastest_is_time_optimal_on_a_free_run():
    # from 50 m at 12 m/s, through cap 65 km/h: accelerate, brake to the cap at the line
    pl = Planner(50.0, 12.0, ROAD, 65 / 3.6, 30.0, KIN)
    p = pl.fastest()
    cap = 65 / 3.6
    vp = math.sqrt((50.0 + 144 / 4 + cap**2 / 9) / (1 / 4 + 1 / 9))
    assert cap < vp < ROAD
    assert p.entry_speed_mps == pytest.approx(cap)
    expect = (vp - 12) / 2 + (vp - cap) / 4.5
    assert p.entry_time_s == pytest.approx(expect, rel=1e-9)


def test_long_delay_stops_at_the_line_and_waits():
    kin = Kinematics.at_the_line()
    pl = Planner(50.0, 15.0, ROAD, 35 / 3.6, 30.0, kin)
    p = pl.at_or_after(60.0)
    traj = sample(p, 0.0, 0.05, 30.0)
    stopped = np.nonzero(traj.speeds() < 1e-9)[0]
    assert len(stopped) > 100
    assert traj.s_m[stopped[0]] == pytest.approx(-kin.stop_gap_m, abs=1e-6)
    assert p.entry_time_s == pytest.approx(60.0, abs=1e-6)


@pytest.mark.parametrize(
    ("d", "v0", "stands_at"),
    [
        (50.0, 15.0, -((35 / 3.6) ** 2) / 4),  # room to stand where the pull-away reaches the cap
        (30.0, 12.0, -(30.0 - 12.0**2 / 9)),  # as far back as it can stop: 14 m
        (12.0, 10.0, -(12.0 - 10.0**2 / 9)),  # it can only just stop: 0.9 m short
    ],
)
def test_long_delay_with_a_run_up_stands_back_and_enters_at_speed(d, v0, stands_at):
    cap = 35 / 3.6
    pl = Planner(d, v0, ROAD, cap, 30.0, KIN)
    p = pl.at_or_after(60.0)
    traj = sample(p, 0.0, 0.05, 30.0)
    stopped = np.nonzero(traj.speeds() < 1e-9)[0]
    assert len(stopped) > 100
    assert traj.s_m[stopped[0]] == pytest.approx(stands_at, abs=1e-6)
    assert p.entry_time_s == pytest.approx(60.0, abs=1e-6)
    assert p.entry_speed_mps == pytest.approx(min(cap, math.sqrt(2 * 2.0 * -stands_at)))
    # the slow-down family creeps to 0.5 m/s before it gives way to stopping
    assert pl._v_min_a() == pytest.approx(max(0.5, math.sqrt(max(0, v0**2 - 9 * d))))


def test_a_vehicle_that_cannot_stop_cannot_wait_long():
    pl = Planner(20.0, ROAD, ROAD, 65 / 3.6, 30.0, KIN)  # needs 42 m to stop
    assert not pl.can_stop()
    assert pl.at_or_after(pl.earliest_entry_s() + 30.0) is None


def test_entry_time_decreases_with_cruise_speed():
    pl = Planner(50.0, 12.0, ROAD, 35 / 3.6, 30.0, KIN)
    speeds = np.linspace(pl._v_min_a(), pl._v_max(), 80)
    times = [pl._a_phases(v)[3] for v in speeds]
    assert all(a >= b - 1e-12 for a, b in itertools.pairwise(times))
