"""A vehicle's own low-level control: stop short of the line, or track a plan by position.

These laws run on the vehicle itself (in simulation: at the gateway's
actuator, every step, from SUMO's measured state), so they need no message
to act: a vehicle without a plan it may fly stops short of the junction's
entry line on its own, whatever its links do. The vehicle's planner uses the
same stop law to predict where it will be when a plan could start, which is
what makes a plan asked for ahead of time flyable.
"""

from __future__ import annotations

import math

import numpy as np

from dica.ica.core.stop_law import STOP_DECEL_MPS2, predict_stop, stop_speed

__all__ = [
    "STOP_DECEL_MPS2",
    "TRACK_ACCEL_MPS2",
    "TRACK_DECEL_MPS2",
    "can_stop_short",
    "entry_time",
    "predict_stop",
    "stop_speed",
    "track_speed",
]

TRACK_ACCEL_MPS2 = 4.0  # [m/s^2] most a tracking vehicle speeds up to catch its plan
TRACK_DECEL_MPS2 = 9.0  # [m/s^2] most it brakes to fall back onto its plan (SUMO's emergency)


def can_stop_short(
    d_m: float, v_mps: float, *, gap_m: float, h: float, accel_mps2: float, decel_mps2: float
) -> bool:
    """Whether the stop law, from now on, keeps the front short of the entry line.

    ``d_m`` is the distance from the front to the line. The law is run step by
    step to a standstill exactly as the actuator would run it (SUMO's stopping
    rule, never braking harder than ``decel_mps2``); a vehicle too close or too
    fast for that would cross the line, so a plan it flies cannot be dropped.
    """
    if d_m <= 0.0:
        return False
    for _ in range(100_000):
        if v_mps <= 1e-9:
            return True
        v_mps = stop_speed(d_m - gap_m, v_mps, v_mps, h, accel_mps2, decel_mps2)
        d_m -= v_mps * h
        if d_m <= 0.0:
            return False
    return False


def track_speed(s_target_m: float, s_m: float, v_mps: float, h: float) -> float:
    """The speed that brings the front from ``s_m`` to ``s_target_m`` in one step.

    Closed loop on the measured position: the distance gained or lost
    (late start, a leader's car-following, a slow actuator) is made up at the
    next step within TRACK_ACCEL_MPS2 and TRACK_DECEL_MPS2, instead of
    persisting as it would with open-loop speeds.
    """
    v = (s_target_m - s_m) / h
    return float(min(max(v, v_mps - TRACK_DECEL_MPS2 * h, 0.0), v_mps + TRACK_ACCEL_MPS2 * h))


def entry_time(t0_s: float, h: float, s_m: np.ndarray) -> float:
    """When a plan's front crosses the entry line (s = 0), linearly between samples."""
    k = int(np.searchsorted(s_m, 0.0, side="left"))
    if k <= 0:
        return t0_s
    if k >= len(s_m):
        return math.inf
    s0, s1 = float(s_m[k - 1]), float(s_m[k])
    return t0_s + h * (k - 1 + (0.0 - s0) / (s1 - s0) if s1 > s0 else k)
