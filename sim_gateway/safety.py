"""Independent collision checker: overlaps of vehicle rectangles as SUMO reports them.

This module is the second opinion on the ICA, so it shares no code with ``ica``: it
builds its own rectangles from raw SUMO poses and uses shapely (GEOS) rather than the
controller's own geometry. If both had the same bug, a shared helper would hide it.

SUMO frames: ``vehicle.getPosition`` is the centre of the front bumper [m];
``vehicle.getAngle`` is degrees, 0 = north (+y), clockwise, so the heading unit vector
is ``(sin a, cos a)`` and the rectangle centre is ``front - heading * length / 2``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import shapely

# Histogram of pair gaps; pairs at >= the last edge are not counted.
GAP_HIST_EDGES_M: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 10.0)
MAX_LISTED_OVERLAPS = 100
# |sin|, |cos| below this are set to 0 so that axis-aligned poses (straight SUMO lanes
# along the axes) give exact corners: a 6e-17 residue must not decide "touching".
_AXIS_SNAP = 1e-12
# Rounding allowance on the numpy lower bound of a pair's gap [m]: pairs whose bound is
# within this of a threshold are handed to GEOS rather than decided in numpy.
_BOUND_SLACK_M = 1e-6
# Corners of a rectangle as multiples of (centre -> front, centre -> right side), closed.
_CORNER_L = np.array([1.0, 1.0, -1.0, -1.0, 1.0])
_CORNER_W = np.array([1.0, -1.0, -1.0, 1.0, 1.0])
_RIGHT_OF_HEADING = np.array([1.0, -1.0])  # right normal of (hx, hy) is (hy, -hx)


@dataclass(frozen=True)
class SafetyReport:
    """What the monitor saw over a run; all pair metrics are over watched vehicles only."""

    steps: int
    overlaps: int
    overlap_pairs: list[tuple[float, str, str]]
    min_gap_m: float
    min_gap_pair: tuple[float, str, str] | None
    gap_hist_edges_m: list[float]
    gap_hist_counts: list[int]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict: tuples become lists and an infinite gap becomes ``None``."""
        d = asdict(self)
        d["overlap_pairs"] = [list(p) for p in self.overlap_pairs]
        d["min_gap_m"] = self.min_gap_m if math.isfinite(self.min_gap_m) else None
        d["min_gap_pair"] = None if self.min_gap_pair is None else list(self.min_gap_pair)
        return d


def _region_polygon(region: np.ndarray) -> shapely.Geometry:
    """Polygon from a (K, 2) ring, open or closed; made valid if it self-intersects."""
    ring = np.asarray(region, dtype=float)
    if ring.ndim != 2 or ring.shape[1] != 2:
        raise ValueError(f"region must have shape (K, 2), got {ring.shape}")
    if not np.isfinite(ring).all():
        raise ValueError("region has non-finite coordinates")
    if len(ring) >= 2 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    if len(ring) < 3:
        raise ValueError(f"region needs at least 3 distinct corners, got {len(ring)}")
    poly = shapely.polygons(ring)
    if not poly.is_valid:
        poly = shapely.make_valid(poly)
    if poly.area <= 0.0:
        raise ValueError("region polygon has zero area")
    return poly


def _as_column(name: str, a: np.ndarray, n: int) -> np.ndarray:
    out = np.asarray(a, dtype=float)
    if out.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) to match vins, got {out.shape}")
    if not np.isfinite(out).all():
        bad = np.flatnonzero(~np.isfinite(out)).tolist()
        raise ValueError(f"{name} has non-finite values at indices {bad}")
    return out


def _separation_lower_bound_m(
    ia: np.ndarray,
    ib: np.ndarray,
    head: np.ndarray,
    half_l: np.ndarray,
    half_w: np.ndarray,
    centre: np.ndarray,
) -> np.ndarray:
    """Per pair (ia, ib), the largest gap between the rectangles' projections on their 4 axes.

    Projection onto a unit axis never lengthens a segment, so this is a lower bound on the
    true distance [m]; it is <= 0 exactly when no axis separates them (they overlap). Used
    only to skip GEOS calls for pairs that are provably far apart.
    """
    d = centre[ib] - centre[ia]
    ha, hb = head[ia], head[ib]
    ax, ay, bx, by, dx, dy = ha[:, 0], ha[:, 1], hb[:, 0], hb[:, 1], d[:, 0], d[:, 1]
    la, wa, lb, wb = half_l[ia], half_w[ia], half_l[ib], half_w[ib]
    # Right normals are (hy, -hx): |h_a . h_b| = |n_a . n_b|, |h_a . n_b| = |n_a . h_b|.
    hh = np.abs(ax * bx + ay * by)
    hn = np.abs(ax * by - ay * bx)
    sep = np.abs(dx * ax + dy * ay) - la - lb * hh - wb * hn  # along h_a
    np.maximum(sep, np.abs(dx * ay - dy * ax) - wa - lb * hn - wb * hh, out=sep)  # n_a
    np.maximum(sep, np.abs(dx * bx + dy * by) - lb - la * hh - wa * hn, out=sep)  # h_b
    np.maximum(sep, np.abs(dx * by - dy * bx) - wb - la * hn - wa * hh, out=sep)  # n_b
    return sep


