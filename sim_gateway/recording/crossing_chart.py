"""The crossings in the conflict-point chart: a band per crossing, below the conflict
points, in which height is the place along the crossing and width is time.

A walker's reservation is space-time (:class:`ica.core.walk.WalkSlot`): where on the
crossing it may be when. A vehicle holds the stretch of the crossing its body covers
(its lane, or the corner it sweeps) while its front is over the crossing's span
(:func:`ica.core.crosswalk.passage`). Both are drawn as boxes in the crossing's band
(a walker's as one box per stretch of the crossing, so its slow and fast walks show
as a staircase), and every person on the crossing as a dot: in a safe run no vehicle
box meets a walker's, and every dot lies in a walker's box (red where it does not).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import rerun as rr

from dica.ica.core.crosswalk import BODY_M, CORNER_M, Crosswalk, passage
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.walk import CLEAR_S, WalkSlot, hold
from dica.sim_gateway.recording.chart_frame import CHART_M_PER_S, FUTURE_S, PAST_S, ROW_M
from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import (
    FRAME_RGB,
    OVERRUN_RGB,
    ROW_GRID_RGB,
    VehicleColours,
    rgba,
)

ROWS = 2  # conflict-point rows a crossing's band is tall
PIECES = 6  # stretches a walker's slot is drawn in
ON_ROAD_M = 1.0  # [m] a person this far along a crossing from either end is on it
WALKER_RGB = (230, 160, 20)  # a walker's reservation, and a person on it


def front_positions(route: Route, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """A TSS's front positions along ``route`` [m], negative before its entry line:
    projected where the TSS is on the route, and counted back along the TSS's own path
    before it (a projection onto the route stops at its start)."""
    xy = np.stack([np.asarray(x_m, float), np.asarray(y_m, float)], axis=-1)
    s, _ = route.project(xy)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    on = np.nonzero(s > 1e-6)[0]
    if not len(on):  # all of it before the line: it ends where the route begins
        return arc - arc[-1] - float(np.hypot(*(xy[-1] - route.xy[0])))
    k = int(on[0])
    out = s.astype(float).copy()
    out[:k] = s[k] - (arc[k] - arc[:k])
    return out


class CrossingChart:
    """A band per crossing, from row ``first_row`` of the conflict-point chart on."""

    def __init__(
        self,
        crosswalks: tuple[Crosswalk, ...],
        first_row: int,
        rows: RowBuffer,
        colours: VehicleColours,
    ) -> None:
        self.crosswalks = crosswalks
        self._index = {c.id: i for i, c in enumerate(crosswalks)}
        self._first = first_row
        self._rows = rows
        self._colours = colours
        self._slots: dict[str, list[WalkSlot]] = {c.id: [] for c in crosswalks}
        self._passages: dict[tuple[str, float, float, float], list] = {}  # [passage or None]
        self._ends = [c.shape[[0, -1]] for c in crosswalks]
        # when a walker was first given a crossing (no light run draws people here): an
        # observer may hear of that slot before the people it has yet to draw from earlier
        # steps, and draws none of those, as the run in one process does not
        self._walked_s = math.inf

    @property
    def n_rows(self) -> int:
        return ROWS * len(self.crosswalks)

    def _y(self, crossing: str, u_m: np.ndarray | float) -> np.ndarray:
        """Chart height of the place ``u_m`` along ``crossing`` (from its first end)."""
        c = self.crosswalks[self._index[crossing]]
        lo, hi = -CORNER_M - BODY_M, c.length_m + CORNER_M + BODY_M
        base = (self._first + ROWS * self._index[crossing]) * ROW_M
        frac = (np.clip(np.asarray(u_m, float), lo, hi) - lo) / (hi - lo)
        return base + 0.5 + frac * (ROWS * ROW_M - 1.0)

    def frames(self, rec: rr.RecordingStream) -> None:
        """Static: each band's name and its edges."""
        if not self.crosswalks:
            return
        k = CHART_M_PER_S
        x0, x1 = -PAST_S * k, FUTURE_S * k
        rows = [self._first + ROWS * i for i in range(len(self.crosswalks))]
        rec.log(
            "charts/frame/zones/crossings",
            rr.Points2D(
                [(x0 - 19.0, (r + ROWS / 2) * ROW_M) for r in rows],
                radii=0.01,
                colors=[FRAME_RGB],
                labels=[f"X{i + 1} crossing {c.id}" for i, c in enumerate(self.crosswalks)],
                show_labels=True,
            ),
            static=True,
        )
        rec.log(
            "charts/frame/zones/crossing_edges",
            rr.LineStrips2D(
                [[(x0, r * ROW_M), (x1, r * ROW_M)] for r in [*rows, rows[-1] + ROWS]],
                radii=0.08,
                colors=[ROW_GRID_RGB],
                draw_order=0.0,
            ),
            static=True,
        )

    def _passage(
        self, route: Route, c: Crosswalk, length_m: float, width_m: float, margin_m: float
    ) -> tuple[float, float, float, float] | None:
        """:func:`passage`, worked out once per route, crossing and size."""
        key = (route.id + "|" + c.id, length_m, width_m, margin_m)
        got = self._passages.get(key)
        if got is None:
            got = self._passages[key] = [passage(route, c, length_m, width_m, margin_m)]
        return got[0]

    def reserved(
        self,
        now: float,
        vin: str,
        route: Route,
        t_s: np.ndarray,
        x_m: np.ndarray,
        y_m: np.ndarray,
        length_m: float,
        width_m: float,
        margin_m: float,
        time_pad_s: float,
    ) -> None:
        """A confirmed vehicle's holds of the crossings its route passes: a box each,
        over the stretch its body covers, from its front reaching the crossing's span to
        its rear clearing it (padded as the ICA pads them)."""
        if not self.crosswalks or len(t_s) < 2:
            return
        t = np.asarray(t_s, float)
        s = front_positions(route, x_m, y_m)
        step = float(t[1] - t[0])
        traj = Trajectory(float(t[0]), step, s)
        out_mps = max(float(s[-1] - s[-2]) / step, 0.1)
        k = CHART_M_PER_S
        centers, halves, labels = [], [], []
        for c in self.crosswalks:
            p = self._passage(route, c, length_m, width_m, margin_m)
            if p is None:
                continue
            s_from, s_to, u_lo, u_hi = p
            t_in, t_out = hold(traj, s_from, s_to, out_mps)
            t_in, t_out = t_in - time_pad_s, t_out + time_pad_s
            y_lo, y_hi = self._y(c.id, u_lo), self._y(c.id, u_hi)
            centers.append(((t_in + t_out) / 2 * k, (y_lo + y_hi) / 2))
            halves.append(((t_out - t_in) / 2 * k, max((y_hi - y_lo) / 2, 0.1)))
            labels.append(f"{vin} on {c.id} {t_in:.2f}-{t_out:.2f} s, {u_lo:.1f}-{u_hi:.1f} m")
        if not centers:
            return
        self._boxes(now, "charts/data/zones/crossing_holds", centers, halves, labels,
                    np.full(len(centers), self._colours.of(vin), dtype=np.uint32))  # fmt: skip

    def walk(self, now: float, slot: WalkSlot) -> None:
        """A walker's reservation: a box per stretch of the crossing, from the walker's
        fastest arrival there to its slowest departure (:meth:`WalkSlot.over`)."""
        if slot.crossing not in self._index:
            return
        self._walked_s = min(self._walked_s, now)
        self._slots[slot.crossing].append(slot)
        c = self.crosswalks[self._index[slot.crossing]]
        cuts = np.linspace(-CORNER_M, c.length_m + CORNER_M, PIECES + 1)
        k = CHART_M_PER_S
        centers, halves, labels = [], [], []
        for a, b in itertools.pairwise(cuts):
            t_in, t_out = slot.over(float(a), float(b), c.length_m, CLEAR_S)
            if not t_out > t_in:
                continue
            y_lo, y_hi = self._y(c.id, a), self._y(c.id, b)
            centers.append(((t_in + t_out) / 2 * k, (y_lo + y_hi) / 2))
            halves.append(((t_out - t_in) / 2 * k, (y_hi - y_lo) / 2))
            labels.append(f"{slot.person} walks {c.id} {t_in:.1f}-{t_out:.1f} s")
        if centers:
            self._boxes(now, "charts/data/zones/walks", centers, halves, labels,
                        np.full(len(centers), rgba(WALKER_RGB), dtype=np.uint32))  # fmt: skip

    def _boxes(self, now, entity, centers, halves, labels, colors) -> None:
        boxes = {
            "centers": np.asarray(centers, np.float32),
            "half_sizes": np.asarray(halves, np.float32),
            "colors": colors,
            "labels": labels,
        }
        ends = np.asarray(centers)[:, 0] + np.asarray(halves)[:, 0]
        self._rows.add(entity, rr.Boxes2D, now, len(centers), **boxes)
        self._rows.again(float(ends.max()) / CHART_M_PER_S, now, entity, rr.Boxes2D,
                         len(centers), boxes)  # fmt: skip

    def people(self, t_s: float, xy: np.ndarray) -> None:
        """A dot for each person on a crossing's strip at ``t_s`` (its ends left out:
        people on the sidewalk beside an end are that near it too): amber within a
        walker's reservation of that place, red outside every one. Only in runs whose
        walkers ask an ICA."""
        if t_s < self._walked_s - 1e-9 or not len(xy):
            return
        pos, cols = [], []
        for c, (p0, p1) in zip(self.crosswalks, self._ends, strict=True):
            d = p1 - p0
            n = float(np.hypot(*d))
            if n < 1e-9:
                continue
            e = d / n
            rel = xy - p0
            u = rel @ e
            across = np.abs(rel[:, 0] * e[1] - rel[:, 1] * e[0])
            on = (across <= c.width_m / 2) & (u >= ON_ROAD_M) & (u <= n - ON_ROAD_M)
            for ui in u[on]:
                ok = any(
                    a - 1e-6 <= t_s <= b + 1e-6
                    for w in self._slots[c.id]
                    for a, b in [w.over(ui - BODY_M, ui + BODY_M, c.length_m, CLEAR_S)]
                )
                pos.append((t_s * CHART_M_PER_S, float(self._y(c.id, ui))))
                cols.append(rgba(WALKER_RGB) if ok else rgba(OVERRUN_RGB))
            self._slots[c.id] = [w for w in self._slots[c.id] if w.end_s >= t_s - 1.0]
        self._rows.add(
            "charts/data/zones/people",
            rr.Points2D,
            t_s,
            len(pos),
            positions=np.asarray(pos, np.float32).reshape(-1, 2),
            colors=np.asarray(cols, np.uint32),
        )
