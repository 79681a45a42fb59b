"""Compiled inner loops of enhanced DICA (numba), bit for bit the numpy versions.

One round of Algorithm 1 on arrays of a hundred or so occupancies costs
almost nothing in arithmetic; with numpy it is dozens of calls, each paying
its own overhead. These loops do the same arithmetic, in the same order, in
one call each:

* :func:`grid_dtot`: footprint centres and headings from the front and
  rear points, the grid index and technique 3's intervals, exact or the
  dissertation's estimate, as the grid's tables say
  (:func:`ica.core.dtot.grid_intervals`, :func:`ica.core.occupancy.footprints`);
* :func:`batch_conflicts`: getCV with techniques 1, 2 and 4 over every
  confirmed vehicle (:func:`ica.core.conflict.get_cv_batch`).

Floating-point results equal numpy's exactly: the expressions are written
in numpy's order, numba does not fuse multiply-adds without ``fastmath``,
and the binary search is numpy's own, so it gives numpy's answer even on
unsorted input. ``tests/test_batch.py``, ``tests/test_kernels.py`` and
``tests/test_dtot.py`` hold the numpy versions beside these as oracles.

The functions are compiled when this module is first imported (explicit
signatures) and cached on disk by numba next to the module, like byte code;
deciding a request does no I/O and no compilation. A fresh cache costs a few
seconds once; a warm one well under a second per process.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

APART, MAYBE, TOUCH = 0, 1, 2  # as in ica.core.zones
_EPS_SAT = 1e-9  # as in ica.core.occupancy.separated


@njit("int64(float64[::1], float64, boolean)", cache=True, nogil=True)
def _search(a: np.ndarray, key: float, right: bool) -> int:
    """np.searchsorted for one key (a plain binary search: a is sorted here)."""
    lo, hi = 0, len(a)
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        if a[mid] <= key if right else a[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit("void(float64[::1], float64[::1], boolean, int64[::1])", cache=True, nogil=True)
def _searchsorted(a: np.ndarray, keys: np.ndarray, right: bool, out: np.ndarray) -> None:
    """np.searchsorted(a, keys), numpy's own algorithm step for step.

    numpy narrows the search with the previous key, so on input that is not
    sorted its answer depends on that; copying it keeps the answer identical
    wherever a trajectory is not monotone by a rounding error.
    """
    n = len(a)
    lo, hi = 0, n
    last = keys[0] if len(keys) else 0.0
    for q in range(len(keys)):
        key = keys[q]
        if (last <= key) if right else (last < key):
            hi = n
        else:
            lo = 0
            hi = hi + 1 if hi < n else n
        last = key
        while lo < hi:
            mid = lo + ((hi - lo) >> 1)
            if (a[mid] <= key) if right else (a[mid] < key):
                lo = mid + 1
            else:
                hi = mid
        out[q] = lo


@njit("boolean(float64[::1])", cache=True, nogil=True)
def _strictly_increasing(a: np.ndarray) -> bool:
    for k in range(len(a) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if not a[k] < a[k + 1]:
            return False
    return True


@njit("void(float64[::1], float64[::1], float64[::1], float64[::1])", cache=True, nogil=True)
def _interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, out: np.ndarray) -> None:
    """``np.interp(x, xp, fp)`` into ``out``, for strictly increasing ``xp`` (2 points or more).

    numpy's arithmetic and special cases (numba's copy of ``arr_interp``);
    only the search differs: on strictly increasing ``xp`` the segment j is
    the last one with ``xp[j] <= x``, which a walk from the previous query
    finds as numpy's binary search does, in O(1) for sorted queries.
    """
    n = len(xp)
    lval = fp[0]
    rval = fp[n - 1]
    j = 0
    for i in range(len(x)):
        xv = x[i]
        if np.isnan(xv):
            out[i] = xv
            continue
        if xv > xp[n - 1]:
            out[i] = rval
            continue
        if xv < xp[0]:
            out[i] = lval
            continue
        # the largest j with xp[j] <= xv: what numpy's search finds on strictly increasing xp
        while j + 1 < n and xp[j + 1] <= xv:
            j += 1
        while xp[j] > xv:
            j -= 1
        if j == n - 1 or xp[j] == xv:  # numpy's two cases giving fp[j]
            out[i] = fp[j]
        else:
            slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
            r = slope * (xv - xp[j]) + fp[j]
            if np.isnan(r):
                r = slope * (xv - xp[j + 1]) + fp[j + 1]
                if np.isnan(r) and fp[j] == fp[j + 1]:
                    r = fp[j]
            out[i] = r


@njit("float64[::1](float64[::1], float64[::1], float64[::1])", cache=True, nogil=True)
def _interp_any(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp``: :func:`_interp` where ``xp`` rises strictly, numba's copy otherwise."""
    if len(xp) >= 2 and _strictly_increasing(xp):
        out = np.empty(len(x))
        _interp(x, xp, fp, out)
        return out
    return np.interp(x, xp, fp)


@njit("float64[:, ::1](float64[::1], float64[::1], float64[:, ::1])", cache=True, nogil=True)
def route_points(s: np.ndarray, route_s: np.ndarray, route_xy: np.ndarray) -> np.ndarray:
    """:meth:`ica.core.route.Route.points` for a 1-D ``s``: (N, 2) points on the polyline."""
    out = np.empty((len(s), 2))
    x = _interp_any(s, route_s, route_xy[:, 0].copy())
    y = _interp_any(s, route_s, route_xy[:, 1].copy())
    for k in range(len(s)):
        out[k, 0] = x[k]
        out[k, 1] = y[k]
    return out