class SafetyMonitor:
    """Counts overlapping vehicle rectangles in (and near) a junction, step by step.

    Each ``observe()`` is one simulation step. A vehicle is watched in that step when its
    rectangle intersects the region grown by ``watch_margin_m``; every pair of watched
    vehicles with different vins is checked. Touching (distance 0) is an overlap.
    """

    def __init__(self, region: np.ndarray, watch_margin_m: float = 0.0) -> None:
        margin = float(watch_margin_m)
        if not math.isfinite(margin) or margin < 0.0:
            raise ValueError(f"watch_margin_m must be finite and >= 0, got {watch_margin_m!r}")
        self._region = _region_polygon(region)
        self._margin_m = margin
        shapely.prepare(self._region)
        # Cheap numpy pre-filter: a rectangle with half-diagonal r can reach the grown
        # region only if its centre is inside the region's bounds grown by margin + r.
        self._bounds = np.asarray(self._region.bounds, dtype=float)
        self._edges_m = np.asarray(GAP_HIST_EDGES_M, dtype=float)
        self._hist_max_m = float(self._edges_m[-1])
        self._steps = 0
        self._overlaps = 0
        self._overlap_pairs: list[tuple[float, str, str]] = []
        self._min_gap_m = math.inf
        self._min_gap_pair: tuple[float, str, str] | None = None
        self._hist = np.zeros(len(self._edges_m) - 1, dtype=np.int64)
        self._upper_cache: dict[int, np.ndarray] = {}

    def _upper(self, m: int) -> np.ndarray:
        """(m, m) mask of pairs i < j, cached: building it costs more than using it."""
        mask = self._upper_cache.get(m)
        if mask is None:
            mask = self._upper_cache[m] = np.triu(np.ones((m, m), dtype=bool), k=1)
        return mask

    def observe(
        self,
        t_s: float,
        vins: Sequence[str],
        front_xy: np.ndarray,
        angle_deg: np.ndarray,
        length_m: np.ndarray,
        width_m: np.ndarray,
    ) -> int:
        """Check one step of raw SUMO poses; returns the number of overlapping pairs found."""
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        n = len(vins)
        xy = np.asarray(front_xy, dtype=float)
        if n == 0 and xy.size == 0:
            xy = xy.reshape(0, 2)
        if xy.shape != (n, 2):
            raise ValueError(f"front_xy must have shape ({n}, 2) to match vins, got {xy.shape}")
        if not np.isfinite(xy).all():
            bad = np.flatnonzero(~np.isfinite(xy).all(axis=1)).tolist()
            raise ValueError(f"front_xy has non-finite positions at indices {bad}")
        ang = _as_column("angle_deg", angle_deg, n)
        length = _as_column("length_m", length_m, n)
        width = _as_column("width_m", width_m, n)
        if (length <= 0.0).any() or (width <= 0.0).any():
            raise ValueError("length_m and width_m must be > 0")
        self._steps += 1
        if n < 2:
            return 0

        rad = np.deg2rad(ang)
        head = np.stack((np.sin(rad), np.cos(rad)), axis=1)  # unit heading, 0 deg = +y
        head[np.abs(head) < _AXIS_SNAP] = 0.0
        half_l, half_w = 0.5 * length, 0.5 * width
        along = head * half_l[:, None]  # rectangle centre -> front bumper
        centre = xy - along
        radius = np.hypot(half_l, half_w)

        # Watched: numpy bounds pre-filter (a rectangle lies within its half-diagonal of
        # its centre), then the exact GEOS test on the survivors.
        reach = (self._margin_m + radius)[:, None]
        near = (centre >= self._bounds[:2] - reach) & (centre <= self._bounds[2:] + reach)
        idx = np.flatnonzero(near.all(axis=1))
        if len(idx) < 2:
            return 0
        if len(idx) < n:
            head, half_l, half_w = head[idx], half_l[idx], half_w[idx]
            along, centre, radius = along[idx], centre[idx], radius[idx]
        across = head[:, ::-1] * (half_w[:, None] * _RIGHT_OF_HEADING)  # centre -> right side
        corners = centre[:, None, :] + _CORNER_L[:, None] * along[:, None, :]
        corners += _CORNER_W[:, None] * across[:, None, :]
        rings = shapely.linearrings(corners)
        polys = shapely.polygons(rings)
        if self._margin_m > 0.0:
            watched = shapely.dwithin(polys, self._region, self._margin_m)
        else:
            watched = shapely.intersects(polys, self._region)
        keep = np.flatnonzero(watched)
        m = len(keep)
        if m < 2:
            return 0
        if m < len(idx):
            idx, rings, polys = idx[keep], rings[keep], polys[keep]
            head, half_l, half_w = head[keep], half_l[keep], half_w[keep]
            centre, radius = centre[keep], radius[keep]

        # Candidate pairs, in two numpy filters so GEOS only sees pairs that matter: pairs
        # provably beyond the histogram range are dropped (or, while no pair has come that
        # close, beyond the smallest gap so far, so that min_gap_m stays exact).
        within = max(self._hist_max_m, self._min_gap_m) + _BOUND_SLACK_M
        # 1. Centre distance minus both half-diagonals, over the m x m matrix.
        d = centre[:, None, :] - centre[None, :, :]
        reach_m = radius[:, None] + radius[None, :] + within
        ia, ib = np.nonzero((np.einsum("ijk,ijk->ij", d, d) <= reach_m * reach_m) & self._upper(m))
        if len(vins) != len(set(vins)):
            names = np.asarray(vins, dtype=object)[idx]
            differ = names[ia] != names[ib]
            ia, ib = ia[differ], ib[differ]
        # 2. Separating-axis lower bound on the survivors.
        lower = _separation_lower_bound_m(ia, ib, head, half_l, half_w, centre)
        cand = lower < within
        ia, ib, lower = ia[cand], ib[cand], lower[cand]
        if len(ia) == 0:
            return 0
        # Overlap is decided by GEOS intersects for every pair not provably apart.
        overlap = np.zeros(len(ia), dtype=bool)
        maybe = np.flatnonzero(lower <= _BOUND_SLACK_M)
        if len(maybe):
            overlap[maybe] = shapely.intersects(polys[ia[maybe]], polys[ib[maybe]])
        # Disjoint rectangles are closest on their boundaries: ring distance is the gap
        # (and GEOS computes it faster than polygon distance, which tests containment).
        gap = np.zeros(len(ia))
        apart = ~overlap
        gap[apart] = shapely.distance(rings[ia[apart]], rings[ib[apart]])

        in_hist = gap < self._hist_max_m
        bins = np.searchsorted(self._edges_m, gap[in_hist], side="right") - 1
        self._hist += np.bincount(bins, minlength=len(self._hist))

        k = int(np.argmin(gap))
        if gap[k] < self._min_gap_m:
            self._min_gap_m = float(gap[k])
            self._min_gap_pair = (t, *self._ordered(vins, idx[ia[k]], idx[ib[k]]))

        found = int(overlap.sum())
        if found:
            self._overlaps += found
            room = MAX_LISTED_OVERLAPS - len(self._overlap_pairs)
            if room > 0:
                listed = sorted(
                    self._ordered(vins, idx[a], idx[b])
                    for a, b in zip(ia[overlap], ib[overlap], strict=True)
                )
                self._overlap_pairs.extend((t, a, b) for a, b in listed[:room])
        return found

    @staticmethod
    def _ordered(vins: Sequence[str], i: int, j: int) -> tuple[str, str]:
        """The pair's vins in sorted order, so a pair reads the same whatever the input order."""
        a, b = str(vins[int(i)]), str(vins[int(j)])
        return (a, b) if a <= b else (b, a)

    def report(self) -> SafetyReport:
        """Snapshot of everything seen so far (the monitor keeps counting afterwards)."""
        return SafetyReport(
            steps=self._steps,
            overlaps=self._overlaps,
            overlap_pairs=list(self._overlap_pairs),
            min_gap_m=self._min_gap_m,
            min_gap_pair=self._min_gap_pair,
            gap_hist_edges_m=[float(e) for e in self._edges_m],
            gap_hist_counts=[int(c) for c in self._hist],
        )
