"""The numeric checks of a REQUEST's TSS, in ``ica.core.validate._check_tss``'s order.

One compiled call instead of a dozen numpy ones, each of which costs a
request more than its work when the caches are cold. The heading check
compares the TSS's headings with the route's (``atan2``, the platform's
libm): a request whose deviation lies within a few ulps of the tolerance
could be judged otherwise by numpy's SIMD ``arctan2``; the ICA judges it
here, the same way every time on one machine.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.types import float64 as f8
from numba.types import int64

from dica.ica.core.kernels.route import front_heading, project


class TssSamples(NamedTuple):
    """A TSS as four arrays of one length: times [s], front x and y [m], headings [rad]."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray


class TssRules(NamedTuple):
    """What a TSS must keep to: its sampling, its route, the state it starts from."""

    step_s: float  # [s] the sample step
    t0_s: float  # [s] the state's time: the first sample's
    off_tol_m: float  # [m] how far a point may lie off the route
    dist_to_entry_m: float  # [m] the state's distance to the entry line
    start_tol_m: float  # [m] how far the first sample may lie from that state
    s_end_m: float  # [m] where the front is once the vehicle is fully out
    length_m: float  # [m] the vehicle's length (front to rear point: the heading)
    heading_tol_rad: float  # [rad] how far a heading may deviate from the route's


class Limits(NamedTuple):
    """The speed and acceleration limits a TSS must keep (``validate.check_limits``)."""

    v0_mps: float  # the reported speed, the first step's reference
    road_mps: float  # the road limit, tolerance included
    cap_mps: float  # the turn cap inside the junction, tolerance included
    accel_mps2: float
    decel_mps2: float
    accel_tol_mps2: float  # slack on every step
    first_slack_mps2: float  # more slack on the first step (the reported speed)


_F1 = np.zeros(1)
_TSS = TssSamples(_F1, _F1, _F1, _F1)
_RULES = TssRules(0.05, 0.0, 0.25, 50.0, 0.5, 30.0, 5.0, 0.3)
_LIMITS = Limits(10.0, 20.0, 18.0, 2.0, 4.5, 0.5, 4.5)
TSS, RULES, LIMITS = typeof(_TSS), typeof(_RULES), typeof(_LIMITS)  # as kernels pass them
# as Python passes them (see the package's docstring)
TSS_ARGS, RULES_ARGS = typeof(tuple(_TSS)), typeof(tuple(_RULES))
LIMITS_ARGS = typeof(tuple(_LIMITS))


@njit(
    types.Tuple((int64, f8, f8[::1]))(TSS, f8[:, ::1], f8[::1], RULES),
    cache=True,
    nogil=True,
)
def tss_checks(
    tss: TssSamples, route_xy: np.ndarray, route_s: np.ndarray, rules: TssRules
) -> tuple[int, float, np.ndarray]:
    """The checks of a TSS up to its arc length, in ``validate._check_tss``'s order.

    Returns (failed check, a value for its message, monotone arc length);
    check 0 means all passed. 1 not finite, 2 times not increasing, 3 not
    sampled every step, 4 not starting at t0, 5 off the route (value: worst
    offset), 6 start not matching the state (value: s[0]), 7 moving
    backwards, 8 ending before the vehicle is out.
    """
    t, x, y, h = tss.t_s, tss.x_m, tss.y_m, tss.heading_rad
    n = len(t)
    empty = np.empty(0)
    for k in range(n):
        if not (np.isfinite(t[k]) and np.isfinite(x[k]) and np.isfinite(y[k])):
            return 1, 0.0, empty
        if not np.isfinite(h[k]):
            return 1, 0.0, empty
    for k in range(n - 1):
        if t[k + 1] - t[k] <= 0:
            return 2, 0.0, empty
    for k in range(n - 1):
        if abs((t[k + 1] - t[k]) - rules.step_s) > 1e-6:
            return 3, 0.0, empty
    if abs(t[0] - rules.t0_s) > 1e-6:
        return 4, 0.0, empty
    p = np.empty((n, 2))
    for k in range(n):
        p[k, 0] = x[k]
        p[k, 1] = y[k]
    s, off = project(route_xy, route_s, p)
    worst = off[0]
    for k in range(1, n):
        worst = max(worst, off[k])
    if worst > rules.off_tol_m:
        return 5, worst, empty
    if abs(s[0] + rules.dist_to_entry_m) > rules.start_tol_m:
        return 6, s[0], empty
    for k in range(n - 1):
        if s[k + 1] - s[k] < -1e-6:
            return 7, 0.0, empty
    for k in range(1, n):  # np.maximum.accumulate: the earlier one unless smaller
        if s[k - 1] >= s[k]:
            s[k] = s[k - 1]
    if s[n - 1] < rules.s_end_m - 1e-6:
        return 8, 0.0, empty
    return 0, 0.0, s


