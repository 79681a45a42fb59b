"""Crossing routes: the path a front bumper follows through a junction.

A route is one incoming lane, the internal lanes of the junction and one
outgoing lane, joined into a single polyline with an arc-length coordinate
``s`` [m]. ``s = 0`` is the entry line (the end of the incoming lane, where a
DTOT starts) and ``s = cross_length_m`` the exit line (the start of the outgoing
lane). Negative ``s`` lies in the approach. Everything the ICA reasons about,
trajectories included, is expressed in this coordinate; (x, y) only appears
when occupancies are drawn as rectangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from dica.ica.core.kernels.route import project, route_points
from dica.ica.core.limits import SpeedCaps, Turn


@dataclass(frozen=True, slots=True, eq=False)
class Route:
    """One way through a junction, as a polyline with arc length.

    ``xy`` (M, 2) are the vertices and ``s`` (M,) their arc length as SUMO drives
    it (inside the junction an internal lane's own length, which may differ from its
    drawn shape by a few percent: see :func:`build_route`), strictly increasing, with
    0 at the entry line; between vertices ``s`` runs in proportion along the segment.
    The polyline reaches at least ``approach_m`` upstream of the entry line and
    ``tail_m`` downstream of the exit line so that every vehicle the ICA accepts can
    be drawn anywhere in its communication region and until it is fully out.
    """

    id: str
    in_lane: str
    out_lane: str
    via_lanes: tuple[str, ...]
    turn: Turn
    speed_cap_mps: float
    cross_length_m: float
    xy: np.ndarray
    s: np.ndarray
    # [m/s] the road's limit on the approach and on the exit lane: the dissertation's road
    # speed, or the net's own limit where that is lower (:func:`net_limit`)
    road_mps: float = SpeedCaps().road_mps
    exit_mps: float = SpeedCaps().road_mps
    # [m] the incoming and outgoing lanes' own lengths (the polyline may reach further)
    in_lane_m: float = math.inf
    out_lane_m: float = math.inf
    cars: bool = True  # passenger cars may take it (not a bus or a delivery lane only)
    # [m/s] the lowest limit the net sets on the lanes inside the junction (SUMO's turn
    # speed): a human driver slows to it, whatever the plans' caps (inf: none known)
    via_mps: float = math.inf
    # [m/s] the net's own limit on the incoming lane, however high (None: not known): SUMO's
    # drivers bring vehicles to the region at it, so the room to stop is counted from it
    in_limit_mps: float | None = None
    # [m] how far back of the incoming lane's end its entry line stands: 0 but where a
    # long vehicle turning from another lane sweeps over the place a vehicle waits at the
    # lane's end (:mod:`ica.core.waiting`); ``in_lane_m`` then counts up to the line
    line_back_m: float = 0.0

    def moved_back(self, back_m: float) -> Route:
        """This route with its entry line ``back_m`` further up the incoming lane: the
        stretch in between is part of the crossing. The polyline must reach far enough
        upstream for the new line (built with ``approach_m`` grown by ``back_m``)."""
        if back_m <= 0.0:
            return self
        return replace(
            self,
            cross_length_m=self.cross_length_m + back_m,
            s=self.s + back_m,
            in_lane_m=self.in_lane_m - back_m,
            line_back_m=self.line_back_m + back_m,
        )

    @property
    def arrival_mps(self) -> float:
        """The fastest a vehicle comes into the region on this route's lane: the net's
        limit there, or the road speed the ICA plans with where the net sets none."""
        return max(self.road_mps, self.in_limit_mps or 0.0)

    @property
    def s_min(self) -> float:
        return float(self.s[0])

    @property
    def s_max(self) -> float:
        return float(self.s[-1])

    def points(self, s: np.ndarray | float) -> np.ndarray:
        """Points (..., 2) at arc lengths ``s``; clamps outside the polyline.

        Compiled for 1-D ``s`` (:func:`ica.core.kernels.route.route_points`), with
        exactly the results of :meth:`points_reference`.
        """
        s = np.asarray(s, dtype=float)
        if s.ndim == 1:
            return route_points(
                np.ascontiguousarray(s), self.s, np.ascontiguousarray(self.xy, dtype=float)
            )
        return self.points_reference(s)

    def points_reference(self, s: np.ndarray | float) -> np.ndarray:
        """:meth:`points` in numpy."""
        s = np.asarray(s, dtype=float)
        return np.stack(
            [np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])], -1
        )

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length of the nearest polyline point and the distance to it, per point.

        Used to check that a requested TSS really lies on this route. Compiled
        (:func:`ica.core.kernels.route.project`), with exactly the results of
        :meth:`project_reference`.
        """
        p = np.ascontiguousarray(np.asarray(xy, dtype=float).reshape(-1, 2))
        return project(np.ascontiguousarray(self.xy, dtype=float), self.s, p)

    def project_reference(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`project` in numpy: every point against every segment."""
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        a = self.xy[:-1]  # (M-1, 2)
        d = self.xy[1:] - a
        seg_len2 = np.einsum("ij,ij->i", d, d)
        w = p[:, None, :] - a[None, :, :]  # (N, M-1, 2)
        u = np.clip(np.einsum("nij,ij->ni", w, d) / seg_len2, 0.0, 1.0)
        closest = a[None] + u[..., None] * d[None]
        dist2 = np.sum((p[:, None, :] - closest) ** 2, axis=-1)
        k = np.argmin(dist2, axis=1)
        rows = np.arange(len(p))
        s = self.s[k] + u[rows, k] * (self.s[k + 1] - self.s[k])
        return s, np.sqrt(dist2[rows, k])


def classify_turn(xy: np.ndarray, straight_deg: float = 30.0) -> Turn:
    """Turn class from the heading change between the path's first and last segment.

    Used when the network does not say (SUMO's ``dir`` is preferred when present).
    """
    h0 = xy[1] - xy[0]
    h1 = xy[-1] - xy[-2]
    change = math.degrees(math.atan2(h0[0] * h1[1] - h0[1] * h1[0], h0 @ h1))
    if change > straight_deg:
        return Turn.LEFT
    if change < -straight_deg:
        return Turn.RIGHT
    return Turn.THROUGH


NET_ROUNDING_MPS = 0.01  # SUMO writes a lane's speed with two decimals (70 km/h: 19.44)


def net_limit(cap_mps: float, lane_mps: float | None) -> float:
    """``cap_mps``, or a lane's own limit where the net sets it lower.

    A limit within :data:`NET_ROUNDING_MPS` below the cap is the cap as SUMO
    rounds it, not a lower one: the dissertation's 70 km/h roads keep planning
    with 70 km/h exactly."""
    if lane_mps is None or lane_mps >= cap_mps - NET_ROUNDING_MPS:
        return cap_mps
    return float(lane_mps)


def _dedup(xy: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    keep = np.ones(len(xy), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(xy, axis=0), axis=1) > eps
    return xy[keep]


class Via(NamedTuple):
    """An internal lane: its drawn shape (K, 2) and its length as SUMO drives it (None:
    as drawn)."""

    shape: np.ndarray
    length_m: float | None = None


def build_route(
    *,
    route_id: str,
    in_lane: str,
    out_lane: str,
    via_lanes: tuple[str, ...],
    in_shape: np.ndarray,
    via_shapes: list[np.ndarray | Via],
    out_shape: np.ndarray,
    turn: Turn,
    caps: SpeedCaps,
    approach_m: float,
    tail_m: float,
    lane_limits_mps: tuple[float, float] | None = None,
) -> Route:
    """Join lane shapes into a route; extend straight where a lane is too short.

    ``via_shapes`` are the internal lanes' shapes, each plain or a :class:`Via` with its
    length as SUMO moves vehicles along it (a net's ``length``, which may differ from
    its drawn shape by a few percent): along each, the arc length is stretched to it,
    so that route position ``s`` is where SUMO places a vehicle that has gone ``s``
    past the entry line, and the crossing is as long as SUMO drives it.

    ``lane_limits_mps`` are the net's speed limits of the incoming and the
    outgoing lane (None: the dissertation's road): the approach keeps the first, the crossing the
    lower of both and the turn's cap (the internal lanes' own speeds are
    netconvert's curvature estimates; the turn caps stand for them).

    ``approach_m`` is how far upstream of the entry line the polyline must
    reach (communication region plus the longest vehicle), ``tail_m`` how far
    past the exit line. Shapes shorter than that are extended along their end
    segment, which is how a vehicle on a short lane would be drawn anyway.
    """
    in_limit_mps, out_limit_mps = lane_limits_mps or (None, None)
    in_shape = _dedup(np.asarray(in_shape, dtype=float))
    out_shape = _dedup(np.asarray(out_shape, dtype=float))
    vias = [v if isinstance(v, Via) else Via(v) for v in via_shapes]
    inner = [_dedup(np.asarray(v.shape, dtype=float)) for v in vias]
    if len(in_shape) < 2 or len(out_shape) < 2:
        raise ValueError(f"route {route_id}: lane shapes need at least two distinct points")

    def seglen(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.diff(p, axis=0), axis=1)

    in_len = in_lane_m = float(seglen(in_shape).sum())
    if in_len < approach_m:
        d = in_shape[0] - in_shape[1]
        d /= np.linalg.norm(d)
        in_shape = np.vstack([in_shape[0] + d * (approach_m - in_len + 1.0), in_shape])
    out_len = out_lane_m = float(seglen(out_shape).sum())
    if out_len < tail_m:
        d = out_shape[-1] - out_shape[-2]
        d /= np.linalg.norm(d)
        out_shape = np.vstack([out_shape, out_shape[-1] + d * (tail_m - out_len + 1.0)])

    entry_xy = in_shape[-1]
    # the crossing's vertices and the length of the step to each: along an internal lane
    # stretched to the length SUMO drives, between lanes as drawn
    pts, steps = [entry_xy[None]], []
    prev = entry_xy
    for i, v in enumerate(inner):
        geo = seglen(v)
        want = vias[i].length_m
        k = want / float(geo.sum()) if want and want > 0.0 and geo.sum() > 0.0 else 1.0
        pts.append(v)
        steps += [float(np.linalg.norm(v[0] - prev)), *(geo * k)]
        prev = v[-1]
    pts.append(out_shape[:1])
    steps.append(float(np.linalg.norm(out_shape[0] - prev)))
    middle, mid_steps = np.vstack(pts), np.array(steps)
    keep = np.linalg.norm(np.diff(middle, axis=0), axis=1) > 1e-6  # as _dedup drops them
    middle = np.vstack([middle[:1], middle[1:][keep]])
    mid_steps = mid_steps[keep]
    cross_length = float(mid_steps.sum()) if len(middle) > 1 else 0.0
    if cross_length <= 0.0:
        raise ValueError(f"route {route_id}: zero length inside the junction")

    in_s = np.concatenate([[0.0], np.cumsum(seglen(in_shape))])
    in_s -= in_s[-1]  # entry line at s = 0
    mid_s = np.cumsum(mid_steps)
    out_tail = _dedup(out_shape)
    out_steps = seglen(out_tail)
    out_s = cross_length + np.cumsum(out_steps)
    xy = np.vstack([in_shape, middle[1:], out_tail[1:]])
    s = np.concatenate([in_s, mid_s, out_s])
    if not (np.diff(s) > 0.0).all():
        raise ValueError(f"route {route_id}: its arc length does not grow along it")
    return Route(
        id=route_id,
        in_lane=in_lane,
        out_lane=out_lane,
        via_lanes=via_lanes,
        turn=turn,
        speed_cap_mps=net_limit(net_limit(caps.for_turn(turn), in_limit_mps), out_limit_mps),
        cross_length_m=cross_length,
        xy=xy,
        s=s,
        road_mps=net_limit(caps.road_mps, in_limit_mps),
        exit_mps=net_limit(caps.road_mps, out_limit_mps),
        in_lane_m=in_lane_m,
        out_lane_m=out_lane_m,
        in_limit_mps=None if in_limit_mps is None else float(in_limit_mps),
    )
