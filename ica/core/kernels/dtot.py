"""A trajectory's DTOT with the route's grid, and where it enters and leaves.

:func:`grid_dtot`: footprint centres and headings from the front and rear
points, the grid index and technique 3's intervals, exact or the
dissertation's estimate, as the grid's tables say
(:func:`ica.core.dtot.grid_intervals`, :func:`ica.core.occupancy.footprints`).
A footprint's heading is the rear-to-front difference over its length (a
square root and a division, no libm), so a DTOT is the same bit for bit on
every machine.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.types import float64 as f8
from numba.types import int64

from dica.ica.core.kernels.interp import interp, nondecreasing
from dica.ica.core.kernels.occupancy import Rect, overlaps


class Grid(NamedTuple):
    """A route's grid as technique 3 reads it, for one vehicle shape and margin
    (:meth:`ica.core.zones.RouteGrid.kernel_grid`)."""

    route_s: np.ndarray  # [m] the route's vertices: arc length, x, y
    route_x: np.ndarray
    route_y: np.ndarray
    length_m: float  # the vehicle's length
    s0_m: float  # [m] the first grid point and the grid step
    ds_m: float
    fwd_m: np.ndarray  # [m] skip distances ahead and behind, per grid point
    back_m: np.ndarray
    half_l_m: float  # [m] footprint half extents, margin included
    half_w_m: float


_GRID = Grid(*(np.zeros(2),) * 3, 5.0, -2.0, 0.25, np.zeros(1), np.zeros(1), 2.75, 1.15)
GRID = typeof(_GRID)  # as kernels pass it
GRID_ARGS = typeof(tuple(_GRID))  # as Python passes it (see the package's docstring)
# a DTOT's arrays as dtot_of gives them: k0, times, arc lengths, centres, headings, lb, ub,
# grid index
DTOT_ARRAYS = types.Tuple(
    (int64, f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], int64[::1])
)


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
def entry_time_of(t0: float, step: float, s: np.ndarray) -> float:
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
    return entry_time_of(t0, step, s)


@njit(inline="always")
def _footprint(centre: np.ndarray, heading: np.ndarray, k: int, grid: Grid) -> Rect:
    return Rect(
        centre[k, 0], centre[k, 1], heading[k, 0], heading[k, 1], grid.half_l_m, grid.half_w_m
    )


@njit(
    types.void(GRID, f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], int64[::1]),
    cache=True,
    nogil=True,
)
def grid_dtot(
    grid: Grid,
    s: np.ndarray,
    t: np.ndarray,
    centre: np.ndarray,
    heading: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    g: np.ndarray,
) -> None:
    """Footprints, grid index and technique 3's intervals of occupancies at ``s``, times ``t``.

    :func:`ica.core.occupancy.footprints` (front and rear points by
    ``np.interp`` on the route polyline), ``RouteGrid.index`` and
    :func:`ica.core.dtot.grid_intervals`, into the out arrays ``centre``,
    ``heading``, ``lb``, ``ub``, ``g``: for each occupancy, the samples
    within the grid's skip distances are taken to overlap it, and beyond them
    the nearest one the exact test finds clear bounds its interval. With
    exact tables that is the exhaustive interval; with the dissertation's the
    first sample tested is already clear.
    """
    n = len(s)
    last = len(grid.fwd_m) - 1
    half = grid.length_m / 2.0
    rear = s - grid.length_m
    fx = interp(s, grid.route_s, grid.route_x)
    fy = interp(s, grid.route_s, grid.route_y)
    rx = interp(rear, grid.route_s, grid.route_x)
    ry = interp(rear, grid.route_s, grid.route_y)
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
        i = np.int64(np.rint((s[k] - grid.s0_m) / grid.ds_m))
        i = min(max(i, 0), last)
        g[k] = i
        behind[k] = s[k] - grid.back_m[i]
        ahead[k] = s[k] + grid.fwd_m[i]
    # where s rises, the skipped samples are one range, found by a walk from the last
    # sample's (np.searchsorted's answer on sorted s, in a step or two); else (a
    # rounding error off monotone) they are skipped one by one
    sorted_s = nondecreasing(s)
    p_lo = 0  # first index with s > behind[k]
    p_hi = 0  # first index with s >= ahead[k]
    for k in range(n):
        here = _footprint(centre, heading, k, grid)
        j = k - 1
        if sorted_s:
            key = behind[k]
            while p_lo < n and s[p_lo] <= key:
                p_lo += 1
            while p_lo > 0 and s[p_lo - 1] > key:
                p_lo -= 1
            j = min(p_lo - 1, j)
        while j >= 0:
            if behind[k] < s[j] <= s[k] or overlaps(here, _footprint(centre, heading, j, grid)):
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
            if s[k] <= s[j] < ahead[k] or overlaps(here, _footprint(centre, heading, j, grid)):
                j += 1
            else:
                break
        ub[k] = t[j] if j < n else t[n - 1]


@njit(cache=True, nogil=True)
def dtot_of(grid: Grid, s_all: np.ndarray, s_end_m: float, t0_s: float, step_s: float) -> tuple:
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
    grid_dtot(grid, s, t, centre, heading, lb, ub, g)
    return k0, t, s, centre, heading, lb, ub, g


@njit(cache=True, nogil=True)
def no_dtot() -> tuple:
    """The arrays of :func:`dtot_of` for no occupancy."""
    empty = np.empty(0)
    return 0, empty, empty, np.empty((0, 2)), np.empty((0, 2)), empty, empty, np.empty(0, np.int64)


@njit(DTOT_ARRAYS(GRID_ARGS, f8[::1], f8, f8, f8), cache=True, nogil=True)
def grid_dtot_of(
    grid_args: tuple, s_all: np.ndarray, s_end_m: float, t0_s: float, step_s: float
) -> tuple:
    """:func:`dtot_of` for a Python caller (``grid_args``: a :class:`Grid` as a tuple)."""
    return dtot_of(Grid(*grid_args), s_all, s_end_m, t0_s, step_s)
