"""The frames the recording meets, and the shapes it draws in the viewer's frame.

SUMO gives a vehicle by its front-bumper centre and an angle in degrees
clockwise from north; the core gives headings in radians counter-clockwise
from +x; Rerun's 2D views are y-down, so everything drawn is ``(x, -y)`` [m],
north up (:data:`FLIP_Y`). Many vehicles on different routes are projected
onto their routes in one numpy pass (:class:`RouteProjector`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route

LANE_WIDTH_M = 3.2  # [m] SUMO's default; to draw lane edges and to tell "on the route"
FLIP_Y = np.array([1.0, -1.0])  # world (x, y) -> viewer (x, -y)


def approach_of(lane: str) -> str:
    """The incoming edge of a lane id (``N_in_2`` -> ``N_in``)."""
    return lane.rsplit("_", 1)[0]


def lane_major(lanes: Sequence[str]) -> list[str]:
    """Lanes ordered by their index, then by approach: a grid of lane charts with a
    column per approach has lane 0 (rightmost) in its first row."""
    return sorted(lanes, key=lambda ln: (ln.rsplit("_", 1)[1], ln))


def rectangles(
    x_m: np.ndarray,
    y_m: np.ndarray,
    heading_rad: np.ndarray,
    length_m: np.ndarray | float,
    width_m: np.ndarray | float,
) -> np.ndarray:
    """Closed outlines (N, 5, 2) of vehicles given by front-bumper centre and heading.

    Heading is counter-clockwise from +x. The outline is in the viewer's
    frame, (x, -y), because ``Boxes2D`` cannot rotate and 2D views are y-down.
    """
    x = np.asarray(x_m, dtype=float).reshape(-1)
    y = np.asarray(y_m, dtype=float).reshape(-1)
    h = np.asarray(heading_rad, dtype=float).reshape(-1)
    half_l = np.broadcast_to(np.asarray(length_m, dtype=float), x.shape) / 2.0
    half_w = np.broadcast_to(np.asarray(width_m, dtype=float), x.shape) / 2.0
    c, s = np.cos(h), np.sin(h)
    return outlines(x - c * half_l, y - s * half_l, c, s, half_l, half_w)


def outlines(cx, cy, c, s, half_l, half_w) -> np.ndarray:
    """Closed outlines (N, 5, 2), viewer frame, of rectangles by centre and unit heading."""
    along = np.array([1.0, 1.0, -1.0, -1.0, 1.0])
    across = np.array([1.0, -1.0, -1.0, 1.0, 1.0])
    dl = along[None, :] * np.reshape(half_l, (-1, 1))
    dw = across[None, :] * np.reshape(half_w, (-1, 1))
    px = cx[:, None] + dl * c[:, None] - dw * s[:, None]
    py = cy[:, None] + dl * s[:, None] + dw * c[:, None]
    return np.stack([px, -py], axis=-1)


def sumo_heading_rad(angle_deg: np.ndarray) -> np.ndarray:
    """SUMO's angle (degrees, 0 = north, clockwise) as radians CCW from +x."""
    return np.pi / 2.0 - np.radians(np.asarray(angle_deg, dtype=float))


class RouteProjector:
    """``Route.project`` for many vehicles on different routes in one numpy pass.

    Routes are padded to the same number of segments by repeating their last
    segment, which changes no nearest point.
    """

    def __init__(self, routes: Sequence[Route]) -> None:
        self.index = {r.id: i for i, r in enumerate(routes)}
        self.cross_m = np.array([r.cross_length_m for r in routes])  # entry to exit line
        n_seg = max(len(r.xy) for r in routes) - 1
        a = np.empty((len(routes), n_seg, 2))
        d = np.empty_like(a)
        s0 = np.empty((len(routes), n_seg))
        ds = np.empty((len(routes), n_seg))
        for i, r in enumerate(routes):
            m = len(r.xy) - 1
            pad = [*range(m), *([m - 1] * (n_seg - m))]
            a[i] = r.xy[:-1][pad]
            d[i] = (r.xy[1:] - r.xy[:-1])[pad]
            s0[i] = r.s[:-1][pad]
            ds[i] = np.diff(r.s)[pad]  # a route's s need not be the drawn length
        self._a, self._d, self._s0, self._ds = a, d, s0, ds
        self._len2 = np.einsum("rij,rij->ri", d, d)

    def project(self, route_idx: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length [m] and distance to the route [m] of each point on its own route."""
        a, d, len2 = self._a[route_idx], self._d[route_idx], self._len2[route_idx]
        w = xy[:, None, :] - a
        u = np.clip(np.einsum("nij,nij->ni", w, d) / len2, 0.0, 1.0)
        dist2 = np.sum((w - u[..., None] * d) ** 2, axis=-1)
        k = np.argmin(dist2, axis=1)
        rows = np.arange(len(xy))
        s = self._s0[route_idx, k] + u[rows, k] * self._ds[route_idx, k]
        return s, np.sqrt(dist2[rows, k])


def clipped(route: Route, s_from: float, s_to: float) -> np.ndarray:
    """The route's polyline from arc length ``s_from`` to ``s_to`` (world frame)."""
    inner = route.xy[(route.s > s_from) & (route.s < s_to)]
    return np.vstack([route.points(s_from)[None], inner, route.points(s_to)[None]])


def offset(route: Route, s_from: float, s_to: float, left_m: float) -> np.ndarray:
    """The route's polyline between two arc lengths, shifted sideways (viewer frame)."""
    p = clipped(route, s_from, s_to)
    d = np.gradient(p, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    n = np.stack([-d[:, 1], d[:, 0]], -1)
    return (p + n * left_m) * FLIP_Y


def across(route: Route, s: float) -> np.ndarray:
    """A lane-wide segment across the route at arc length ``s``, in the viewer frame."""
    a, b = route.points(s - 0.5), route.points(s + 0.5)
    d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
    n = np.array([-d[1], d[0]]) * LANE_WIDTH_M / 2.0
    p = route.points(s)
    return np.array([p - n, p + n]) * FLIP_Y


def route_lanes(inter: Intersection) -> np.ndarray:
    """Per route (in ``inter.routes`` order), the index of its lane in ``inter.in_lanes``."""
    return np.array([inter.in_lanes.index(r.in_lane) for r in inter.routes])


def crossing_outlines(inter: Intersection) -> list[np.ndarray]:
    """Closed outlines (5, 2), viewer frame, of every strip of the junction's pedestrian
    crossings (one per segment of a crossing's centre line)."""
    out = []
    for c in inter.crosswalks:
        for strip in c.strips():
            corners = strip.corners()[0]
            out.append(np.vstack([corners, corners[:1]]) * FLIP_Y)
    return out
