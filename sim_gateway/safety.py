"""Independent collision checker: overlaps of vehicle rectangles as SUMO reports them.

This module is the second opinion on the ICA, so it shares no code with ``ica``: it
builds its own rectangles from raw SUMO poses and uses shapely (GEOS) rather than the
controller's own geometry. If both had the same bug, a shared helper would hide it.

SUMO frames: ``vehicle.getPosition`` is the centre of the front bumper [m];
``vehicle.getAngle`` is degrees, 0 = north (+y), clockwise, so the heading unit vector
is ``(sin a, cos a)`` and the rectangle centre is ``front - heading * length / 2``.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import shapely

# Histogram of pair gaps; pairs at >= the last edge are not counted.
GAP_HIST_EDGES_M: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 10.0)
MAX_LISTED_OVERLAPS = 100
PERSON_GAP_M = 3.0  # [m] vehicle-person gaps beyond this are not measured (min gap: None)
# |sin|, |cos| below this are set to 0 so that axis-aligned poses (straight SUMO lanes
# along the axes) give exact corners: a 6e-17 residue must not decide "touching".
_AXIS_SNAP = 1e-12
# Rounding allowance [m] on the numpy pre-filter of pairs, and the GEOS distance at or
# below which the exact intersects predicate (not float distance) decides "overlap".
_SLACK_M = 1e-6
# Up to this many watched vehicles, candidate pairs are found in plain Python (faster).
_PY_PAIRS_MAX = 12
# Grid of region distances for the watch pre-check: cells per side of the grown box, and
# how far beyond the margin it reaches (vehicles' half-diagonals, 12 m buses included).
_GRID_CELLS = 64
_GRID_REACH_M = 8.0


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
        # Cheap pre-checks, so that GEOS sees only the vehicles it must decide: a bounding
        # circle (centre, half-diagonal) beyond the region's box grown by the margin is never
        # watched; a point of the rectangle inside ``_surely_watched`` (the region grown by
        # a bit less than the margin) makes it watched.
        lo_x, lo_y, hi_x, hi_y = shapely.bounds(self._region).tolist()
        self._box_centre = (0.5 * (lo_x + hi_x), 0.5 * (lo_y + hi_y))
        scale = max(abs(lo_x), abs(lo_y), abs(hi_x), abs(hi_y), 1.0)
        self._box_slack_m = _SLACK_M + 1e-9 * scale
        grow = margin + self._box_slack_m
        self._box_half = (0.5 * (hi_x - lo_x) + grow, 0.5 * (hi_y - lo_y) + grow)
        inner = margin - _SLACK_M - 1e-9 * (scale + margin)
        if inner > 0.0:
            self._surely_watched = shapely.buffer(self._region, inner)
        else:
            self._surely_watched = self._region
        shapely.prepare(self._surely_watched)
        # A grid over the box grown by ``margin + _GRID_REACH_M`` holds, per cell, -1 when
        # every centre in it is surely watched, else a lower bound on the distance from the
        # cell to the region (a centre there is unwatched if farther than margin + radius).
        # Cells are grown by a rounding allowance so the looked-up cell holds the centre.
        reach = margin + _GRID_REACH_M
        self._grid_lo = (lo_x - reach, lo_y - reach)
        cell = (max(hi_x - lo_x, hi_y - lo_y) + 2.0 * reach) / _GRID_CELLS
        self._grid_inv_cell = 1.0 / cell
        self._grid_n = (
            math.ceil((hi_x - lo_x + 2.0 * reach) / cell),
            math.ceil((hi_y - lo_y + 2.0 * reach) / cell),
        )
        gx = self._grid_lo[0] + cell * np.arange(self._grid_n[0])
        gy = self._grid_lo[1] + cell * np.arange(self._grid_n[1])
        x0, y0 = np.meshgrid(gx, gy, indexing="ij")
        eps = self._box_slack_m
        cells = shapely.box(x0 - eps, y0 - eps, x0 + cell + eps, y0 + cell + eps)
        dist = np.maximum(shapely.distance(cells, self._region) - self._box_slack_m, 0.0)
        inside = shapely.covered_by(cells, self._surely_watched)
        self._grid: list[list[float]] = np.where(inside, -1.0, dist).tolist()
        self._edges_m = np.asarray(GAP_HIST_EDGES_M, dtype=float)
        self._hist_max_m = float(self._edges_m[-1])
        self._steps = 0
        self._overlaps = 0
        self._overlap_pairs: list[tuple[float, str, str]] = []
        self._min_gap_m = math.inf
        self._min_gap_pair: tuple[float, str, str] | None = None
        self._inner_edges = self._edges_m[1:].tolist()
        self._hist = [0] * (len(self._edges_m) - 1)
        self._upper_cache: dict[int, np.ndarray] = {}
        self._ring_offsets: dict[int, tuple[np.ndarray, np.ndarray]] = {}

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
        ang = np.asarray(angle_deg, dtype=float)
        length = np.asarray(length_m, dtype=float)
        width = np.asarray(width_m, dtype=float)
        # One finiteness check for the usual good input; anything odd gets the full checks
        # (in their order, for the same message). A finite sum can only be finite inputs.
        ok = xy.shape == (n, 2) and ang.shape == length.shape == width.shape == (n,)
        if ok:
            flat_xy, ang_l = xy.ravel().tolist(), ang.tolist()
            len_l, wid_l = length.tolist(), width.tolist()
            ok = math.isfinite(sum(flat_xy) + sum(ang_l) + sum(len_l) + sum(wid_l))
        if not ok:
            xy, ang, length, width = self._checked(n, xy, angle_deg, length_m, width_m)
            flat_xy, ang_l = xy.ravel().tolist(), ang.tolist()
            len_l, wid_l = length.tolist(), width.tolist()
        if n and (min(len_l) <= 0.0 or min(wid_l) <= 0.0):
            raise ValueError("length_m and width_m must be > 0")
        self._steps += 1
        if n < 2:
            return 0

        # Per-call cost is dominated by the number of numpy/GEOS calls, not by n (tens of
        # vehicles): numpy only for the trigonometry, plain floats for the rest. Every
        # corner is the same float expression as ``centre + l * along + w * across`` over
        # arrays (l, w = +-1 are exact), so the rectangles GEOS sees are bit for bit the same.
        rad = np.deg2rad(ang)
        sin_a, cos_a = np.sin(rad).tolist(), np.cos(rad).tolist()
        bcx, bcy = self._box_centre
        bhx, bhy = self._box_half
        thin = self._box_slack_m
        gx0, gy0 = self._grid_lo
        inv_cell, (gnx, gny), grid = self._grid_inv_cell, self._grid_n, self._grid
        far = self._margin_m + thin

        def at(x: float, y: float) -> float:
            """Grid value at a point: -1 (surely watched) or a lower bound on its distance."""
            u, v = (x - gx0) * inv_cell, (y - gy0) * inv_cell
            return grid[int(u)][int(v)] if 0.0 <= u < gnx and 0.0 <= v < gny else 0.0

        cand: list[int] = []
        rings: list[float] = []
        cxs: list[float] = []
        cys: list[float] = []
        radius: list[float] = []
        sure: list[bool] = []
        zipped = zip(flat_xy[::2], flat_xy[1::2], sin_a, cos_a, len_l, wid_l, strict=True)
        for i, (fx, fy, hx, hy, ln, wd) in enumerate(zipped):
            if abs(hx) < _AXIS_SNAP:
                hx = 0.0
            if abs(hy) < _AXIS_SNAP:
                hy = 0.0
            hl, hw = 0.5 * ln, 0.5 * wd
            r = math.hypot(hl, hw)  # half-diagonal
            ax, ay = hx * hl, hy * hl  # rectangle centre -> front bumper
            cx, cy = fx - ax, fy - ay
            u, v = (cx - gx0) * inv_cell, (cy - gy0) * inv_cell
            if 0.0 <= u < gnx and 0.0 <= v < gny:
                d = grid[int(u)][int(v)]
                if d > far + r:
                    continue  # the bounding circle is beyond the margin
                if d >= 0.0:
                    # Each half of the rectangle lies in a disc around its middle point.
                    qx, qy = 0.5 * ax, 0.5 * ay
                    d = min(at(cx + qx, cy + qy), at(cx - qx, cy - qy))
                    if d > far + math.hypot(0.5 * hl, hw):
                        continue
                    if d >= 0.0:  # the bumpers' middle points are in the rectangle too
                        d = min(at(fx, fy), at(cx - ax, cy - ay))
                sure.append(d < 0.0 and hl > thin and hw > thin)
            elif abs(cx - bcx) > bhx + r or abs(cy - bcy) > bhy + r:
                continue  # the bounding circle is beyond the region's box grown by the margin
            else:
                sure.append(False)
            bx, by = hy * hw, -(hx * hw)  # centre -> right side
            px, mx, py, my = cx + ax, cx - ax, cy + ay, cy - ay
            x0, y0 = px + bx, py + by
            rings += (x0, y0, px - bx, py - by, mx - bx, my - by, mx + bx, my + by, x0, y0)
            cand.append(i)
            cxs.append(cx)
            cys.append(cy)
            radius.append(r)
        if len(cand) < 2:
            return 0
        polys = self._rectangles(rings, len(cand))
        # GEOS decides only the vehicles the grid left unsure.
        if all(sure):
            sub = list(range(len(cand)))
        else:
            unsure = [k for k, s in enumerate(sure) if not s]
            if self._margin_m > 0.0:
                near = shapely.dwithin(polys[unsure], self._region, self._margin_m)
            else:
                near = shapely.intersects(polys[unsure], self._region)
            for k, w in zip(unsure, near.tolist(), strict=True):
                sure[k] = w
            sub = [k for k, s in enumerate(sure) if s]
        m = len(sub)
        if m < 2:
            return 0
        idx = [cand[s] for s in sub]
        cxs = [cxs[s] for s in sub]
        cys = [cys[s] for s in sub]
        radius = [radius[s] for s in sub]
        if m < len(cand):
            polys = polys[sub]

        # Candidate pairs i < j: the centre distance minus both half-diagonals is a lower
        # bound on the gap, so pairs beyond the histogram range are dropped before GEOS
        # (while no pair has come that close, nothing is dropped: min_gap_m stays exact).
        # Rounding in this bound only moves pairs whose gap exceeds ``within``, which
        # count nowhere, so the pairs that matter, and their order, are always the same.
        within = max(self._hist_max_m, self._min_gap_m) + _SLACK_M
        if m <= _PY_PAIRS_MAX:
            ia: Any = []
            ib: Any = []
            for i in range(m - 1):
                xi, yi, ri = cxs[i], cys[i], radius[i] + within
                for j in range(i + 1, m):
                    if math.hypot(cxs[j] - xi, cys[j] - yi) <= ri + radius[j]:
                        ia.append(i)
                        ib.append(j)
            ia, ib = np.array(ia, dtype=np.intp), np.array(ib, dtype=np.intp)
        else:
            rad_a = np.array(radius)
            reach = rad_a[:, None] + rad_a + within
            z = np.array(cxs) + 1j * np.array(cys)
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
        if min(gap.tolist()) <= _SLACK_M:
            maybe = np.flatnonzero(gap <= _SLACK_M)
            overlap = np.zeros(len(ia), dtype=bool)
            overlap[maybe] = shapely.intersects(polys[ia[maybe]], polys[ib[maybe]])
            gap[maybe[overlap[maybe]]] = 0.0
        else:
            overlap = None
        if names is not None:
            keep = _closest_per_vin_pair(names[ia], names[ib], gap)
            ia, ib, gap = ia[keep], ib[keep], gap[keep]
            overlap = None if overlap is None else overlap[keep]

        # Bin k holds edges[k] <= gap < edges[k + 1]; gaps >= the last edge are dropped.
        gaps = gap.tolist()
        hist, inner_edges, n_bins = self._hist, self._inner_edges, len(self._hist)
        best = 0
        for k, g in enumerate(gaps):
            b = bisect.bisect_right(inner_edges, g)
            if b < n_bins:
                hist[b] += 1
            if g < gaps[best]:
                best = k
        if gaps[best] < self._min_gap_m:
            self._min_gap_m = float(gaps[best])
            self._min_gap_pair = (t, *self._ordered(vins, idx[ia[best]], idx[ib[best]]))

        if overlap is None:
            return 0
        found = int(overlap.sum())
        if found:
            self._overlaps += found
            room = MAX_LISTED_OVERLAPS - len(self._overlap_pairs)
            if room > 0:
                listed = sorted(
                    self._ordered(vins, idx[a], idx[b])
                    for a, b in zip(ia[overlap].tolist(), ib[overlap].tolist(), strict=True)
                )
                self._overlap_pairs.extend((t, a, b) for a, b in listed[:room])
        return found

    def _rectangles(self, rings: list[float], k: int) -> np.ndarray:
        """k polygons from their closed 5-corner rings, flat as x0, y0, x1, y1, ..."""
        offsets = self._ring_offsets.get(k)
        if offsets is None:
            offsets = self._ring_offsets[k] = (np.arange(0, 5 * k + 1, 5), np.arange(k + 1))
        coords = np.array(rings).reshape(5 * k, 2)
        return shapely.from_ragged_array(shapely.GeometryType.POLYGON, coords, offsets)

    @staticmethod
    def _checked(
        n: int, xy: np.ndarray, angle_deg: np.ndarray, length_m: np.ndarray, width_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Full input checks, each with its own message; returns the arrays if all pass."""
        if xy.shape != (n, 2):
            raise ValueError(f"front_xy must have shape ({n}, 2) to match vins, got {xy.shape}")
        if not np.isfinite(xy).all():
            bad = np.flatnonzero(~np.isfinite(xy).all(axis=1)).tolist()
            raise ValueError(f"front_xy has non-finite positions at indices {bad}")
        ang = _as_column("angle_deg", angle_deg, n)
        length = _as_column("length_m", length_m, n)
        width = _as_column("width_m", width_m, n)
        return xy, ang, length, width

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
            gap_hist_counts=list(self._hist),
        )


