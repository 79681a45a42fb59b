"""The least separation at which the road's driver takes a vehicle over, compiled.

``ica.core.handover``'s search (doubling, then bisection to 0.01 s) over
``Handover.gap_ok``: the same samples and the same arithmetic, stopping at
the first short gap. The driver comes as :class:`Driver`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numba import njit, typeof
from numba.types import float64 as f8


class Driver(NamedTuple):
    """The road's car-following driver beyond the junction (``Handover``)."""

    road_mps: float  # the road speed it accelerates to
    accel_mps2: float
    decel_mps2: float  # the braking its safe gap assumes
    tau_s: float  # reaction time
    min_gap_m: float  # standstill gap
    buffer_m: float  # on top of the safe gap: the driver's discrete steps
    step_s: float  # the time step the gap is checked at


DRIVER_ARGS = typeof(tuple(Driver(19.4, 2.0, 4.5, 1.0, 2.5, 1.0, 0.05)))  # see the package


@njit(cache=True, nogil=True)
def free_run(driver: Driver, v0: float, t: float) -> tuple[float, float]:
    """``Handover._free`` at one time: distance and speed of a free run from ``v0``."""
    road, accel = driver.road_mps, driver.accel_mps2
    v_top = max(road, v0)
    t_acc = (v_top - v0) / accel
    ta = min(t, t_acc)
    x = v0 * ta + 0.5 * accel * ta * ta + v_top * max(t - t_acc, 0.0)
    return x, min(v0 + accel * t, v_top)


@njit(cache=True, nogil=True)
def gap_ok(driver: Driver, v_lead: float, v_follow: float, length: float, sep: float) -> bool:
    """``Handover.gap_ok``: the same samples (numpy's ``arange``: ``i * step``, as many
    as ``ceil(stop / step)``) and the same arithmetic, stopping at the first short gap."""
    step = driver.step_s
    horizon = sep + (driver.road_mps - min(v_lead, v_follow)) / driver.accel_mps2 + 1.0
    n = math.ceil((horizon + step) / step)
    floor_m = driver.min_gap_m + driver.buffer_m
    for i in range(n):
        t = i * step
        x_l, v_l = free_run(driver, v_lead, t + sep)
        x_f, v_f = free_run(driver, v_follow, t)
        gap = x_l - x_f - length
        need = floor_m + v_f * driver.tau_s
        need = need + (v_f * v_f - v_l * v_l) / (2.0 * driver.decel_mps2)
        if not gap >= need:
            return False
    return True


@njit(f8(DRIVER_ARGS, f8, f8, f8), cache=True, nogil=True)
def separation(driver_args: tuple, v_lead: float, v_follow: float, length: float) -> float:
    """The least separation [s] from the leader's rear leaving the junction to the
    follower's at which the follower's driver never brakes; inf beyond 120 s
    (``driver_args``: a :class:`Driver` as a tuple)."""
    driver = Driver(*driver_args)
    lo, hi = 0.0, 1.0
    while not gap_ok(driver, v_lead, v_follow, length, hi):
        lo, hi = hi, 2.0 * hi
        if hi > 120.0:
            return math.inf
    if gap_ok(driver, v_lead, v_follow, length, lo):
        return lo
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        if gap_ok(driver, v_lead, v_follow, length, mid):
            hi = mid
        else:
            lo = mid
    return hi
