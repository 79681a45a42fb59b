"""The planner's arithmetic compiled: phases, bisection, plan building and sampling.

:class:`ica.core.planner._Builder`, ``Planner._a_phases``, ``Planner._build_a``,
``Planner._build_b``, ``Planner.at_or_after`` and ``Profile.time_at``,
expression for expression, with Python's ``min`` and ``max`` as
:func:`py_min` and :func:`py_max`, so each plan is the Python planner's bit
for bit. A vehicle's approach comes as :class:`Approach`; what the round loop
plans from, once per planner, as :class:`Plan`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.types import boolean
from numba.types import float64 as f8

from dica.ica.core.kernels.interp import searchsorted_one

EPS_PLAN = 1e-9  # as in ica.core.planner._EPS
MAX_SEGS = 16  # a plan has at most 7 segments (stop family), 6 (slow-down family)


class Approach(NamedTuple):
    """A vehicle's approach as the planner reads it (``Planner``): limits [m/s^2],
    state, caps [m/s] and where the plan ends [m]."""

    accel_mps2: float
    decel_mps2: float
    v0_mps: float  # the speed ...
    d_m: float  # ... and distance to the entry line of the state
    road_mps: float  # caps the approach
    cap_mps: float  # caps the crossing
    s_end_m: float  # where the front is once the vehicle is fully out
    creep_mps: float  # the slowest cruise of a slow-down plan
    stop_gap_m: float  # how far short of the line a stop-family plan stands, at least
    run_up: bool  # stand where pulling away reaches the cap at the line
    hold: bool  # a standing vehicle waits where it stands
    cap_sq: float  # Python's cap_mps ** 2 and v0_mps ** 2 (its power is not always
    v0_sq: float  # the product)


class Plan(NamedTuple):
    """What ``Planner.at_or_after`` computes once per planner (``Planner.plan_constants``):
    the approach's limits and state, the time-optimal plan's cruise speed and entry
    [s, from the state], the slowest slow-down plan's, the stop family's earliest entry
    (inf: it cannot stop) and its stop-at-the-line base as segments (t, s, v, a) and as
    the builder's (t, s, v)."""

    accel_mps2: float
    decel_mps2: float
    v0_mps: float
    d_m: float
    cap_mps: float
    s_end_m: float
    v_hi_mps: float
    hi_ok: bool
    hi_entry_s: float
    v_lo_mps: float
    lo_ok: bool
    lo_entry_s: float
    stop_entry_s: float
    b_segs: np.ndarray
    b_state: np.ndarray


_APPROACH = Approach(2.0, 4.5, 10.0, 40.0, 19.4, 18.0, 30.0, 0.5, 0.5, True, False, 324.0, 100.0)
_PLAN = Plan(2.0, 4.5, 10.0, 40.0, 18.0, 30.0, 19.0, True, 3.0, 0.5, True, 9.0, 5.0,
             np.zeros((1, 4)), np.zeros(3))  # fmt: skip
APPROACH_ARGS = typeof(tuple(_APPROACH))  # as Python passes them (see the package's docstring)
PLAN_ARGS = typeof(tuple(_PLAN))


@njit("float64(float64, float64)", cache=True, nogil=True)
def py_min(a: float, b: float) -> float:
    """Python's ``min(a, b)``: the first unless the second is smaller (signed zeros too)."""
    return b if b < a else a


@njit("float64(float64, float64)", cache=True, nogil=True)
def py_max(a: float, b: float) -> float:
    return b if b > a else a