@njit(types.Tuple((int64, f8))(f8[::1], f8, LIMITS), cache=True, nogil=True)
def limit_checks(s: np.ndarray, step_s: float, lim: Limits) -> tuple[int, float]:
    """``validate.check_limits`` with a reported speed: (failed check, value).

    1 above the road limit (value: top speed), 2 above the turn cap inside,
    3 beyond the acceleration or deceleration limit; 0 passed.
    """
    n = len(s) - 1
    v = np.empty(n)
    for k in range(n):
        v[k] = (s[k + 1] - s[k]) / step_s
    for k in range(n):
        if v[k] > lim.road_mps:
            top = v[0]
            for q in range(1, n):
                top = max(top, v[q])
            return 1, top
    for k in range(n):
        if s[k] >= 0.0 and v[k] > lim.cap_mps:
            return 2, 0.0
    for k in range(n):
        acc = ((v[k] - lim.v0_mps) if k == 0 else (v[k] - v[k - 1])) / step_s
        slack = lim.accel_tol_mps2 + lim.first_slack_mps2 if k == 0 else lim.accel_tol_mps2
        if acc > lim.accel_mps2 + slack:
            return 3, 0.0
    for k in range(n):
        acc = ((v[k] - lim.v0_mps) if k == 0 else (v[k] - v[k - 1])) / step_s
        slack = lim.accel_tol_mps2 + lim.first_slack_mps2 if k == 0 else lim.accel_tol_mps2
        if acc < -lim.decel_mps2 - slack:
            return 3, 0.0
    return 0, 0.0


@njit(types.boolean(f8[:], f8, f8), cache=True, nogil=True)
def over_cap(s: np.ndarray, step_s: float, lim_mps: float) -> bool:
    """``np.any(np.diff(s)[s[:-1] >= 0] / step_s > lim_mps)``: faster than ``lim_mps``
    over a step that starts inside the junction."""
    for k in range(len(s) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if s[k] >= 0.0 and (s[k + 1] - s[k]) / step_s > lim_mps:
            return True
    return False


@njit(
    types.Tuple((int64, int64, f8, f8[::1]))(
        TSS_ARGS, f8[:, ::1], f8[::1], RULES_ARGS, LIMITS_ARGS
    ),
    cache=True,
    nogil=True,
)
def request_checks(
    tss_args: tuple, route_xy: np.ndarray, route_s: np.ndarray, rules_args: tuple,
    limits_args: tuple,
) -> tuple[int, int, float, np.ndarray]:  # fmt: skip
    """Every numeric check of ``validate._check_tss`` in one call, in its order:
    :func:`tss_checks`, the heading against the route's, :func:`limit_checks`
    (bundles as tuples: :class:`TssSamples`, :class:`TssRules`, :class:`Limits`).

    Returns (stage, failed check, value, arc length): stage 0 all passed, 1 a
    TSS check failed, 2 the heading deviates (value: the largest deviation),
    3 a limit check failed.
    """
    tss, rules = TssSamples(*tss_args), TssRules(*rules_args)
    failed, value, s = tss_checks(tss, route_xy, route_s, rules)
    if failed:
        return 1, failed, value, s
    _, expect = front_heading(s, rules.length_m, route_s, route_xy)
    h = tss.heading_rad
    worst = 0.0
    for k in range(len(s)):  # np.abs((h - expect + pi) % (2 pi) - pi), its maximum
        dh = abs((h[k] - expect[k] + np.pi) % (2 * np.pi) - np.pi)
        worst = dh if k == 0 else max(worst, dh)
    if worst > rules.heading_tol_rad:
        return 2, 0, worst, s
    failed, value = limit_checks(s, rules.step_s, Limits(*limits_args))
    if failed:
        return 3, failed, value, s
    return 0, 0, 0.0, s
