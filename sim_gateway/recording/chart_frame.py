"""What every chart shares: the time scale and window, the "now" line, the shift
that keeps "now" in place, and the time ticks.

Rerun's 2D views have fixed bounds, so chart data is logged at
``(CHART_M_PER_S * t, y)`` under ``charts/data``, and a transform on
``charts/data`` shifts it by ``-CHART_M_PER_S * t_now`` every chart step:
"now" is always at x = 0, the window is the same for every chart, and the
frame (axis labels, the entry and exit lines, "now") is static.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from dica.sim_gateway.recording.rows import RowBuffer
from dica.sim_gateway.recording.style import GRID_RGB, NOW_RGBA, rgba

CHART_M_PER_S = 2.0  # [chart units] width of 1 s in the charts
PAST_S = 40.0  # [s] of history every chart shows left of "now"
FUTURE_S = 20.0  # [s] of plans every chart shows right of "now"
HISTORY_S = PAST_S  # [s] rows logged this long before the cursor are drawn
CHART_EVERY = 5  # chart samples every 5 steps (0.25 s)
TICK_S = 10.0  # [s] time grid of the charts
ROW_M = 5.0  # [chart units] pitch of the conflict-point rows


class ChartFrame:
    """The "now" line across both kinds of chart, the shift, and the time ticks.

    The lane charts run from ``-top_m`` (the highest exit, viewer frame) down
    to the communication region's start; the conflict-point chart from 0 down
    to ``n_points`` rows.
    """

    def __init__(self, rows: RowBuffer, top_m: float, n_points: int) -> None:
        self._rows = rows
        self._top_m = top_m
        self._n_points = n_points
        self._tick_enter = 0.0  # next tick to log as it enters the window
        self._tick_at = 0.0  # next tick to log at its own time

    def now_line(self, rec: rr.RecordingStream, comm_m: float) -> None:
        """The static "now" line, labelled, at x = 0 in every chart."""
        n = self._n_points
        rec.log(
            "charts/frame/now",
            rr.LineStrips2D(
                [
                    [(0.0, -self._top_m - 2.0), (0.0, comm_m + 4.0)],
                    [(0.0, -3.0), (0.0, n * ROW_M)],
                ],
                radii=0.25,
                colors=[NOW_RGBA],
                draw_order=30.0,
            ),
            static=True,
        )
        rec.log(
            "charts/frame/now/label",
            rr.Points2D(
                [(0.0, -self._top_m + 3.0), (0.0, n * ROW_M + 2.5)],
                radii=0.01,
                labels=["now", "now"],
                show_labels=True,
            ),
            static=True,
        )

    def shift(self, times: np.ndarray) -> None:
        """The transform that moves the chart data by ``-CHART_M_PER_S * t`` at each time."""
        k = CHART_M_PER_S
        self._rows.add_many(
            "charts/data",
            rr.Transform3D,
            times,
            np.ones(len(times), int),
            translation=np.stack([-k * times, np.zeros_like(times), np.zeros_like(times)], -1),
        )

    def ticks(self, t_s: float, start_s: float) -> None:
        """A labelled time tick every TICK_S. A chart shows the rows of the last PAST_S,
        so each tick is logged twice: when it enters the window (FUTURE_S ahead of
        its time) and at its time; never later than the run has got, nor before the
        recording's start ``start_s``."""
        while self._tick_enter <= t_s + FUTURE_S + 1e-9:
            self._tick(self._tick_enter, max(self._tick_enter - FUTURE_S, start_s))
            self._tick_enter += TICK_S
        while self._tick_at <= t_s + 1e-9:
            self._tick(self._tick_at, max(self._tick_at, start_s))
            self._tick_at += TICK_S

    def _tick(self, t0: float, at: float) -> None:
        x = t0 * CHART_M_PER_S
        n = max(self._n_points, 1)
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
