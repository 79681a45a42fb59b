"""Conflict points of a junction, and when each confirmed vehicle holds each of them.

DICA's safety argument is about occupancies: two occupancies that overlap must
have disjoint occupancy time intervals. To draw it, the junction is reduced to
a few *conflict points*: where the centrelines of two conflicting routes from
different incoming lanes cross or merge (or come closest), merged when they lie
within ``merge_m`` of each other. A vehicle *holds* a point for the union of the
occupancy time intervals of its occupancies that cover the point.

Why points and not areas: two footprints that cover the same point overlap, so
for a confirmed set that DICA accepted, no two vehicles' holding intervals at
one point can overlap. A larger area would not give that guarantee (two
vehicles can share a merging lane's area one behind the other), and the
picture would show overlaps that are not conflicts.

Everything here is numpy on the core's types (routes, DTOTs, rectangles); no
I/O, no drawing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dica.ica.core.dtot import Dtot, build_dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import ConflictTables, Shape

SAMPLE_M = 0.1  # [m] resolution of the centreline search
MERGE_M = 3.5  # [m] conflict points closer than this become one


@dataclass(frozen=True, slots=True, eq=False)
class ConflictPoints:
    """P points (x, y) [m] and for each the route pairs that meet there."""

    xy: np.ndarray  # (P, 2)
    pairs: tuple[tuple[tuple[str, str], ...], ...]  # route id pairs per point

    def __len__(self) -> int:
        return len(self.xy)

    def name(self, i: int) -> str:
        """A short name for a person: the movements that meet there (``N→S × W→E``)."""
        moves = [f"{_move(a)} × {_move(b)}" for a, b in self.pairs[i]]
        more = f" +{len(moves) - 1}" if len(moves) > 1 else ""
        return f"{moves[0]}{more}"


def _move(route_id: str) -> str:
    """``N_in_1>S_out_1`` -> ``N→S``: where it comes from and where it goes."""
    a, _, b = route_id.partition(">")
    return f"{a.split('_')[0]}→{b.split('_')[0]}"


def _centreline(route: Route) -> np.ndarray:
    s = np.arange(0.0, route.cross_length_m + SAMPLE_M / 2, SAMPLE_M)
    return route.points(s)


def find_conflict_points(
    inter: Intersection,
    tables: ConflictTables,
    shape: Shape,
    merge_m: float = MERGE_M,
) -> ConflictPoints:
    """The conflict points of every conflicting route pair from different incoming lanes.

    For a pair, the point is where the centrelines first meet along the first
    route (a crossing, or the start of a merge), or the middle of their
    closest approach when they do not meet but the footprints can touch.
    """
    lines = {r.id: _centreline(r) for r in inter.routes}
    found: list[tuple[np.ndarray, tuple[str, str]]] = []
    routes = inter.routes
    for i, a in enumerate(routes):
        for b in routes[i + 1 :]:
            if a.in_lane == b.in_lane or tables.compatible(a, shape, b, shape):
                continue
            pa, pb = lines[a.id], lines[b.id]
            d = np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=-1)
            near = np.nonzero(d.min(axis=1) <= SAMPLE_M)[0]
            if len(near):  # first meeting point along a
                k = int(near[0])
                p = (pa[k] + pb[int(np.argmin(d[k]))]) / 2.0
            else:
                k, m = np.unravel_index(int(np.argmin(d)), d.shape)
                p = (pa[k] + pb[m]) / 2.0
            found.append((p, (a.id, b.id)))
    clusters: list[list[tuple[np.ndarray, tuple[str, str]]]] = []
    for p, pair in found:
        for c in clusters:
            if np.linalg.norm(np.mean([q for q, _ in c], axis=0) - p) < merge_m:
                c.append((p, pair))
                break
        else:
            clusters.append([(p, pair)])
    if not clusters:
        return ConflictPoints(np.zeros((0, 2)), ())
    xy = np.array([np.mean([q for q, _ in c], axis=0) for c in clusters])
    centre = np.asarray(inter.region, dtype=float).mean(axis=0)
    order = np.argsort(np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0]))
    pairs = tuple(tuple(pair for _, pair in clusters[i]) for i in order)
    return ConflictPoints(xy[order], pairs)


def covers(
    centre: np.ndarray,
    heading: np.ndarray,
    half_length_m: np.ndarray | float,
    half_width_m: np.ndarray | float,
    points: np.ndarray,
) -> np.ndarray:
    """(N, P): whether rectangle n (centre, unit heading, half extents) covers point p."""
    d = points[None, :, :] - centre[:, None, :]
    along = np.abs(d[..., 0] * heading[:, None, 0] + d[..., 1] * heading[:, None, 1])
    across = np.abs(-d[..., 0] * heading[:, None, 1] + d[..., 1] * heading[:, None, 0])
    hl = np.reshape(np.asarray(half_length_m, dtype=float), (-1, 1))
    hw = np.reshape(np.asarray(half_width_m, dtype=float), (-1, 1))
    return (along <= hl) & (across <= hw)


@dataclass(frozen=True, slots=True, eq=False)
class Holding:
    """When one confirmed vehicle holds which conflict points: K bars."""

    point: np.ndarray  # (K,) conflict point index
    lb_s: np.ndarray  # (K,) [s]
    ub_s: np.ndarray  # (K,) [s]

    def __len__(self) -> int:
        return len(self.point)


def dtot_of_tss(
    route: Route,
    t_s: np.ndarray,
    x_m: np.ndarray,
    y_m: np.ndarray,
    length_m: float,
    width_m: float,
    margin_m: float,
) -> Dtot:
    """The DTOT of a confirmed TSS, with the dissertation's exhaustive intervals.

    The ICA may have reserved wider intervals (enhanced DICA estimates them,
    never narrower); the exhaustive ones are the definition, and they are
    what the guarantee needs.
    """
    t = np.asarray(t_s, dtype=float)
    s, _ = route.project(np.stack([np.asarray(x_m, float), np.asarray(y_m, float)], axis=-1))
    step = float(t[1] - t[0]) if len(t) > 1 else 0.05
    traj = Trajectory(float(t[0]), step, s)
    return build_dtot(route, Shape.of(length_m, width_m), traj, margin_m)


def holding(dtot: Dtot, points: ConflictPoints) -> Holding:
    """For each conflict point the DTOT covers: the union of the covering occupancies'
    intervals. Occupancies covering one point follow one another and their
    intervals overlap, so the union is one interval."""
    if len(points) == 0 or len(dtot) == 0:
        empty = np.zeros(0)
        return Holding(empty.astype(int), empty, empty)
    r = dtot.rects
    cov = covers(r.centre, r.heading, r.half_length, r.half_width, points.xy)
    hit = np.nonzero(cov.any(axis=0))[0]
    lb = np.array([dtot.lb_s[cov[:, p]].min() for p in hit])
    ub = np.array([dtot.ub_s[cov[:, p]].max() for p in hit])
    return Holding(hit, lb, ub)
