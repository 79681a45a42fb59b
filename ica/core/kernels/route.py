"""Points on a route's polyline, headings, projections, and a trajectory as a TSS.

The compiled :meth:`ica.core.route.Route.points` and ``Route.project`` and
the compiled ``Trajectory.xy_heading`` and ``Trajectory.tss``. Headings are
``atan2`` of the rear-to-front difference: the platform's libm here, which
may differ from numpy's SIMD ``arctan2`` in the last bit. A heading feeds no
decision (the footprints that getCV tests take their heading from a square
root and a division, :mod:`.dtot`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from dica.ica.core.kernels.interp import interp


@njit("float64[:, ::1](float64[::1], float64[::1], float64[:, ::1])", cache=True, nogil=True)
def route_points(s: np.ndarray, route_s: np.ndarray, route_xy: np.ndarray) -> np.ndarray:
    """:meth:`ica.core.route.Route.points` for a 1-D ``s``: (N, 2) points on the polyline."""
    out = np.empty((len(s), 2))
    x = interp(s, route_s, route_xy[:, 0].copy())
    y = interp(s, route_s, route_xy[:, 1].copy())
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
        s[q] = route_s[bk] + bu * (route_s[bk + 1] - route_s[bk])
        dist[q] = math.sqrt(best)
    return s, dist
