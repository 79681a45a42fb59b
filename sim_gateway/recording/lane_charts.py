"""One space-time chart per incoming lane: distance along the route against time,
the confirmed plan as a thin translucent line, the actual progress as dots, and
an emergency vehicle's reorderings as red marks.

Distances are from the entry line (0 m), drawn upwards (viewer y = -s); the
communication region starts at ``-comm_length_m``, each movement's exit line
at its route's crossing length.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.sim_gateway.recording.batch import StepBatch
from dica.sim_gateway.recording.chart_frame import CHART_EVERY, CHART_M_PER_S, FUTURE_S, PAST_S
from dica.sim_gateway.recording.geometry import LANE_WIDTH_M, route_lanes
from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import (
    EMERGENCY_RGBA,
    ENTRY_RGB,
    FRAME_RGB,
    LANE_CHART_LEGEND,
    PLAN_ALPHA,
    REGION_START_RGB,
    TEXT_RGB,
    VehicleColours,
)


class LaneCharts:
    """The lane charts of one junction: static frames, plans, reorderings, dots."""

    def __init__(
        self, inter: Intersection, rows: RowBuffer, colours: VehicleColours, top_m: float
    ) -> None:
        """``top_m``: the highest distance drawn [m], beyond every exit line."""
        self.intersection = inter
        self.lanes = inter.in_lanes
        self._rows = rows
        self._colours = colours
        self._top_m = top_m
        self._route_lane = route_lanes(inter)
        self._route_end_m = np.array([r.s_max for r in inter.routes])

    def frames(self, rec: rr.RecordingStream) -> None:
        """Per lane, static: labelled region, entry and exit lines, the distance axis
        and the legend."""
        k = CHART_M_PER_S
        x0, x1 = -PAST_S * k, FUTURE_S * k
        comm = self.intersection.comm_length_m
        for lane in self.lanes:
            routes = [r for r in self.intersection.routes if r.in_lane == lane]
            lines = [(-comm, "region start"), (0.0, "entry")]
            for length in sorted({round(r.cross_length_m, 1) for r in routes}):
                turns = sorted(
                    {r.turn.value for r in routes if round(r.cross_length_m, 1) == length}
                )
                lines.append((length, f"exit ({'/'.join(turns)})"))
            rec.log(
                f"charts/frame/lanes/{lane}/lines",
                rr.LineStrips2D(
                    [[(x0, -s), (x1, -s)] for s, _ in lines],
                    radii=0.18,
                    colors=[REGION_START_RGB] + [ENTRY_RGB] * (len(lines) - 1),
                    labels=[f"{name} {s:g} m" for s, name in lines],
                    show_labels=False,
                    draw_order=1.0,
                ),
                static=True,
            )
            # the distance axis: every 10 m, a named line's own label where there is one
            marks = {round(s, 1): f"{s:.0f} {name.split()[0]}" for s, name in lines}
            for s in np.arange(-comm, self._top_m, 10.0):
                if all(abs(s - m) > 5.0 for m in marks):
                    marks[float(s)] = f"{s:.0f}"
            # and the legend, in the same entity: every static entity costs the viewer a chunk
            pos = [(x0 - 11.0, -s) for s in marks] + [(x0 + 58.0, comm + 2.5)]
            rec.log(
                f"charts/frame/lanes/{lane}/axis",
                rr.Points2D(
                    pos,
                    radii=0.01,
                    colors=[FRAME_RGB] * len(marks) + [TEXT_RGB],
                    labels=[*marks.values(), LANE_CHART_LEGEND],
                    show_labels=True,
                ),
                static=True,
            )

    def plan(
        self, now: float, vin: str, route: Route, t_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray
    ) -> None:
        """A confirmed plan (its TSS) as a line, every CHART_EVERY samples and the last,
        logged at ``now`` and again when it ends."""
        k = CHART_M_PER_S
        n = len(t_s)
        s, _ = route.project(np.stack([np.asarray(x_m, float), np.asarray(y_m, float)], -1))
        keep = np.unique(np.append(np.arange(0, n, CHART_EVERY), n - 1))
        line = np.stack([t_s[keep] * k, -s[keep]], axis=-1).astype(np.float32)
        fields = {
            "strips": [line],
            "colors": np.array([self._colours.of(vin) & 0xFFFFFF00 | PLAN_ALPHA], dtype=np.uint32),
            "labels": [f"{vin} plan"],
        }
        entity = f"charts/data/lanes/{route.in_lane}/plans"
        self._rows.add(entity, rr.LineStrips2D, now, 1, **fields)
        self._rows.again(float(t_s[-1]), now, entity, rr.LineStrips2D, 1, fields)

    def envelope(self, now: float, vin: str, route: Route, fast, slow) -> None:
        """A human driver's envelope on its lane's chart: its fastest and its slowest
        crossing (route position against time) as two lines, logged at ``now`` and
        again when the slowest ends."""
        k = CHART_M_PER_S
        strips = [
            np.stack([b.t_s[::CHART_EVERY] * k, -b.s_m[::CHART_EVERY]], -1).astype(np.float32)
            for b in (fast, slow)
        ]
        fields = {
            "strips": strips,
            "colors": np.full(2, self._colours.of(vin) & 0xFFFFFF00 | PLAN_ALPHA, np.uint32),
            "labels": [
                f"{vin} fastest ({route.turn.value})",
                f"{vin} slowest ({route.turn.value})",
            ],
        }
        entity = f"charts/data/lanes/{route.in_lane}/plans"
        self._rows.add(entity, rr.LineStrips2D, now, 2, **fields)
        self._rows.again(float(slow.t_s[-1]), now, entity, rr.LineStrips2D, 2, fields)

    def reorder(
        self, t: float, ev: str, lane: str, solver: str, entry_before_s: float, entry_after_s: float
    ) -> None:
        """A reordering for ``ev`` on its lane's chart: a line across it at ``t`` and,
        when both are known, one along the entry line from the EV's entry before to
        its entry after; logged again at the latest of those times."""
        k = CHART_M_PER_S
        comm = self.intersection.comm_length_m
        strips = [np.array([(t * k, -self._top_m), (t * k, comm)], np.float32)]
        labels = [f"reorder for {ev} ({solver})"]
        ends = [t]
        if math.isfinite(entry_before_s) and math.isfinite(entry_after_s):
            a, b = float(entry_before_s), float(entry_after_s)
            strips.append(np.array([(a * k, 0.6), (b * k, 0.6)], np.float32))
            labels.append(f"{ev} entry {b:.1f} s (was {a:.1f} s)")
            ends += [a, b]
        fields = {
            "strips": strips,
            "colors": np.full(len(strips), EMERGENCY_RGBA, np.uint32),
            "labels": labels,
        }
        entity = f"charts/data/lanes/{lane}/reorders"
        self._rows.add(entity, rr.LineStrips2D, t, len(strips), **fields)
        self._rows.again(max(ends), t, entity, rr.LineStrips2D, len(strips), fields)

    def actual(self, batch: StepBatch, chart_step: np.ndarray) -> None:
        """Dots where vehicles on their route in the region really were, at the chart
        steps (``chart_step`` per step of the batch)."""
        ridx, s = batch.route_idx, batch.s
        known = ridx >= 0
        on_chart = (
            chart_step[batch.step_of]
            & known
            & (batch.dist <= LANE_WIDTH_M)
            & (s >= -self.intersection.comm_length_m)
            & (s < np.where(known, self._route_end_m[np.maximum(ridx, 0)], 0.0))
        )
        colors = self._colours.of_many(batch.vins)
        lane_of = np.where(known, self._route_lane[np.maximum(ridx, 0)], -1)
        chart_steps = np.nonzero(chart_step)[0]
        times = batch.times[chart_steps]
        t_row = batch.times[batch.step_of]
        for li, lane in enumerate(self.lanes):
            sel = on_chart & (lane_of == li)
            if not sel.any():
                continue
            idx = np.nonzero(sel)[0]
            per = np.bincount(
                np.searchsorted(chart_steps, batch.step_of[idx]), minlength=len(chart_steps)
            )
            self._rows.add_many(
                f"charts/data/lanes/{lane}/actual",
                rr.Points2D,
                times,
                per,
                positions=np.stack([t_row[idx] * CHART_M_PER_S, -s[idx]], -1).astype(np.float32),
                colors=colors[idx],
                labels=[batch.vins[i] for i in idx],
            )
