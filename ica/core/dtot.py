"""DTOT: a trajectory turned into timed occupancies with occupancy time intervals.

Occupancy k is the vehicle's footprint (grown by the safety margin) at sample
time t_k. Its occupancy time interval [lb_k, ub_k] runs from the time of the
nearest earlier occupancy that does not overlap it to the time of the nearest
later one that does not (the first and last sample's time where none exists).
Between two samples a vehicle lies within the union of their footprints and
both intervals cover that time, so two DTOTs whose overlapping occupancies
have disjoint intervals never touch, in continuous time.

The DTOT starts at the last sample before the front crosses the entry line and
ends at the first sample at which the rear has left the exit line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dica.ica.core.kernels.dtot import grid_dtot_of
from dica.ica.core.occupancy import Rects, footprints, overlap_matrix, separated
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import RouteGrid, Shape


@dataclass(frozen=True, slots=True, eq=False)
class Dtot:
    """Timed occupancies of one vehicle on one route.

    ``t_s``, ``s_m``, ``lb_s``, ``ub_s`` are (N,); ``rects`` holds the N
    footprints. ``k0`` is the index of the first occupancy in the trajectory.
    """

    route: Route
    shape: Shape
    trajectory: Trajectory
    k0: int
    t_s: np.ndarray
    s_m: np.ndarray
    rects: Rects
    lb_s: np.ndarray
    ub_s: np.ndarray
    grid_idx: np.ndarray | None = None  # nearest offline grid point per occupancy

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def start_s(self) -> float:
        """Earliest time the vehicle can touch the junction (interval of its first occupancy)."""
        return float(self.lb_s[0])

    @property
    def end_s(self) -> float:
        return float(self.ub_s[-1])

    @property
    def exit_speed_mps(self) -> float:
        s = self.trajectory.s_m
        if len(s) < 2:
            return 0.0
        k = min(max(self.k0 + len(self.t_s) - 2, 0), len(s) - 2)
        return float(s[k + 1] - s[k]) / self.trajectory.step_s


def build_dtot(
    route: Route,
    shape: Shape,
    traj: Trajectory,
    margin_m: float,
    grid: RouteGrid | None = None,
    estimated: bool = False,
) -> Dtot:
    """Occupancies of ``traj``; intervals exhaustively, or with ``grid`` (technique 3) if
    ``estimated``.

    The exhaustive intervals follow the dissertation's getOTI in numpy. With
    the grid (one compiled call, :func:`ica.core.kernels.dtot.grid_dtot_of`, with
    exactly the results of :func:`footprints`, :func:`grid_intervals` and
    ``grid.index``) they are the same intervals when the grid's tables are
    exact, and the dissertation's estimate, never narrower, when not.
    """
    s_end = route.cross_length_m + shape.length_m
    if estimated:
        if grid is None:
            raise ValueError("technique 3 needs the route's offline grid")
        arrays = grid_dtot_of(
            tuple(grid.kernel_grid(margin_m)), np.ascontiguousarray(traj.s_m, dtype=float),
            s_end, traj.t0_s, traj.step_s,
        )  # fmt: skip
        return dtot_of_arrays(route, shape, traj, margin_m, arrays)
    k0 = traj.entry_index()
    k1 = traj.exit_index(s_end)
    s = traj.s_m[k0 : k1 + 1]
    t = traj.t0_s + traj.step_s * np.arange(k0, k1 + 1)
    rects = footprints(route, s, shape.length_m, shape.width_m, margin_m)
    lb, ub = exhaustive_intervals(t, rects)
    g = grid.index(s) if grid is not None else None
    return Dtot(route, shape, traj, k0, t, s, rects, lb, ub, g)


def dtot_of_arrays(
    route: Route, shape: Shape, traj: Trajectory, margin_m: float, arrays: tuple
) -> Dtot:
    """The DTOT of ``traj`` with the grid from what the compiled DTOT gives
    (:func:`ica.core.kernels.dtot.dtot_of`: k0, times, arc lengths, centres, headings,
    lb, ub, grid index), footprints grown by ``margin_m``."""
    k0, t, s, centre, heading, lb, ub, g = arrays
    half_l, half_w = shape.length_m / 2.0 + margin_m, shape.width_m / 2.0 + margin_m
    return Dtot(route, shape, traj, k0, t, s, Rects(centre, heading, half_l, half_w), lb, ub, g)


def exhaustive_intervals(t: np.ndarray, rects: Rects) -> tuple[np.ndarray, np.ndarray]:
    """getOTI for every occupancy: nearest non-overlapping neighbour on each side."""
    n = len(t)
    clear = ~overlap_matrix(rects, rects)
    idx = np.arange(n)
    before = np.where(clear & (idx[None, :] < idx[:, None]), idx[None, :], -1).max(axis=1)
    after = np.where(clear & (idx[None, :] > idx[:, None]), idx[None, :], n).min(axis=1)
    lb = np.where(before >= 0, t[np.maximum(before, 0)], t[0])
    ub = np.where(after < n, t[np.minimum(after, n - 1)], t[-1])
    return lb, ub


def grid_intervals(
    t: np.ndarray, s: np.ndarray, rects: Rects, grid: RouteGrid
) -> tuple[np.ndarray, np.ndarray]:
    """Technique 3: intervals from the route's skip distances and the exact test beyond them.

    The reference version: :func:`build_dtot` computes the same in one
    compiled call.

    For occupancy k the samples whose fronts lie within ``grid.skip_behind_m``
    behind it (``skip_ahead_m`` ahead) are taken to overlap it; beyond them
    the nearest sample the exact test finds clear bounds the interval. With
    exact tables the skipped samples do overlap, so this is the exhaustive
    interval after a few tests; with the dissertation's, every sample beyond
    is clear, so the first one tested is the answer, never nearer than the
    exhaustive one.
    """
    n = len(t)
    behind = s - grid.skip_behind_m(s)
    ahead = s + grid.skip_ahead_m(s)
    ordered = bool(np.all(s[:-1] <= s[1:]))
    lb, ub = np.empty(n), np.empty(n)

    def overlaps(k: int, j: int) -> bool:
        d = rects.centre[j] - rects.centre[k]
        return not bool(
            separated(
                d[0],
                d[1],
                rects.heading[k],
                rects.heading[j],
                rects.half_length,
                rects.half_width,
                rects.half_length,
                rects.half_width,
            )
        )

    for k in range(n):
        j = k - 1
        if ordered:
            j = min(int(np.searchsorted(s, behind[k], side="right")) - 1, j)
        while j >= 0 and (behind[k] < s[j] <= s[k] or overlaps(k, j)):
            j -= 1
        lb[k] = t[j] if j >= 0 else t[0]
        j = k + 1
        if ordered:
            j = max(int(np.searchsorted(s, ahead[k], side="left")), j)
        while j < n and (s[k] <= s[j] < ahead[k] or overlaps(k, j)):
            j += 1
        ub[k] = t[j] if j < n else t[n - 1]
    return lb, ub
