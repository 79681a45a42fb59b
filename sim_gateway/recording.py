"""A Rerun recording of a run: the junction, every confirmed plan, and what vehicles did.

The recorder sits beside the control loop, never inside it: the ICA core does
not know it exists, and it takes plain arrays and strings, so the embedded
runner, a Zenoh process or a test can all feed it. It writes to its own
:class:`rerun.RecordingStream` (never Rerun's global one) and saves a ``.rrd``
with a default layout: a top view of the junction and one space-time chart
per approach (incoming edge), where a confirmed plan and the vehicle's actual
progress can be compared.

Frames. Rerun's 2D views are y-down, so the top view logs (x, -y) to keep
north up, and the space-time charts log (CHART_M_PER_S * t [s], -s [m]) so
that distance along the route grows upwards and 1 s of time is drawn as long
as CHART_M_PER_S metres of road: speeds show as slopes. All data
is on the ``sim_time`` timeline (a duration). Entity paths are listed in
``docs/recording.md``.

Cost. A Rerun log call costs 0.1-0.5 ms, more than a whole step's worth of
budget for a handful of them, so per-step data (footprints, progress, counts)
is buffered and sent as one column chunk per entity every ``batch_steps``
steps; a confirmation is logged at once (it is rare and carries its whole
future as one column chunk).
"""

from __future__ import annotations

import colorsys
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ica.core.intersection import Intersection
from ica.core.route import Route

TIMELINE = "sim_time"
LANE_WIDTH_M = 3.2  # [m] SUMO's default; to draw entry lines and to tell "on the route"
_STRIP_RADIUS_M = 0.08  # [m] line half-width in the top view
_POINT_RADIUS = 0.25  # [scene units] progress points in the space-time charts
_FLIP_Y = np.array([1.0, -1.0])
TICK_S = 10.0  # [s] time grid of the space-time charts
CHART_M_PER_S = 3.0  # [m] chart width of 1 s: a 15 m/s vehicle climbs at 5:1, not 15:1
CHART_WINDOW_S = 40.0  # [s] of history each chart shows before the time cursor
_GRID_COLOR = (190, 190, 190)
_ACTUAL_SHADE = 0.55  # actual progress: the vehicle's colour, darker than its plan


def approach_of(lane: str) -> str:
    """The incoming edge of a lane id (``N_in_2`` -> ``N_in``): one chart per edge."""
    return lane.rsplit("_", 1)[0]


def rectangles(
    x_m: np.ndarray,
    y_m: np.ndarray,
    heading_rad: np.ndarray,
    length_m: np.ndarray | float,
    width_m: np.ndarray | float,
) -> np.ndarray:
    """Closed outlines (N, 5, 2) of vehicles given by front-bumper centre and heading.

    Heading is counter-clockwise from +x. The outline is in the viewer's
    frame, (x, -y), because ``Boxes2D`` cannot rotate and 2D views are y-down.
    """
    x = np.asarray(x_m, dtype=float).reshape(-1)
    y = np.asarray(y_m, dtype=float).reshape(-1)
    h = np.asarray(heading_rad, dtype=float).reshape(-1)
    half_l = np.broadcast_to(np.asarray(length_m, dtype=float), x.shape) / 2.0
    half_w = np.broadcast_to(np.asarray(width_m, dtype=float), x.shape) / 2.0
    c, s = np.cos(h), np.sin(h)
    cx, cy = x - c * half_l, y - s * half_l  # centre = front - heading * length / 2
    # corners as (along, across) multiples: front-left, front-right, rear-right, rear-left
    along = np.array([1.0, 1.0, -1.0, -1.0, 1.0])
    across = np.array([1.0, -1.0, -1.0, 1.0, 1.0])
    dl = along[None, :] * half_l[:, None]
    dw = across[None, :] * half_w[:, None]
    px = cx[:, None] + dl * c[:, None] - dw * s[:, None]
    py = cy[:, None] + dl * s[:, None] + dw * c[:, None]
    return np.stack([px, -py], axis=-1)


def sumo_heading_rad(angle_deg: np.ndarray) -> np.ndarray:
    """SUMO's angle (degrees, 0 = north, clockwise) as radians CCW from +x."""
    return np.pi / 2.0 - np.radians(np.asarray(angle_deg, dtype=float))


