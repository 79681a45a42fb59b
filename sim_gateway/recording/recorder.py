"""A Rerun recording of a run: the junction, every reservation, and what vehicles did.

The recorder sits beside the control loop, never inside it: the ICA core does
not know it exists, and it takes plain arrays and strings, so the embedded
runner, a Zenoh process or a test can all feed it. It writes to its own
:class:`rerun.RecordingStream` (never Rerun's global one), to a ``.rrd`` file
and, when asked, to a gRPC server on loopback that viewers can watch live.
``docs/recording.md`` says how to read each view.

Views. A top view of the junction (actual footprints coloured by state, the
reserved footprint with its margin as a translucent band, names beside the
kerb); one space-time chart per incoming lane (distance along the route
against time, the plan as a thin translucent line and the actual progress as
dots); a conflict-point chart (for each point where conflicting routes meet,
the interval each confirmed vehicle holds it, and dots where it really was);
tables of confirmations and rejections; counts.

Charts that move with time. Rerun's 2D views have fixed bounds, so chart data
is logged at ``(CHART_M_PER_S * t, y)`` under ``charts/data``, and a transform
on ``charts/data`` shifts it by ``-CHART_M_PER_S * t_now`` every chart step:
"now" is always at x = 0, the window is the same for every chart, and the
frame (axis labels, the entry and exit lines, "now") is static.

Cost. A Rerun call costs 0.1-0.5 ms, so a step only appends its arrays to a
buffer; every ``flush_s`` of simulated time the buffer is drawn with numpy
into rows per entity. The web viewer pays dearly for every chunk, so rows
are sent as one column chunk per entity only when it holds MAX_ROWS of them,
and at the end: a 10-minute run makes about a hundred chunks. A live
recording sends every LIVE_FLUSH_S instead, so that viewers see the run as
it goes.

How it looks (colours, states, legends) is in :mod:`.style`; the frames and
shapes in :mod:`.geometry`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.ica.core.zones import ConflictTables, Shape
from dica.sim_gateway.conflict_points import (
    ConflictPoints,
    Holding,
    covers,
    dtot_of_tss,
    find_conflict_points,
    holding,
)
from dica.sim_gateway.recording.batch import Plan, Step, StepBatch
from dica.sim_gateway.recording.geometry import (
    FLIP_Y,
    LANE_WIDTH_M,
    RouteProjector,
    across,
    approach_of,
    clipped,
    lane_major,
    offset,
    outlines,
    route_lanes,
)
from dica.sim_gateway.recording.rows import TIMELINE, RowBuffer
from dica.sim_gateway.recording.style import (
    EMERGENCY_RGBA,
    ENTRY_RGB,
    FRAME_RGB,
    GRID_RGB,
    LANE_CHART_LEGEND,
    LANE_EDGE_RGB,
    NOW_RGBA,
    OVERRUN_RGB,
    PLAN_ALPHA,
    REGION_RGB,
    REGION_START_RGB,
    ROUTE_RGB,
    ROW_GRID_RGB,
    STATUS_RGBA,
    TEXT_RGB,
    ZONE_LEGEND,
    VehicleColours,
    rgba,
    row_styles,
    top_legend,
)

STEP_S = 0.05  # [s] the simulation step the recorder expects
CHART_M_PER_S = 2.0  # [chart units] width of 1 s in the charts
PAST_S = 40.0  # [s] of history every chart shows left of "now"
FUTURE_S = 20.0  # [s] of plans every chart shows right of "now"
HISTORY_S = PAST_S  # [s] rows logged this long before the cursor are drawn
CHART_EVERY = 5  # chart samples every 5 steps (0.25 s)
TOP_EVERY = 2  # the top view every 2 steps (10 Hz): half the file, motion still smooth
TICK_S = 10.0  # [s] time grid of the charts
ROW_M = 5.0  # [chart units] pitch of the conflict-point rows
LABEL_GAP_M = 4.0  # [m] names start this far beyond the kerb
START_WAIT_S = 60.0  # [s] how long the recording waits for a first confirmation
FLUSH_S = 20.0  # [s] of simulated time buffered before it is sent (saved file)
LIVE_FLUSH_S = 1.0  # [s] the same when viewers watch live (and rows are sent then)


class SpaceTimeRecorder:
    """Logs one junction's run into a ``.rrd`` file; see the module docstring.

    Raises ValueError for arrays of unequal length or an unknown route id:
    those are the caller's bugs. A caller that must not stop because of the
    recording (a live run) should catch and log them.
    """

    def __init__(
        self,
        intersection: Intersection,
        path: str | Path,
        *,
        application_id: str = "dica",
        recording_id: str | None = None,
        margin_m: float = 0.25,
        shape: Shape | None = None,
        flush_s: float = FLUSH_S,
        live_port: int | None = None,
    ) -> None:
        """``live_port``: also serve the recording over gRPC on 127.0.0.1 at that port
        (viewers attach with ``rerun+http://127.0.0.1:PORT/proxy``); sends every
        ``LIVE_FLUSH_S`` then."""
        self.intersection = intersection
        self.path = Path(path)
        self.margin_m = margin_m
        self.live = live_port is not None
        self.flush_s = LIVE_FLUSH_S if self.live else flush_s
        routes = intersection.routes
        self.lanes: tuple[str, ...] = intersection.in_lanes
        self._projector = RouteProjector(routes)
        self._route_lane = route_lanes(intersection)
        self._route_end_m = np.array([r.s_max for r in routes])
        self._label_at = _LabelPlaces(intersection)
        shape = shape or Shape(5.0, 1.8)
        self._top_m = max(r.cross_length_m for r in routes) + shape.length_m
        self.points: ConflictPoints = find_conflict_points(
            intersection, ConflictTables(intersection, margin_m), shape
        )
        self._plans: dict[str, Plan] = {}
        self._colours = VehicleColours()
        self._steps: list[Step] = []
        self._step_no = 0
        self._buf_t0 = 0.0
        self._tick_enter = 0.0  # next tick to log as it enters the window
        self._tick_at = 0.0  # next tick to log at its own time
        self._n_confirmed = 0
        self._n_rejected = 0
        self._start_s: float | None = None  # the timeline starts at the first confirmation
        self._rows = RowBuffer(row_styles(self.lanes, margin_m))

        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.rec.set_log_time_enabled(False)  # only sim_time: wall clock would mislead
        self.path.parent.mkdir(parents=True, exist_ok=True)
        sinks: list[Any] = [rr.FileSink(str(self.path))]
        if live_port is not None:
            sinks.append(rr.GrpcServerSink(bind_ip="127.0.0.1", port=live_port))
        self.rec.set_sinks(*sinks, default_blueprint=self.blueprint())
        log = self.rec.log
        log("counts/vehicles", rr.SeriesLines(names="vehicles in the region"), static=True)
        log("counts/confirmed", rr.SeriesLines(names="confirmed so far"), static=True)
        log("counts/rejected", rr.SeriesLines(names="rejected so far"), static=True)

    def __enter__(self) -> SpaceTimeRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- layout --------------------------------------------------------------
    def chart_bounds(self) -> rrb.VisualBounds2D:
        """The one window and distance scale every space-time chart shares."""
        k = CHART_M_PER_S
        return rrb.VisualBounds2D(
            x_range=[-PAST_S * k - 24.0, FUTURE_S * k + 2.0],
            y_range=[-self._top_m - 2.0, self.intersection.comm_length_m + 4.0],
        )

    def zone_bounds(self) -> rrb.VisualBounds2D:
        k = CHART_M_PER_S
        n = max(len(self.points), 1)
        return rrb.VisualBounds2D(
            x_range=[-PAST_S * k - 38.0, FUTURE_S * k + 2.0], y_range=[-3.0, n * ROW_M + 5.5]
        )

    def views(self) -> dict[str, Any]:
        """Every view of the layout by name: top, zones, counts, confirmed, rejected,
        reorders and one per lane (its lane id); ``tools/screenshots.py`` shows them
        one by one."""
        reach = _frame_reach(self.intersection)
        top = rrb.Spatial2DView(
            origin="junction",
            name="junction: top view, north up",
            visual_bounds=rrb.VisualBounds2D(x_range=[-reach, reach], y_range=[-reach, reach]),
        )
        history = rrb.VisibleTimeRange(
            TIMELINE,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-HISTORY_S),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        )
        lanes = lane_major(self.lanes)
        charts = [
            rrb.Spatial2DView(
                origin="charts",
                contents=[
                    "+ /charts/frame/now/**",
                    f"+ /charts/frame/lanes/{lane}/**",
                    f"+ /charts/data/lanes/{lane}/**",
                    "+ /charts/data/ticks/**",
                    "- /charts/data/ticks/zone_labels",
                ],
                name=f"{lane}: distance [m] vs time [s]",
                visual_bounds=self.chart_bounds(),
                time_ranges=history,
            )
            for lane in lanes
        ]
        zones = rrb.Spatial2DView(
            origin="charts",
            contents=[
                "+ /charts/frame/now/**",
                "+ /charts/frame/zones/**",
                "+ /charts/data/zones/**",
                "+ /charts/data/ticks/**",
                "- /charts/data/ticks/lane_labels",
            ],
            name="conflict points: reserved (box) and held (dots) vs time [s]",
            visual_bounds=self.zone_bounds(),
            time_ranges=history,
        )
        table_columns = rrb.TextLogColumns(
            timeline_columns=[rrb.encodings.TimelineColumn(TIMELINE)],
            text_log_columns=[
                rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.Body),
            ],
        )
        mono = rrb.TextLogFormat(monospace_body=True)
        counts = rrb.TimeSeriesView(
            origin="counts", name="counts", plot_legend=rrb.PlotLegend(corner="LeftTop")
        )
        confirmed = rrb.TextLogView(
            origin="tables/confirmed",
            name="confirmed: VIN, route, entry s, exit s, delay s, rounds",
            columns=table_columns,
            format_options=mono,
        )
        rejected = rrb.TextLogView(
            origin="tables/rejected",
            name="rejected: VIN, reason",
            columns=table_columns,
            format_options=mono,
        )
        reorders = rrb.TextLogView(
            origin="tables/reorders",
            name="reorders: EV, solver, EV entry s before, after, order (* revoked)",
            columns=table_columns,
            format_options=mono,
        )
        views = dict(zip(lanes, charts, strict=True))
        views.update(
            top=top,
            zones=zones,
            counts=counts,
            confirmed=confirmed,
            rejected=rejected,
            reorders=reorders,
        )
        return views

    def blueprint(self) -> rrb.Blueprint:
        """Top view and conflict points on the left; lane charts, counts and tables on
        the right; paused at the start, the time panel folded to its play bar."""
        v = self.views()
        lanes = lane_major(self.lanes)
        n_cols = len({approach_of(ln) for ln in self.lanes})
        bottom = rrb.Horizontal(
            v["counts"], v["confirmed"], v["rejected"], v["reorders"], column_shares=[2, 4, 3, 3]
        )
        left = rrb.Vertical(v["top"], v["zones"], row_shares=[3, 2])
        grid = rrb.Grid(*(v[lane] for lane in lanes), grid_columns=n_cols)
        right = rrb.Vertical(grid, bottom, row_shares=[3, 1])
        return rrb.Blueprint(
            rrb.Horizontal(left, right, column_shares=[2, 3]),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", play_state="paused", timeline=TIMELINE),
        )

    # -- static geometry -----------------------------------------------------
    def geometry(self) -> None:
        """Static drawings: the junction, lane edges, entry lines, legends and chart frames."""
        inter = self.intersection
        comm = inter.comm_length_m
        log = self.rec.log
        region = np.asarray(inter.region, dtype=float)
        log(
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
        for lane in self.lanes:
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
        log(
            "junction/lane_edges",
            rr.LineStrips2D(edges, radii=0.06, colors=[LANE_EDGE_RGB], draw_order=1.0),
            static=True,
        )
        log(
            "junction/entry_lines",
            rr.LineStrips2D(
                entry, radii=0.15, colors=[ENTRY_RGB], labels=lane_names, show_labels=False
            ),
            static=True,
        )
        log(
            "junction/region_start_lines",
            rr.LineStrips2D(
                start, radii=0.15, colors=[REGION_START_RGB], labels=lane_names, show_labels=False
            ),
            static=True,
        )
        routes = [clipped(r, 0.0, r.cross_length_m) * FLIP_Y for r in inter.routes]
        log(
            "junction/routes",
            rr.LineStrips2D(
                routes,
                radii=0.04,
                colors=[ROUTE_RGB],
                labels=[r.id for r in inter.routes],
                show_labels=False,
                draw_order=0.5,
            ),
            static=True,
        )
        self._top_legend()
        self._chart_frames()

    def _top_legend(self) -> None:
        """A legend in the top view's upper left corner, clear of the roads: each entry
        written in the colour of what it names (labels have a fixed size on screen, so
        separate key shapes would drift into the text when zooming)."""
        reach = _frame_reach(self.intersection)
        x0, y0 = -reach + 11.0, -reach + 1.5  # viewer frame: y grows downwards
        entries = top_legend(self.margin_m)
        self.rec.log(
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

    def _chart_frames(self) -> None:
        """Static chart frames: "now", distance labels, labelled region/entry/exit lines."""
        k = CHART_M_PER_S
        x0, x1 = -PAST_S * k, FUTURE_S * k
        comm = self.intersection.comm_length_m
        log = self.rec.log
        n = len(self.points)
        log(
            "charts/frame/now",
            rr.LineStrips2D(
                [[(0.0, -self._top_m - 2.0), (0.0, comm + 4.0)], [(0.0, -3.0), (0.0, n * ROW_M)]],
                radii=0.25,
                colors=[NOW_RGBA],
                draw_order=30.0,
            ),
            static=True,
        )
        log(
            "charts/frame/now/label",
            rr.Points2D(
                [(0.0, -self._top_m + 3.0), (0.0, n * ROW_M + 2.5)],
                radii=0.01,
                labels=["now", "now"],
                show_labels=True,
            ),
            static=True,
        )
        for lane in self.lanes:
            routes = [r for r in self.intersection.routes if r.in_lane == lane]
            lines = [(-comm, "region start"), (0.0, "entry")]
            for length in sorted({round(r.cross_length_m, 1) for r in routes}):
                turns = sorted(
                    {r.turn.value for r in routes if round(r.cross_length_m, 1) == length}
                )
                lines.append((length, f"exit ({'/'.join(turns)})"))
            log(
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
            log(
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
        names = [f"P{i + 1} {self.points.name(i)}" for i in range(n)]
        log(
            "charts/frame/zones/rows",
            rr.Points2D(
                [(x0 - 19.0, (i + 0.5) * ROW_M) for i in range(n)],
                radii=0.01,
                colors=[FRAME_RGB],
                labels=names,
                show_labels=True,
            ),
            static=True,
        )
        log(
            "charts/frame/zones/grid",
            rr.LineStrips2D(
                [[(x0, i * ROW_M), (x1, i * ROW_M)] for i in range(n + 1)],
                radii=0.04,
                colors=[ROW_GRID_RGB],
                draw_order=0.0,
            ),
            static=True,
        )
        log(
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

    # -- confirmations and rejections ----------------------------------------
    def confirmed(
        self,
        vin: str,
        route_id: str,
        t_s: np.ndarray,
        x_m: np.ndarray,
        y_m: np.ndarray,
        heading_rad: np.ndarray,
        length_m: float,
        width_m: float,
        entry_time_s: float,
        exit_time_s: float,
        *,
        now_s: float | None = None,
        delay_s: float = math.nan,
        rounds: int = -1,
        margin_m: float | None = None,
        time_pad_s: float = 0.0,
    ) -> None:
        """One confirmation, logged at ``now_s`` (default: the TSS's first time).

        Its plan goes to its lane's chart, the intervals in which it holds
        each conflict point (from its DTOT, computed by the core) to the
        conflict-point chart, and its reserved footprints with their margin to
        the top view, step by step as the run reaches them. ``margin_m``: the
        ICA's margin (default: the recorder's); ``time_pad_s``: the ICA's time
        padding, which it adds to every interval on each side.
        """
        route = self._route(route_id)
        t = np.asarray(t_s, dtype=float)
        n = len(t)
        if n == 0 or not all(len(a) == n for a in (x_m, y_m, heading_rad)):
            raise ValueError(f"{vin}: TSS arrays must be non-empty and of equal length")
        now = float(t[0]) if now_s is None else float(now_s)
        if self._start_s is None:
            self._start_s = now
        ridx = self._projector.index[route_id]
        margin = self.margin_m if margin_m is None else float(margin_m)
        dtot = dtot_of_tss(route, t, x_m, y_m, length_m, width_m, margin)
        r = dtot.rects
        half_m = margin / 2.0
        band = outlines(
            r.centre[:, 0],
            r.centre[:, 1],
            r.heading[:, 0],
            r.heading[:, 1],
            np.full(len(r), r.half_length - half_m),
            np.full(len(r), r.half_width - half_m),
        ).astype(np.float32)
        hold = holding(dtot, self.points)
        if time_pad_s > 0.0:
            hold = Holding(hold.point, hold.lb_s - time_pad_s, hold.ub_s + time_pad_s)
        self._plans[vin] = Plan(
            now, ridx, route.cross_length_m + length_m, float(dtot.t_s[0]), band, hold
        )
        color = self._colours.of(vin)
        k = CHART_M_PER_S
        s, _ = route.project(np.stack([np.asarray(x_m, float), np.asarray(y_m, float)], -1))
        keep = np.unique(np.append(np.arange(0, n, CHART_EVERY), n - 1))
        line = np.stack([t[keep] * k, -s[keep]], axis=-1).astype(np.float32)
        plan = {
            "strips": [line],
            "colors": np.array([color & 0xFFFFFF00 | PLAN_ALPHA], dtype=np.uint32),
            "labels": [f"{vin} plan"],
        }
        entity = f"charts/data/lanes/{route.in_lane}/plans"
        self._rows.add(entity, rr.LineStrips2D, now, 1, **plan)
        self._rows.again(float(t[-1]), now, entity, rr.LineStrips2D, 1, plan)
        if len(hold):
            centers = np.stack([(hold.lb_s + hold.ub_s) / 2 * k, (hold.point + 0.5) * ROW_M], -1)
            halves = np.stack(
                [(hold.ub_s - hold.lb_s) / 2 * k, np.full(len(hold), 0.4 * ROW_M)], -1
            )
            boxes = {
                "centers": centers.astype(np.float32),
                "half_sizes": halves.astype(np.float32),
                "colors": np.full(len(hold), color, dtype=np.uint32),
                "labels": [
                    f"{vin} P{p + 1} {a:.2f}-{b:.2f} s"
                    for p, a, b in zip(hold.point, hold.lb_s, hold.ub_s, strict=True)
                ],
            }
            entity = "charts/data/zones/reserved"
            self._rows.add(entity, rr.Boxes2D, now, len(hold), **boxes)
            self._rows.again(float(hold.ub_s.max()), now, entity, rr.Boxes2D, len(hold), boxes)
        self._n_confirmed += 1
        self._rows.add(
            "counts/confirmed", rr.Scalars, now, 1, scalars=np.array([self._n_confirmed])
        )
        delay = f"{delay_s:6.2f}" if math.isfinite(delay_s) else "     -"
        rounds_txt = f"{rounds:3d}" if rounds >= 0 else "  -"
        self._rows.add(
            "tables/confirmed",
            rr.TextLog,
            now,
            1,
            text=[
                f"{vin:<8} {route_id:<15} {entry_time_s:8.2f} {exit_time_s:8.2f} "
                f"{delay} {rounds_txt}"
            ],
        )
        self._maybe_flush(now)

    def rejected(self, t_s: float, vin: str, reason: str, detail: str = "") -> None:
        """One rejection: a row in the rejections table and the count."""
        self._n_rejected += 1
        text = f"{vin:<8} {reason:<17} {detail[:60]}".rstrip()
        self._rows.add("tables/rejected", rr.TextLog, float(t_s), 1, text=[text])
        self._rows.add(
            "counts/rejected", rr.Scalars, float(t_s), 1, scalars=np.array([self._n_rejected])
        )

    # -- what really happened ------------------------------------------------
    def withdrawn(self, t_s: float, vin: str, why: str) -> None:
        """``vin``'s confirmation no longer holds (revoked): from ``t_s`` its reserved
        footprint is no longer drawn and its plan and reserved intervals are not
        logged again, so they leave the charts with the window; a row says why.
        The steps buffered so far are drawn first, with the plan in force before
        ``t_s`` (which may lie a little in the past) and withdrawn from it."""
        plan = self._plans.get(vin)
        if plan is not None:
            plan.until_s = float(t_s)
            self.flush()
            self._plans.pop(vin, None)
        self._rows.forget((f"{vin} plan", f"{vin} P"))
        self.rejected(t_s, vin, why)

    def emergency(self, vin: str) -> None:
        """Draw ``vin`` in the emergency vehicles' colour from now on: in the top view
        until it has cleared, and its plans and progress in the charts (call it before
        its first confirmation, so that its plan is drawn in that colour too)."""
        self._colours.mark_emergency(vin)

    def reordered(
        self,
        t_s: float,
        ev: str,
        lane: str,
        solver: str,
        order: Sequence[str],
        ev_entry_before_s: float,
        ev_entry_after_s: float,
        *,
        revoked: Sequence[str] = (),
        refused: str = "",
    ) -> None:
        """Reactive DICA reordered the vehicles for emergency vehicle ``ev`` at ``t_s``.

        On the EV's lane chart: a line across the chart at ``t_s`` and one along
        the entry line from the EV's entry in the present order to its entry in
        the new one (by the ordering model), in the EV's colour and labelled; a
        row in the reorders table with the solver, both entries and the new
        order, revoked vehicles starred (``refused``: the present order was kept).
        """
        if lane not in self.lanes:
            raise ValueError(f"unknown lane {lane!r}")
        t = float(t_s)
        k = CHART_M_PER_S
        comm = self.intersection.comm_length_m
        strips = [np.array([(t * k, -self._top_m), (t * k, comm)], np.float32)]
        labels = [f"reorder for {ev} ({solver})"]
        ends = [t]
        if math.isfinite(ev_entry_before_s) and math.isfinite(ev_entry_after_s):
            a, b = float(ev_entry_before_s), float(ev_entry_after_s)
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
        star = set(revoked)
        listed = " ".join(f"{v}*" if v in star else v for v in order)
        if refused:
            text = f"{ev:<8} {solver:<10} present order kept: {refused[:80]}"
        else:
            text = (
                f"{ev:<8} {solver:<10} {ev_entry_before_s:7.2f} {ev_entry_after_s:7.2f}  {listed}"
            )
        self._rows.add("tables/reorders", rr.TextLog, t, 1, text=[text])

    def kept(self, t_s: float, vin: str, why: str) -> None:
        """A revoked plan that stands after all (the vehicle could not stop short of the
        line, or no answer came before the plan ended): it stays drawn; a row says why."""
        self._rows.add("tables/reorders", rr.TextLog, float(t_s), 1, text=[f"{vin:<8} {why}"])

    def footprints(
        self,
        t_s: float,
        vins: Sequence[str],
        x_m: np.ndarray,
        y_m: np.ndarray,
        angle_deg: np.ndarray,
        length_m: np.ndarray | float,
        width_m: np.ndarray | float,
        route_ids: Sequence[str | None] | None = None,
    ) -> None:
        """All vehicles of one SUMO step, in SUMO's frame (front bumper, degrees from north).

        Call it every step, even with no vehicles, so that vehicles that left
        vanish from the top view. ``route_ids`` (None or "" where the route is
        not known yet) put a vehicle on its lane's chart and give it a state.
        Only buffers: the drawing is done in batches (:meth:`flush`).
        """
        n = len(vins)
        x = np.asarray(x_m, dtype=float).reshape(-1)
        y = np.asarray(y_m, dtype=float).reshape(-1)
        angle = np.asarray(angle_deg, dtype=float).reshape(-1)
        if not len(x) == len(y) == len(angle) == n:
            raise ValueError("footprints: vins, x_m, y_m and angle_deg must have equal length")
        if route_ids is None:
            ridx = np.full(n, -1)
        else:
            if len(route_ids) != n:
                raise ValueError("footprints: route_ids must have one entry per vehicle")
            ridx = self._route_indices(route_ids)
        length = np.broadcast_to(np.asarray(length_m, dtype=float), (n,))
        width = np.broadcast_to(np.asarray(width_m, dtype=float), (n,))
        t = float(t_s)
        self._steps.append(Step(t, list(vins), x, y, angle, length, width, ridx))
        self._maybe_flush(t)

    def _maybe_flush(self, t_s: float) -> None:
        if t_s - self._buf_t0 >= self.flush_s:
            self.flush()
            self._buf_t0 = t_s

    def flush(self, final: bool = False) -> None:
        """Draw the buffered steps (done every ``flush_s`` of simulated time) and send
        the rows of entities that have MAX_ROWS of them; ``final`` (on close), or a
        live recording: send everything.

        The recording starts at the first confirmation, so that a viewer opens
        on it; steps before it are dropped. A run with no confirmation within
        START_WAIT_S (a signalised baseline) starts at its first step.
        """
        steps = self._steps
        if steps and self._start_s is None:
            if not final and steps[-1].t_s - steps[0].t_s < START_WAIT_S:
                return  # keep waiting for the first confirmation
            self._start_s = steps[0].t_s
        if steps:
            start = self._start_s or 0.0
            kept = [st for st in steps if st.t_s >= start - 1e-9]
            if kept:
                self._draw_steps(kept)
            self._steps = []
        self._rows.send(self.rec, everything=final or self.live)

    def close(self) -> None:
        """Send what is buffered and finish the file (Rerun writes its footer on disconnect)."""
        self.flush(final=True)
        self.rec.flush()
        self.rec.disconnect()

    # -- drawing a batch of steps --------------------------------------------
    def _draw_steps(self, steps: list[Step]) -> None:
        b = StepBatch.of(
            steps, self._step_no, self._projector, self._plans, self._colours.emergency
        )
        self._step_no += len(steps)
        times, counts, step_of, vins = b.times, b.counts, b.step_of, b.vins
        x, y, length, width, ridx, s, dist = b.x, b.y, b.length, b.width, b.route_idx, b.s, b.dist
        plans, confirmed, c, sn = b.plans, b.confirmed, b.cos, b.sin
        t_row = times[step_of]
        known = ridx >= 0

        # top view: every TOP_EVERY steps
        top_step = b.every(TOP_EVERY)
        top_idx = np.nonzero(top_step)[0]
        top = np.nonzero(top_step[step_of])[0]
        tc, ts, tl, tw = c[top], sn[top], length[top], width[top]
        strips = outlines(x[top] - tc * tl / 2, y[top] - ts * tl / 2, tc, ts, tl / 2, tw / 2)
        self._rows.add_many(
            "junction/vehicles",
            rr.LineStrips2D,
            times[top_idx],
            counts[top_idx],
            strips=strips.astype(np.float32),
            colors=STATUS_RGBA[b.state[top]],
        )
        self._names(times, top_step, step_of, vins, ridx, s, dist, length)
        self._reserved(times[top_idx])

        # charts: every CHART_EVERY steps
        chart_step = b.every(CHART_EVERY)
        k = CHART_M_PER_S
        if chart_step.any():
            ct = times[chart_step]
            self._rows.add_many(
                "counts/vehicles",
                rr.Scalars,
                ct,
                np.ones(len(ct), int),
                scalars=counts[chart_step].astype(float),
            )
            self._rows.add_many(
                "charts/data",
                rr.Transform3D,
                ct,
                np.ones(len(ct), int),
                translation=np.stack([-k * ct, np.zeros_like(ct), np.zeros_like(ct)], -1),
            )
        self._ticks(times[-1] if len(times) else 0.0)
        if len(times):
            self._rows.due(float(times[-1]))
        at_chart = chart_step[step_of]
        on_chart = (
            at_chart
            & known
            & (dist <= LANE_WIDTH_M)
            & (s >= -self.intersection.comm_length_m)
            & (s < np.where(known, self._route_end_m[np.maximum(ridx, 0)], 0.0))
        )
        colors = self._colours.of_many(vins)
        lane_of = np.where(known, self._route_lane[np.maximum(ridx, 0)], -1)
        chart_steps = np.nonzero(chart_step)[0]
        for li, lane in enumerate(self.lanes):
            sel = on_chart & (lane_of == li)
            if not sel.any():
                continue
            idx = np.nonzero(sel)[0]
            per = np.bincount(
                np.searchsorted(chart_steps, step_of[idx]), minlength=len(chart_steps)
            )
            self._rows.add_many(
                f"charts/data/lanes/{lane}/actual",
                rr.Points2D,
                times[chart_steps],
                per,
                positions=np.stack([t_row[idx] * k, -s[idx]], -1).astype(np.float32),
                colors=colors[idx],
                labels=[vins[i] for i in idx],
            )
        self._held(
            times,
            chart_steps,
            step_of,
            vins,
            plans,
            confirmed & at_chart,
            x,
            y,
            c,
            sn,
            length,
            width,
        )

    def _names(self, times, top_step, step_of, vins, ridx, s, dist, length) -> None:
        """Names beside the kerb, level with the vehicle, for vehicles in the approach."""
        sel = (
            top_step[step_of]
            & (ridx >= 0)
            & (dist <= LANE_WIDTH_M)
            & (s < 0.0)
            & (s >= -self.intersection.comm_length_m - 5.0)
        )
        idx = np.nonzero(sel)[0]
        top_idx = np.nonzero(top_step)[0]
        per = np.bincount(np.searchsorted(top_idx, step_of[idx]), minlength=len(top_idx))
        pos = (
            self._label_at.places(self._route_lane[ridx[idx]], s[idx] - length[idx] / 2)
            if len(idx)
            else np.zeros((0, 2))
        )
        self._rows.add_many(
            "junction/names",
            rr.Points2D,
            times[top_idx],
            per,
            positions=(pos * FLIP_Y).astype(np.float32),
            labels=[vins[i] for i in idx],
        )

    def _reserved(self, times: np.ndarray) -> None:
        """Reserved footprints (margin bands) of every plan whose DTOT spans a step."""
        if not len(times):
            return
        lo, hi = float(times[0]) - 1e-6, float(times[-1]) + 1e-6
        at_step: list[np.ndarray] = []
        blocks: list[np.ndarray] = []
        for vin in list(self._plans):
            p = self._plans[vin]
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

    def _held(
        self, times, chart_steps, step_of, vins, plans, sel, x, y, c, sn, length, width
    ) -> None:
        """Dots where a confirmed vehicle's real footprint covers a conflict point;
        red where that is outside the interval reserved for it there."""
        if len(self.points) == 0 or not len(chart_steps):
            return
        idx = np.nonzero(sel)[0]
        cx, cy = x[idx] - c[idx] * length[idx] / 2, y[idx] - sn[idx] * length[idx] / 2
        cov = covers(
            np.stack([cx, cy], -1),
            np.stack([c[idx], sn[idx]], -1),
            length[idx] / 2,
            width[idx] / 2,
            self.points.xy,
        )
        rows, pts = np.nonzero(cov)
        k = CHART_M_PER_S
        t = times[step_of[idx[rows]]]
        inside = np.zeros(len(rows), dtype=bool)
        for n, (r, p) in enumerate(zip(rows, pts, strict=True)):
            h = plans[idx[r]].hold
            m = np.nonzero(h.point == p)[0]
            inside[n] = bool(len(m)) and h.lb_s[m[0]] - 1e-9 <= t[n] <= h.ub_s[m[0]] + 1e-9
        colors = self._colours.of_many([vins[idx[r]] for r in rows])
        colors = np.where(inside, colors, np.uint32(rgba(OVERRUN_RGB)))
        per = np.bincount(
            np.searchsorted(chart_steps, step_of[idx[rows]]), minlength=len(chart_steps)
        )
        self._rows.add_many(
            "charts/data/zones/held",
            rr.Points2D,
            times[chart_steps],
            per,
            positions=np.stack([t * k, (pts + 0.5) * ROW_M], -1).astype(np.float32),
            colors=colors,
            labels=[
                f"{vins[idx[r]]} P{p + 1}{'' if ok else ' outside its reservation'}"
                for r, p, ok in zip(rows, pts, inside, strict=True)
            ],
        )

    def _ticks(self, t_s: float) -> None:
        """A labelled time tick every TICK_S. A chart shows the rows of the last PAST_S,
        so each tick is logged twice: when it enters the window (FUTURE_S ahead of
        its time) and at its time; never later than the run has got."""
        start = self._start_s or 0.0
        while self._tick_enter <= t_s + FUTURE_S + 1e-9:
            self._tick(self._tick_enter, max(self._tick_enter - FUTURE_S, start))
            self._tick_enter += TICK_S
        while self._tick_at <= t_s + 1e-9:
            self._tick(self._tick_at, max(self._tick_at, start))
            self._tick_at += TICK_S

    def _tick(self, t0: float, at: float) -> None:
        x = t0 * CHART_M_PER_S
        n = max(len(self.points), 1)
        self._rows.add(
            "charts/data/ticks/lines",
            rr.LineStrips2D,
            at,
            1,
            strips=[np.array([(x, -self._top_m - 2.0), (x, n * ROW_M + 60.0)], np.float32)],
            colors=np.array([rgba(GRID_RGB)], np.uint32),
        )
        label = [f"{t0:g} s"]
        self._rows.add(
            "charts/data/ticks/lane_labels",
            rr.Points2D,
            at,
            1,
            positions=np.array([(x, -self._top_m)], np.float32),
            labels=label,
        )
        self._rows.add(
            "charts/data/ticks/zone_labels",
            rr.Points2D,
            at,
            1,
            positions=np.array([(x, -1.0)], np.float32),
            labels=label,
        )

    # -- helpers -------------------------------------------------------------
    def _route(self, route_id: str) -> Route:
        route = self.intersection.route_by_id(route_id)
        if route is None:
            raise ValueError(f"unknown route {route_id!r}")
        return route

    def _route_indices(self, route_ids: Sequence[str | None]) -> np.ndarray:
        try:
            return np.array([self._projector.index[r] if r else -1 for r in route_ids], dtype=int)
        except KeyError as e:
            raise ValueError(f"unknown route {e.args[0]!r}") from None


class _LabelPlaces:
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


def _frame_reach(inter: Intersection) -> float:
    """Half the side of the top view's opening frame: the junction and 22 m around it."""
    region = np.asarray(inter.region, dtype=float)
    return float(np.abs(region).max()) + 22.0
