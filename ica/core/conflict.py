"""getCV: which confirmed vehicles a DTOT conflicts with in space and time.

Two occupancies conflict when their rectangles intersect (touching counts)
and their occupancy time intervals overlap (closed intervals). For every
confirmed vehicle in conflict we report ``firstTimeAtCollision`` (the interval
start of its earliest conflicting occupancy, the dissertation's ordering key)
and the delay that would clear every conflicting pair under a pure shift.

Techniques 1, 2 and 4 only skip work that cannot find a conflict, so they
return exactly what the exhaustive search returns; technique 3 changes the
intervals themselves (never to narrower ones).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ica.core.config import Techniques
from ica.core.dtot import Dtot
from ica.core.occupancy import overlap_matrix, overlap_pairs
from ica.core.trajectory import Trajectory
from ica.core.zones import MAYBE, TOUCH, ConflictTables


@dataclass(frozen=True, slots=True)
class Conflict:
    vin: str
    first_time_s: float  # firstTimeAtCollision
    delay_s: float  # max over conflicting pairs of ub_j - lb_i


def get_cv(
    dtot: Dtot,
    confirmed: Iterable[tuple[str, Dtot]],
    tech: Techniques,
    tables: ConflictTables,
) -> list[Conflict]:
    """Conflicting confirmed vehicles, in ascending firstTimeAtCollision."""
    out: list[Conflict] = []
    for vin, other in confirmed:
        if tech.reduced_set and _skippable(dtot, other, tables):
            continue
        found = pair_conflict(dtot, other, tech, tables)
        if found is not None:
            out.append(Conflict(vin, *found))
    out.sort(key=lambda c: c.first_time_s)
    return out


def _skippable(i: Dtot, j: Dtot, tables: ConflictTables) -> bool:
    """Technique 1: disjoint crossing intervals or compatible routes."""
    if j.end_s < i.start_s or i.end_s < j.start_s:
        return True
    return tables.compatible(i.route, i.shape, j.route, j.shape)


def pair_conflict(
    i: Dtot, j: Dtot, tech: Techniques, tables: ConflictTables
) -> tuple[float, float] | None:
    """(firstTimeAtCollision, delay) for requester ``i`` against confirmed ``j``."""
    ki = np.arange(len(i))
    kj = np.arange(len(j))
    table = None
    if tech.conflict_zones:
        if i.grid_idx is None or j.grid_idx is None:
            raise ValueError("conflict zones need DTOTs built with their offline grid")
        ki = ki[tables.zone(i.route, i.shape, j.route, j.shape)[i.grid_idx]]
        kj = kj[tables.zone(j.route, j.shape, i.route, i.shape)[j.grid_idx]]
        if len(ki) == 0 or len(kj) == 0:
            return None
        table = tables.pairs(i.route, i.shape, j.route, j.shape)
    if tech.bisection or table is not None:
        if tech.bisection:
            pi, pj = _candidate_pairs(i, ki, j, kj)
        else:
            pi, pj = np.repeat(ki, len(kj)), np.tile(kj, len(ki))
        when = (i.lb_s[pi] <= j.ub_s[pj]) & (j.lb_s[pj] <= i.ub_s[pi])
        pi, pj = pi[when], pj[when]
        if len(pi) == 0:
            return None
        if table is not None:
            # the offline tables settle pairs clearly apart or clearly touching
            code = table[i.grid_idx[pi], j.grid_idx[pj]]
            hit = code == TOUCH
            unsure = np.nonzero(code == MAYBE)[0]
            hit[unsure] = overlap_pairs(i.rects, pi[unsure], j.rects, pj[unsure])
        else:
            hit = overlap_pairs(i.rects, pi, j.rects, pj)
        if not hit.any():
            return None
        pi, pj = pi[hit], pj[hit]
    else:
        space = overlap_matrix(i.rects.take(ki), j.rects.take(kj))
        lb_i, ub_i = i.lb_s[ki][:, None], i.ub_s[ki][:, None]
        lb_j, ub_j = j.lb_s[kj][None, :], j.ub_s[kj][None, :]
        hit = space & (lb_i <= ub_j) & (lb_j <= ub_i)
        if not hit.any():
            return None
        a, b = np.nonzero(hit)
        pi, pj = ki[a], kj[b]
    first = float(j.lb_s[pj].min())
    delay = float((j.ub_s[pj] - i.lb_s[pi]).max())
    return first, delay


def _candidate_pairs(
    i: Dtot, ki: np.ndarray, j: Dtot, kj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Technique 4: for each occupancy of j, the requester's occupancies whose
    intervals can overlap it, by binary search.

    Interval bounds are made monotone (running max of ends, running min of
    starts from the right) so the search is valid; the hulls only widen the
    candidate set, and the exact interval test follows.
    """
    ub_hull = np.maximum.accumulate(i.ub_s[ki])
    lb_hull = np.minimum.accumulate(i.lb_s[ki][::-1])[::-1]
    lo = np.searchsorted(ub_hull, j.lb_s[kj], side="left")
    hi = np.searchsorted(lb_hull, j.ub_s[kj], side="right")
    count = np.maximum(hi - lo, 0)
    total = int(count.sum())
    if total == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    pj = np.repeat(kj, count)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(count)[:-1]]), count)
    pos = np.arange(total) + starts
    return ki[pos], pj


def follow_conflict(
    follower: Trajectory, leader: Trajectory, leader_length_m: float, gap_m: float
) -> tuple[float, float] | None:
    """checkFV in the approach: keep ``gap_m`` behind the lane leader's rear.

    Both vehicles share the incoming lane's coordinate (s < 0). A confirmed
    vehicle flies its TSS exactly, so before its DTOT starts nothing else
    keeps it off the vehicle ahead. Both move linearly between samples, so
    testing at the union of their sample times is exact. Returns
    (first violation time, delay that clears every violating sample) or None.
    """
    tf, sf = follower.t_s, follower.s_m
    tl, sl = leader.t_s, leader.s_m
    approach = sf < 0.0
    if not approach.any():
        return None
    t_end = tf[approach][-1] + follower.step_s
    extra = tl[(tl >= tf[0]) & (tl <= t_end)]
    t = np.concatenate([tf[approach], extra])
    s_f = np.interp(t, tf, sf)
    s_l = np.interp(t, tl, sl)
    bad = (s_f < 0.0) & (s_f > s_l - leader_length_m - gap_m)
    if not bad.any():
        return None
    need = s_f[bad] + leader_length_m + gap_m
    k = np.minimum(np.searchsorted(sl, need, side="left"), len(sl) - 1)
    delay = float((tl[k] - t[bad]).max())
    return float(t[bad].min()), max(delay, 0.0)