@njit(cache=True, nogil=True)
def phases(p: Approach | Plan, v_m: float) -> tuple[bool, float, float, float, float]:
    """(fits, D1, D3, v_e, T) of the slow-down plan A(v_m); see ``Planner._a_phases``.
    ``p``: an :class:`Approach` or a :class:`Plan` (both name the limits, state and cap)."""
    a, br, v0, d, cap = p.accel_mps2, p.decel_mps2, p.v0_mps, p.d_m, p.cap_mps
    if v_m >= v0:
        d1 = (v_m * v_m - v0 * v0) / (2 * a)
        t1 = abs(v_m - v0) / a
    else:
        d1 = (v0 * v0 - v_m * v_m) / (2 * br)
        t1 = abs(v_m - v0) / br
    if d1 > d + 1e-7:
        return False, 0.0, 0.0, 0.0, 0.0
    if v_m > cap:
        v_e = cap
        d3 = (v_m * v_m - cap * cap) / (2 * br)
        t3 = (v_m - cap) / br
    else:
        v_e = py_min(cap, math.sqrt(py_max(v_m * v_m + 2 * a * (d - d1), 0.0)))
        d3 = (v_e * v_e - v_m * v_m) / (2 * a)
        t3 = (v_e - v_m) / a
    d2 = d - d1 - d3
    if d2 < -1e-7:
        return False, 0.0, 0.0, 0.0, 0.0
    if d2 > 1e-9 and v_m <= 1e-9:
        return False, 0.0, 0.0, 0.0, 0.0
    t2 = d2 / v_m if d2 > 1e-9 else 0.0
    return True, d1, d3, v_e, t1 + t2 + t3


@njit(types.Tuple((boolean, f8, f8, f8, f8))(APPROACH_ARGS, f8), cache=True, nogil=True)
def a_phases(approach_args: tuple, v_m: float) -> tuple[bool, float, float, float, float]:
    """:func:`phases` for a Python caller (``approach_args``: an :class:`Approach` as a tuple)."""
    return phases(Approach(*approach_args), v_m)


@njit(cache=True, nogil=True)
def cruise_for(p: Approach | Plan, v_lo: float, v_hi: float, t_entry: float) -> float:
    """The bisection of ``Planner.at_or_after``: the cruise speed arriving at ``t_entry``."""
    lo_v, hi_v = v_lo, v_hi
    for _ in range(60):
        mid = 0.5 * (lo_v + hi_v)
        fits, _d1, _d3, _ve, t = phases(p, mid)
        if not fits or t > t_entry:
            lo_v = mid
        else:
            hi_v = mid
        # the entry time's slope is d2 / v^2: 80 s per m/s when creeping at 0.5 m/s
        # 20 m short of the line, so the speed must be this fine for microseconds
        if hi_v - lo_v < 1e-10:
            break
    return hi_v


@njit(f8(APPROACH_ARGS, f8, f8, f8), cache=True, nogil=True)
def bisect_cruise(approach_args: tuple, v_lo: float, v_hi: float, t_entry: float) -> float:
    """:func:`cruise_for` for a Python caller (``approach_args``: an :class:`Approach`)."""
    return cruise_for(Approach(*approach_args), v_lo, v_hi, t_entry)


@njit(
    "void(float64[::1], float64[::1], float64[::1], float64[::1], float64, float64[::1])",
    cache=True,
    nogil=True,
)
def profile_position(
    t_s: np.ndarray,
    s_m: np.ndarray,
    v_mps: np.ndarray,
    a_mps2: np.ndarray,
    step_s: float,
    out: np.ndarray,
) -> None:
    """:meth:`ica.core.planner.Profile.position` at ``step_s * k`` for every k of ``out``."""
    last = len(t_s) - 1
    k = 0
    for q in range(len(out)):
        t = step_s * q
        k = min(max(searchsorted_one(t_s, t, True) - 1, 0), last)
        tau = max(t - t_s[k], 0.0)
        out[q] = s_m[k] + v_mps[k] * tau + 0.5 * a_mps2[k] * tau * tau


# -- plan building: _Builder's segments into a (MAX_SEGS, 4) array ---------------------
# ``st`` is the builder's (t, s, v); each call returns the number of segments so far


@njit(cache=True, nogil=True)
def _seg(segs: np.ndarray, n: int, t: float, s: float, v: float, a: float) -> int:
    segs[n, 0] = t
    segs[n, 1] = s
    segs[n, 2] = v
    segs[n, 3] = a
    return n + 1


@njit(cache=True, nogil=True)
def _accel_to(st: np.ndarray, segs: np.ndarray, n: int, v1: float, rate: float) -> int:
    """``_Builder.accel_to``."""
    if abs(v1 - st[2]) < EPS_PLAN:
        return n
    a = rate if v1 > st[2] else -rate
    dt = (v1 - st[2]) / a
    n = _seg(segs, n, st[0], st[1], st[2], a)
    st[1] += (st[2] + v1) / 2.0 * dt
    st[0] += dt
    st[2] = v1
    return n


