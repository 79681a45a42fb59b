"""A Rerun recording of a run: the junction, every reservation, and what vehicles did.

The recorder sits beside the control loop, never inside it: the ICA core does
not know it exists, and it takes plain arrays and strings, so the embedded
runner, a Zenoh process or a test can all feed it. It writes to its own
:class:`rerun.RecordingStream` (never Rerun's global one), to a ``.rrd`` file
and, when asked, to a gRPC server on loopback that viewers can watch live.
``docs/recording.md`` says how to read each view.

It composes the views, each in its own module: the top view
(:mod:`.top_view`), the lane charts (:mod:`.lane_charts`), the conflict-point
chart (:mod:`.conflict_chart`), the counts and tables (:mod:`.tables`), laid
out by :mod:`.layout`; all of them add rows to one :class:`RowBuffer`.

Cost. A Rerun call costs 0.1-0.5 ms, so a step only appends its arrays to a
buffer; every ``flush_s`` of simulated time the buffer is drawn with numpy
into rows per entity (:class:`StepBatch`), which are sent as one column
chunk per entity once it holds MAX_ROWS of them, and at the end: a 10-minute
run makes about a hundred chunks. A live recording sends every LIVE_FLUSH_S
instead, so that viewers see the run as it goes.
"""

from __future__ import annotations

import math
import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dica.ica.core.dtot import Dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.walk import WalkSlot
from dica.ica.core.zones import ConflictTables, Shape
from dica.sim_gateway.conflict_points import ConflictPoints, dtot_of_tss, find_conflict_points
from dica.sim_gateway.recording.batch import Plan, Step, StepBatch
from dica.sim_gateway.recording.chart_frame import CHART_EVERY, ChartFrame
from dica.sim_gateway.recording.conflict_chart import ConflictChart
from dica.sim_gateway.recording.crossing_chart import CrossingChart
from dica.sim_gateway.recording.geometry import FLIP_Y, RouteProjector
from dica.sim_gateway.recording.lane_charts import LaneCharts
from dica.sim_gateway.recording.layout import Layout
from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import (
    HEAD_GREEN_RGB,
    HEAD_RED_RGB,
    PERSON_WAITING_RGB,
    PERSON_WALKING_RGB,
    VehicleColours,
    row_styles,
)
from dica.sim_gateway.recording.tables import Tables
from dica.sim_gateway.recording.top_view import TopView, reserved_bands

START_WAIT_S = 60.0  # [s] how long the recording waits for a first confirmation
FLUSH_S = 20.0  # [s] of simulated time buffered before it is sent (saved file)
PEOPLE_EVERY_S = 0.25  # [s] of simulated time between two drawings of the people
LIVE_FLUSH_S = 1.0  # [s] the same when viewers watch live (and rows are sent then)


