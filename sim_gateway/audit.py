"""A brute-force safety audit that trusts nothing but the confirmed TSSs.

The tests use it as their oracle; ``dica stream`` runs it on every stream.

Footprints are rebuilt from each confirmed TSS (front bumper, heading) with
shapely, grown by the ICA's margin. Inside the junction (from the last sample
before the entry line to the first sample fully out) every pair of
occupancies of two vehicles is tested: polygons intersect (touching counts)
and exhaustive occupancy time intervals overlap means a conflict. In the
approach, a follower must stay clear of its lane leader at every sample time
of either vehicle (positions interpolated linearly, as vehicles move).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import shapely

from dica.ica.core.route import Route


@dataclass(frozen=True)
class Flown:
    vin: str
    route: Route
    length_m: float
    width_m: float
    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray


def _polys(x, y, h, length, width, margin) -> np.ndarray:
    ux, uy = np.cos(h), np.sin(h)
    cx, cy = x - ux * length / 2, y - uy * length / 2
    hl, hw = length / 2 + margin, width / 2 + margin
    corners = []
    for a, b in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)):
        corners.append(np.stack([cx + a * ux - b * uy, cy + a * uy + b * ux], -1))
    ring = np.stack(corners + corners[:1], axis=1)
    return shapely.polygons(ring)


def _inside_range(f: Flown) -> slice:
    """Last sample before the front reaches the entry line .. first sample fully out."""
    s, _ = f.route.project(np.stack([f.x_m, f.y_m], -1))
    inside = np.nonzero(s > 0.0)[0]
    k0 = max(int(inside[0]) - 1, 0) if len(inside) else len(s) - 1
    out = np.nonzero(s >= f.route.cross_length_m + f.length_m - 1e-9)[0]
    k1 = int(out[0]) if len(out) else len(s) - 1
    return slice(k0, k1 + 1)


def _intervals(t: np.ndarray, polys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(t)
    clear = ~shapely.intersects(polys[:, None], polys[None, :])
    lb, ub = np.empty(n), np.empty(n)
    for k in range(n):
        before = np.nonzero(clear[k, :k])[0]
        after = np.nonzero(clear[k, k + 1 :])[0]
        lb[k] = t[before[-1]] if len(before) else t[0]
        ub[k] = t[k + 1 + after[0]] if len(after) else t[-1]
    return lb, ub


def conflicts(flown: list[Flown], margin_m: float) -> list[tuple[str, str, float]]:
    """Every (vin, vin, time) at which two confirmed vehicles conflict."""
    occ = []
    for f in flown:
        r = _inside_range(f)
        t = f.t_s[r]
        p = _polys(f.x_m[r], f.y_m[r], f.heading_rad[r], f.length_m, f.width_m, margin_m)
        lb, ub = _intervals(t, p)
        occ.append((f, t, p, lb, ub))
    found: list[tuple[str, str, float]] = []
    for a in range(len(occ)):
        fa, ta, pa, lba, uba = occ[a]
        for b in range(a + 1, len(occ)):
            fb, _tb, pb, lbb, ubb = occ[b]
            if uba[-1] < lbb[0] or ubb[-1] < lba[0]:
                continue  # disjoint in time: no interval can overlap
            hit = shapely.intersects(pa[:, None], pb[None, :])
            hit &= (lba[:, None] <= ubb[None, :]) & (lbb[None, :] <= uba[:, None])
            if hit.any():
                i, _ = np.nonzero(hit)
                found.append((fa.vin, fb.vin, float(ta[i[0]])))
    found += _approach_conflicts(flown, margin_m)
    return found


def _approach_conflicts(flown: list[Flown], margin_m: float) -> list[tuple[str, str, float]]:
    found = []
    by_lane: dict[str, list[Flown]] = {}
    for f in flown:
        by_lane.setdefault(f.route.in_lane, []).append(f)
    for group in by_lane.values():
        group.sort(key=lambda f: f.t_s[0])
        for lead, fol in itertools.pairwise(group):
            s_f, _ = fol.route.project(np.stack([fol.x_m, fol.y_m], -1))
            t = np.union1d(fol.t_s[s_f < 0], lead.t_s)
            t = t[(t >= max(fol.t_s[0], lead.t_s[0])) & (t <= min(fol.t_s[-1], lead.t_s[-1]))]
            if len(t) == 0:
                continue
            sf = np.interp(t, fol.t_s, s_f)
            t = t[sf < 0]
            if len(t) == 0:
                continue

            def at(f: Flown, tt: np.ndarray) -> np.ndarray:
                x = np.interp(tt, f.t_s, f.x_m)
                y = np.interp(tt, f.t_s, f.y_m)
                h = np.interp(tt, f.t_s, np.unwrap(f.heading_rad))
                return _polys(x, y, h, f.length_m, f.width_m, margin_m)

            hit = shapely.intersects(at(lead, t), at(fol, t))
            if hit.any():
                found.append((lead.vin, fol.vin, float(t[np.argmax(hit)])))
    return found


def kinematic_violations(f: Flown, road_mps: float, accel: float, decel: float, tol: float = 1e-6):
    """Speed and acceleration limits on the flown samples (what SUMO will execute);
    the road's limit is ``road_mps`` or the route's own approach limit if lower."""
    road_mps = min(road_mps, f.route.road_mps)
    s, off = f.route.project(np.stack([f.x_m, f.y_m], -1))
    problems = []
    if off.max() > 1e-6:
        problems.append(f"off route by {off.max():.3g} m")
    h = float(np.diff(f.t_s).mean())
    v = np.diff(s) / h
    if v.min() < -tol:
        problems.append("moves backwards")
    if v.max() > road_mps + tol:
        problems.append(f"speed {v.max():.3f} > road limit")
    inside = s[:-1] >= 0
    if inside.any() and v[inside].max() > f.route.speed_cap_mps + tol:
        problems.append(f"speed {v[inside].max():.3f} > {f.route.turn.value} cap inside")
    acc = np.diff(v) / h
    if len(acc) and (acc.max() > accel + 1e-4 or acc.min() < -decel - 1e-4):
        problems.append(f"acceleration {acc.min():.3f}..{acc.max():.3f} outside limits")
    return problems
