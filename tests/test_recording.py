"""The Rerun recording, read back with Rerun's own reader, and ``dica view``.

Confirmations come from the real DICA core on the real chapter 4-5 junction;
the "actual" vehicles fly exactly their confirmed TSS, so what the recording
holds can be checked against numbers computed here independently.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from ica.core.dica import Dica
from ica.core.intersection import Intersection
from ica.core.proposal import propose
from ica.core.request import Confirmation
from sim_gateway.recording import (
    CHART_M_PER_S,
    RouteProjector,
    SpaceTimeRecorder,
    approach_of,
    rectangles,
    sumo_heading_rad,
)
from tools.cli import main as dica

LENGTH_M, WIDTH_M = 5.0, 1.8
N_STEPS = 40  # actual steps recorded, then one step with no vehicles


def _confirmations(inter: Intersection) -> list[Confirmation]:
    """One head vehicle per approach, through movements, confirmed by the real core."""
    ica = Dica(inter)
    out = []
    for k, appr in enumerate(sorted({approach_of(r.in_lane) for r in inter.routes})):
        route = next(
            r for r in inter.routes if approach_of(r.in_lane) == appr and r.turn == "through"
        )
        vin = f"veh/{k}"  # a slash, to check the entity path is escaped
        ica.detect(vin, route.in_lane, 0.0)
        req = propose(route, vin=vin, seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=12.0)
        conf = ica.handle(req, 0.0)
        assert isinstance(conf, Confirmation), conf
        out.append(conf)
    return out


def _sumo_angle_deg(heading_rad: np.ndarray) -> np.ndarray:
    return 90.0 - np.degrees(heading_rad)  # CCW from +x -> clockwise from north


@pytest.fixture(scope="module")
def recorded(ch45: Intersection, tmp_path_factory: pytest.TempPathFactory):
    confs = _confirmations(ch45)
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    rec = SpaceTimeRecorder(ch45, path, batch_steps=7)  # batches that do not divide N_STEPS
    rec.geometry()
    for c in confs:
        tss = c.tss
        rec.confirmed(
            c.vin, c.route_id, tss.t_s, tss.x_m, tss.y_m, tss.heading_rad,
            LENGTH_M, WIDTH_M, c.entry_time_s, c.exit_time_s,
        )  # fmt: skip
    vins = [c.vin for c in confs]
    for i in range(N_STEPS):
        rec.footprints(
            float(confs[0].tss.t_s[i]),
            vins,
            np.array([c.tss.x_m[i] for c in confs]),
            np.array([c.tss.y_m[i] for c in confs]),
            _sumo_angle_deg(np.array([c.tss.heading_rad[i] for c in confs])),
            LENGTH_M,
            WIDTH_M,
            route_ids=[c.route_id for c in confs],
        )
    rec.footprints(N_STEPS * 0.05, [], np.zeros(0), np.zeros(0), np.zeros(0), LENGTH_M, WIDTH_M)
    rec.close()
    return path, confs


def _read(path: Path, blueprint: bool = False) -> dict[str, list[pa.RecordBatch]]:
    reader = RrdReader(path)
    store = reader.blueprints()[0] if blueprint else None
    out: dict[str, list[pa.RecordBatch]] = defaultdict(list)
    for chunk in reader.stream(store=store):
        out[chunk.entity_path].append(chunk.to_record_batch())
    return out


def _rows(batches: list[pa.RecordBatch], column: str) -> list[tuple[float, object]]:
    """(sim_time [s], value) of every row of a temporal component, in time order."""
    rows = []
    for b in batches:
        if column in b.schema.names and "sim_time" in b.schema.names:
            times = b.column("sim_time").cast(pa.int64()).to_pylist()
            rows += zip((t / 1e9 for t in times), b.column(column).to_pylist(), strict=True)
    return sorted(rows, key=lambda r: r[0])


def _static(batches: list[pa.RecordBatch], column: str) -> object:
    for b in batches:
        if column in b.schema.names and "sim_time" not in b.schema.names:
            return b.column(column).to_pylist()[0]
    raise AssertionError(f"no static {column}")


def _esc(vin: str) -> str:
    return vin.replace("/", "\\/")


def test_files_hold_one_recording_and_its_blueprint(recorded):
    path, _ = recorded
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1
    origins = []
    for batches in _read(path, blueprint=True).values():
        for b in batches:
            if "ViewBlueprint:space_origin" in b.schema.names:
                origins += b.column("ViewBlueprint:space_origin").to_pylist()
    flat = {o if isinstance(o, str) else o[0] for o in origins}
    assert {"junction", "counts/vehicles", "counts/confirmed", "events"} <= flat
    assert {f"spacetime/{a}" for a in ("E_in", "N_in", "S_in", "W_in")} <= flat


def test_only_sim_time_is_recorded(recorded):
    path, _ = recorded
    for entity, batches in _read(path).items():
        for b in batches:
            idx = [f.name for f in b.schema if (f.metadata or {}).get(b"rerun:kind") == b"index"]
            assert idx in ([], ["sim_time"]), (entity, idx)


def test_geometry_is_static_and_north_up(recorded, ch45):
    path, _ = recorded
    data = _read(path)
    region = np.array(_static(data["/junction/region"], "LineStrips2D:strips")[0])
    expected = np.vstack([ch45.region, ch45.region[:1]]) * [1.0, -1.0]
    np.testing.assert_allclose(region, expected, atol=1e-4)
    routes = _static(data["/junction/routes"], "LineStrips2D:strips")
    assert len(routes) == len(ch45.routes)
    assert len(_static(data["/junction/entry_lines"], "LineStrips2D:strips")) == len(ch45.in_lanes)


def test_planned_footprints_follow_the_tss_and_clear_after_it(recorded, ch45):
    path, confs = recorded
    data = _read(path)
    for c in confs:
        rows = _rows(data[f"/junction/planned/{_esc(c.vin)}"], "LineStrips2D:strips")
        assert len(rows) == len(c.tss) + 1
        np.testing.assert_allclose([t for t, _ in rows[:-1]], c.tss.t_s, atol=1e-6)
        assert rows[-1][1] == []  # the footprint vanishes one step after the plan ends
        for i in (0, len(c.tss) // 2, len(c.tss) - 1):
            strip = np.array(rows[i][1][0])
            assert strip.shape == (5, 2)
            np.testing.assert_allclose(strip[0], strip[-1])  # closed
            h = c.tss.heading_rad[i]
            centre = np.array([c.tss.x_m[i], c.tss.y_m[i]]) - LENGTH_M / 2 * np.array(
                [math.cos(h), math.sin(h)]
            )
            np.testing.assert_allclose(strip[:4].mean(axis=0), centre * [1, -1], atol=1e-3)
            sides = np.linalg.norm(np.diff(strip, axis=0), axis=1)
            np.testing.assert_allclose(sorted(sides), [WIDTH_M] * 2 + [LENGTH_M] * 2, atol=1e-3)


def test_space_time_plan_and_occupancy_box(recorded, ch45):
    path, confs = recorded
    data = _read(path)
    for c in confs:
        route = ch45.route_by_id(c.route_id)
        chart = f"/spacetime/{approach_of(route.in_lane)}"
        ((t_box, centers),) = _rows(data[f"{chart}/occupancy/{_esc(c.vin)}"], "Boxes2D:centers")
        ((_, halves),) = _rows(data[f"{chart}/occupancy/{_esc(c.vin)}"], "Boxes2D:half_sizes")
        mins = np.array(centers[0]) - halves[0]
        sizes = 2 * np.array(halves[0])
        k = CHART_M_PER_S  # chart metres per second
        np.testing.assert_allclose(mins, [k * c.entry_time_s, -route.cross_length_m], atol=1e-3)
        np.testing.assert_allclose(
            sizes, [k * (c.exit_time_s - c.entry_time_s), route.cross_length_m], atol=1e-3
        )
        assert t_box == pytest.approx(c.tss.t_s[0])
        ((_, strips),) = _rows(data[f"{chart}/plan/{_esc(c.vin)}"], "LineStrips2D:strips")
        line = np.array(strips[0])
        np.testing.assert_allclose(line[:, 0], k * c.tss.t_s, atol=1e-4)
        assert -line[0, 1] == pytest.approx(-40.0, abs=0.05)  # requested 40 m before entry
        s_at_entry = -np.interp(k * c.entry_time_s, line[:, 0], line[:, 1])
        assert abs(s_at_entry) < 1.0  # the front bumper crosses s = 0 at the entry time


def test_actual_vehicles_and_their_progress(recorded, ch45):
    path, confs = recorded
    data = _read(path)
    rows = _rows(data["/junction/vehicles"], "LineStrips2D:strips")
    labels = _rows(data["/junction/vehicles"], "LineStrips2D:labels")
    assert len(rows) == N_STEPS + 1
    assert all(len(strips) == len(confs) for _, strips in rows[:-1])
    assert rows[-1][1] == []  # the empty step clears the view
    assert labels[0][1] == [c.vin for c in confs]
    # the footprint drawn from SUMO's frame equals the planned one at the same time
    planned = _rows(data[f"/junction/planned/{_esc(confs[1].vin)}"], "LineStrips2D:strips")
    np.testing.assert_allclose(rows[5][1][1], planned[5][1][0], atol=1e-3)
    counts = _rows(data["/counts/vehicles"], "Scalars:scalars")
    assert [v for _, v in counts] == [[len(confs)]] * N_STEPS + [[0]]

    for c in confs:
        route = ch45.route_by_id(c.route_id)
        chart = f"/spacetime/{approach_of(route.in_lane)}"
        actual = _rows(data[f"{chart}/actual"], "Points2D:positions")
        assert len(actual) == N_STEPS
        s_plan = route.project(np.stack([c.tss.x_m, c.tss.y_m], -1))[0]
        for i, (t, pts) in enumerate(actual):
            assert t == pytest.approx(c.tss.t_s[i])
            np.testing.assert_allclose(
                pts[0], [CHART_M_PER_S * c.tss.t_s[i], -s_plan[i]], atol=1e-3
            )


def test_actual_progress_is_a_darker_shade_of_the_plan(recorded, ch45):
    path, confs = recorded
    data = _read(path)
    for c in confs:
        chart = f"/spacetime/{approach_of(ch45.route_by_id(c.route_id).in_lane)}"
        plan = _only_row(data[f"{chart}/plan/{_esc(c.vin)}"], "LineStrips2D:colors")
        actual = _rows(data[f"{chart}/actual"], "Points2D:colors")[0][1][0]
        rgb = [(plan >> k) & 0xFF for k in (24, 16, 8)]
        assert [(actual >> k) & 0xFF for k in (24, 16, 8)] == [int(v * 0.55) for v in rgb]
        assert actual & 0xFF == plan & 0xFF  # same opacity


def _only_row(batches: list[pa.RecordBatch], column: str) -> int:
    ((_, colors),) = _rows(batches, column)
    return colors[0]


def test_charts_get_a_time_grid_every_ten_seconds(ch45, tmp_path):
    """A 2D view has no axes: each chart gets a labelled tick every 10 s of sim
    time, with the entry lines, logged at that time (so a moving window shows them)."""
    rec = SpaceTimeRecorder(ch45, tmp_path / "g.rrd")
    for k in range(0, 501):  # 0 .. 25 s
        rec.footprints(k * 0.05, [], np.zeros(0), np.zeros(0), np.zeros(0), 5.0, 1.8)
    rec.close()
    data = _read(tmp_path / "g.rrd")
    comm = ch45.comm_length_m
    for a in ("E_in", "N_in", "S_in", "W_in"):
        labels = _rows(data[f"/spacetime/{a}/grid_time"], "Points2D:labels")
        assert labels == [(0.0, ["0 s"]), (10.0, ["10 s"]), (20.0, ["20 s"])]
        grid = _rows(data[f"/spacetime/{a}/grid"], "LineStrips2D:strips")
        t, (tick, entry, region) = grid[1]
        assert t == 10.0
        x10, x20 = 10.0 * CHART_M_PER_S, 20.0 * CHART_M_PER_S
        assert [p[0] for p in tick] == [x10, x10] and tick[0][1] == pytest.approx(comm)
        assert entry == [[x10, 0.0], [x20, 0.0]]
        assert region == [[x10, pytest.approx(comm)], [x20, pytest.approx(comm)]]


def test_charts_show_a_moving_window_and_the_time_panel_is_open(recorded):
    """Each chart shows the last 40 s before the cursor, not the whole run
    squeezed into one view; the time panel starts expanded."""
    path, _ = recorded
    blueprint = _read(path, blueprint=True)
    ranges = [
        b.column(c).to_pylist()
        for batches in blueprint.values()
        for b in batches
        for c in b.schema.names
        if c.endswith("VisibleTimeRanges:ranges")
    ]
    assert len(ranges) == 4  # one per chart
    for (r,) in ranges:  # from 40 s before the cursor (relative, in ns) to the cursor
        assert r == [{"timeline": "sim_time", "range": {"start": -40_000_000_000, "end": 0}}]
    panels = {
        e: b.column(c).to_pylist()[0][0]
        for e, batches in blueprint.items()
        for b in batches
        for c in b.schema.names
        if c.endswith("Blueprint:state")
    }
    assert panels == {"/time_panel": 3, "/blueprint_panel": 2, "/selection_panel": 2}  # 3 open


def test_rectangles_in_sumo_frame_by_hand():
    # facing north, front bumper at (0, 10): body from y = 5 to 10, x = -1..1
    r = rectangles(np.array([0.0]), np.array([10.0]), sumo_heading_rad(np.array([0.0])), 5.0, 2.0)
    world = r[0] * [1, -1]
    np.testing.assert_allclose(world.min(axis=0), [-1, 5], atol=1e-9)
    np.testing.assert_allclose(world.max(axis=0), [1, 10], atol=1e-9)
    # facing east (SUMO 90 degrees), front at (10, 0): x = 5..10, y = -1..1
    r = rectangles(np.array([10.0]), np.array([0.0]), sumo_heading_rad(np.array([90.0])), 5.0, 2.0)
    world = r[0] * [1, -1]
    np.testing.assert_allclose(world.min(axis=0), [5, -1], atol=1e-9)
    np.testing.assert_allclose(world.max(axis=0), [10, 1], atol=1e-9)


def test_batched_projection_matches_route_project(ch45, tee):
    rng = np.random.default_rng(7)
    for inter in (ch45, tee):
        proj = RouteProjector(inter.routes)
        idx = rng.integers(len(inter.routes), size=400)
        s_true = np.array([rng.uniform(r.s_min, r.s_max) for r in (inter.routes[i] for i in idx)])
        xy = np.array([inter.routes[i].points(s) for i, s in zip(idx, s_true, strict=True)])
        xy += rng.normal(0.0, 1.5, xy.shape)
        s, d = proj.project(idx, xy)
        for k, i in enumerate(idx):
            s_ref, d_ref = inter.routes[i].project(xy[k])
            assert s[k] == pytest.approx(s_ref[0], abs=1e-9)
            assert d[k] == pytest.approx(d_ref[0], abs=1e-9)


def test_caller_bugs_are_value_errors(ch45, tmp_path):
    with SpaceTimeRecorder(ch45, tmp_path / "x.rrd") as rec:
        z = np.zeros(3)
        with pytest.raises(ValueError, match="unknown route"):
            rec.confirmed("a", "nowhere", z, z, z, z, 5.0, 1.8, 1.0, 2.0)
        with pytest.raises(ValueError, match="equal length"):
            rec.footprints(0.0, ["a", "b"], z, z, z, 5.0, 1.8)
        with pytest.raises(ValueError, match="unknown route"):
            rec.progress(0.0, ["a"], ["nowhere"], np.zeros(1))


# -- dica view ---------------------------------------------------------------------
@pytest.mark.parametrize("case", ["missing", "empty", "not_rrd"])
def test_view_without_a_recording_is_one_line_and_status_2(case, tmp_path, capsys):
    target = {"missing": tmp_path / "nope", "empty": tmp_path, "not_rrd": tmp_path / "a.txt"}[case]
    if case == "not_rrd":
        target.write_text("x")
    assert dica(["view", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dica: ") and err.count("\n") == 1, err
    assert "Traceback" not in err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_view_web_serves_on_loopback_and_stops_its_viewer(recorded):
    path, _ = recorded
    port, grpc = _free_port(), _free_port()
    cmd = [sys.executable, "-m", "tools.cli", "view", "--web", "--port", str(port)]
    cmd += ["--grpc-port", str(grpc), str(path.parent)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True
    )
    try:
        line = proc.stdout.readline()  # printed once the web port accepts connections
        assert line.startswith(f"web viewer: http://127.0.0.1:{port}/"), line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as resp:
            assert resp.status == 200
        assert _port_open(grpc)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=15)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
    assert rc == 130
    deadline = time.monotonic() + 5
    while (_port_open(port) or _port_open(grpc)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _port_open(port) and not _port_open(grpc), "the viewer outlived dica view"
