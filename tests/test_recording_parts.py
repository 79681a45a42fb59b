"""Parts of the recording alone: the row buffer, a batch of steps, the charts' time
ticks and the layout's grid, each written through a real Rerun stream and read
back with Rerun's own reader where it sends rows."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from dica.ica.core.intersection import Intersection
from dica.sim_gateway.conflict_points import Holding
from dica.sim_gateway.recording import Status
from dica.sim_gateway.recording.batch import Plan, Step, StepBatch
from dica.sim_gateway.recording.chart_frame import FUTURE_S, TICK_S, ChartFrame
from dica.sim_gateway.recording.geometry import RouteProjector, approach_of, lane_major
from dica.sim_gateway.recording.layout import Layout
from dica.sim_gateway.recording.rows import MAX_ROWS, RowBuffer


def _send(path: Path, rows: RowBuffer, *batches: Callable[[], bool]) -> None:
    """Each batch adds rows and says whether to send everything; then the file ends."""
    rec = rr.RecordingStream("test", recording_id="parts")
    rec.set_log_time_enabled(False)
    rec.set_sinks(rr.FileSink(str(path)))
    for fill in batches:
        rows.send(rec, everything=fill())
    rec.flush()
    rec.disconnect()


def _chunks(path: Path, entity: str) -> list[pa.RecordBatch]:
    return [c.to_record_batch() for c in RrdReader(path).stream() if str(c.entity_path) == entity]


def _rows(path: Path, entity: str, column: str) -> list[tuple[float, object]]:
    """(sim_time [s], value) of every row of one component, in the order they were sent."""
    out = []
    for b in _chunks(path, entity):
        times = b.column("sim_time").cast(pa.int64()).to_pylist()
        out += zip((t / 1e9 for t in times), b.column(column).to_pylist(), strict=True)
    return out


def test_rows_added_out_of_time_order_go_out_in_time_order_with_their_own_instances(tmp_path):
    rows = RowBuffer({"e": {"radii": 0.5}})

    def fill() -> bool:
        pos = np.array([[2.0, 0.0], [2.0, 1.0]], np.float32)
        rows.add("e", rr.Points2D, 2.0, 2, positions=pos, labels=["b1", "b2"])
        rows.add_many(
            "e", rr.Points2D, np.array([3.0, 0.5]), np.array([1, 0]),
            positions=np.array([[3.0, 0.0]], np.float32), labels=["c"],
        )  # fmt: skip
        rows.add("e", rr.Points2D, 1.0, 1, positions=np.array([[1.0, 0.0]]), labels=["a"])
        return True

    _send(tmp_path / "r.rrd", rows, fill)
    labels = _rows(tmp_path / "r.rrd", "/e", "Points2D:labels")
    assert labels == [(0.5, []), (1.0, ["a"]), (2.0, ["b1", "b2"]), (3.0, ["c"])]
    xs = [[p[0] for p in v] for _, v in _rows(tmp_path / "r.rrd", "/e", "Points2D:positions")]
    assert xs == [[], [1.0], [2.0, 2.0], [3.0]]
    radii = [v for _, v in _rows(tmp_path / "r.rrd", "/e", "Points2D:radii")]
    assert radii == [[0.5]] * 4  # the style rides along once with every row


def test_an_entity_goes_out_as_one_chunk_once_it_holds_max_rows(tmp_path):
    rows = RowBuffer({})
    t = iter(np.arange(MAX_ROWS + 2) * 0.05)

    def add(n: int, everything: bool) -> Callable[[], bool]:
        def fill() -> bool:
            times = np.array([next(t) for _ in range(n)])
            rows.add_many("n", rr.Scalars, times, np.ones(n, int), scalars=np.ones(n))
            return everything

        return fill

    # one short of the limit: kept; at the limit: sent; the rest only when asked
    _send(tmp_path / "m.rrd", rows, add(MAX_ROWS - 1, False), add(1, False), add(1, False),
          add(1, True))  # fmt: skip
    assert [b.num_rows for b in _chunks(tmp_path / "m.rrd", "/n")] == [MAX_ROWS, 2]


def test_a_row_is_logged_again_when_what_it_draws_ends_unless_forgotten(tmp_path):
    rows = RowBuffer({})

    def plan(label: str) -> dict:
        return {"positions": np.zeros((1, 2), np.float32), "labels": [label]}

    def fill() -> bool:
        rows.again(5.0, 1.0, "p", rr.Points2D, 1, plan("v1 plan"))
        rows.again(1.0, 1.0, "p", rr.Points2D, 1, plan("v2 plan"))  # ends now: once is enough
        rows.again(6.0, 1.0, "p", rr.Points2D, 1, plan("v10 plan"))
        rows.again(7.0, 1.0, "p", rr.Points2D, 1, plan("v1 P3 1.00-7.00 s"))
        rows.due(5.0 - 1e-6)  # not yet
        rows.forget(("v1 plan", "v1 P"))  # v1's plan withdrawn; v10 is another vehicle
        rows.due(100.0)
        return True

    _send(tmp_path / "a.rrd", rows, fill)
    assert _rows(tmp_path / "a.rrd", "/p", "Points2D:labels") == [(6.0, ["v10 plan"])]


def test_a_plan_holds_its_vehicle_from_its_confirmation_until_its_withdrawal(ch45):
    """To the step: confirmed at the confirmation's own time, no longer at the
    withdrawal's; a vehicle on no known route is requesting; an EV is an EV."""
    route = next(r for r in ch45.routes if r.turn == "through")
    proj = RouteProjector(ch45.routes)
    x, y = route.points(-10.0)
    empty = np.zeros(0)
    plan = Plan(1.0, proj.index[route.id], route.cross_length_m + 5.0, 1.0,
                np.zeros((0, 5, 2), np.float32), Holding(empty.astype(int), empty, empty),
                until_s=2.0)  # fmt: skip
    times = [0.95, 1.0, 1.05, 1.95, 2.0, 2.05]
    steps = [
        Step(t, ["a", "b", "ev"], np.array([x, 0.0, x]), np.array([y, 0.0, y]),
             np.zeros(3), np.full(3, 5.0), np.full(3, 1.8),
             np.array([proj.index[route.id], -1, proj.index[route.id]]))
        for t in times
    ]  # fmt: skip
    batch = StepBatch.of(steps, 7, proj, {"a": plan}, {"ev"})
    a = batch.state[0::3]
    assert list(a) == [Status.REQUESTING, *[Status.CONFIRMED] * 3, *[Status.REQUESTING] * 2]
    assert list(batch.confirmed[0::3]) == [False, True, True, True, False, False]
    assert np.isnan(batch.s[1]) and np.isinf(batch.dist[1])
    assert set(batch.state[1::3]) == {Status.REQUESTING}
    assert set(batch.state[2::3]) == {Status.EMERGENCY}
    assert batch.s[0] == pytest.approx(-10.0, abs=1e-6)
    assert list(batch.every(2)) == [False, True, False, True, False, True]  # steps 7..12


