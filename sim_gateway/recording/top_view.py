"""The junction seen from above, north up: lane edges and lines, every vehicle's real
footprint coloured by its state, the footprint reserved for it now as a band as
wide as the safety margin, and names beside the kerb.

Drawn every TOP_EVERY steps (10 Hz): half the file of every step, and the
motion still smooth.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import rerun as rr

from dica.ica.core.dtot import Dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.sim_gateway.recording.batch import Plan, StepBatch
from dica.sim_gateway.recording.geometry import (
    FLIP_Y,
    LANE_WIDTH_M,
    across,
    clipped,
    crossing_outlines,
    offset,
    outlines,
    route_lanes,
)
from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import (
    CROSSING_RGB,
    ENTRY_RGB,
    LANE_EDGE_RGB,
    REGION_RGB,
    REGION_START_RGB,
    ROUTE_RGB,
    STATUS_RGBA,
    rgba,
    top_legend,
)

TOP_EVERY = 2  # the top view every 2 steps (10 Hz): half the file, motion still smooth
STEP_S = 0.05  # [s] the simulation step the recorder expects
LABEL_GAP_M = 4.0  # [m] names start this far beyond the kerb


def frame_reach(inter: Intersection) -> float:
    """Half the side of the top view's opening frame: the junction and 22 m around it."""
    region = np.asarray(inter.region, dtype=float)
    return float(np.abs(region).max()) + 22.0


def reserved_bands(dtot: Dtot, margin_m: float) -> np.ndarray:
    """(K, 5, 2) outlines, viewer frame, of the middle of each reserved footprint's
    margin band: drawn as wide as the margin, the band's inner edge is the vehicle's
    own footprint."""
    r = dtot.rects
    half_m = margin_m / 2.0
    return outlines(
        r.centre[:, 0],
        r.centre[:, 1],
        r.heading[:, 0],
        r.heading[:, 1],
        np.full(len(r), r.half_length - half_m),
        np.full(len(r), r.half_width - half_m),
    ).astype(np.float32)


class LabelPlaces:
    """Where a vehicle's name goes: beside the kerb of its approach, level with it,
    one column per lane, so a name never covers a vehicle."""

    def __init__(self, inter: Intersection) -> None:
        by_lane: dict[str, Route] = {}
        for r in inter.routes:
            by_lane.setdefault(r.in_lane, r)
        lanes = inter.in_lanes
        self.start = np.zeros((len(lanes), 2))
        self.dir = np.zeros((len(lanes), 2))
        self.right = np.zeros((len(lanes), 2))
        self.offset = np.zeros(len(lanes))
        for i, lane in enumerate(lanes):
            r = by_lane[lane]
            a, b = r.points(-inter.comm_length_m), r.points(0.0)
            d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
            self.start[i], self.dir[i] = b, d
            self.right[i] = (d[1], -d[0])
            index = int(lane.rsplit("_", 1)[1]) if lane.rsplit("_", 1)[1].isdigit() else 0
            kerb = (index + 0.5) * LANE_WIDTH_M  # SUMO numbers lanes from the right
            self.offset[i] = kerb + LABEL_GAP_M + index * 4.5

    def places(self, lane_idx: np.ndarray, s_m: np.ndarray) -> np.ndarray:
        """World (x, y) [m] of the names of vehicles at ``s_m`` (< 0) on these lanes."""
        return (
            self.start[lane_idx]
            + self.dir[lane_idx] * s_m[:, None]
            + self.right[lane_idx] * self.offset[lane_idx][:, None]
        )


