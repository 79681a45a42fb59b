"""getCV over the confirmed rows, and the lane-leader check.

:func:`batch_conflicts` is getCV with techniques 1, 2 and 4 over every
confirmed vehicle (:func:`ica.core.conflict.get_cv_batch`); :func:`first_conflict`
the same search for only the vehicle Algorithm 1 takes first, as the round
loop asks it; :func:`follow_check` checkFV in the approach
(:func:`ica.core.conflict.follow_conflict`). The confirmed set comes as
:class:`Rows` (built once per confirmed set and route by
:class:`ica.core.conflict.ConfirmedBatch`), the requester as
:class:`Occupancies`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.types import boolean, int64
from numba.types import float64 as f8

from dica.ica.core.kernels.interp import interp, searchsorted, searchsorted_one
from dica.ica.core.kernels.occupancy import Rect, overlaps

APART, MAYBE, TOUCH = 0, 1, 2  # as in ica.core.zones


class Occupancies(NamedTuple):
    """A requester's DTOT as getCV reads it (``ica.core.dtot.Dtot``)."""

    lb_s: np.ndarray  # [s] occupancy time intervals
    ub_s: np.ndarray
    grid_idx: np.ndarray  # nearest grid point of each occupancy
    centre: np.ndarray  # (N, 2) [m] footprint centres and unit headings
    heading: np.ndarray
    half_l_m: float  # [m] footprint half extents, margin included
    half_w_m: float


class Rows(NamedTuple):
    """The confirmed occupancies one route and shape can touch (``ConfirmedBatch``).

    ``packed`` rows are ``ica.core.conflict.PACKED`` (interval, centre,
    heading, half extents, grid index) of every confirmed vehicle, ``vid``
    each row's vehicle; ``m_idx`` picks the rows that can touch the route,
    in ascending ``lb_j`` (``lb_s``), with their row in the route's pair
    stack and the first and last grid point of the route not APART from
    them. ``codes`` is the flat stack, ``width`` its row length, ``nv`` the
    number of vehicles, ``span_s`` the longest interval among the picked rows
    (NaN where a bound is NaN, never from a real DTOT: the rows are then not
    in order).
    """

    packed: np.ndarray
    vid: np.ndarray
    m_idx: np.ndarray
    row: np.ndarray
    row_lo: np.ndarray
    row_hi: np.ndarray
    codes: np.ndarray
    width: int
    nv: int
    span_s: float
    lb_s: np.ndarray


class Hulls(NamedTuple):
    """Monotone hulls of a requester's interval bounds and grid index, for binary search."""

    ub_hull: np.ndarray  # running maximum of ub_i
    lb_hull: np.ndarray  # running minimum of lb_i from the right
    g_hi: np.ndarray  # running maximum of the grid index
    g_lo: np.ndarray  # running minimum of the grid index from the right


_F1, _I1 = np.zeros(1), np.zeros(1, np.int64)
_OCC = Occupancies(_F1, _F1, _I1, np.zeros((1, 2)), np.zeros((1, 2)), 2.75, 1.15)
_ROWS = Rows(np.zeros((1, 9)), _I1, _I1, _I1, _I1, _I1, np.zeros(1, np.int8), 1, 1, 0.0, _F1)
OCCUPANCIES_ARGS = typeof(tuple(_OCC))  # as Python passes them (see the package's docstring)
ROWS_ARGS = typeof(tuple(_ROWS))


