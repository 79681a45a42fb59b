"""getCV: which confirmed vehicles a DTOT conflicts with in space and time.

Two occupancies conflict when their rectangles intersect (touching counts)
and their occupancy time intervals overlap (closed intervals). For every
confirmed vehicle in conflict we report ``firstTimeAtCollision`` (the interval
start of its earliest conflicting occupancy, the dissertation's ordering key)
and the delay that would clear every conflicting pair under a pure shift.

Techniques 1, 2 and 4 only skip work that cannot find a conflict, so they
return exactly what the exhaustive search returns; technique 3 changes the
intervals themselves (never to narrower ones).

With techniques 1, 2 and 4 all on, :func:`get_cv_batch` does the same work for
every confirmed vehicle at once: the confirmed occupancies are gathered end
to end as vehicles are confirmed (:class:`ConfirmedRows`), those inside a conflict
zone with the requester's route picked once per request
(:class:`ConfirmedBatch`), and one round of getCV is one compiled loop
however many vehicles are confirmed. It finds exactly the
conflicting pairs :func:`pair_conflict` finds, so the answer is identical.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from dica.ica.core.config import Techniques
from dica.ica.core.dtot import Dtot
from dica.ica.core.kernels.conflict import (
    Occupancies,
    Rows,
    batch_conflicts,
    follow_check,
    pack_rows,
    select_rows,
)
from dica.ica.core.occupancy import overlap_matrix, overlap_pairs
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import MAYBE, TOUCH, ConflictTables, Shape


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


PACKED = ("lb_s", "ub_s", "centre_x", "centre_y", "heading_x", "heading_y", "half_length_m",
          "half_width_m", "grid_idx")  # fmt: skip


def pack(d: Dtot) -> np.ndarray:
    """A DTOT's occupancies as rows of :data:`PACKED` columns, for the batched getCV.

    Made once when a vehicle is confirmed; a confirmed set is then gathered by
    one concatenation. The grid index is held as a float (exact).
    """
    if d.grid_idx is None:
        raise ValueError("conflict zones need DTOTs built with their offline grid")
    r = d.rects
    return pack_rows(
        d.lb_s,
        d.ub_s,
        r.centre,
        r.heading,
        float(r.half_length),
        float(r.half_width),
        d.grid_idx,
    )


@dataclass(frozen=True, slots=True, eq=False)
class Gathered:
    """Every occupancy of a confirmed set, end to end, in the set's order.

    ``packed`` rows (:func:`pack`) and ``vid[m]``, whose occupancy row ``m``
    is (an index into ``vins`` and ``routes``: the vehicle, its route and
    shape). A vehicle that has left may still own rows until they are
    compacted away; its ``vins`` and ``routes`` entries are then None and no
    getCV looks at its rows. A snapshot: later changes to the set never
    change it.
    """

    vins: list[str | None]
    routes: list[tuple[Route, Shape] | None]
    vid: np.ndarray
    packed: np.ndarray


class ConfirmedRows:
    """The confirmed set's occupancy rows, kept up to date as vehicles come and go.

    Regathering every confirmed vehicle's rows for each request cost as much
    as the request's rounds of Algorithm 1 at n = 40. Here a confirmation
    appends its rows, a departure only marks them dead, and the dead rows are
    compacted away (keeping the set's order) once they outnumber the live
    ones, so a request pays for neither.
    """

    def __init__(self, capacity: int = 4096) -> None:
        self._packed = np.empty((capacity, len(PACKED)))
        self._vid = np.empty(capacity, np.int64)
        self._n = 0  # rows in use, dead ones included
        self._dead = 0  # rows of vehicles that have left
        self._vins: list[str | None] = []
        self._routes: list[tuple[Route, Shape] | None] = []
        self._count: list[int] = []  # rows per slot
        self._slot: dict[str, int] = {}
        self._view: Gathered | None = None

    def __len__(self) -> int:
        return len(self._slot)

    def __contains__(self, vin: str) -> bool:
        return vin in self._slot

    def add(self, vin: str, dtot: Dtot, packed: np.ndarray) -> None:
        """Append a newly confirmed vehicle: it goes last in the set's order."""
        if vin in self._slot:
            raise ValueError(f"{vin} is already in the confirmed rows")
        k = len(packed)
        if self._n + k > len(self._vid):
            self._regrow(self._n + k)
        v = len(self._vins)
        self._packed[self._n : self._n + k] = packed
        self._vid[self._n : self._n + k] = v
        self._n += k
        self._vins.append(vin)
        self._routes.append((dtot.route, dtot.shape))
        self._count.append(k)
        self._slot[vin] = v
        self._view = None

    def remove(self, vin: str) -> None:
        """A vehicle has left: its rows are dead from now on."""
        v = self._slot.pop(vin)
        self._vins[v] = None
        self._routes[v] = None
        self._dead += self._count[v]
        self._view = None
        if 2 * self._dead > self._n:
            self._regrow(self._n - self._dead)

    def gathered(self) -> Gathered:
        """The rows as they are now, as an immutable :class:`Gathered`."""
        if self._view is None:
            self._view = Gathered(
                list(self._vins), list(self._routes), self._vid[: self._n], self._packed[: self._n]
            )
        return self._view

    def _regrow(self, need: int) -> None:
        """Compact into fresh buffers with room for ``need`` rows and more.

        Fresh buffers, never in place: a :class:`Gathered` handed out earlier
        keeps looking at the old ones.
        """
        live = [v for v, vin in enumerate(self._vins) if vin is not None]
        keep = np.repeat(np.array([vin is not None for vin in self._vins], bool), self._count)
        capacity = max(len(self._vid), 2 * need)
        packed = np.empty((capacity, len(PACKED)))
        vid = np.empty(capacity, np.int64)
        n = int(keep.sum())
        packed[:n] = self._packed[: self._n][keep]
        vid[:n] = np.repeat(np.arange(len(live)), [self._count[v] for v in live])
        self._packed, self._vid, self._n, self._dead = packed, vid, n, 0
        self._vins = [self._vins[v] for v in live]
        self._routes = [self._routes[v] for v in live]
        self._count = [self._count[v] for v in live]
        self._slot = {vin: i for i, vin in enumerate(self._vins) if vin is not None}
        self._view = None


@dataclass(frozen=True, slots=True, eq=False)
class ConfirmedBatch:
    """The confirmed occupancies that can touch one route (techniques 1 and 2).

    Rows of :class:`Gathered` not on a route compatible with it (technique 1)
    and inside the conflict zone (technique 2): some grid point of the route
    is other than APART from them. ``rows`` holds them as the compiled getCV
    reads them (:class:`ica.core.kernels.conflict.Rows`): each one's row in
    the route's :class:`~ica.core.zones.PairStack`, the first and last grid
    point of the route not APART from it, the flat stack, in ascending
    ``lb_j`` with the longest interval among them (NaN if a bound is NaN), for
    :func:`ica.core.kernels.conflict.first_conflict`. Built once per confirmed
    set and route.
    """

    gathered: Gathered
    rows: Rows

    def __len__(self) -> int:
        return len(self.rows.m_idx)

    @staticmethod
    def of(
        route: Route, shape: Shape, gathered: Gathered, tables: ConflictTables
    ) -> ConfirmedBatch:
        offsets = tables.rows_of(route, shape)
        first: list[int] = []
        for seen in gathered.routes:
            if seen is None:  # a vehicle that has left
                first.append(-1)
                continue
            other, sh = seen
            key = (other.id, sh.length_m, sh.width_m)
            off = offsets.get(key)
            if off is None:
                if tables.compatible(other, sh, route, shape):
                    off = -1
                else:
                    off = tables.stack_offset(route, shape, other, sh)
                offsets[key] = off
            first.append(off)
        first_row = np.array(first, dtype=np.int64)
        stack = tables.stack(route, shape)  # after the offsets: they may have grown it
        m, row, lo, hi, span, lb_s = select_rows(
            gathered.packed, gathered.vid, first_row, stack.row_lo, stack.row_hi
        )
        rows = Rows(
            packed=gathered.packed,
            vid=gathered.vid,
            m_idx=m,
            row=row,
            row_lo=lo,
            row_hi=hi,
            codes=stack.codes,
            width=stack.width,
            nv=len(gathered.vins),
            span_s=span,
            lb_s=lb_s,
        )
        return ConfirmedBatch(gathered, rows)


def occupancies(d: Dtot) -> Occupancies:
    """A requester's DTOT as the compiled getCV reads it."""
    if d.grid_idx is None:
        raise ValueError("conflict zones need DTOTs built with their offline grid")
    c = np.ascontiguousarray
    r = d.rects
    return Occupancies(
        lb_s=c(d.lb_s),
        ub_s=c(d.ub_s),
        grid_idx=c(d.grid_idx),
        centre=c(r.centre),
        heading=c(r.heading),
        half_l_m=float(r.half_length),
        half_w_m=float(r.half_width),
    )


def get_cv_batch(i: Dtot, batch: ConfirmedBatch) -> list[Conflict]:
    """getCV with techniques 1, 2 and 4 over all confirmed vehicles at once.

    For each confirmed occupancy m, the requester's candidates are found by
    binary search twice: on time, as in technique 4 (monotone hulls of the
    interval bounds), and on space, between the first and last of the
    requester's grid points that the offline table does not call APART for
    m (monotone hulls of the grid index). Only the intersection of the two
    ranges is tested, exactly as :func:`pair_conflict` tests: intervals, then
    the offline code, then the exact rectangle test for MAYBE. A pair outside
    either range cannot conflict, so the conflicting pairs, and with them
    firstTimeAtCollision and the delay, are exactly those of
    :func:`pair_conflict`; vehicles come out in the same order as from
    :func:`get_cv`. The loop is compiled
    (:func:`ica.core.kernels.conflict.batch_conflicts`).
    """
    if len(batch) == 0:
        return []
    occ = occupancies(i)
    g = batch.gathered
    nv = len(g.vins)
    hit = np.zeros(nv, dtype=bool)
    first, delay = np.empty(nv), np.empty(nv)
    if not batch_conflicts(tuple(occ), tuple(batch.rows), hit, first, delay):
        return []
    fs, ds = first.tolist(), delay.tolist()
    out = [Conflict(g.vins[v], fs[v], ds[v]) for v in np.nonzero(hit)[0].tolist()]
    out.sort(key=lambda c: c.first_time_s)
    return out


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
    """checkFV in the approach, compiled (:func:`ica.core.kernels.conflict.follow_check`):
    exactly the answer of :func:`follow_conflict_reference`."""
    found, first, delay = follow_check(
        follower.t0_s,
        follower.step_s,
        np.ascontiguousarray(follower.s_m, dtype=float),
        leader.t0_s,
        leader.step_s,
        np.ascontiguousarray(leader.s_m, dtype=float),
        leader_length_m,
        gap_m,
    )
    return (first, max(delay, 0.0)) if found else None


def follow_conflict_reference(
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
