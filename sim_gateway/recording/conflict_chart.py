"""The conflict-point chart, DICA's safety argument drawn: one row per conflict point,
a box for the interval each confirmed vehicle holds it by its reservation, and a
dot for each moment a vehicle's real footprint covers it, red outside its box.

Two footprints that cover one point overlap, so in a safe run no two boxes of
a row overlap and every dot is inside its vehicle's box.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from dica.ica.core.dtot import Dtot
from dica.sim_gateway.conflict_points import ConflictPoints, Holding, covers, holding
from dica.sim_gateway.recording.batch import StepBatch
from dica.sim_gateway.recording.chart_frame import CHART_M_PER_S, FUTURE_S, PAST_S, ROW_M
from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import (
    FRAME_RGB,
    OVERRUN_RGB,
    ROW_GRID_RGB,
    ZONE_LEGEND,
    VehicleColours,
    rgba,
)


class ConflictChart:
    """Rows of conflict points (row ``p`` spans ``p * ROW_M`` to ``(p + 1) * ROW_M``)."""

    def __init__(self, points: ConflictPoints, rows: RowBuffer, colours: VehicleColours) -> None:
        self.points = points
        self._rows = rows
        self._colours = colours

    def frames(self, rec: rr.RecordingStream) -> None:
        """Static: each row's name, the lines between rows, the legend."""
        k = CHART_M_PER_S
        x0, x1 = -PAST_S * k, FUTURE_S * k
        n = len(self.points)
        rec.log(
            "charts/frame/zones/rows",
            rr.Points2D(
                [(x0 - 19.0, (i + 0.5) * ROW_M) for i in range(n)],
                radii=0.01,
                colors=[FRAME_RGB],
                labels=[f"P{i + 1} {self.points.name(i)}" for i in range(n)],
                show_labels=True,
            ),
            static=True,
        )
        rec.log(
            "charts/frame/zones/grid",
            rr.LineStrips2D(
                [[(x0, i * ROW_M), (x1, i * ROW_M)] for i in range(n + 1)],
                radii=0.04,
                colors=[ROW_GRID_RGB],
                draw_order=0.0,
            ),
            static=True,
        )
        rec.log(
            "charts/frame/zones/legend",
            rr.Points2D(
                [(x0 + 12.0, n * ROW_M + 2.5), (x0 + 55.0, n * ROW_M + 2.5)],
                radii=[0.5, 0.5],
                colors=[rgb for _, rgb in ZONE_LEGEND],
                labels=[text for text, _ in ZONE_LEGEND],
                show_labels=True,
            ),
            static=True,
        )

    def holding(self, dtot: Dtot, time_pad_s: float = 0.0) -> Holding:
        """When a confirmed DTOT holds which point; ``time_pad_s``: the ICA's time
        padding, which it adds to every interval on each side."""
        hold = holding(dtot, self.points)
        if time_pad_s > 0.0:
            hold = Holding(hold.point, hold.lb_s - time_pad_s, hold.ub_s + time_pad_s)
        return hold

    def reserved(self, now: float, vin: str, hold: Holding) -> None:
        """A confirmation's boxes, logged at ``now`` and again when the last one ends."""
        if not len(hold):
            return
        k = CHART_M_PER_S
        centers = np.stack([(hold.lb_s + hold.ub_s) / 2 * k, (hold.point + 0.5) * ROW_M], -1)
        halves = np.stack([(hold.ub_s - hold.lb_s) / 2 * k, np.full(len(hold), 0.4 * ROW_M)], -1)
        boxes = {
            "centers": centers.astype(np.float32),
            "half_sizes": halves.astype(np.float32),
            "colors": np.full(len(hold), self._colours.of(vin), dtype=np.uint32),
            "labels": [
                f"{vin} P{p + 1} {a:.2f}-{b:.2f} s"
                for p, a, b in zip(hold.point, hold.lb_s, hold.ub_s, strict=True)
            ],
        }
        entity = "charts/data/zones/reserved"
        self._rows.add(entity, rr.Boxes2D, now, len(hold), **boxes)
        self._rows.again(float(hold.ub_s.max()), now, entity, rr.Boxes2D, len(hold), boxes)

    def held(self, batch: StepBatch, chart_step: np.ndarray) -> None:
        """Dots where a confirmed vehicle's real footprint covers a conflict point at the
        chart steps; red where that is outside the interval reserved for it there."""
        chart_steps = np.nonzero(chart_step)[0]
        if len(self.points) == 0 or not len(chart_steps):
            return
        idx = np.nonzero(batch.confirmed & chart_step[batch.step_of])[0]
        c, sn, length = batch.cos[idx], batch.sin[idx], batch.length[idx]
        cx, cy = batch.x[idx] - c * length / 2, batch.y[idx] - sn * length / 2
        cov = covers(
            np.stack([cx, cy], -1),
            np.stack([c, sn], -1),
            length / 2,
            batch.width[idx] / 2,
            self.points.xy,
        )
        rows, pts = np.nonzero(cov)
        t = batch.times[batch.step_of[idx[rows]]]
        inside = self._inside([batch.plans[idx[r]].hold for r in rows], pts, t)
        colors = self._colours.of_many([batch.vins[idx[r]] for r in rows])
        colors = np.where(inside, colors, np.uint32(rgba(OVERRUN_RGB)))
        per = np.bincount(
            np.searchsorted(chart_steps, batch.step_of[idx[rows]]), minlength=len(chart_steps)
        )
        self._rows.add_many(
            "charts/data/zones/held",
            rr.Points2D,
            batch.times[chart_steps],
            per,
            positions=np.stack([t * CHART_M_PER_S, (pts + 0.5) * ROW_M], -1).astype(np.float32),
            colors=colors,
            labels=[
                f"{batch.vins[idx[r]]} P{p + 1}{'' if ok else ' outside its reservation'}"
                for r, p, ok in zip(rows, pts, inside, strict=True)
            ],
        )

    @staticmethod
    def _inside(holds: Sequence[Holding], pts: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Per dot: is time ``t`` within the interval its vehicle holds point ``pts``."""
        inside = np.zeros(len(pts), dtype=bool)
        for n, (h, p) in enumerate(zip(holds, pts, strict=True)):
            m = np.nonzero(h.point == p)[0]
            inside[n] = bool(len(m)) and h.lb_s[m[0]] - 1e-9 <= t[n] <= h.ub_s[m[0]] + 1e-9
        return inside