def test_a_tick_enters_the_window_ahead_of_its_time_and_never_before_the_start(tmp_path):
    rows = RowBuffer({})
    frame = ChartFrame(rows, top_m=30.0, n_points=4)

    def fill(t_s: float) -> Callable[[], bool]:
        def f() -> bool:
            frame.ticks(t_s, start_s=3.0)
            return False

        return f

    _send(tmp_path / "t.rrd", rows, fill(25.0), fill(25.5), fill(30.0), lambda: True)
    got = sorted(
        (t, lb) for t, (lb,) in _rows(tmp_path / "t.rrd", "/charts/data/ticks/lane_labels",
                                      "Points2D:labels")
    )  # fmt: skip
    entering = [(max(k * TICK_S - FUTURE_S, 3.0), f"{k * TICK_S:g} s") for k in range(6)]
    at_time = [(max(k * TICK_S, 3.0), f"{k * TICK_S:g} s") for k in range(4)]
    assert got == sorted(entering + at_time)  # each once on entering and once at its time
    lines = _rows(tmp_path / "t.rrd", "/charts/data/ticks/lines", "LineStrips2D:strips")
    assert len(lines) == len(got)


@pytest.mark.parametrize("layout", ["ch45", "tee"])
def test_the_lane_charts_form_a_grid_with_a_column_per_approach_and_a_row_per_lane(layout, request):
    inter: Intersection = request.getfixturevalue(layout)
    bp = Layout(inter, top_m=30.0, n_points=5).blueprint()
    _left, right = bp.root_container.contents
    grid = right.contents[0]
    approaches = sorted({approach_of(ln) for ln in inter.in_lanes})
    assert grid.grid_columns == len(approaches)
    names = [v.name.split(":")[0] for v in grid.contents]
    assert names == lane_major(inter.in_lanes)
    # row r holds lane index r of every approach
    for r in range(len(names) // len(approaches)):
        row = names[r * len(approaches) : (r + 1) * len(approaches)]
        assert {ln.rsplit("_", 1)[1] for ln in row} == {str(r)}
        assert [approach_of(ln) for ln in row] == approaches


def test_a_packed_style_colour_over_three_rows_draws_without_a_warning(tmp_path):
    """A style's packed colour (0xRRGGBBAA) repeated over three or four rows reads, as a
    plain list, like one colour's channels: Rerun warned in every live observer's log."""
    import warnings

    import rerun as rr

    from dica.sim_gateway.recording.rows import EntityRows

    rec = rr.RecordingStream("t")
    rec.set_sinks(rr.FileSink(str(tmp_path / "w.rrd")))
    for n in (3, 4):
        rows = EntityRows("x", rr.Points2D, {"colors": 0x102030FF})
        for t in range(n):
            rows.add(float(t), 1, positions=np.zeros((1, 2)))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rows.send(rec)
    rec.disconnect()
