"""Separation times between two vehicles' entries, measured with DICA's own test.

The ordering problem (:mod:`ica.core.ordering`) needs, for a vehicle ``j``
entering first and ``k`` after it, the least time from ``j``'s entry to
``k``'s. The dissertation takes three constants from the literature (0 for
compatible routes, delta_c for conflicting ones, delta_s in one lane). Here
they come from this junction, per pair of routes and entry speeds:

* **compatible** routes (the offline conflict tables say no footprint on one
  can touch one on the other): 0.
* otherwise the two vehicles are put on their routes alone, ``j`` entering
  at time 0, ``k`` at ``delta``, each moving as every plan moves inside the
  junction (from its entry speed, full acceleration up to the route's
  crossing cap, then holding it), and ``delta`` grows by Algorithm 1's update
  (the conflict's delay, at least a step) until DICA's conflict search
  (:func:`ica.core.conflict.get_cv`, the ICA's own techniques and tables) and,
  in one lane, its check on the lane leader find nothing. That is the
  separation DICA itself will ask for between such vehicles.

Entry speeds are rounded to a few levels so that measurements can be cached
per junction: ``j``'s down and ``k``'s up, which can only lengthen the
separation (a slower ``j`` holds the junction longer, a faster ``k`` reaches
it sooner). A vehicle pulling away from its stop just before the line enters
slowest (:meth:`SeparationModel.stop_and_go_entry_mps`).

These are estimates to choose an order with. Safety never rests on them: every
plan of the new order is confirmed by DICA's own conflict search against the
whole confirmed set.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from dica.ica.core.config import ENHANCED, Techniques
from dica.ica.core.conflict import follow_conflict, get_cv
from dica.ica.core.dtot import Dtot, build_dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Kinematics
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import ConflictTables, Shape

SPEED_LEVELS_MPS = (1.4, 3.0, 6.0, 10.0, 14.0, 18.0, 20.0)  # entry speeds measured


class Relation(IntEnum):
    COMPATIBLE = 0
    CROSSING = 1
    MERGING = 2
    SAME_LANE = 3


def _level_down(v: float) -> float:
    below = [x for x in SPEED_LEVELS_MPS if x <= v + 1e-9]
    return below[-1] if below else SPEED_LEVELS_MPS[0]


def _level_up(v: float) -> float:
    above = [x for x in SPEED_LEVELS_MPS if x >= v - 1e-9]
    return above[0] if above else SPEED_LEVELS_MPS[-1]


class SeparationModel:
    """Separation times for one junction and one vehicle shape, measured once per
    pair of routes and entry-speed levels."""

    def __init__(
        self,
        intersection: Intersection,
        tables: ConflictTables,
        shape: Shape,
        kinematics: Kinematics,
        margin_m: float,
        step_s: float = 0.05,
        techniques: Techniques = ENHANCED,
    ) -> None:
        self.intersection = intersection
        self.tables = tables
        self.shape = shape
        self.kin = kinematics
        self.margin_m = margin_m
        self.step_s = step_s
        self.techniques = techniques
        self._measured: dict[tuple[str, float, str, float], float] = {}
        self._dtots: dict[tuple[str, float, float], Dtot] = {}

    def relation(self, a: Route, b: Route) -> Relation:
        if a.in_lane == b.in_lane:
            return Relation.SAME_LANE
        if self.tables.compatible(a, self.shape, b, self.shape):
            return Relation.COMPATIBLE
        return Relation.MERGING if a.out_lane == b.out_lane else Relation.CROSSING

    def separation_s(self, a: Route, a_entry_mps: float, b: Route, b_entry_mps: float) -> float:
        """Least time from the entry of a vehicle on ``a`` to that of one on ``b`` after it."""
        rel = self.relation(a, b)
        if rel is Relation.COMPATIBLE:
            return 0.0
        va = _level_down(min(a_entry_mps, a.speed_cap_mps))
        vb = _level_up(min(b_entry_mps, b.speed_cap_mps))
        key = (a.id, va, b.id, vb)
        sep = self._measured.get(key)
        if sep is None:
            sep = self._measure(a, va, b, vb, rel is Relation.SAME_LANE)
            self._measured[key] = sep
        return sep

    def precompute(self) -> int:
        """Measure now every pair of routes and entry-speed levels that
        :meth:`separation_s` can be asked for (the offline step, about 1.5 s on the
        chapter 4-5 layout), so that ordering looks separations up instead of
        measuring them while a request waits (about 0.5 ms each, and a reorder can
        meet a dozen new ones). Returns how many pairs are measured."""
        routes = self.intersection.routes
        levels_down = {
            r.id: sorted({_level_down(min(v, r.speed_cap_mps)) for v in (0.0, *SPEED_LEVELS_MPS)})
            for r in routes
        }
        levels_up = {
            r.id: sorted({_level_up(min(v, r.speed_cap_mps)) for v in (0.0, *SPEED_LEVELS_MPS)})
            for r in routes
        }
        for a in routes:
            for b in routes:
                if self.relation(a, b) is Relation.COMPATIBLE:
                    continue
                for va in levels_down[a.id]:
                    for vb in levels_up[b.id]:
                        self.separation_s(a, va, b, vb)
        return len(self._measured)

    def matrix(self, routes: list[Route], entry_mps: list[float]) -> np.ndarray:
        """sep[j, k] for every ordered pair of the given vehicles (0 on the diagonal)."""
        n = len(routes)
        out = np.zeros((n, n))
        for j in range(n):
            for k in range(n):
                if j != k:
                    out[j, k] = self.separation_s(routes[j], entry_mps[j], routes[k], entry_mps[k])
        return out

    def release_after(
        self,
        t_s: float,
        routes: tuple[Route, ...],
        entry_mps: float,
        fixed: list[tuple[Route, float, float]],
    ) -> float:
        """``t_s``, or later as the reservations that stay need: each ``fixed``
        (route, entry [s], entry speed) enters first, and a vehicle entering at
        ``entry_mps`` by any of ``routes`` keeps its separation behind it."""
        for f_route, f_entry, f_mps in fixed:
            sep = max(self.separation_s(f_route, f_mps, r, entry_mps) for r in routes)
            t_s = max(t_s, f_entry + sep)
        return t_s

    def stop_and_go_entry_mps(self, route: Route) -> float:
        """Entry speed of a vehicle pulling away from its stop just before the line."""
        gap = self.kin.stop_gap_m
        return min(route.speed_cap_mps, math.sqrt(2.0 * self.kin.accel_mps2 * gap))

    # -- measuring ------------------------------------------------------------------------
    def crossing(self, route: Route, entry_mps: float, t_entry_s: float) -> Trajectory:
        """Entering at ``t_entry_s`` with ``entry_mps``, then as every plan crosses;
        sampled from one step before the entry until fully out."""
        h = self.step_s
        v = max(min(entry_mps, route.speed_cap_mps), 0.1)
        cap = max(route.speed_cap_mps, v)
        a = self.kin.accel_mps2
        t_acc = (cap - v) / a
        d_acc = (cap * cap - v * v) / (2.0 * a)
        s_end = route.cross_length_m + self.shape.length_m
        t_out = t_acc + (s_end - d_acc) / cap if s_end > d_acc else (
            (math.sqrt(v * v + 2.0 * a * s_end) - v) / a
        )  # fmt: skip
        tau = -h + h * np.arange(math.ceil((t_out + h) / h - 1e-9) + 1)
        s = np.where(
            tau < 0.0,
            v * tau,
            np.where(tau <= t_acc, v * tau + 0.5 * a * tau * tau, d_acc + cap * (tau - t_acc)),
        )
        return Trajectory(t_entry_s - h, h, s)

    def _dtot(self, route: Route, v: float, t_entry_s: float) -> Dtot:
        grid = self.tables.grid(route, self.shape)
        traj = self.crossing(route, v, t_entry_s)
        return build_dtot(
            route, self.shape, traj, self.margin_m, grid, self.techniques.estimated_oti
        )

    def _measure(self, a: Route, va: float, b: Route, vb: float, same_lane: bool) -> float:
        first = self._dtot(a, va, 0.0)
        gap = 2.0 * self.margin_m
        delta = 0.0
        for _ in range(1000):
            second = self._dtot(b, vb, delta)
            found = get_cv(second, [("j", first)], self.techniques, self.tables)
            delays = [c.delay_s for c in found]
            if same_lane:
                lead = follow_conflict(
                    second.trajectory, first.trajectory, self.shape.length_m, gap
                )
                if lead is not None:
                    delays.append(lead[1])
            if not delays:
                return delta
            delta += max(max(delays), self.step_s)
        return delta