def free_port(port: int) -> None:
    """Raise OSError if ``port`` on 127.0.0.1 is taken (another run's live view)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError as e:
            raise OSError(f"{e.strerror or e} (another live view?)") from None


def finish(rec: rr.RecordingStream, live: bool) -> None:
    """Send what the stream holds and finish its file (Rerun writes the footer on
    disconnect), even where a live server's thread has stopped."""
    try:
        rec.flush()
    except RuntimeError as e:  # Rerun's gRPC server thread stopped
        if not live:
            raise
        print(f"note: the live view stopped ({e}); the file is finished", file=sys.stderr)
    finally:
        rec.disconnect()


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
        shape = shape or Shape(5.0, 1.8)
        top_m = max(r.cross_length_m for r in routes) + shape.length_m
        self.points: ConflictPoints = find_conflict_points(
            intersection, ConflictTables(intersection, margin_m), shape
        )
        self._plans: dict[str, Plan] = {}
        self._colours = VehicleColours()
        self._steps: list[Step] = []
        self._step_no = 0
        self._buf_t0 = 0.0
        self._start_s: float | None = None  # the timeline starts at the first confirmation
        self._rows = RowBuffer(row_styles(self.lanes, margin_m))
        self._crossings = CrossingChart(
            intersection.crosswalks, len(self.points), self._rows, self._colours
        )
        n_rows = len(self.points) + self._crossings.n_rows
        self._layout = Layout(intersection, top_m, n_rows)
        self._top = TopView(intersection, self._rows, margin_m)
        self._lane_charts = LaneCharts(intersection, self._rows, self._colours, top_m)
        self._conflicts = ConflictChart(self.points, self._rows, self._colours)
        self._frame = ChartFrame(self._rows, top_m, n_rows)
        self._tables = Tables(self._rows)

        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.rec.set_log_time_enabled(False)  # only sim_time: wall clock would mislead
        self.path.parent.mkdir(parents=True, exist_ok=True)
        sinks: list[Any] = [rr.FileSink(str(self.path))]
        if live_port is not None:
            free_port(live_port)  # Rerun would only log that it cannot listen, then fail late
            sinks.append(rr.GrpcServerSink(bind_ip="127.0.0.1", port=live_port))
        self.rec.set_sinks(*sinks, default_blueprint=self.blueprint())
        self._tables.series(self.rec)
        self._people_t = -math.inf  # when people were last drawn
        region = np.asarray(intersection.region, dtype=float).reshape(-1, 2)
        self._people_at = region.mean(axis=0)  # people this near are drawn: the sidewalks too
        self._people_reach = float(np.abs(region - self._people_at).max()) + 45.0
        self._heads_t = -math.inf

    def __enter__(self) -> SpaceTimeRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- layout --------------------------------------------------------------
    def chart_bounds(self) -> rrb.VisualBounds2D:
        """The one window and distance scale every space-time chart shares."""
        return self._layout.chart_bounds()

    def zone_bounds(self) -> rrb.VisualBounds2D:
        return self._layout.zone_bounds()

    def views(self) -> dict[str, Any]:
        """Every view of the layout by name (see :meth:`Layout.views`)."""
        return self._layout.views()

    def blueprint(self) -> rrb.Blueprint:
        return self._layout.blueprint()

    def geometry(self) -> None:
        """Static drawings: the junction, lane edges, entry lines, legends and chart frames."""
        self._top.geometry(self.rec)
        self._frame.now_line(self.rec, self.intersection.comm_length_m)
        self._lane_charts.frames(self.rec)
        self._conflicts.frames(self.rec)
        self._crossings.frames(self.rec)

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
        margin = self.margin_m if margin_m is None else float(margin_m)
        dtot = dtot_of_tss(route, t, x_m, y_m, length_m, width_m, margin)
        hold = self._conflicts.holding(dtot, time_pad_s)
        self._plans[vin] = Plan(
            now,
            self._projector.index[route_id],
            route.cross_length_m + length_m,
            float(dtot.t_s[0]),
            reserved_bands(dtot, margin),
            hold,
        )
        self._lane_charts.plan(now, vin, route, t, x_m, y_m)
        self._conflicts.reserved(now, vin, hold)
        self._crossings.reserved(
            now, vin, route, t, x_m, y_m, length_m, width_m, margin, 2.0 * time_pad_s
        )
        self._tables.confirmed(now, vin, route_id, entry_time_s, exit_time_s, delay_s, rounds)
        self._maybe_flush(now)

    def rejected(self, t_s: float, vin: str, reason: str, detail: str = "") -> None:
        """One rejection: a row in the rejections table and the count."""
        self._tables.rejected(float(t_s), vin, reason, detail)

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

    def human(self, vin: str) -> None:
        """Draw ``vin`` as a human driver from now on (it holds no plan: the ICA reserves
        its envelope, :meth:`envelope`)."""
        self._colours.mark_human(vin)

    def envelope(
        self,
        now_s: float,
        vin: str,
        routes: Sequence[tuple[str, Dtot, Trajectory, Trajectory]],
        time_pad_s: float = 0.0,
    ) -> None:
        """A human driver's green at ``now_s``: per route of its lane (route id, the
        envelope's DTOT as the core built it, its fastest and slowest crossing), the
        intervals in which it holds each conflict point go to the conflict-point chart,
        and the two bounds to its lane's chart. A sooner green replaces the boxes of
        the one before from here on."""
        self._rows.forget((f"{vin} P",))
        for route_id, dtot, fast, slow in routes:
            hold = self._conflicts.holding(dtot, time_pad_s)
            self._conflicts.reserved(float(now_s), vin, hold)
            self._lane_charts.envelope(float(now_s), vin, self._route(route_id), fast, slow)

    def heads(self, t_s: float, red_xy: np.ndarray, green_xy: np.ndarray) -> None:
        """The signal heads of the lanes where a human driver stands or goes, in SUMO's
        frame, every :data:`PEOPLE_EVERY_S`: red until the ICA's green, then green."""
        t = float(t_s)
        tick = math.floor(t / PEOPLE_EVERY_S + 1e-6)  # on a fixed grid: the same in any run
        if tick == self._heads_t:
            return
        self._heads_t = tick
        red = np.asarray(red_xy, dtype=float).reshape(-1, 2)
        green = np.asarray(green_xy, dtype=float).reshape(-1, 2)
        xy = np.vstack([red, green])
        colors = [HEAD_RED_RGB] * len(red) + [HEAD_GREEN_RGB] * len(green)
        self._rows.add_many(
            "junction/heads",
            rr.Points2D,
            np.array([t]),
            np.array([len(xy)]),
            positions=(xy * FLIP_Y).astype(np.float32),
            colors=np.array(colors, dtype=np.uint8).reshape(-1, 3),
            radii=np.full(len(xy), 0.6, dtype=np.float32),
        )

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
        self._lane_charts.reorder(t, ev, lane, solver, ev_entry_before_s, ev_entry_after_s)
        self._tables.reordered(
            t, ev, solver, order, ev_entry_before_s, ev_entry_after_s, revoked, refused
        )

    def kept(self, t_s: float, vin: str, why: str) -> None:
        """A revoked plan that stands after all (the vehicle could not stop short of the
        line, or no answer came before the plan ended): it stays drawn; a row says why."""
        self._tables.kept(float(t_s), vin, why)

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

    def walk(self, now_s: float, slot: WalkSlot) -> None:
        """A walker given a crossing: its reservation in the crossing's band of the
        conflict-point chart (:mod:`.crossing_chart`)."""
        self._crossings.walk(float(now_s), slot)

    def people(self, t_s: float, xy: np.ndarray, waiting: np.ndarray) -> None:
        """People near the junction at one step, in SUMO's frame: a dot each in the top
        view (amber: waiting at the kerb, blue: walking), every :data:`PEOPLE_EVERY_S`."""
        t = float(t_s)
        if t - self._people_t < PEOPLE_EVERY_S - 1e-9:
            return
        self._people_t = t
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        self._crossings.people(t, xy)
        near = np.abs(xy - self._people_at).max(axis=1) <= self._people_reach
        xy, wait = xy[near], np.asarray(waiting, dtype=bool)[near]
        self._rows.add_many(
            "junction/people",
            rr.Points2D,
            np.array([t]),
            np.array([len(xy)]),
            positions=(xy * FLIP_Y).astype(np.float32),
            colors=np.where(wait[:, None], PERSON_WAITING_RGB, PERSON_WALKING_RGB).astype(np.uint8),
            radii=np.full(len(xy), 0.35, dtype=np.float32),
        )

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
                self._draw(kept)
            self._steps = []
        self._rows.send(self.rec, everything=final or self.live)

    def close(self) -> None:
        """Send what is buffered and finish the file (Rerun writes its footer on disconnect).
        A live server that went away (its viewers' side) does not keep the file from
        being finished."""
        self.flush(final=True)
        finish(self.rec, self.live)

    def _draw(self, steps: list[Step]) -> None:
        """A batch of steps into rows: the top view every TOP_EVERY steps, the charts
        and the vehicle count every CHART_EVERY steps, and the rows due again."""
        batch = StepBatch.of(
            steps, self._step_no, self._projector, self._plans, self._colours.emergency,
            self._colours.human,
        )  # fmt: skip
        self._step_no += len(steps)
        self._top.draw(batch, self._plans)
        chart_step = batch.every(CHART_EVERY)
        if chart_step.any():
            self._tables.vehicles(batch.times[chart_step], batch.counts[chart_step])
            self._frame.shift(batch.times[chart_step])
        times = batch.times
        self._frame.ticks(times[-1] if len(times) else 0.0, self._start_s or 0.0)
        if len(times):
            self._rows.due(float(times[-1]))
        self._lane_charts.actual(batch, chart_step)
        self._conflicts.held(batch, chart_step)

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
