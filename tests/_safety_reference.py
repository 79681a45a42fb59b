# Frozen copy of sim_gateway/safety.py before the speed-up: the reference for tests.
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
# Rounding allowance [m] on the numpy pre-filter of pairs, and the GEOS distance at or
# below which the exact intersects predicate (not float distance) decides "overlap".
_SLACK_M = 1e-6
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


def _closest_per_vin_pair(a: np.ndarray, b: np.ndarray, gap_m: np.ndarray) -> np.ndarray:
    """Indices keeping one entry per unordered vin pair (its smallest gap), in input order.

    Only for steps where a vin appears twice, so that a pair still counts once per step.
    """
    seen: set[tuple[str, str]] = set()
    keep = []
    for k in np.argsort(gap_m, kind="stable"):
        key = (a[k], b[k]) if a[k] <= b[k] else (b[k], a[k])
        if key not in seen:
            seen.add(key)
            keep.append(k)
    return np.sort(np.asarray(keep, dtype=np.intp))


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

        # Per-call cost is dominated by the number of numpy/GEOS calls, not by n: keep few.
        rad = np.deg2rad(ang)
        head = np.column_stack((np.sin(rad), np.cos(rad)))  # 0 deg = +y, clockwise
        head[np.abs(head) < _AXIS_SNAP] = 0.0
        half_l, half_w = 0.5 * length, 0.5 * width
        radius = np.hypot(half_l, half_w)  # half-diagonal
        along = head * half_l[:, None]  # rectangle centre -> front bumper
        across = head[:, ::-1] * half_w[:, None] * _RIGHT_OF_HEADING  # centre -> right side
        centre = xy - along
        corners = centre[:, None, :] + _CORNER_L[:, None] * along[:, None, :]
        corners += _CORNER_W[:, None] * across[:, None, :]
        polys = shapely.polygons(corners)
        if self._margin_m > 0.0:
            watched = shapely.dwithin(polys, self._region, self._margin_m)
        else:
            watched = shapely.intersects(polys, self._region)
        idx = np.flatnonzero(watched)
        m = len(idx)
        if m < 2:
            return 0
        if m < n:
            polys, centre, radius = polys[idx], centre[idx], radius[idx]

        # Candidate pairs i < j: the centre distance minus both half-diagonals is a lower
        # bound on the gap, so pairs beyond the histogram range are dropped before GEOS
        # (while no pair has come that close, nothing is dropped: min_gap_m stays exact).
        within = max(self._hist_max_m, self._min_gap_m) + _SLACK_M
        reach = radius[:, None] + radius + within
        z = np.ascontiguousarray(centre).view(np.complex128)[:, 0]  # x + iy, no copy
        ia, ib = np.nonzero((np.abs(z[:, None] - z) <= reach) & self._upper(m))
        names = None
        if len(vins) != len(set(vins)):  # never in SUMO; tolerated rather than trusted
            names = np.asarray(vins, dtype=object)[idx]
            differ = names[ia] != names[ib]
            ia, ib = ia[differ], ib[differ]
        if len(ia) == 0:
            return 0
        gap = shapely.distance(polys[ia], polys[ib])
        # The exact GEOS predicate, not the float distance, decides touching pairs.
        maybe = np.flatnonzero(gap <= _SLACK_M)
        overlap = np.zeros(len(ia), dtype=bool)
        if len(maybe):
            overlap[maybe] = shapely.intersects(polys[ia[maybe]], polys[ib[maybe]])
            gap[maybe[overlap[maybe]]] = 0.0
        if names is not None:
            keep = _closest_per_vin_pair(names[ia], names[ib], gap)
            ia, ib, gap, overlap = ia[keep], ib[keep], gap[keep], overlap[keep]

        # Bin k holds edges[k] <= gap < edges[k + 1]; the extra last bin (>= 10 m) is dropped.
        counts = np.bincount(np.searchsorted(self._edges_m[1:], gap, side="right"))
        self._hist[: len(counts)] += counts[: len(self._hist)]

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