def merge_reports(reports: Sequence[SafetyReport]) -> SafetyReport:
    """Several junctions' monitors as one: overlaps added, the smallest gap, the
    histograms summed (one junction's report is returned as it is)."""
    if len(reports) == 1:
        return reports[0]
    closest = min(reports, key=lambda r: r.min_gap_m)
    counts = np.sum([r.gap_hist_counts for r in reports], axis=0)
    return SafetyReport(
        steps=max(r.steps for r in reports),
        overlaps=sum(r.overlaps for r in reports),
        overlap_pairs=sorted(p for r in reports for p in r.overlap_pairs),
        min_gap_m=closest.min_gap_m,
        min_gap_pair=closest.min_gap_pair,
        gap_hist_edges_m=reports[0].gap_hist_edges_m,
        gap_hist_counts=[int(c) for c in counts],
    )


@dataclass(frozen=True)
class PersonReport:
    """What the person check saw: vehicles touching people, and the closest approach."""

    steps: int
    hits: int  # (step, vehicle, person) touches
    hit_pairs: list[tuple[float, str, str]]
    min_gap_m: float
    min_gap_pair: tuple[float, str, str] | None

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["hit_pairs"] = [list(p) for p in self.hit_pairs]
        d["min_gap_m"] = self.min_gap_m if math.isfinite(self.min_gap_m) else None
        d["min_gap_pair"] = None if self.min_gap_pair is None else list(self.min_gap_pair)
        return d