@njit(cache=True, nogil=True)
def _hold(st: np.ndarray, segs: np.ndarray, n: int, dt: float) -> int:
    if dt <= EPS_PLAN:
        return n
    n = _seg(segs, n, st[0], st[1], st[2], 0.0)
    st[1] += st[2] * dt
    st[0] += dt
    return n


@njit(cache=True, nogil=True)
def _cruise_to(st: np.ndarray, segs: np.ndarray, n: int, s1: float) -> int:
    if s1 - st[1] > EPS_PLAN and st[2] > EPS_PLAN:
        n = _hold(st, segs, n, (s1 - st[1]) / st[2])
    return n


@njit(cache=True, nogil=True)
def plan_of(p: Approach) -> Plan:
    """``Planner.plan_constants`` (see ``Planner.plan_constants_reference``): the
    time-optimal plan's cruise speed and entry, the slowest slow-down plan's, the stop
    family's earliest entry and its stop-at-the-line base, expression for expression."""
    a, br, v0, d, road, cap = p.accel_mps2, p.decel_mps2, p.v0_mps, p.d_m, p.road_mps, p.cap_mps
    cap_sq, v0_sq = p.cap_sq, p.v0_sq
    # Planner._v_max
    reach = math.sqrt(v0 * v0 + 2 * a * d)
    if reach <= cap and v0 <= cap:
        v_hi = py_min(reach, road)
    else:
        peak2 = (d + v0 * v0 / (2 * a) + cap * cap / (2 * br)) / (1 / (2 * a) + 1 / (2 * br))
        v_hi = py_min(road, math.sqrt(py_max(peak2, 0.0)))
    hi_ok, _, _, _, hi_t = phases(p, v_hi)
    # Planner._v_min_a
    v_lo = py_max(p.creep_mps, math.sqrt(py_max(0.0, v0_sq - 2 * br * d)))
    lo_ok, lo_t = False, 0.0
    if v_lo < v_hi:
        lo_ok, _, _, _, lo_t = phases(p, v_lo)
    if not hi_ok:
        hi_t = 0.0
    if not lo_ok:
        lo_t = 0.0
    # Planner._stop_gap
    if p.hold and v0 <= 0.0:
        gap = d
    else:
        gap = p.stop_gap_m
        if p.run_up:
            gap = py_max(gap, py_min(cap_sq / (2 * a), d - v0_sq / (2 * br)))
        gap = py_min(gap, d)
    # Planner.stop_entry_s: can_stop, _b_base_build, _pull_away_time
    if not v0_sq <= 2 * br * (d - gap) + 1e-7:
        return Plan(
            a, br, v0, d, cap, p.s_end_m, v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, math.inf,
            np.zeros((0, 4)), np.zeros(3),
        )  # fmt: skip
    d_stop = d - gap
    segs = np.empty((MAX_SEGS, 4))
    st = np.empty(3)
    st[0], st[1], st[2] = 0.0, -d, v0
    peak2 = (d_stop + v0 * v0 / (2 * a)) / (1 / (2 * a) + 1 / (2 * br))
    peak = py_max(v0, py_min(road, math.sqrt(py_max(peak2, 0.0))))
    n = _accel_to(st, segs, 0, peak, a)
    n = _cruise_to(st, segs, n, -gap - peak * peak / (2 * br))
    n = _accel_to(st, segs, n, 0.0, br)
    st[1] = -gap
    if gap <= cap * cap / (2 * a):
        pull = math.sqrt(2 * gap / a)
    else:
        pull = cap / a + (gap - cap * cap / (2 * a)) / cap
    return Plan(
        a, br, v0, d, cap, p.s_end_m, v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, st[0] + pull,
        segs[:n].copy(), st,
    )  # fmt: skip


@njit(PLAN_ARGS(APPROACH_ARGS), cache=True, nogil=True)
def plan_constants_of(approach_args: tuple) -> tuple:
    """:func:`plan_of` for a Python caller, both ways as tuples: an :class:`Approach`
    in, a :class:`Plan` out (numba hands a named tuple back to Python at about three
    times the cost of a plain one)."""
    return plan_of(Approach(*approach_args))[:]


