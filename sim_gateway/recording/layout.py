"""The viewer's layout (Rerun's blueprint): which view shows what, and where.

Top view and conflict points on the left; the lane charts in a grid (a column
per approach, a row per lane index), counts and tables on the right; the
viewer opens paused, its panels folded. Every lane chart has the same window
and distance scale, so lanes can be compared side by side.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import rerun.blueprint as rrb

from dica.ica.core.intersection import Intersection
from dica.sim_gateway.recording.chart_frame import (
    CHART_M_PER_S,
    FUTURE_S,
    HISTORY_S,
    PAST_S,
    ROW_M,
)
from dica.sim_gateway.recording.geometry import approach_of, lane_major
from dica.sim_gateway.recording.rows import TIMELINE
from dica.sim_gateway.recording.top_view import frame_reach


@dataclass(frozen=True, slots=True, eq=False)
class Layout:
    """The views of one junction's recording. ``top_m``: the lane charts' highest
    distance [m]; ``n_points``: the conflict points (rows of their chart)."""

    intersection: Intersection
    top_m: float
    n_points: int

    def chart_bounds(self) -> rrb.VisualBounds2D:
        """The one window and distance scale every space-time chart shares."""
        k = CHART_M_PER_S
        return rrb.VisualBounds2D(
            x_range=[-PAST_S * k - 24.0, FUTURE_S * k + 2.0],
            y_range=[-self.top_m - 2.0, self.intersection.comm_length_m + 4.0],
        )

    def zone_bounds(self) -> rrb.VisualBounds2D:
        k = CHART_M_PER_S
        n = max(self.n_points, 1)
        return rrb.VisualBounds2D(
            x_range=[-PAST_S * k - 38.0, FUTURE_S * k + 2.0], y_range=[-3.0, n * ROW_M + 5.5]
        )

    def views(self) -> dict[str, Any]:
        """Every view by name: top, zones, counts, confirmed, rejected, reorders and one
        per lane (its lane id); ``tools/screenshots.py`` shows them one by one."""
        reach = frame_reach(self.intersection)
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
        lanes = lane_major(self.intersection.in_lanes)
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
        views = dict(zip(lanes, charts, strict=True))
        views.update(top=top, zones=zones, **_tables())
        return views

    def blueprint(self) -> rrb.Blueprint:
        """Top view and conflict points on the left; lane charts, counts and tables on
        the right; paused at the start, the time panel folded to its play bar."""
        v = self.views()
        lanes = lane_major(self.intersection.in_lanes)
        n_cols = len({approach_of(ln) for ln in lanes})
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


def _tables() -> dict[str, Any]:
    """The counts and the three tables, each titled with its columns."""
    columns = rrb.TextLogColumns(
        timeline_columns=[rrb.encodings.TimelineColumn(TIMELINE)],
        text_log_columns=[
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.Body),
        ],
    )
    mono = rrb.TextLogFormat(monospace_body=True)
    titles = {
        "confirmed": "confirmed: VIN, route, entry s, exit s, delay s, rounds",
        "rejected": "rejected: VIN, reason",
        "reorders": "reorders: EV, solver, EV entry s before, after, order (* revoked)",
    }
    counts = rrb.TimeSeriesView(
        origin="counts", name="counts", plot_legend=rrb.PlotLegend(corner="LeftTop")
    )
    tables = {
        key: rrb.TextLogView(
            origin=f"tables/{key}", name=title, columns=columns, format_options=mono
        )
        for key, title in titles.items()
    }
    return {"counts": counts, **tables}