@njit(
    "Tuple((float64[:, ::1], float64[::1]))(float64[:], float64, float64[::1], float64[:, ::1])",
    cache=True,
    nogil=True,
)
def front_heading(
    s: np.ndarray, length_m: float, route_s: np.ndarray, route_xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``Trajectory.xy_heading``: front points at ``s`` and the heading from the rear
    point ``length_m`` behind, ``np.arctan2`` of their difference."""
    n = len(s)
    front_s = np.empty(n)
    rear_s = np.empty(n)
    for k in range(n):
        front_s[k] = s[k]
        rear_s[k] = s[k] - length_m
    front = route_points(front_s, route_s, route_xy)
    rear = route_points(rear_s, route_s, route_xy)
    heading = np.empty(n)
    for k in range(n):
        heading[k] = np.arctan2(front[k, 1] - rear[k, 1], front[k, 0] - rear[k, 0])
    return front, heading


@njit(
    "UniTuple(float64[::1], 4)(float64, float64, float64[:], float64, float64[::1],"
    " float64[:, ::1])",
    cache=True,
    nogil=True,
)
def tss_of(
    t0_s: float, step_s: float, s: np.ndarray, length_m: float, route_s: np.ndarray,
    route_xy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """A trajectory as a TSS: sample times (``Trajectory.t_s``), front points and
    headings (:func:`front_heading`), as four arrays."""
    n = len(s)
    t = np.empty(n)
    for k in range(n):
        t[k] = t0_s + step_s * np.float64(k)
    front, heading = front_heading(s, length_m, route_s, route_xy)
    x = np.empty(n)
    y = np.empty(n)
    for k in range(n):
        x[k] = front[k, 0]
        y[k] = front[k, 1]
    return t, x, y, heading


@njit(
    "float64[:, ::1](float64[:], float64[:], float64[:, :], float64[:, :], float64, float64,"
    " int64[:])",
    cache=True,
    nogil=True,
)
def pack_rows(
    lb: np.ndarray, ub: np.ndarray, centre: np.ndarray, heading: np.ndarray, half_l: float,
    half_w: float, g: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """``ica.core.conflict.pack``: a DTOT's occupancies as rows of its PACKED columns."""
    n = len(lb)
    out = np.empty((n, 9))
    for k in range(n):
        out[k, 0] = lb[k]
        out[k, 1] = ub[k]
        out[k, 2] = centre[k, 0]
        out[k, 3] = centre[k, 1]
        out[k, 4] = heading[k, 0]
        out[k, 5] = heading[k, 1]
        out[k, 6] = half_l
        out[k, 7] = half_w
        out[k, 8] = np.float64(g[k])
    return out


@njit("UniTuple(int64, 2)(float64[::1], float64)", cache=True, nogil=True)
def dtot_span(s: np.ndarray, s_end_m: float) -> tuple[int, int]:
    """(entry_index, exit_index) of :class:`ica.core.trajectory.Trajectory`."""
    n = len(s)
    k0 = n - 1
    for k in range(n):
        if s[k] > 0.0:
            k0 = max(k - 1, 0)
            break
    k1 = n - 1
    for k in range(n):
        if s[k] >= s_end_m - 1e-9:
            k1 = k
            break
    return k0, k1


@njit(cache=True, nogil=True)
def _self_overlap(
    centre: np.ndarray, heading: np.ndarray, la: float, wa: float, k: int, j: int
) -> bool:
    """``overlap_matrix(rects, rects)[k, j]``: the separating-axis test of
    :func:`ica.core.occupancy.separated`, term for term."""
    ax, ay = heading[k, 0], heading[k, 1]
    bx, by = heading[j, 0], heading[j, 1]
    dx = centre[j, 0] - centre[k, 0]
    dy = centre[j, 1] - centre[k, 1]
    cs = abs(ax * bx + ay * by)
    sn = abs(ax * by - ay * bx)
    if abs(dx * ax + dy * ay) > la + la * cs + wa * sn + _EPS_SAT:
        return False
    if abs(dy * ax - dx * ay) > wa + la * sn + wa * cs + _EPS_SAT:
        return False
    if abs(dx * bx + dy * by) > la + la * cs + wa * sn + _EPS_SAT:
        return False
    return not abs(dy * bx - dx * by) > wa + la * sn + wa * cs + _EPS_SAT


@njit(cache=True, nogil=True)
def _nondecreasing(a: np.ndarray) -> bool:
    for k in range(len(a) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if not a[k] <= a[k + 1]:
            return False
    return True


@njit(
    "void(float64[::1], float64[::1], float64[::1], float64, float64[::1], float64,"
    " float64, float64[::1], float64[::1], float64, float64,"
    " float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], int64[::1])",
    cache=True,
    nogil=True,
)
def grid_dtot(
    route_s: np.ndarray,
    route_x: np.ndarray,
    route_y: np.ndarray,
    length_m: float,
    s: np.ndarray,
    s0_m: float,
    ds_m: float,
    fwd_m: np.ndarray,
    back_m: np.ndarray,
    half_l: float,
    half_w: float,
    centre: np.ndarray,
    heading: np.ndarray,
    t: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    g: np.ndarray,
) -> None:
    """Footprints, grid index and technique 3's intervals of occupancies at ``s``, times ``t``.

    :func:`ica.core.occupancy.footprints` (front and rear points by
    ``np.interp`` on the route polyline), ``RouteGrid.index`` and
    :func:`ica.core.dtot.grid_intervals`, into the out arrays: for each
    occupancy, the samples within the grid's skip distances are taken to
    overlap it, and beyond them the nearest one the exact test finds clear
    bounds its interval. With exact tables that is the exhaustive interval;
    with the dissertation's the first sample tested is already clear.
    """
    n = len(s)
    last = len(fwd_m) - 1
    half = length_m / 2.0
    rear = s - length_m
    fx = _interp_any(s, route_s, route_x)
    fy = _interp_any(s, route_s, route_y)
    rx = _interp_any(rear, route_s, route_x)
    ry = _interp_any(rear, route_s, route_y)
    behind = np.empty(n)
    ahead = np.empty(n)
    for k in range(n):
        ax = fx[k] - rx[k]
        ay = fy[k] - ry[k]
        norm = math.sqrt(ax * ax + ay * ay)
        d = max(norm, 1e-12)
        hx = ax / d
        hy = ay / d
        heading[k, 0] = hx
        heading[k, 1] = hy
        centre[k, 0] = fx[k] - hx * half
        centre[k, 1] = fy[k] - hy * half
        i = np.int64(np.rint((s[k] - s0_m) / ds_m))
        i = min(max(i, 0), last)
        g[k] = i
        behind[k] = s[k] - back_m[i]
        ahead[k] = s[k] + fwd_m[i]
    # where s rises, the skipped samples are one range, found by a walk from the last
    # sample's (np.searchsorted's answer on sorted s, in a step or two); else (a
    # rounding error off monotone) they are skipped one by one
    sorted_s = _nondecreasing(s)
    p_lo = 0  # first index with s > behind[k]
    p_hi = 0  # first index with s >= ahead[k]
    for k in range(n):
        j = k - 1
        if sorted_s:
            key = behind[k]
            while p_lo < n and s[p_lo] <= key:
                p_lo += 1
            while p_lo > 0 and s[p_lo - 1] > key:
                p_lo -= 1
            j = min(p_lo - 1, j)
        while j >= 0:
            if behind[k] < s[j] <= s[k] or _self_overlap(centre, heading, half_l, half_w, k, j):
                j -= 1
            else:
                break
        lb[k] = t[j] if j >= 0 else t[0]
        j = k + 1
        if sorted_s:
            key = ahead[k]
            while p_hi < n and s[p_hi] < key:
                p_hi += 1
            while p_hi > 0 and s[p_hi - 1] >= key:
                p_hi -= 1
            j = max(p_hi, j)
        while j < n:
            if s[k] <= s[j] < ahead[k] or _self_overlap(centre, heading, half_l, half_w, k, j):
                j += 1
            else:
                break
        ub[k] = t[j] if j < n else t[n - 1]


@njit(
    "Tuple((int64, float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[::1],"
    " float64[::1], int64[::1]))(float64[::1], float64, float64, float64, float64[::1],"
    " float64[::1], float64[::1], float64, float64, float64, float64[::1], float64[::1],"
    " float64, float64)",
    cache=True,
    nogil=True,
)
def grid_dtot_of(
    s_all: np.ndarray, s_end_m: float, t0_s: float, step_s: float, route_s: np.ndarray,
    route_x: np.ndarray, route_y: np.ndarray, length_m: float, s0_m: float, ds_m: float,
    fwd_m: np.ndarray, back_m: np.ndarray, half_l: float, half_w: float,
) -> tuple:  # fmt: skip
    """``build_dtot`` with the grid, its arrays in one call: (k0, times, arc lengths,
    centres, headings, lb, ub, grid index) of the occupancies of samples ``s_all``
    (the trajectory from ``t0_s``, every ``step_s``) from the entry to the exit."""
    k0, k1 = dtot_span(s_all, s_end_m)
    s = s_all[k0 : k1 + 1].copy()
    n = len(s)
    t = np.empty(n)
    for q in range(n):
        t[q] = t0_s + step_s * np.float64(k0 + q)
    centre = np.empty((n, 2))
    heading = np.empty((n, 2))
    lb = np.empty(n)
    ub = np.empty(n)
    g = np.empty(n, np.int64)
    grid_dtot(
        route_s, route_x, route_y, length_m, s, s0_m, ds_m, fwd_m, back_m, half_l, half_w,
        centre, heading, t, lb, ub, g,
    )  # fmt: skip
    return k0, t, s, centre, heading, lb, ub, g


@njit(
    "Tuple((boolean, float64, float64))(float64, float64, float64[::1], float64, float64,"
    " float64[::1], float64, float64)",
    cache=True,
    nogil=True,
)
def follow_check(
    t0_f: float,
    step_f: float,
    s_f: np.ndarray,
    t0_l: float,
    step_l: float,
    s_l: np.ndarray,
    leader_length_m: float,
    gap_m: float,
) -> tuple[bool, float, float]:
    """:func:`ica.core.conflict.follow_conflict`: (violated, first time, raw delay)."""
    nf, nl = len(s_f), len(s_l)
    tf = np.empty(nf)
    for k in range(nf):
        tf[k] = t0_f + step_f * k
    tl = np.empty(nl)
    for k in range(nl):
        tl[k] = t0_l + step_l * k
    m = 0
    last = -1
    for k in range(nf):
        if s_f[k] < 0.0:
            m += 1
            last = k
    if m == 0:
        return False, 0.0, 0.0
    t_end = tf[last] + step_f
    extra = 0
    for k in range(nl):
        if tl[k] >= tf[0] and tl[k] <= t_end:
            extra += 1
    t = np.empty(m + extra)
    q = 0
    for k in range(nf):
        if s_f[k] < 0.0:
            t[q] = tf[k]
            q += 1
    for k in range(nl):
        if tl[k] >= tf[0] and tl[k] <= t_end:
            t[q] = tl[k]
            q += 1
    sf_t = _interp_any(t, tf, s_f)
    sl_t = _interp_any(t, tl, s_l)
    nbad = 0
    for q in range(len(t)):
        if sf_t[q] < 0.0 and sf_t[q] > sl_t[q] - leader_length_m - gap_m:
            nbad += 1
    if nbad == 0:
        return False, 0.0, 0.0
    need = np.empty(nbad)
    tb = np.empty(nbad)
    r = 0
    for q in range(len(t)):
        if sf_t[q] < 0.0 and sf_t[q] > sl_t[q] - leader_length_m - gap_m:
            need[r] = sf_t[q] + leader_length_m + gap_m
            tb[r] = t[q]
            r += 1
    idx = np.empty(nbad, np.int64)
    _searchsorted(s_l, need, False, idx)
    first = tb[0]
    delay = tl[min(idx[0], nl - 1)] - tb[0]
    for r in range(1, nbad):
        first = min(first, tb[r])
        delay = max(delay, tl[min(idx[r], nl - 1)] - tb[r])
    return True, first, delay


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
        k = min(max(_search(t_s, t, True) - 1, 0), last)
        tau = max(t - t_s[k], 0.0)
        out[q] = s_m[k] + v_mps[k] * tau + 0.5 * a_mps2[k] * tau * tau


@njit(
    "boolean(float64[::1], float64[::1], int64[::1], float64[:, ::1], float64[:, ::1], float64,"
    " float64, float64[:, ::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1],"
    " int8[::1], int64, boolean[::1], float64[::1], float64[::1])",
    cache=True,
    nogil=True,
)
def batch_conflicts(
    lb_i: np.ndarray,
    ub_i: np.ndarray,
    g_i: np.ndarray,
    centre_i: np.ndarray,
    heading_i: np.ndarray,
    la: float,
    wa: float,
    packed: np.ndarray,
    vid: np.ndarray,
    m_idx: np.ndarray,
    row: np.ndarray,
    row_lo: np.ndarray,
    row_hi: np.ndarray,
    codes: np.ndarray,
    width: int,
    hit: np.ndarray,
    first: np.ndarray,
    delay: np.ndarray,
) -> bool:
    """getCV of requester i against the confirmed occupancies ``packed[m_idx]``.

    ``packed`` rows are ``ica.core.conflict.PACKED`` (interval, centre,
    heading, half extents, grid index). Per vehicle v: ``hit[v]``, and over
    its conflicting pairs the least ``lb_j`` (firstTimeAtCollision) and the
    greatest ``ub_j - lb_i`` (delay). Returns whether any vehicle conflicts.
    """
    n = len(lb_i)
    found = False
    if n == 0:
        return found
    ub_hull = np.empty(n)
    lb_hull = np.empty(n)
    g_hi = np.empty(n)
    g_lo = np.empty(n)
    for k in range(n):
        ub_hull[k] = ub_i[k] if k == 0 else max(ub_hull[k - 1], ub_i[k])
        g_hi[k] = g_i[k] if k == 0 else max(g_hi[k - 1], g_i[k])
    for k in range(n - 1, -1, -1):
        lb_hull[k] = lb_i[k] if k == n - 1 else min(lb_hull[k + 1], lb_i[k])
        g_lo[k] = g_i[k] if k == n - 1 else min(g_lo[k + 1], g_i[k])
    t_lo, t_hi = lb_hull[0], ub_hull[n - 1]  # the requester's whole crossing
    for c in range(len(m_idx)):
        q = m_idx[c]
        lb_j, ub_j = packed[q, 0], packed[q, 1]
        if ub_j < t_lo or lb_j > t_hi:
            continue  # no interval of the requester can overlap
        lo = max(_search(ub_hull, lb_j, False), _search(g_hi, float(row_lo[c]), False))
        hi = min(_search(lb_hull, ub_j, True), _search(g_lo, float(row_hi[c]), True))
        base = row[c] * width
        for k in range(lo, hi):
            if not (lb_i[k] <= ub_j and lb_j <= ub_i[k]):
                continue
            code = codes[base + g_i[k]]
            if code == APART:
                continue
            if code == MAYBE:
                # ica.core.occupancy.separated, a = requester, b = confirmed
                ax, ay = heading_i[k, 0], heading_i[k, 1]
                bx, by = packed[q, 4], packed[q, 5]
                dx = packed[q, 2] - centre_i[k, 0]
                dy = packed[q, 3] - centre_i[k, 1]
                cs = abs(ax * bx + ay * by)
                sn = abs(ax * by - ay * bx)
                lb, wb = packed[q, 6], packed[q, 7]
                if abs(dx * ax + dy * ay) > la + lb * cs + wb * sn + _EPS_SAT:
                    continue
                if abs(dy * ax - dx * ay) > wa + lb * sn + wb * cs + _EPS_SAT:
                    continue
                if abs(dx * bx + dy * by) > lb + la * cs + wa * sn + _EPS_SAT:
                    continue
                if abs(dy * bx - dx * by) > wb + la * sn + wa * cs + _EPS_SAT:
                    continue
            v = vid[q]
            d = ub_j - lb_i[k]
            if hit[v]:
                first[v] = min(first[v], lb_j)
                delay[v] = max(delay[v], d)
            else:
                hit[v] = True
                first[v] = lb_j
                delay[v] = d
            found = True
    return found


@njit(cache=True, nogil=True)
def _row_conflict(
    c: int, lb_i: np.ndarray, ub_i: np.ndarray, g_i: np.ndarray, centre_i: np.ndarray,
    heading_i: np.ndarray, la: float, wa: float, packed: np.ndarray, m_idx: np.ndarray,
    row: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray, codes: np.ndarray, width: int,
    ub_hull: np.ndarray, lb_hull: np.ndarray, g_hi: np.ndarray, g_lo: np.ndarray,
) -> tuple[bool, float]:  # fmt: skip
    """The pairs of :func:`batch_conflicts` for confirmed occupancy ``m_idx[c]``:
    (any conflicting, the greatest ``ub_j - lb_i`` over them)."""
    q = m_idx[c]
    lb_j, ub_j = packed[q, 0], packed[q, 1]
    lo = max(_search(ub_hull, lb_j, False), _search(g_hi, float(row_lo[c]), False))
    hi = min(_search(lb_hull, ub_j, True), _search(g_lo, float(row_hi[c]), True))
    base = row[c] * width
    found = False
    worst = 0.0
    for k in range(lo, hi):
        if not (lb_i[k] <= ub_j and lb_j <= ub_i[k]):
            continue
        code = codes[base + g_i[k]]
        if code == APART:
            continue
        if code == MAYBE:
            ax, ay = heading_i[k, 0], heading_i[k, 1]
            bx, by = packed[q, 4], packed[q, 5]
            dx = packed[q, 2] - centre_i[k, 0]
            dy = packed[q, 3] - centre_i[k, 1]
            cs = abs(ax * bx + ay * by)
            sn = abs(ax * by - ay * bx)
            lb, wb = packed[q, 6], packed[q, 7]
            if abs(dx * ax + dy * ay) > la + lb * cs + wb * sn + _EPS_SAT:
                continue
            if abs(dy * ax - dx * ay) > wa + lb * sn + wb * cs + _EPS_SAT:
                continue
            if abs(dx * bx + dy * by) > lb + la * cs + wa * sn + _EPS_SAT:
                continue
            if abs(dy * bx - dx * by) > wb + la * sn + wa * cs + _EPS_SAT:
                continue
        d = ub_j - lb_i[k]
        worst = max(worst, d) if found else d
        found = True
    return found, worst


@njit(cache=True, nogil=True)
def first_conflict(
    lb_i: np.ndarray, ub_i: np.ndarray, g_i: np.ndarray, centre_i: np.ndarray,
    heading_i: np.ndarray, la: float, wa: float, packed: np.ndarray, vid: np.ndarray,
    m_idx: np.ndarray, row: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray,
    codes: np.ndarray, width: int, lbs: np.ndarray, span_s: float, bound: float,
) -> tuple[int, float, float]:  # fmt: skip
    """The first conflicting vehicle of :func:`batch_conflicts` and its two values.

    Returns (v, firstTimeAtCollision, delay) of the vehicle ``Dica._resolve``
    takes first: the least firstTimeAtCollision, the lower index on a tie;
    v = -1 if no vehicle conflicts at or before ``bound``. The rows must come
    in ascending ``lb_j`` (``packed[m_idx, 0]``): the first conflicting row
    then holds the least firstTimeAtCollision of all, rows after the
    requester's crossing or after that time cannot change the choice, and
    only the chosen vehicle's later rows are searched for its delay (a
    maximum: the order does not change it). ``lbs`` are those ``lb_j``, and no
    row's interval is longer than ``span_s``: the rows that start more than
    that before the requester's crossing end before it and are skipped by
    binary search.
    """
    n = len(lb_i)
    if n == 0:
        return -1, 0.0, 0.0
    ub_hull = np.empty(n)
    lb_hull = np.empty(n)
    g_hi = np.empty(n)
    g_lo = np.empty(n)
    for k in range(n):
        ub_hull[k] = ub_i[k] if k == 0 else max(ub_hull[k - 1], ub_i[k])
        g_hi[k] = g_i[k] if k == 0 else max(g_hi[k - 1], g_i[k])
    for k in range(n - 1, -1, -1):
        lb_hull[k] = lb_i[k] if k == n - 1 else min(lb_hull[k + 1], lb_i[k])
        g_lo[k] = g_i[k] if k == n - 1 else min(g_lo[k + 1], g_i[k])
    t_lo, t_hi = lb_hull[0], ub_hull[n - 1]
    best = -1
    best_first = 0.0
    best_delay = 0.0
    rows = len(m_idx)
    # ub_j <= lb_j + span_s < t_lo below that (1e-6 s over rounding)
    c = _search(lbs, t_lo - span_s - 1e-6, False)
    while c < rows:
        q = m_idx[c]
        lb_j, ub_j = packed[q, 0], packed[q, 1]
        if lb_j > t_hi or lb_j > bound or (best >= 0 and lb_j > best_first):
            break
        if ub_j >= t_lo:
            found, worst = _row_conflict(
                c, lb_i, ub_i, g_i, centre_i, heading_i, la, wa, packed, m_idx, row,
                row_lo, row_hi, codes, width, ub_hull, lb_hull, g_hi, g_lo,
            )  # fmt: skip
            if found:
                v = vid[q]
                if best < 0 or v < best:
                    best = v
                    best_first = lb_j
                    best_delay = worst
                elif v == best:
                    best_delay = max(best_delay, worst)
        c += 1
    if best < 0:
        return -1, 0.0, 0.0
    # rows of lb_j == best_first seen so far may hold delays of other vehicles: only best's count
    while c < rows:
        q = m_idx[c]
        lb_j, ub_j = packed[q, 0], packed[q, 1]
        if lb_j > t_hi:
            break
        if vid[q] == best and ub_j >= t_lo:
            found, worst = _row_conflict(
                c, lb_i, ub_i, g_i, centre_i, heading_i, la, wa, packed, m_idx, row,
                row_lo, row_hi, codes, width, ub_hull, lb_hull, g_hi, g_lo,
            )  # fmt: skip
            if found:
                best_delay = max(best_delay, worst)
        c += 1
    return best, best_first, best_delay


@njit(
    "Tuple((float64[::1], float64[::1]))(float64[:, ::1], float64[::1], float64[:, ::1])",
    cache=True,
    nogil=True,
)
def project(xy: np.ndarray, route_s: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`ica.core.route.Route.project`: arc length of the nearest polyline
    point and the distance to it, per point of ``p`` (N, 2); first nearest wins."""
    m = len(xy) - 1
    n = len(p)
    s = np.empty(n)
    dist = np.empty(n)
    seg = np.empty(m)
    for j in range(m):
        dx = xy[j + 1, 0] - xy[j, 0]
        dy = xy[j + 1, 1] - xy[j, 1]
        seg[j] = dx * dx + dy * dy
    for q in range(n):
        best = np.inf
        bk = 0
        bu = 0.0
        for j in range(m):
            dx = xy[j + 1, 0] - xy[j, 0]
            dy = xy[j + 1, 1] - xy[j, 1]
            wx = p[q, 0] - xy[j, 0]
            wy = p[q, 1] - xy[j, 1]
            u = (wx * dx + wy * dy) / seg[j]
            u = u if u > 0.0 else 0.0  # np.clip's order and signs
            u = u if u < 1.0 else 1.0
            ex = p[q, 0] - (xy[j, 0] + u * dx)
            ey = p[q, 1] - (xy[j, 1] + u * dy)
            d2 = ex * ex + ey * ey
            if d2 < best:
                best = d2
                bk = j
                bu = u
        s[q] = route_s[bk] + bu * math.sqrt(seg[bk])
        dist[q] = math.sqrt(best)
    return s, dist


@njit("float64(float64, float64)", cache=True, nogil=True)
def _py_min(a: float, b: float) -> float:
    """Python's ``min(a, b)``: the first unless the second is smaller (signed zeros too)."""
    return b if b < a else a


@njit("float64(float64, float64)", cache=True, nogil=True)
def _py_max(a: float, b: float) -> float:
    return b if b > a else a


@njit(
    "Tuple((boolean, float64, float64, float64, float64))"
    "(float64, float64, float64, float64, float64, float64)",
    cache=True,
    nogil=True,
)
def a_phases(
    a: float, br: float, v0: float, d: float, cap: float, v_m: float
) -> tuple[bool, float, float, float, float]:
    """(fits, D1, D3, v_e, T) of the slow-down plan A(v_m); see ``Planner._a_phases``."""
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
        v_e = _py_min(cap, math.sqrt(_py_max(v_m * v_m + 2 * a * (d - d1), 0.0)))
        d3 = (v_e * v_e - v_m * v_m) / (2 * a)
        t3 = (v_e - v_m) / a
    d2 = d - d1 - d3
    if d2 < -1e-7:
        return False, 0.0, 0.0, 0.0, 0.0
    if d2 > 1e-9 and v_m <= 1e-9:
        return False, 0.0, 0.0, 0.0, 0.0
    t2 = d2 / v_m if d2 > 1e-9 else 0.0
    return True, d1, d3, v_e, t1 + t2 + t3


@njit(
    "float64(float64, float64, float64, float64, float64, float64, float64, float64)",
    cache=True,
    nogil=True,
)
def bisect_cruise(
    a: float, br: float, v0: float, d: float, cap: float, v_lo: float, v_hi: float, t_entry: float
) -> float:
    """The bisection of ``Planner.at_or_after``: the cruise speed arriving at ``t_entry``."""
    lo_v, hi_v = v_lo, v_hi
    for _ in range(60):
        mid = 0.5 * (lo_v + hi_v)
        fits, _d1, _d3, _ve, t = a_phases(a, br, v0, d, cap, mid)
        if not fits or t > t_entry:
            lo_v = mid
        else:
            hi_v = mid
        # the entry time's slope is d2 / v^2: 80 s per m/s when creeping at 0.5 m/s
        # 20 m short of the line, so the speed must be this fine for microseconds
        if hi_v - lo_v < 1e-10:
            break
    return hi_v


@njit(
    "Tuple((int64, float64, float64[::1]))(float64[::1], float64[::1], float64[::1], float64[::1],"
    " float64, float64, float64[:, ::1], float64[::1], float64, float64, float64, float64)",
    cache=True,
    nogil=True,
)
def tss_checks(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    h: np.ndarray,
    step_s: float,
    t0_s: float,
    route_xy: np.ndarray,
    route_s: np.ndarray,
    off_tol_m: float,
    dist_to_entry_m: float,
    start_tol_m: float,
    s_end_m: float,
) -> tuple[int, float, np.ndarray]:
    """The numeric checks of a TSS up to its arc length, in ``validate._check_tss``'s order.

    Returns (failed check, a value for its message, monotone arc length);
    check 0 means all passed. 1 not finite, 2 times not increasing, 3 not
    sampled every step, 4 not starting at t0, 5 off the route (value: worst
    offset), 6 start not matching the state (value: s[0]), 7 moving
    backwards, 8 ending before the vehicle is out.
    """
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
        if abs((t[k + 1] - t[k]) - step_s) > 1e-6:
            return 3, 0.0, empty
    if abs(t[0] - t0_s) > 1e-6:
        return 4, 0.0, empty
    p = np.empty((n, 2))
    for k in range(n):
        p[k, 0] = x[k]
        p[k, 1] = y[k]
    s, off = project(route_xy, route_s, p)
    worst = off[0]
    for k in range(1, n):
        worst = max(worst, off[k])
    if worst > off_tol_m:
        return 5, worst, empty
    if abs(s[0] + dist_to_entry_m) > start_tol_m:
        return 6, s[0], empty
    for k in range(n - 1):
        if s[k + 1] - s[k] < -1e-6:
            return 7, 0.0, empty
    for k in range(1, n):  # np.maximum.accumulate: the earlier one unless smaller
        if s[k - 1] >= s[k]:
            s[k] = s[k - 1]
    if s[n - 1] < s_end_m - 1e-6:
        return 8, 0.0, empty
    return 0, 0.0, s


@njit(
    "Tuple((int64, float64))(float64[::1], float64, float64, float64, float64, float64,"
    " float64, float64, float64)",
    cache=True,
    nogil=True,
)
def limit_checks(
    s: np.ndarray,
    step_s: float,
    v0_mps: float,
    road_lim_mps: float,
    cap_lim_mps: float,
    accel_mps2: float,
    decel_mps2: float,
    accel_tol_mps2: float,
    first_slack_mps2: float,
) -> tuple[int, float]:
    """``validate.check_limits`` with a reported speed: (failed check, value).

    1 above the road limit (value: top speed), 2 above the turn cap inside,
    3 beyond the acceleration or deceleration limit; 0 passed.
    """
    n = len(s) - 1
    v = np.empty(n)
    for k in range(n):
        v[k] = (s[k + 1] - s[k]) / step_s
    for k in range(n):
        if v[k] > road_lim_mps:
            top = v[0]
            for q in range(1, n):
                top = max(top, v[q])
            return 1, top
    for k in range(n):
        if s[k] >= 0.0 and v[k] > cap_lim_mps:
            return 2, 0.0
    for k in range(n):
        acc = ((v[k] - v0_mps) if k == 0 else (v[k] - v[k - 1])) / step_s
        slack = accel_tol_mps2 + first_slack_mps2 if k == 0 else accel_tol_mps2
        if acc > accel_mps2 + slack:
            return 3, 0.0
    for k in range(n):
        acc = ((v[k] - v0_mps) if k == 0 else (v[k] - v[k - 1])) / step_s
        slack = accel_tol_mps2 + first_slack_mps2 if k == 0 else accel_tol_mps2
        if acc < -decel_mps2 - slack:
            return 3, 0.0
    return 0, 0.0


@njit("boolean(float64[:], float64, float64)", cache=True, nogil=True)
def over_cap(s: np.ndarray, step_s: float, lim_mps: float) -> bool:
    """``np.any(np.diff(s)[s[:-1] >= 0] / step_s > lim_mps)``: faster than ``lim_mps``
    over a step that starts inside the junction."""
    for k in range(len(s) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if s[k] >= 0.0 and (s[k + 1] - s[k]) / step_s > lim_mps:
            return True
    return False


@njit(
    "Tuple((int64, int64, float64, float64[::1]))(float64[::1], float64[::1], float64[::1],"
    " float64[::1], float64, float64, float64[:, ::1], float64[::1], float64, float64, float64,"
    " float64, float64, float64, float64, float64, float64, float64, float64, float64, float64)",
    cache=True,
    nogil=True,
)
def request_checks(
    t: np.ndarray, x: np.ndarray, y: np.ndarray, h: np.ndarray, step_s: float, t0_s: float,
    route_xy: np.ndarray, route_s: np.ndarray, off_tol_m: float, dist_to_entry_m: float,
    start_tol_m: float, s_end_m: float, length_m: float, heading_tol_rad: float,
    v0_mps: float, road_lim_mps: float, cap_lim_mps: float, accel_mps2: float,
    decel_mps2: float, accel_tol_mps2: float, first_slack_mps2: float,
) -> tuple[int, int, float, np.ndarray]:  # fmt: skip
    """Every numeric check of ``validate._check_tss`` in one call, in its order:
    :func:`tss_checks`, the heading against the route's, :func:`limit_checks`.

    Returns (stage, failed check, value, arc length): stage 0 all passed, 1 a
    TSS check failed, 2 the heading deviates (value: the largest deviation),
    3 a limit check failed. One call instead of a dozen numpy ones, each of
    which costs a request more than its work when the caches are cold.
    """
    failed, value, s = tss_checks(
        t, x, y, h, step_s, t0_s, route_xy, route_s, off_tol_m, dist_to_entry_m, start_tol_m,
        s_end_m,
    )  # fmt: skip
    if failed:
        return 1, failed, value, s
    _, expect = front_heading(s, length_m, route_s, route_xy)
    worst = 0.0
    for k in range(len(s)):  # np.abs((h - expect + pi) % (2 pi) - pi), its maximum
        dh = abs((h[k] - expect[k] + np.pi) % (2 * np.pi) - np.pi)
        worst = dh if k == 0 else max(worst, dh)
    if worst > heading_tol_rad:
        return 2, 0, worst, s
    failed, value = limit_checks(
        s, step_s, v0_mps, road_lim_mps, cap_lim_mps, accel_mps2, decel_mps2, accel_tol_mps2,
        first_slack_mps2,
    )  # fmt: skip
    if failed:
        return 3, failed, value, s
    return 0, 0, 0.0, s


@njit(
    "Tuple((int64[::1], int64[::1], int64[::1], int64[::1], float64))("
    "float64[:, ::1], int64[::1], int64[::1], int64[::1], int64[::1])",
    cache=True,
    nogil=True,
)
def select_rows(
    packed: np.ndarray,
    vid: np.ndarray,
    first_row: np.ndarray,
    stack_lo: np.ndarray,
    stack_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Occupancies of a gathered confirmed set that a route's grid can touch.

    ``first_row[v]`` is vehicle v's block in the route's pair stack (-1: a
    compatible route). Returns the occupancies kept in ascending ``lb_j``,
    their stack rows, the first and last grid point of the route not APART
    from each, and the longest interval ``ub_j - lb_j`` among them: a round
    of :func:`first_conflict` skips the rows that end before the requester
    starts by binary search instead of reading them all. The span is NaN
    where a bound is NaN (never from a real DTOT): the rows are then not in
    order and every round searches them all.
    """
    total = len(vid)
    keep = np.zeros(total, np.bool_)
    count = 0
    for q in range(total):
        fr = first_row[vid[q]]
        if fr < 0:
            continue
        r = fr + np.int64(packed[q, 8])
        if stack_lo[r] <= stack_hi[r]:
            keep[q] = True
            count += 1
    m = np.empty(count, np.int64)
    lbs = np.empty(count)
    span = 0.0
    c = 0
    for q in range(total):
        if keep[q]:
            m[c] = q
            lbs[c] = packed[q, 0]
            d = packed[q, 1] - packed[q, 0]
            span = math.nan if np.isnan(d) or np.isnan(span) else max(span, d)
            c += 1
    m = m[np.argsort(lbs)]
    row = np.empty(count, np.int64)
    lo = np.empty(count, np.int64)
    hi = np.empty(count, np.int64)
    for c in range(count):
        q = m[c]
        r = first_row[vid[q]] + np.int64(packed[q, 8])
        row[c] = r
        lo[c] = stack_lo[r]
        hi[c] = stack_hi[r]
    return m, row, lo, hi, span


# -- Algorithm 1's round loop, whole --------------------------------------
#
# The planner's plan building (:class:`ica.core.planner._Builder`,
# ``Planner._build_a``, ``Planner._build_b``, ``Planner.at_or_after``),
# ``Profile.time_at``, :func:`ica.core.trajectory.sample`, the estimated
# DTOT, the batched getCV, the lane-leader check and the update rule of
# ``Dica._resolve``, in one compiled call. Every expression is the Python
# one in the same order (Python's ``min`` and ``max`` as :func:`_py_min`,
# :func:`_py_max`), so each round gives the same plan bit for bit.

_EPS_PLAN = 1e-9  # as in ica.core.planner._EPS
_MAX_SEGS = 16  # a plan has at most 7 segments (stop family), 6 (slow-down family)

# resolve_rounds' status; BLOCKED: a stop-family plan meets the lane leader where every
# later stop-family plan goes too (the vehicle must stop behind the leader first);
# TOO_LATE: the next entry would be later than ``max_wait_s``
# PAUSED: round ``last_round`` done, the next round's entry target returned fourth
RESOLVED, FALL_BACK, BLOCKED, TOO_LATE, PAUSED = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True)
def _seg(segs: np.ndarray, n: int, t: float, s: float, v: float, a: float) -> int:
    segs[n, 0] = t
    segs[n, 1] = s
    segs[n, 2] = v
    segs[n, 3] = a
    return n + 1


@njit(cache=True, nogil=True)
def _accel_to(st: np.ndarray, segs: np.ndarray, n: int, v1: float, rate: float) -> int:
    """``_Builder.accel_to``; ``st`` is the builder's (t, s, v)."""
    if abs(v1 - st[2]) < _EPS_PLAN:
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
    if dt <= _EPS_PLAN:
        return n
    n = _seg(segs, n, st[0], st[1], st[2], 0.0)
    st[1] += st[2] * dt
    st[0] += dt
    return n


@njit(cache=True, nogil=True)
def _cruise_to(st: np.ndarray, segs: np.ndarray, n: int, s1: float) -> int:
    if s1 - st[1] > _EPS_PLAN and st[2] > _EPS_PLAN:
        n = _hold(st, segs, n, (s1 - st[1]) / st[2])
    return n


@njit(
    "Tuple((float64, boolean, float64, float64, boolean, float64, float64, float64[:, ::1],"
    " float64[::1]))(float64, float64, float64, float64, float64, float64, float64, float64,"
    " boolean, boolean, float64, float64)",
    cache=True,
    nogil=True,
)
def plan_constants_of(
    a: float, br: float, v0: float, d: float, road: float, cap: float, creep: float,
    stop_gap_m: float, run_up: bool, hold: bool, cap_sq: float, v0_sq: float,
) -> tuple:  # fmt: skip
    """``Planner.plan_constants`` (see ``Planner.plan_constants_reference``): the
    time-optimal plan's cruise speed and entry, the slowest slow-down plan's, the stop
    family's earliest entry and its stop-at-the-line base, expression for expression.
    ``cap_sq`` and ``v0_sq`` are Python's ``cap ** 2`` and ``v0 ** 2`` (its power is
    not always the product)."""
    # Planner._v_max
    reach = math.sqrt(v0 * v0 + 2 * a * d)
    if reach <= cap and v0 <= cap:
        v_hi = _py_min(reach, road)
    else:
        peak2 = (d + v0 * v0 / (2 * a) + cap * cap / (2 * br)) / (1 / (2 * a) + 1 / (2 * br))
        v_hi = _py_min(road, math.sqrt(_py_max(peak2, 0.0)))
    hi_ok, _, _, _, hi_t = a_phases(a, br, v0, d, cap, v_hi)
    # Planner._v_min_a
    v_lo = _py_max(creep, math.sqrt(_py_max(0.0, v0_sq - 2 * br * d)))
    lo_ok, lo_t = False, 0.0
    if v_lo < v_hi:
        lo_ok, _, _, _, lo_t = a_phases(a, br, v0, d, cap, v_lo)
    if not hi_ok:
        hi_t = 0.0
    if not lo_ok:
        lo_t = 0.0
    # Planner._stop_gap
    if hold and v0 <= 0.0:
        gap = d
    else:
        gap = stop_gap_m
        if run_up:
            gap = _py_max(gap, _py_min(cap_sq / (2 * a), d - v0_sq / (2 * br)))
        gap = _py_min(gap, d)
    # Planner.stop_entry_s: can_stop, _b_base_build, _pull_away_time
    if not v0_sq <= 2 * br * (d - gap) + 1e-7:
        return v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, math.inf, np.zeros((0, 4)), np.zeros(3)
    d_stop = d - gap
    segs = np.empty((_MAX_SEGS, 4))
    st = np.empty(3)
    st[0], st[1], st[2] = 0.0, -d, v0
    peak2 = (d_stop + v0 * v0 / (2 * a)) / (1 / (2 * a) + 1 / (2 * br))
    peak = _py_max(v0, _py_min(road, math.sqrt(_py_max(peak2, 0.0))))
    n = _accel_to(st, segs, 0, peak, a)
    n = _cruise_to(st, segs, n, -gap - peak * peak / (2 * br))
    n = _accel_to(st, segs, n, 0.0, br)
    st[1] = -gap
    if gap <= cap * cap / (2 * a):
        pull = math.sqrt(2 * gap / a)
    else:
        pull = cap / a + (gap - cap * cap / (2 * a)) / cap
    return v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, st[0] + pull, segs[:n].copy(), st


@njit(cache=True, nogil=True)
def _crossing(
    st: np.ndarray, segs: np.ndarray, n: int, cap: float, accel: float, s_end: float
) -> int:
    """``Planner._crossing`` and the closing segment of ``_Builder.profile``."""
    n = _accel_to(st, segs, n, _py_max(st[2], cap), accel)
    n = _cruise_to(st, segs, n, s_end)
    return _seg(segs, n, st[0], st[1], st[2], 0.0)


@njit(cache=True, nogil=True)
def _build_a(
    a: float, br: float, v0: float, d: float, cap: float, s_end: float, v_m: float,
    segs: np.ndarray,
) -> int:  # fmt: skip
    """``Planner._build_a`` into ``segs``: the number of segments, 0 if it does not fit."""
    fits, _d1, d3, v_e, _t = a_phases(a, br, v0, d, cap, v_m)
    if not fits:
        return 0
    st = np.empty(3)
    st[0], st[1], st[2] = 0.0, -d, v0
    n = _accel_to(st, segs, 0, v_m, a if v_m >= v0 else br)
    n = _cruise_to(st, segs, n, -d3)
    n = _accel_to(st, segs, n, v_e, a if v_e >= v_m else br)
    st[1] = 0.0
    return _crossing(st, segs, n, cap, a, s_end)


@njit(cache=True, nogil=True)
def _build_b(
    a: float, cap: float, s_end: float, wait_s: float, b_segs: np.ndarray, b_state: np.ndarray,
    segs: np.ndarray,
) -> int:  # fmt: skip
    """``Planner._build_b`` from the stop-at-the-line base (its segments and (t, s, v))."""
    n = len(b_segs)
    segs[:n] = b_segs
    st = b_state.copy()
    if wait_s > 0:
        n = _seg(segs, n, st[0], st[1], 0.0, 0.0)
        st[0] += wait_s
    return _crossing(st, segs, n, cap, a, s_end)


@njit(cache=True, nogil=True)
def _time_at(segs: np.ndarray, n: int, s: float) -> float:
    """``Profile.time_at``."""
    for k in range(n):
        s0, v0, a = segs[k, 1], segs[k, 2], segs[k, 3]
        end = segs[k + 1, 0] - segs[k, 0] if k + 1 < n else math.inf
        ds = s - s0
        if ds <= 0.0:
            return segs[k, 0]
        if abs(a) < _EPS_PLAN:
            tau = ds / v0 if v0 > _EPS_PLAN else math.inf
        else:
            disc = v0 * v0 + 2.0 * a * ds
            tau = math.inf if disc < 0.0 else (math.sqrt(disc) - v0) / a
        if tau <= end + 1e-9:
            return segs[k, 0] + tau
    return math.inf


@njit(cache=True, nogil=True)
def _entry_time(t0: float, step: float, s: np.ndarray) -> float:
    """``Trajectory.entry_time_s``: the time the front reaches s = 0, linear between
    the samples around it."""
    n = len(s)
    k = n - 1
    for q in range(n):
        if s[q] > 0.0:
            k = max(q - 1, 0)
            break
    if s[k] > 0.0 or k + 1 >= n:
        return t0 + k * step
    s0, s1 = s[k], s[k + 1]
    return t0 + (k + (0.0 - s0) / (s1 - s0)) * step


@njit("float64(float64, float64, float64[:])", cache=True, nogil=True)
def entry_time(t0: float, step: float, s: np.ndarray) -> float:
    """``Trajectory.entry_time_s`` (at least one sample)."""
    return _entry_time(t0, step, s)


@njit(cache=True, nogil=True)
def _next_plan(
    target: float, planner: tuple, b_segs: np.ndarray, b_state: np.ndarray, step: float,
    segs: np.ndarray, s: np.ndarray,
) -> tuple[bool, np.ndarray, float]:  # fmt: skip
    """``Planner.at_or_after(target)``, sampled: (built, its samples, its wait if of the
    stop family else -1); (False, ``s``, -1) where the Python loop raises. ``planner``
    is (a, br, v0, d, cap, s_end, v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, t_b0)."""
    a, br, v0, d, cap, s_end, v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, t_b0 = planner
    if not hi_ok:
        return False, s, -1.0
    b_wait = -1.0
    if target <= hi_t + 1e-9:
        ns = _build_a(a, br, v0, d, cap, s_end, v_hi, segs)
    elif lo_ok and target <= lo_t:
        v = bisect_cruise(a, br, v0, d, cap, v_lo, v_hi, target)
        ns = _build_a(a, br, v0, d, cap, s_end, v, segs)
    elif not math.isfinite(t_b0):
        ns = 0
    else:
        b_wait = _py_max(0.0, target - t_b0)
        ns = _build_b(a, cap, s_end, b_wait, b_segs, b_state, segs)
    if ns == 0:
        return False, s, -1.0
    t_out = _time_at(segs, ns, s_end)
    if not math.isfinite(t_out):
        return False, s, -1.0
    count = math.ceil(t_out / step - 1e-9) + 1
    out = np.empty(count)
    p = np.ascontiguousarray(segs[:ns].T)
    profile_position(p[0], p[1], p[2], p[3], step, out)
    return True, out, b_wait


@njit(
    "Tuple((int64, int64, float64[::1], float64))("
    "float64, float64, float64, float64, float64, float64,"  # a, br, v0, d, cap, s_end
    " float64, boolean, float64, float64, boolean, float64,"  # v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t
    " float64, float64[:, ::1], float64[::1],"  # t_b0, b_segs, b_state
    " float64, float64, float64[::1],"  # t0, step, s_init
    " float64[::1], float64[::1], float64[::1], float64, float64, float64,"
    " float64[::1], float64[::1], float64, float64,"  # route, grid, half extents
    " float64[:, ::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1],"
    " int8[::1], int64, int64, float64,"  # confirmed batch
    " boolean, float64, float64, float64[::1], float64, float64,"  # lane leader
    " int64, float64, int64, float64, float64, int64)",  # max_iterations, ..., target0, last_round
    cache=True,
    nogil=True,
)
def resolve_rounds(
    a: float, br: float, v0: float, d: float, cap: float, s_end: float,
    v_hi: float, hi_ok: bool, hi_t: float, v_lo: float, lo_ok: bool, lo_t: float,
    t_b0: float, b_segs: np.ndarray, b_state: np.ndarray,
    t0: float, step: float, s_init: np.ndarray,
    route_s: np.ndarray, route_x: np.ndarray, route_y: np.ndarray, length_m: float,
    grid_s0: float, grid_ds: float, fwd_m: np.ndarray, back_m: np.ndarray,
    half_l: float, half_w: float,
    packed: np.ndarray, vid: np.ndarray, m_idx: np.ndarray, row: np.ndarray,
    row_lo: np.ndarray, row_hi: np.ndarray, codes: np.ndarray, width: int, nv: int,
    span_s: float, has_leader: bool, lead_t0: float, lead_step: float, lead_s: np.ndarray,
    lead_length_m: float, gap_m: float,
    max_iterations: int, max_wait_s: float, first_round: int, b_wait0: float,
    target0: float, last_round: int,
) -> tuple[int, int, np.ndarray, float]:  # fmt: skip
    """The rounds of ``Dica._resolve`` (enhanced DICA) from the first plan ``s_init``.

    Returns (RESOLVED, rounds, the conflict-free plan's samples, NaN), BLOCKED
    (see the constant), TOO_LATE (the wait exceeded), PAUSED after round
    ``last_round`` with the next round's entry target (go on from there with
    ``first_round`` one higher and that ``target0``), or FALL_BACK where the Python
    loop raises (no plan, the round limit exceeded, the state too close to the lane
    leader, a plan that never leaves): the caller then runs the Python loop, which
    raises with its message. ``first_round`` and ``b_wait0`` (-1: none) go on from
    a round the caller made (a delay for an exit rule, which this loop does not
    know); with ``target0`` (NaN: none) the first plan is ``Planner.at_or_after``
    that entry, sampled, instead of ``s_init``. The planner's constants per request come from
    ``Planner.plan_constants``; the confirmed set from ``ConfirmedBatch``, its
    rows in ascending ``lb_j`` with their longest interval ``span_s`` (NaN: a
    NaN bound, never from a real DTOT; every round then searches all rows).
    """
    segs = np.empty((_MAX_SEGS, 4))
    hit = np.zeros(nv, np.bool_)
    first = np.empty(nv)
    delay = np.empty(nv)
    planner = (a, br, v0, d, cap, s_end, v_hi, hi_ok, hi_t, v_lo, lo_ok, lo_t, t_b0)
    ordered = not np.isnan(span_s)
    lbs = np.empty(len(m_idx))
    for c in range(len(m_idx)):
        lbs[c] = packed[m_idx[c], 0]
    s = s_init
    if not np.isnan(target0):
        ok, s, _ = _next_plan(target0, planner, b_segs, b_state, step, segs, s)
        if not ok:
            return FALL_BACK, first_round, s, math.nan
    b_wait = b_wait0  # the current plan's wait if it is of the stop family, else -1
    for it in range(first_round, max_iterations + 1):
        # the DTOT (ica.core.dtot.build_dtot with the grid)
        _, _, _, centre, heading, lb, ub, g = grid_dtot_of(
            s, s_end, t0, step, route_s, route_x, route_y, length_m, grid_s0, grid_ds, fwd_m,
            back_m, half_l, half_w,
        )  # fmt: skip
        # the lane leader, then getCV, and the first conflict as Dica._resolve
        # sorts them (the leader after the others on a tie)
        found, f_first, f_delay = False, 0.0, 0.0
        if has_leader:
            found, f_first, f_delay = follow_check(
                t0, step, s, lead_t0, lead_step, lead_s, lead_length_m, gap_m
            )
            if found and f_first <= t0 + step + 1e-9:
                return FALL_BACK, it, s, math.nan
            if found and b_wait >= 0.0 and f_first - t0 <= b_state[0] + b_wait + 1e-9:
                return BLOCKED, it, s, math.nan
        best = -1
        best_first = 0.0
        best_delay = 0.0
        if ordered:
            best, best_first, best_delay = first_conflict(
                lb, ub, g, centre, heading, half_l, half_w, packed, vid, m_idx, row,
                row_lo, row_hi, codes, width, lbs, span_s, f_first if found else math.inf,
            )  # fmt: skip
        else:
            hit[:] = False
            if batch_conflicts(
                lb, ub, g, centre, heading, half_l, half_w, packed, vid, m_idx, row,
                row_lo, row_hi, codes, width, hit, first, delay,
            ):  # fmt: skip
                for v in range(nv):
                    if hit[v] and (best < 0 or first[v] < best_first):
                        best = v
                        best_first = first[v]
                        best_delay = delay[v]
        if found and (best < 0 or f_first < best_first):
            best = nv
            best_first = f_first
            best_delay = _py_max(f_delay, 0.0)
        if best < 0:
            return RESOLVED, it, s, math.nan
        target = _entry_time(t0, step, s) - t0 + _py_max(best_delay, step)
        if target > max_wait_s:
            return TOO_LATE, it, s, target
        if it >= last_round and it < max_iterations:
            return PAUSED, it, s, target
        ok, s, b_wait = _next_plan(target, planner, b_segs, b_state, step, segs, s)
        if not ok:
            return FALL_BACK, it, s, math.nan
    return FALL_BACK, max_iterations, s, math.nan


@njit(cache=True, nogil=True)
def _free_run(road: float, accel: float, v0: float, t: float) -> tuple[float, float]:
    """``Handover._free`` at one time: distance and speed of a free run from ``v0``."""
    v_top = max(road, v0)
    t_acc = (v_top - v0) / accel
    ta = min(t, t_acc)
    x = v0 * ta + 0.5 * accel * ta * ta + v_top * max(t - t_acc, 0.0)
    return x, min(v0 + accel * t, v_top)


@njit(cache=True, nogil=True)
def _gap_ok(h: tuple, v_lead: float, v_follow: float, length: float, sep: float) -> bool:
    """``Handover.gap_ok``: the same samples (numpy's ``arange``: ``i * step``, as many
    as ``ceil(stop / step)``) and the same arithmetic, stopping at the first short gap."""
    road, accel, decel, tau, min_gap, buffer, step = h
    horizon = sep + (road - min(v_lead, v_follow)) / accel + 1.0
    n = math.ceil((horizon + step) / step)
    floor_m = min_gap + buffer
    for i in range(n):
        t = i * step
        x_l, v_l = _free_run(road, accel, v_lead, t + sep)
        x_f, v_f = _free_run(road, accel, v_follow, t)
        gap = x_l - x_f - length
        need = floor_m + v_f * tau
        need = need + (v_f * v_f - v_l * v_l) / (2.0 * decel)
        if not gap >= need:
            return False
    return True


@njit(
    "float64(UniTuple(float64, 7), float64, float64, float64)", cache=True, nogil=True
)  # fmt: skip
def separation(h: tuple, v_lead: float, v_follow: float, length: float) -> float:
    """``ica.core.handover``'s search for the least separation (doubling, then
    bisection to 0.01 s), over :func:`_gap_ok`: ``h`` is the driver's (road speed,
    acceleration, deceleration, tau, standstill gap, buffer, time step)."""
    lo, hi = 0.0, 1.0
    while not _gap_ok(h, v_lead, v_follow, length, hi):
        lo, hi = hi, 2.0 * hi
        if hi > 120.0:
            return math.inf
    if _gap_ok(h, v_lead, v_follow, length, lo):
        return lo
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        if _gap_ok(h, v_lead, v_follow, length, mid):
            hi = mid
        else:
            lo = mid
    return hi