class PersonCheck:
    """Counts vehicle rectangles touching a person's body, step by step, from SUMO's raw
    poses: the same second opinion as :class:`SafetyMonitor`, for people.

    A person is a disc around SUMO's position for it, as wide as its length or width,
    whichever is more; a vehicle the rectangle behind its front bumper. Only people
    within ``reach_m`` of the region are checked (those on the junction's crossings and
    walking areas, and the sidewalks' ends).
    """

    def __init__(self, region: np.ndarray, reach_m: float = 5.0) -> None:
        self._area = shapely.buffer(_region_polygon(region), reach_m)
        shapely.prepare(self._area)
        # a bounding circle of the area: most people are beyond it, found without GEOS
        ring = np.asarray(self._area.exterior.coords)
        self._centre = ring.mean(axis=0)
        self._radius = float(np.linalg.norm(ring - self._centre, axis=1).max())
        self._steps = 0
        self._hits = 0
        self._pairs: list[tuple[float, str, str]] = []
        self._min_gap_m = math.inf
        self._min_pair: tuple[float, str, str] | None = None

    def observe(
        self,
        t_s: float,
        vins: Sequence[str],
        front_xy: np.ndarray,
        angle_deg: np.ndarray,
        length_m: np.ndarray,
        width_m: np.ndarray,
        people: Sequence[str],
        people_xy: np.ndarray,
        radius_m: np.ndarray,
    ) -> int:
        """Check one step; returns the vehicle-person touches found."""
        self._steps += 1
        if not len(vins) or not len(people):
            return 0
        pxy = np.asarray(people_xy, dtype=float).reshape(-1, 2)
        near = np.flatnonzero(np.hypot(*(pxy - self._centre).T) <= self._radius)
        if not len(near):
            return 0
        inside = shapely.contains_xy(self._area, pxy[near, 0], pxy[near, 1])
        if not inside.any():
            return 0
        idx = near[inside]
        pxy, rad = pxy[idx], np.asarray(radius_m, dtype=float)[idx]
        names = [people[i] for i in idx]
        xy = np.asarray(front_xy, dtype=float).reshape(-1, 2)
        a = np.deg2rad(np.asarray(angle_deg, dtype=float))
        head = np.stack([np.sin(a), np.cos(a)], axis=1)
        side = np.stack([head[:, 1], -head[:, 0]], axis=1)
        length = np.asarray(length_m, dtype=float)[:, None]
        half_w = 0.5 * np.asarray(width_m, dtype=float)[:, None]
        centre = xy - head * length / 2.0
        # pairs that may come within PERSON_GAP_M: centre distance less both radii
        reach = np.hypot(length[:, 0] / 2.0, half_w[:, 0])[:, None] + rad[None, :] + PERSON_GAP_M
        dist = np.linalg.norm(centre[:, None, :] - pxy[None, :, :], axis=2)
        iv, ip = np.nonzero(dist <= reach)
        if not len(iv):
            return 0
        corners = np.stack(
            [xy + side * half_w, xy - side * half_w, xy - head * length - side * half_w,
             xy - head * length + side * half_w],
            axis=1,
        )  # fmt: skip
        cars = shapely.polygons(corners[iv])
        bodies = shapely.buffer(shapely.points(pxy[ip]), rad[ip])
        gap = shapely.distance(cars, bodies)
        touch = shapely.intersects(cars, bodies)
        gap[touch] = 0.0
        k = int(np.argmin(gap))
        if gap[k] < self._min_gap_m:
            self._min_gap_m = float(gap[k])
            self._min_pair = (float(t_s), str(vins[iv[k]]), names[ip[k]])
        found = int(touch.sum())
        if found:
            self._hits += found
            for j in np.flatnonzero(touch)[: max(MAX_LISTED_OVERLAPS - len(self._pairs), 0)]:
                self._pairs.append((float(t_s), str(vins[iv[j]]), names[ip[j]]))
        return found

    def report(self) -> PersonReport:
        return PersonReport(
            self._steps, self._hits, list(self._pairs), self._min_gap_m, self._min_pair
        )