@njit(
    f8[:, ::1](f8[:], f8[:], f8[:, :], f8[:, :], f8, f8, int64[:]),
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


@njit(
    types.Tuple((int64[::1], int64[::1], int64[::1], int64[::1], f8, f8[::1]))(
        f8[:, ::1], int64[::1], int64[::1], int64[::1], int64[::1]
    ),
    cache=True,
    nogil=True,
)
def select_rows(
    packed: np.ndarray,
    vid: np.ndarray,
    first_row: np.ndarray,
    stack_lo: np.ndarray,
    stack_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """Occupancies of a gathered confirmed set that a route's grid can touch.

    ``first_row[v]`` is vehicle v's block in the route's pair stack (-1: a
    compatible route). Returns the occupancies kept in ascending ``lb_j``,
    their stack rows, the first and last grid point of the route not APART
    from each, the longest interval ``ub_j - lb_j`` among them, and their
    ``lb_j``: a round of :func:`first_conflict` skips the rows that end
    before the requester starts by binary search instead of reading them
    all. The span is NaN where a bound is NaN (never from a real DTOT): the
    rows are then not in order and every round searches them all.
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
    lb_s = np.empty(count)
    for c in range(count):
        q = m[c]
        r = first_row[vid[q]] + np.int64(packed[q, 8])
        row[c] = r
        lo[c] = stack_lo[r]
        hi[c] = stack_hi[r]
        lb_s[c] = packed[q, 0]
    return m, row, lo, hi, span, lb_s


@njit(cache=True, nogil=True)
def hulls_of(occ: Occupancies) -> Hulls:
    n = len(occ.lb_s)
    ub_hull = np.empty(n)
    lb_hull = np.empty(n)
    g_hi = np.empty(n)
    g_lo = np.empty(n)
    lb_i, ub_i, g_i = occ.lb_s, occ.ub_s, occ.grid_idx
    for k in range(n):
        ub_hull[k] = ub_i[k] if k == 0 else max(ub_hull[k - 1], ub_i[k])
        g_hi[k] = g_i[k] if k == 0 else max(g_hi[k - 1], g_i[k])
    for k in range(n - 1, -1, -1):
        lb_hull[k] = lb_i[k] if k == n - 1 else min(lb_hull[k + 1], lb_i[k])
        g_lo[k] = g_i[k] if k == n - 1 else min(g_lo[k + 1], g_i[k])
    return Hulls(ub_hull, lb_hull, g_hi, g_lo)


@njit(inline="always")
def _touch(occ: Occupancies, k: int, rows: Rows, q: int) -> bool:
    """Do requester occupancy ``k`` and confirmed row ``q`` intersect, the offline
    code ``code`` being MAYBE (:func:`ica.core.occupancy.separated`, a = requester)."""
    p = rows.packed
    here = Rect(
        occ.centre[k, 0], occ.centre[k, 1], occ.heading[k, 0], occ.heading[k, 1],
        occ.half_l_m, occ.half_w_m,
    )  # fmt: skip
    there = Rect(p[q, 2], p[q, 3], p[q, 4], p[q, 5], p[q, 6], p[q, 7])
    return overlaps(here, there)


@njit(cache=True, nogil=True)
def _candidates(c: int, rows: Rows, hulls: Hulls) -> tuple[int, int]:
    """The requester's occupancies ``[lo, hi)`` that confirmed occupancy ``m_idx[c]``
    can meet: by time (technique 4) and by the grid points not APART from it."""
    q = rows.m_idx[c]
    lb_j, ub_j = rows.packed[q, 0], rows.packed[q, 1]
    lo = max(
        searchsorted_one(hulls.ub_hull, lb_j, False),
        searchsorted_one(hulls.g_hi, float(rows.row_lo[c]), False),
    )
    hi = min(
        searchsorted_one(hulls.lb_hull, ub_j, True),
        searchsorted_one(hulls.g_lo, float(rows.row_hi[c]), True),
    )
    return lo, hi


@njit(cache=True, nogil=True)
def conflicts_of(
    occ: Occupancies, rows: Rows, hit: np.ndarray, first: np.ndarray, delay: np.ndarray
) -> bool:
    """getCV of a requester against the confirmed occupancies ``packed[m_idx]``.

    Per vehicle v: ``hit[v]``, and over its conflicting pairs the least
    ``lb_j`` (firstTimeAtCollision) and the greatest ``ub_j - lb_i`` (delay).
    Returns whether any vehicle conflicts.
    """
    n = len(occ.lb_s)
    found = False
    if n == 0:
        return found
    hulls = hulls_of(occ)
    t_lo, t_hi = hulls.lb_hull[0], hulls.ub_hull[n - 1]  # the requester's whole crossing
    lb_i, ub_i, g_i = occ.lb_s, occ.ub_s, occ.grid_idx
    for c in range(len(rows.m_idx)):
        q = rows.m_idx[c]
        lb_j, ub_j = rows.packed[q, 0], rows.packed[q, 1]
        if ub_j < t_lo or lb_j > t_hi:
            continue  # no interval of the requester can overlap
        lo, hi = _candidates(c, rows, hulls)
        base = rows.row[c] * rows.width
        for k in range(lo, hi):
            if not (lb_i[k] <= ub_j and lb_j <= ub_i[k]):
                continue
            code = rows.codes[base + g_i[k]]
            if code == APART:
                continue
            if code == MAYBE and not _touch(occ, k, rows, q):
                continue
            v = rows.vid[q]
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


@njit(
    boolean(OCCUPANCIES_ARGS, ROWS_ARGS, boolean[::1], f8[::1], f8[::1]),
    cache=True,
    nogil=True,
)
def batch_conflicts(
    occ_args: tuple, rows_args: tuple, hit: np.ndarray, first: np.ndarray, delay: np.ndarray
) -> bool:
    """:func:`conflicts_of` for a Python caller (bundles as tuples: :class:`Occupancies`,
    :class:`Rows`)."""
    return conflicts_of(Occupancies(*occ_args), Rows(*rows_args), hit, first, delay)


@njit(cache=True, nogil=True)
def _row_conflict(c: int, occ: Occupancies, rows: Rows, hulls: Hulls) -> tuple[bool, float]:
    """The pairs of :func:`conflicts_of` for confirmed occupancy ``m_idx[c]``:
    (any conflicting, the greatest ``ub_j - lb_i`` over them)."""
    q = rows.m_idx[c]
    lb_j, ub_j = rows.packed[q, 0], rows.packed[q, 1]
    lo, hi = _candidates(c, rows, hulls)
    base = rows.row[c] * rows.width
    lb_i, ub_i, g_i = occ.lb_s, occ.ub_s, occ.grid_idx
    found = False
    worst = 0.0
    for k in range(lo, hi):
        if not (lb_i[k] <= ub_j and lb_j <= ub_i[k]):
            continue
        code = rows.codes[base + g_i[k]]
        if code == APART:
            continue
        if code == MAYBE and not _touch(occ, k, rows, q):
            continue
        d = ub_j - lb_i[k]
        worst = max(worst, d) if found else d
        found = True
    return found, worst


@njit(cache=True, nogil=True)
def first_conflict(occ: Occupancies, rows: Rows, bound: float) -> tuple[int, float, float]:
    """The first conflicting vehicle of :func:`conflicts_of` and its two values.

    Returns (v, firstTimeAtCollision, delay) of the vehicle Algorithm 1
    takes first: the least firstTimeAtCollision, the lower index on a tie;
    v = -1 if no vehicle conflicts at or before ``bound``. The rows come in
    ascending ``lb_j`` (``rows.lb_s``): the first conflicting row then holds
    the least firstTimeAtCollision of all, rows after the requester's
    crossing or after that time cannot change the choice, and only the
    chosen vehicle's later rows are searched for its delay (a maximum: the
    order does not change it). No row's interval is longer than
    ``rows.span_s``: the rows that start more than that before the
    requester's crossing end before it and are skipped by binary search.
    """
    n = len(occ.lb_s)
    if n == 0:
        return -1, 0.0, 0.0
    hulls = hulls_of(occ)
    t_lo, t_hi = hulls.lb_hull[0], hulls.ub_hull[n - 1]
    best = -1
    best_first = 0.0
    best_delay = 0.0
    count = len(rows.m_idx)
    # ub_j <= lb_j + span_s < t_lo below that (1e-6 s over rounding)
    c = searchsorted_one(rows.lb_s, t_lo - rows.span_s - 1e-6, False)
    while c < count:
        q = rows.m_idx[c]
        lb_j, ub_j = rows.packed[q, 0], rows.packed[q, 1]
        if lb_j > t_hi or lb_j > bound or (best >= 0 and lb_j > best_first):
            break
        if ub_j >= t_lo:
            found, worst = _row_conflict(c, occ, rows, hulls)
            if found:
                v = rows.vid[q]
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
    while c < count:
        q = rows.m_idx[c]
        lb_j, ub_j = rows.packed[q, 0], rows.packed[q, 1]
        if lb_j > t_hi:
            break
        if rows.vid[q] == best and ub_j >= t_lo:
            found, worst = _row_conflict(c, occ, rows, hulls)
            if found:
                best_delay = max(best_delay, worst)
        c += 1
    return best, best_first, best_delay


@njit(
    types.Tuple((boolean, f8, f8))(f8, f8, f8[::1], f8, f8, f8[::1], f8, f8),
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
    """:func:`ica.core.conflict.follow_conflict`: (violated, first time, raw delay) of
    a follower sampled from ``t0_f`` every ``step_f`` behind a leader from ``t0_l``."""
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
    sf_t = interp(t, tf, s_f)
    sl_t = interp(t, tl, s_l)
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
    searchsorted(s_l, need, False, idx)
    first = tb[0]
    delay = tl[min(idx[0], nl - 1)] - tb[0]
    for r in range(1, nbad):
        first = min(first, tb[r])
        delay = max(delay, tl[min(idx[r], nl - 1)] - tb[r])
    return True, first, delay