@njit(cache=True, nogil=True)
def _crossing(
    st: np.ndarray, segs: np.ndarray, n: int, cap: float, accel: float, s_end: float
) -> int:
    """``Planner._crossing`` and the closing segment of ``_Builder.profile``."""
    n = _accel_to(st, segs, n, py_max(st[2], cap), accel)
    n = _cruise_to(st, segs, n, s_end)
    return _seg(segs, n, st[0], st[1], st[2], 0.0)


@njit(cache=True, nogil=True)
def _build_a(plan: Plan, v_m: float, segs: np.ndarray) -> int:
    """``Planner._build_a`` into ``segs``: the number of segments, 0 if it does not fit."""
    fits, _d1, d3, v_e, _t = phases(plan, v_m)
    if not fits:
        return 0
    a, br, v0 = plan.accel_mps2, plan.decel_mps2, plan.v0_mps
    st = np.empty(3)
    st[0], st[1], st[2] = 0.0, -plan.d_m, v0
    n = _accel_to(st, segs, 0, v_m, a if v_m >= v0 else br)
    n = _cruise_to(st, segs, n, -d3)
    n = _accel_to(st, segs, n, v_e, a if v_e >= v_m else br)
    st[1] = 0.0
    return _crossing(st, segs, n, plan.cap_mps, a, plan.s_end_m)


@njit(cache=True, nogil=True)
def _build_b(plan: Plan, wait_s: float, segs: np.ndarray) -> int:
    """``Planner._build_b`` from the stop-at-the-line base (its segments and (t, s, v))."""
    n = len(plan.b_segs)
    segs[:n] = plan.b_segs
    st = plan.b_state.copy()
    if wait_s > 0:
        n = _seg(segs, n, st[0], st[1], 0.0, 0.0)
        st[0] += wait_s
    return _crossing(st, segs, n, plan.cap_mps, plan.accel_mps2, plan.s_end_m)


@njit(cache=True, nogil=True)
def time_at(segs: np.ndarray, n: int, s: float) -> float:
    """``Profile.time_at`` of the first ``n`` segments."""
    for k in range(n):
        s0, v0, a = segs[k, 1], segs[k, 2], segs[k, 3]
        end = segs[k + 1, 0] - segs[k, 0] if k + 1 < n else math.inf
        ds = s - s0
        if ds <= 0.0:
            return segs[k, 0]
        if abs(a) < EPS_PLAN:
            tau = ds / v0 if v0 > EPS_PLAN else math.inf
        else:
            disc = v0 * v0 + 2.0 * a * ds
            tau = math.inf if disc < 0.0 else (math.sqrt(disc) - v0) / a
        if tau <= end + 1e-9:
            return segs[k, 0] + tau
    return math.inf


@njit(cache=True, nogil=True)
def next_plan(
    target: float, plan: Plan, step: float, segs: np.ndarray, s: np.ndarray
) -> tuple[bool, np.ndarray, float]:
    """``Planner.at_or_after(target)``, sampled every ``step``: (built, its samples, its
    wait if of the stop family else -1); (False, ``s``, -1) where the Python loop
    raises. ``segs`` is room for the segments."""
    if not plan.hi_ok:
        return False, s, -1.0
    b_wait = -1.0
    if target <= plan.hi_entry_s + 1e-9:
        ns = _build_a(plan, plan.v_hi_mps, segs)
    elif plan.lo_ok and target <= plan.lo_entry_s:
        v = cruise_for(plan, plan.v_lo_mps, plan.v_hi_mps, target)
        ns = _build_a(plan, v, segs)
    elif not math.isfinite(plan.stop_entry_s):
        ns = 0
    else:
        b_wait = py_max(0.0, target - plan.stop_entry_s)
        ns = _build_b(plan, b_wait, segs)
    if ns == 0:
        return False, s, -1.0
    t_out = time_at(segs, ns, plan.s_end_m)
    if not math.isfinite(t_out):
        return False, s, -1.0
    count = math.ceil(t_out / step - 1e-9) + 1
    out = np.empty(count)
    p = np.ascontiguousarray(segs[:ns].T)
    profile_position(p[0], p[1], p[2], p[3], step, out)
    return True, out, b_wait
