"""The stop law every vehicle without a plan runs: stop short of the junction's entry line.

It runs on the vehicle (:mod:`vehicle_agent.control`); the ICA runs it too, to
predict where a vehicle whose plan it revoked will be when it asks again
(:meth:`ica.core.reactive.ReactiveDica._over_bound`). Pure arithmetic.
"""

from __future__ import annotations

import math

STOP_DECEL_MPS2 = 4.0  # [m/s^2] braking an unconfirmed vehicle plans with (below SUMO's 4.5)


def stop_speed(
    room_m: float, v_mps: float, cap_mps: float, h: float, accel_mps2: float, decel_mps2: float
) -> float:
    """The speed for the next step that keeps the front short of a line ``room_m`` ahead.

    SUMO's discrete stopping rule at STOP_DECEL_MPS2 (so that with Euler steps
    the vehicle stops exactly at the line), never above ``cap_mps``, and within
    what one step of the vehicle's acceleration and deceleration can change,
    which is what SUMO executes for a vehicle free of a leader.
    """
    room = max(room_m, 0.0)
    b = STOP_DECEL_MPS2
    v_stop = math.sqrt(2.0 * b * room + (b * h / 2.0) ** 2) - b * h / 2.0
    v = min(cap_mps, v_stop, room / h, v_mps + accel_mps2 * h)
    return max(v, v_mps - decel_mps2 * h, 0.0)


def stop_distance(v_mps: float, decel_mps2: float, h: float) -> float:
    """How far a vehicle that moves at ``v_mps`` over the next step, then brakes at
    ``decel_mps2`` every step after (Euler steps of ``h``, as SUMO moves it), goes before
    it stands."""
    n = max(math.ceil(v_mps / (decel_mps2 * h) - 1e-12) - 1, 0)  # moving steps after this
    return h * ((n + 1) * v_mps - decel_mps2 * h * n * (n + 1) / 2.0) if v_mps > 0.0 else 0.0


def predict_stop(
    d_m: float,
    v_mps: float,
    steps: int,
    *,
    gap_m: float,
    cap_mps: float,
    h: float,
    accel_mps2: float,
    decel_mps2: float,
) -> tuple[float, float]:
    """Distance to the entry line and speed after ``steps`` steps of the stop law."""
    for _ in range(steps):
        v_mps = stop_speed(d_m - gap_m, v_mps, cap_mps, h, accel_mps2, decel_mps2)
        d_m -= v_mps * h
    return d_m, v_mps