class TopView:
    """The top view of one junction: static drawings, then vehicles batch by batch."""

    def __init__(self, inter: Intersection, rows: RowBuffer, margin_m: float) -> None:
        self.intersection = inter
        self._rows = rows
        self._margin_m = margin_m
        self._route_lane = route_lanes(inter)
        self._label_at = LabelPlaces(inter)

    def geometry(self, rec: rr.RecordingStream) -> None:
        """Static: the junction, lane edges, entry and region start lines, routes, the
        pedestrian crossings (where the net has them), legend."""
        inter = self.intersection
        comm = inter.comm_length_m
        region = np.asarray(inter.region, dtype=float)
        rec.log(
            "junction/region",
            rr.LineStrips2D([np.vstack([region, region[:1]]) * FLIP_Y], colors=[REGION_RGB]),
            static=True,
        )
        edges, entry, start, lane_names = [], [], [], []
        first: dict[str, Route] = {}
        for r in inter.routes:
            first.setdefault(r.in_lane, r)
        outs: dict[str, Route] = {}
        for r in inter.routes:
            outs.setdefault(r.out_lane, r)
        for lane in inter.in_lanes:
            r = first[lane]
            for side in (-1.0, 1.0):
                edges.append(offset(r, -comm - 5.0, 0.0, side * LANE_WIDTH_M / 2.0))
            entry.append(across(r, 0.0))
            start.append(across(r, -comm))
            lane_names.append(lane)
        for r in outs.values():
            a = r.cross_length_m
            for side in (-1.0, 1.0):
                edges.append(offset(r, a, a + comm, side * LANE_WIDTH_M / 2.0))
        rec.log(
            "junction/lane_edges",
            rr.LineStrips2D(edges, radii=0.06, colors=[LANE_EDGE_RGB], draw_order=1.0),
            static=True,
        )
        for entity, lines, rgb in (
            ("junction/entry_lines", entry, ENTRY_RGB),
            ("junction/region_start_lines", start, REGION_START_RGB),
        ):
            rec.log(
                entity,
                rr.LineStrips2D(
                    lines, radii=0.15, colors=[rgb], labels=lane_names, show_labels=False
                ),
                static=True,
            )
        rec.log(
            "junction/routes",
            rr.LineStrips2D(
                [clipped(r, 0.0, r.cross_length_m) * FLIP_Y for r in inter.routes],
                radii=0.04,
                colors=[ROUTE_RGB],
                labels=[r.id for r in inter.routes],
                show_labels=False,
                draw_order=0.5,
            ),
            static=True,
        )
        walks = crossing_outlines(inter)
        if walks:
            names = [c.id for c in inter.crosswalks for _ in c.strips()]
            rec.log(
                "junction/crossings",
                rr.LineStrips2D(walks, radii=0.12, colors=[CROSSING_RGB], labels=names,
                                show_labels=False, draw_order=0.8),
                static=True,
            )  # fmt: skip
        self._legend(rec)

    def _legend(self, rec: rr.RecordingStream) -> None:
        """A legend in the upper left corner, clear of the roads: each entry written in
        the colour of what it names (labels have a fixed size on screen, so separate
        key shapes would drift into the text when zooming)."""
        reach = frame_reach(self.intersection)
        x0, y0 = -reach + 11.0, -reach + 1.5  # viewer frame: y grows downwards
        entries = top_legend(self._margin_m)
        rec.log(
            "junction/legend/text",
            rr.Points2D(
                [(x0, y0 + i * 2.4) for i in range(len(entries))],
                radii=0.01,
                colors=[rgba(rgb) for _, rgb in entries],
                labels=[text for text, _ in entries],
                show_labels=True,
            ),
            static=True,
        )

    def draw(self, batch: StepBatch, plans: Mapping[str, Plan]) -> None:
        """Vehicles, names and the reserved footprints in force, every TOP_EVERY steps."""
        top_step = batch.every(TOP_EVERY)
        top_idx = np.nonzero(top_step)[0]
        top = np.nonzero(top_step[batch.step_of])[0]
        tc, ts, tl, tw = batch.cos[top], batch.sin[top], batch.length[top], batch.width[top]
        strips = outlines(
            batch.x[top] - tc * tl / 2, batch.y[top] - ts * tl / 2, tc, ts, tl / 2, tw / 2
        )
        self._rows.add_many(
            "junction/vehicles",
            rr.LineStrips2D,
            batch.times[top_idx],
            batch.counts[top_idx],
            strips=strips.astype(np.float32),
            colors=STATUS_RGBA[batch.state[top]],
        )
        self._names(batch, top_step)
        self._reserved(batch.times[top_idx], plans)

    def _names(self, batch: StepBatch, top_step: np.ndarray) -> None:
        """Names beside the kerb, level with the vehicle, for vehicles in the approach."""
        ridx, s = batch.route_idx, batch.s
        sel = (
            top_step[batch.step_of]
            & (ridx >= 0)
            & (batch.dist <= LANE_WIDTH_M)
            & (s < 0.0)
            & (s >= -self.intersection.comm_length_m - 5.0)
        )
        idx = np.nonzero(sel)[0]
        top_idx = np.nonzero(top_step)[0]
        per = np.bincount(np.searchsorted(top_idx, batch.step_of[idx]), minlength=len(top_idx))
        pos = (
            self._label_at.places(self._route_lane[ridx[idx]], s[idx] - batch.length[idx] / 2)
            if len(idx)
            else np.zeros((0, 2))
        )
        self._rows.add_many(
            "junction/names",
            rr.Points2D,
            batch.times[top_idx],
            per,
            positions=(pos * FLIP_Y).astype(np.float32),
            labels=[batch.vins[i] for i in idx],
        )

    def _reserved(self, times: np.ndarray, plans: Mapping[str, Plan]) -> None:
        """Reserved footprints (margin bands) of every plan whose DTOT spans a step; a
        plan long past keeps only what the charts still need."""
        if not len(times):
            return
        lo, hi = float(times[0]) - 1e-6, float(times[-1]) + 1e-6
        at_step: list[np.ndarray] = []
        blocks: list[np.ndarray] = []
        for p in list(plans.values()):
            t_end = p.t0_s + (len(p.band) - 1) * STEP_S
            if t_end < lo - 120.0:
                p.band = p.band[:0]  # long past: keep only what the charts still need
                continue
            if p.t0_s > hi or t_end < lo or len(p.band) == 0:
                continue
            j = np.rint((times - p.t0_s) / STEP_S).astype(int)
            ok = (j >= 0) & (j < len(p.band)) & (times < p.until_s - 1e-9)
            if ok.any():
                at_step.append(np.nonzero(ok)[0])
                blocks.append(p.band[j[ok]])
        if at_step:
            step_idx = np.concatenate(at_step)
            order = np.argsort(step_idx, kind="stable")
            bands = np.concatenate(blocks)[order]
            per = np.bincount(step_idx, minlength=len(times))
        else:
            bands, per = np.zeros((0, 5, 2), np.float32), np.zeros(len(times), int)
        self._rows.add_many("junction/reserved", rr.LineStrips2D, times, per, strips=bands)