def vehicle_color(vin: str) -> int:
    """A colour (0xRRGGBBAA) fixed by the VIN, so plan, footprint and progress match."""
    hue = (zlib.crc32(vin.encode()) % 360) / 360.0
    r, g, b = (round(c * 255) for c in colorsys.hsv_to_rgb(hue, 0.75, 0.95))
    return (r << 24) | (g << 16) | (b << 8) | 0xFF


class RouteProjector:
    """``Route.project`` for many vehicles on different routes in one numpy pass.

    Routes are padded to the same number of segments by repeating their last
    segment, which changes no nearest point. Saves a Python loop per route
    every step.
    """

    def __init__(self, routes: Sequence[Route]) -> None:
        self.index = {r.id: i for i, r in enumerate(routes)}
        n_seg = max(len(r.xy) for r in routes) - 1
        a = np.empty((len(routes), n_seg, 2))
        d = np.empty_like(a)
        s0 = np.empty((len(routes), n_seg))
        for i, r in enumerate(routes):
            m = len(r.xy) - 1
            pad = [*range(m), *([m - 1] * (n_seg - m))]
            a[i] = r.xy[:-1][pad]
            d[i] = (r.xy[1:] - r.xy[:-1])[pad]
            s0[i] = r.s[:-1][pad]
        self._a, self._d, self._s0 = a, d, s0
        self._len2 = np.einsum("rij,rij->ri", d, d)

    def project(self, route_idx: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length [m] and distance to the route [m] of each point on its own route."""
        a, d, len2 = self._a[route_idx], self._d[route_idx], self._len2[route_idx]
        w = xy[:, None, :] - a
        u = np.clip(np.einsum("nij,nij->ni", w, d) / len2, 0.0, 1.0)
        dist2 = np.sum((w - u[..., None] * d) ** 2, axis=-1)
        k = np.argmin(dist2, axis=1)
        rows = np.arange(len(xy))
        s = self._s0[route_idx, k] + u[rows, k] * np.sqrt(len2[rows, k])
        return s, np.sqrt(dist2[rows, k])


class _Rows:
    """Rows of one entity, kept until they are sent as one column chunk."""

    def __init__(self, entity: str, archetype: Any) -> None:
        self.entity = entity
        self.archetype = archetype
        self.times: list[float] = []
        self.lengths: list[int] = []
        self.fields: dict[str, list[Any]] = {}

    def add(self, t_s: float, n: int, **fields: Any) -> None:
        self.times.append(t_s)
        self.lengths.append(n)
        for k, v in fields.items():
            self.fields.setdefault(k, []).append(v)

    def send(self, rec: rr.RecordingStream) -> None:
        if not self.times:
            return
        data = {k: _joined(v) for k, v in self.fields.items()}
        cols = self.archetype.columns(**data).partition(self.lengths)
        rec.send_columns(
            self.entity, indexes=[rr.TimeColumn(TIMELINE, duration=self.times)], columns=cols
        )
        self.times, self.lengths, self.fields = [], [], {}


def _joined(parts: list[Any]) -> Any:
    """Rows of one field as one batch; floats as float32, which Rerun converts twice as fast."""
    if isinstance(parts[0], list):
        return [x for part in parts for x in part]
    joined = np.concatenate(parts)
    return joined.astype(np.float32) if joined.dtype == np.float64 else joined


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
        batch_steps: int = 20,
        window_s: float = CHART_WINDOW_S,
    ) -> None:
        self.intersection = intersection
        self.window_s = window_s
        self.path = Path(path)
        self.batch_steps = max(1, batch_steps)
        self.approaches: tuple[str, ...] = tuple(
            sorted({approach_of(lane) for lane in intersection.in_lanes})
        )
        self._approach_of_route = {r.id: approach_of(r.in_lane) for r in intersection.routes}
        self._projector = RouteProjector(intersection.routes)
        self._route_approach = np.array(
            [self.approaches.index(approach_of(r.in_lane)) for r in intersection.routes]
        )
        self._route_end_m = np.array([r.s_max for r in intersection.routes])
        self._chart_top_m = [
            max(r.cross_length_m for r in intersection.routes if approach_of(r.in_lane) == a)
            for a in self.approaches
        ]
        self._colors: dict[str, int] = {}
        self._next_tick = 0.0
        self._n_confirmed = 0
        self._pending = 0
        self._vehicles = _Rows("junction/vehicles", rr.LineStrips2D)
        self._count = _Rows("counts/vehicles", rr.Scalars)
        self._actual = {a: _Rows(f"spacetime/{a}/actual", rr.Points2D) for a in self.approaches}

        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.rec.set_log_time_enabled(False)  # only sim_time: wall clock would mislead
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(self.path, default_blueprint=self.blueprint())
        # sizes that never change, logged once so the batched rows carry only data
        self.rec.log(
            "junction/vehicles", rr.LineStrips2D.from_fields(radii=_STRIP_RADIUS_M), static=True
        )
        for a in self.approaches:
            self.rec.log(
                f"spacetime/{a}/actual", rr.Points2D.from_fields(radii=_POINT_RADIUS), static=True
            )

    def __enter__(self) -> SpaceTimeRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- layout --------------------------------------------------------------
    def blueprint(self) -> rrb.Blueprint:
        """Top view and counts on the left, one space-time chart per approach on the right.

        The charts show the ``window_s`` before the time cursor (not just the
        latest data), so plans and progress form lines as the run is replayed,
        and the chart moves along with the cursor instead of squeezing the
        whole run into one view.
        """
        reach = self.intersection.comm_length_m + 10.0
        top = rrb.Spatial2DView(
            origin="junction",
            name="junction (north up)",
            visual_bounds=rrb.VisualBounds2D(x_range=[-reach, reach], y_range=[-reach, reach]),
        )
        history = rrb.VisibleTimeRange(
            TIMELINE,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-self.window_s),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        )
        charts = [
            rrb.Spatial2DView(
                origin=f"spacetime/{a}", name=f"{a}: distance up, time right", time_ranges=history
            )
            for a in self.approaches
        ]
        counts = rrb.Vertical(
            rrb.TimeSeriesView(origin="counts/vehicles", name="vehicles in the region"),
            rrb.TimeSeriesView(origin="counts/confirmed", name="confirmations so far"),
        )
        left = rrb.Vertical(
            top,
            rrb.Horizontal(
                counts,
                rrb.TextLogView(origin="events", name="confirmations"),
                column_shares=[1, 2],
            ),
            row_shares=[3, 2],
        )
        return rrb.Blueprint(
            rrb.Horizontal(left, rrb.Grid(*charts)),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="expanded"),
        )

    # -- static geometry -----------------------------------------------------
    def geometry(self) -> None:
        """Junction area, routes (from the communication region's entry line on), entry lines."""
        inter = self.intersection
        region = np.asarray(inter.region, dtype=float)
        outline = np.vstack([region, region[:1]]) * _FLIP_Y
        self.rec.log(
            "junction/region", rr.LineStrips2D([outline], colors=[(200, 200, 200)]), static=True
        )
        paths = [_clipped(r, -inter.comm_length_m) * _FLIP_Y for r in inter.routes]
        self.rec.log(
            "junction/routes",
            rr.LineStrips2D(
                paths,
                radii=0.05,
                colors=[(110, 110, 110)],
                labels=[r.id for r in inter.routes],
                show_labels=False,
            ),
            static=True,
        )
        first_route: dict[str, Route] = {}
        for r in inter.routes:
            first_route.setdefault(r.in_lane, r)
        lanes = sorted(first_route)
        for name, s in (("entry_lines", 0.0), ("comm_entry_lines", -inter.comm_length_m)):
            segs = [_across(first_route[lane], s) for lane in lanes]
            self.rec.log(
                f"junction/{name}",
                rr.LineStrips2D(
                    segs, radii=0.1, colors=[(240, 240, 240)], labels=lanes, show_labels=False
                ),
                static=True,
            )

    # -- confirmations -------------------------------------------------------
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
    ) -> None:
        """One confirmation, logged at ``now_s`` (default: the TSS's first time).

        The planned footprint goes to the top view as a time series (one
        column send for the whole future, cleared one step after the last
        sample); the plan's distance-time line and its junction occupancy box
        [entry, exit] x [0, cross length] go to the approach's chart.
        """
        route = self._route(route_id)
        t = np.asarray(t_s, dtype=float)
        n = len(t)
        if n == 0 or not all(len(a) == n for a in (x_m, y_m, heading_rad)):
            raise ValueError(f"{vin}: TSS arrays must be non-empty and of equal length")
        now = float(t[0]) if now_s is None else float(now_s)
        color = self._color(vin)
        part = rr.escape_entity_path_part(vin)

        planned = f"junction/planned/{part}"
        step = float(t[-1] - t[-2]) if n > 1 else 0.05
        times = np.append(t, t[-1] + step)  # the extra, empty row clears the footprint
        rects = rectangles(x_m, y_m, heading_rad, length_m, width_m)
        self.rec.send_columns(
            planned,
            indexes=[rr.TimeColumn(TIMELINE, duration=times)],
            columns=rr.LineStrips2D.columns(strips=rects).partition([1] * n + [0]),
        )
        self.rec.log(
            planned,
            rr.LineStrips2D.from_fields(colors=[color], radii=_STRIP_RADIUS_M),
            static=True,
        )

        self.rec.set_time(TIMELINE, duration=now)
        s, _ = route.project(np.stack([np.asarray(x_m), np.asarray(y_m)], axis=-1))
        chart = f"spacetime/{self._approach_of_route[route_id]}"
        self.rec.log(
            f"{chart}/plan/{part}",
            rr.LineStrips2D(
                [np.stack([t * CHART_M_PER_S, -s], axis=-1)],
                colors=[color],
                labels=[vin],
                show_labels=False,
            ),
        )
        self.rec.log(
            f"{chart}/occupancy/{part}",
            rr.Boxes2D(
                mins=[(entry_time_s * CHART_M_PER_S, -route.cross_length_m)],
                sizes=[((exit_time_s - entry_time_s) * CHART_M_PER_S, route.cross_length_m)],
                colors=[color & 0xFFFFFF00 | 90],  # translucent fill
                labels=[vin],
                show_labels=False,
            ),
        )
        self._n_confirmed += 1
        self.rec.log("counts/confirmed", rr.Scalars(self._n_confirmed))
        self.rec.log(
            "events",
            rr.TextLog(
                f"{vin} on {route_id}: enters {entry_time_s:.2f} s, "
                f"leaves {exit_time_s:.2f} s (confirmed at {now:.2f} s)",
                level="INFO",
            ),
        )

    # -- what really happened ------------------------------------------------
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
        vanish from the top view. With ``route_ids`` (None or "" where the
        route is not known yet) the distance along the route is projected from
        the front bumper and recorded as :meth:`progress`.
        """
        n = len(vins)
        x = np.asarray(x_m, dtype=float).reshape(-1)
        y = np.asarray(y_m, dtype=float).reshape(-1)
        if not len(x) == len(y) == len(np.atleast_1d(angle_deg)) == n:
            raise ValueError("footprints: vins, x_m, y_m and angle_deg must have equal length")
        colors = self._colors_of(vins)
        strips = rectangles(x, y, sumo_heading_rad(angle_deg), length_m, width_m)
        self._grid(float(t_s))
        self._vehicles.add(float(t_s), n, strips=strips, colors=colors, labels=list(vins))
        self._count.add(float(t_s), 1, scalars=np.array([float(n)]))
        if route_ids is not None:
            if len(route_ids) != n:
                raise ValueError("footprints: route_ids must have one entry per vehicle")
            known = np.array([bool(r) for r in route_ids], dtype=bool)
            ridx = self._route_indices([r for r in route_ids if r])
            s, dist = self._projector.project(ridx, np.stack([x[known], y[known]], axis=-1))
            self._add_progress(float(t_s), ridx, colors[known], s, dist)
        self._step()

    def progress(
        self,
        t_s: float,
        vins: Sequence[str],
        route_ids: Sequence[str],
        s_m: np.ndarray,
    ) -> None:
        """Actual distance along the route [m] (0 = entry line), for callers that know it.

        Use either this or ``footprints(..., route_ids=...)`` for a step, not both.
        """
        s = np.asarray(s_m, dtype=float).reshape(-1)
        if not len(vins) == len(route_ids) == len(s):
            raise ValueError("progress: vins, route_ids and s_m must have equal length")
        ridx = self._route_indices(route_ids)
        self._grid(float(t_s))
        self._add_progress(float(t_s), ridx, self._colors_of(vins), s, np.zeros_like(s))
        self._step()

    def _grid(self, t_s: float) -> None:
        """Every TICK_S of sim time, a time tick with its label and the entry lines
        in each chart: a 2D view has no axes of its own."""
        while t_s >= self._next_tick - 1e-9:
            t0 = self._next_tick
            x0, x1 = t0 * CHART_M_PER_S, (t0 + TICK_S) * CHART_M_PER_S
            self.rec.set_time(TIMELINE, duration=t0)
            comm = self.intersection.comm_length_m
            for a, top in zip(self.approaches, self._chart_top_m, strict=True):
                lines = [
                    [(x0, comm), (x0, -top)],  # the tick
                    [(x0, 0.0), (x1, 0.0)],  # the junction's entry line
                    [(x0, comm), (x1, comm)],  # the communication region's
                ]
                self.rec.log(
                    f"spacetime/{a}/grid",
                    rr.LineStrips2D(lines, colors=[_GRID_COLOR], radii=0.05, draw_order=0.0),
                )
                self.rec.log(
                    f"spacetime/{a}/grid_time",
                    rr.Points2D(
                        [(x0, comm)], radii=0.01, colors=[_GRID_COLOR], labels=[f"{t0:g} s"]
                    ),
                )
            self._next_tick += TICK_S

    def flush(self) -> None:
        """Send the buffered rows now (also done every ``batch_steps`` steps and on close)."""
        for rows in (self._vehicles, self._count, *self._actual.values()):
            rows.send(self.rec)
        self._pending = 0

    def close(self) -> None:
        """Send what is buffered and finish the file (Rerun writes its footer on disconnect)."""
        self.flush()
        self.rec.flush()
        self.rec.disconnect()

    # -- helpers -------------------------------------------------------------
    def _add_progress(
        self, t_s: float, ridx: np.ndarray, colors: np.ndarray, s: np.ndarray, dist: np.ndarray
    ) -> None:
        """Points inside the chart's extent only: from the communication region's
        entry line to the route's end, and on the route (not clamped onto its end)."""
        in_chart = (s >= -self.intersection.comm_length_m) & (s < self._route_end_m[ridx])
        keep = in_chart & (dist <= LANE_WIDTH_M)
        appr = self._route_approach[ridx]
        for i, a in enumerate(self.approaches):
            sel = keep & (appr == i)
            if sel.any():
                x = np.full(int(sel.sum()), t_s * CHART_M_PER_S)
                pts = np.stack([x, -s[sel]], axis=-1)
                self._actual[a].add(t_s, len(pts), positions=pts, colors=_darker(colors[sel]))

    def _step(self) -> None:
        self._pending += 1
        if self._pending >= self.batch_steps:
            self.flush()

    def _route(self, route_id: str) -> Route:
        route = self.intersection.route_by_id(route_id)
        if route is None:
            raise ValueError(f"unknown route {route_id!r}")
        return route

    def _route_indices(self, route_ids: Sequence[str | None]) -> np.ndarray:
        try:
            return np.array([self._projector.index[r] for r in route_ids], dtype=int)
        except KeyError as e:
            raise ValueError(f"unknown route {e.args[0]!r}") from None

    def _color(self, vin: str) -> int:
        c = self._colors.get(vin)
        if c is None:
            c = self._colors[vin] = vehicle_color(vin)
        return c

    def _colors_of(self, vins: Sequence[str]) -> np.ndarray:
        return np.fromiter((self._color(v) for v in vins), dtype=np.uint32, count=len(vins))


def _darker(rgba: np.ndarray) -> np.ndarray:
    """The same colours (packed 0xRRGGBBAA), each channel scaled by _ACTUAL_SHADE."""
    c = rgba.astype(np.uint32)
    out = c & np.uint32(0xFF)
    for shift in (8, 16, 24):
        channel = (c >> np.uint32(shift)) & np.uint32(0xFF)
        out |= (channel * _ACTUAL_SHADE).astype(np.uint32) << np.uint32(shift)
    return out


def _clipped(route: Route, s_from: float) -> np.ndarray:
    """The route's polyline from arc length ``s_from`` on."""
    return np.vstack([route.points(s_from)[None], route.xy[route.s > s_from]])


def _across(route: Route, s: float) -> np.ndarray:
    """A lane-wide segment across the route at arc length ``s``, in the viewer frame."""
    a, b = route.points(s - 0.5), route.points(s + 0.5)
    d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
    n = np.array([-d[1], d[0]]) * LANE_WIDTH_M / 2.0
    p = route.points(s)
    return np.array([p - n, p + n]) * _FLIP_Y
