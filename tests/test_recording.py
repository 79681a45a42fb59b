"""The Rerun recording, read back with Rerun's own reader, and ``dica view``.

Confirmations come from the real DICA core on the real chapter 4-5 junction;
the "actual" vehicles fly exactly their confirmed TSS, so what the recording
holds can be checked against numbers computed here independently (footprints
with shapely, intervals with the core's exhaustive getOTI).
"""

from __future__ import annotations

import colorsys
import itertools
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
import shapely
from rerun.chunk import RrdReader

from dica.ica.core.dica import Dica
from dica.ica.core.dtot import build_dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import ConflictTables, Shape
from dica.sim_gateway.conflict_points import covers, find_conflict_points
from dica.sim_gateway.recording import (
    STATUS_STYLE,
    TOP_EVERY,
    SpaceTimeRecorder,
    Status,
    approach_of,
)
from dica.sim_gateway.recording.chart_frame import CHART_EVERY, CHART_M_PER_S, PAST_S, ROW_M
from dica.sim_gateway.recording.geometry import RouteProjector, rectangles, sumo_heading_rad
from dica.sim_gateway.recording.style import vehicle_color, vehicle_statuses
from dica.tools.cli import main as dica

LENGTH_M, WIDTH_M, MARGIN_M = 5.0, 1.8, 0.25
N_STEPS = 120  # actual steps recorded, then one step with no vehicles
K = CHART_M_PER_S


def _confirmations(inter: Intersection) -> list[Confirmation]:
    """Head vehicles going through from every approach, then turning left from every
    approach, confirmed by the real core: they cross one another, so the core has to
    order them."""
    ica = Dica(inter)
    out = []
    approaches = sorted({approach_of(r.in_lane) for r in inter.routes})
    for k, (turn, appr) in enumerate((t, a) for t in ("through", "left") for a in approaches):
        route = next(r for r in inter.routes if approach_of(r.in_lane) == appr and r.turn == turn)
        vin = f"veh/{k}"  # a slash, to check names survive
        ica.detect(vin, route.in_lane, 0.0)
        req = propose(route, vin=vin, seq=0, t0_s=0.0, dist_to_entry_m=20.0, speed_mps=12.0)
        conf = ica.handle(req, 0.0)
        assert isinstance(conf, Confirmation), conf
        out.append(conf)
    return out


def _sumo_angle_deg(heading_rad: np.ndarray) -> np.ndarray:
    return 90.0 - np.degrees(heading_rad)  # CCW from +x -> clockwise from north


def _fly(rec: SpaceTimeRecorder, confs: list[Confirmation], n_steps: int) -> None:
    """Every vehicle at its confirmed TSS sample, step by step (held at its last one)."""
    for i in range(n_steps):
        j = [min(i, len(c.tss) - 1) for c in confs]
        rec.footprints(
            round(i * 0.05, 10),
            [c.vin for c in confs],
            np.array([c.tss.x_m[k] for c, k in zip(confs, j, strict=True)]),
            np.array([c.tss.y_m[k] for c, k in zip(confs, j, strict=True)]),
            _sumo_angle_deg(
                np.array([c.tss.heading_rad[k] for c, k in zip(confs, j, strict=True)])
            ),
            LENGTH_M,
            WIDTH_M,
            route_ids=[c.route_id for c in confs],
        )


def _confirm(rec: SpaceTimeRecorder, confs: list[Confirmation]) -> None:
    for c in confs:
        tss = c.tss
        rec.confirmed(
            c.vin, c.route_id, tss.t_s, tss.x_m, tss.y_m, tss.heading_rad,
            LENGTH_M, WIDTH_M, c.entry_time_s, c.exit_time_s,
            delay_s=c.delay_s, rounds=c.iterations,
        )  # fmt: skip


@pytest.fixture(scope="module")
def recorded(ch45: Intersection, tmp_path_factory: pytest.TempPathFactory):
    confs = _confirmations(ch45)
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    rec = SpaceTimeRecorder(ch45, path, flush_s=1.3)  # batches that do not divide the run
    rec.geometry()
    _confirm(rec, confs)
    rec.rejected(0.5, "veh/9", "not_head", "a vehicle ahead")
    _fly(rec, confs, N_STEPS)
    rec.footprints(N_STEPS * 0.05, [], np.zeros(0), np.zeros(0), np.zeros(0), LENGTH_M, WIDTH_M)
    points = rec.points
    rec.close()
    return path, confs, points


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


def _static(batches: list[pa.RecordBatch], column: str) -> list:
    for b in batches:
        if column in b.schema.names and "sim_time" not in b.schema.names:
            return b.column(column).to_pylist()[0]
    raise AssertionError(f"no static {column}")


def _blueprint(path: Path) -> dict[str, dict[str, object]]:
    """The blueprint's entities: path -> {component: first value}, components only."""
    out: dict[str, dict[str, object]] = defaultdict(dict)
    for entity, batches in _read(path, blueprint=True).items():
        for b in batches:
            for c in b.schema.names:
                if ":" in c:
                    out[entity][c.split(":", 1)[1]] = b.column(c).to_pylist()[0]
    return out


def _chart_views(path: Path) -> dict[str, dict[str, object]]:
    """2D views by name, each with its own properties (bounds, time ranges) merged in."""
    bp = _blueprint(path)
    out = {}
    for entity, fields in bp.items():
        if entity.startswith("/view/") and entity.count("/") == 2:
            props = {
                k: v for e, f in bp.items() if e.startswith(entity + "/") for k, v in f.items()
            }
            out[fields["display_name"][0]] = {**fields, **props}
    return out


def test_files_hold_one_recording_and_its_blueprint(recorded):
    path, _, _ = recorded
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1
    origins = set()
    for batches in _read(path, blueprint=True).values():
        for b in batches:
            if "ViewBlueprint:space_origin" in b.schema.names:
                origins |= {
                    o if isinstance(o, str) else o[0]
                    for o in b.column("ViewBlueprint:space_origin").to_pylist()
                }
    assert {"junction", "charts", "counts", "tables/confirmed", "tables/rejected"} <= origins


def test_only_sim_time_is_recorded(recorded):
    path, _, _ = recorded
    for entity, batches in _read(path).items():
        for b in batches:
            idx = [f.name for f in b.schema if (f.metadata or {}).get(b"rerun:kind") == b"index"]
            assert idx in ([], ["sim_time"]), (entity, idx)


def test_one_chart_per_lane_all_with_one_window_and_one_distance_scale(recorded, ch45):
    path, _, _ = recorded
    charts = _chart_views(path)
    lanes = {
        n.split(":")[0]: v for n, v in charts.items() if n.endswith("distance [m] vs time [s]")
    }
    assert set(lanes) == set(ch45.in_lanes)
    bounds = {str(v["range"]) for v in lanes.values()}
    ranges = {str(v["ranges"]) for v in lanes.values()}
    assert len(bounds) == 1 and len(ranges) == 1  # one window, one scale, every chart
    (r,) = lanes[ch45.in_lanes[0]]["ranges"]
    assert r == {"timeline": "sim_time", "range": {"start": -int(PAST_S * 1e9), "end": 0}}
    (box,) = lanes[ch45.in_lanes[0]]["range"]
    assert box["x_range"][1] == pytest.approx(20.0 * K + 2.0)  # "now" is at x = 0
    zones = charts["conflict points: reserved (box) and held (dots) vs time [s]"]
    assert str(zones["ranges"]) == ranges.pop()


def test_the_viewer_opens_paused_on_the_first_confirmation(ch45, tmp_path):
    """Steps before the first confirmation are not recorded: a viewer opens at the
    start of the timeline, and that is where the first plan is."""
    (conf, *_) = _confirmations(ch45)
    rec = SpaceTimeRecorder(ch45, tmp_path / "first.rrd", flush_s=0.5)
    for i in range(60):  # 3 s, the confirmation at 1 s
        if i == 20:
            t = conf.tss
            rec.confirmed(conf.vin, conf.route_id, t.t_s + 1.0, t.x_m, t.y_m, t.heading_rad,
                          LENGTH_M, WIDTH_M, conf.entry_time_s + 1,
                          conf.exit_time_s + 1)  # fmt: skip
        rec.footprints(i * 0.05, [], np.zeros(0), np.zeros(0), np.zeros(0), LENGTH_M, WIDTH_M)
    rec.close()
    times = [
        t / 1e9
        for batches in _read(tmp_path / "first.rrd").values()
        for b in batches
        if "sim_time" in b.schema.names
        for t in b.column("sim_time").cast(pa.int64()).to_pylist()
    ]
    assert min(times) == pytest.approx(1.0)
    panel = _blueprint(tmp_path / "first.rrd")["/time_panel"]
    assert panel["state"] in (2, [2])  # collapsed to its play bar
    assert panel["play_state"] in (1, [1])  # paused


def test_geometry_is_static_north_up_with_lane_edges_and_entry_lines(recorded, ch45):
    path, _, _ = recorded
    data = _read(path)
    region = np.array(_static(data["/junction/region"], "LineStrips2D:strips")[0])
    expected = np.vstack([ch45.region, ch45.region[:1]]) * [1.0, -1.0]
    np.testing.assert_allclose(region, expected, atol=1e-4)
    n_in, n_out = len(ch45.in_lanes), len(ch45.out_lanes)
    assert len(_static(data["/junction/lane_edges"], "LineStrips2D:strips")) == 2 * (n_in + n_out)
    assert len(_static(data["/junction/entry_lines"], "LineStrips2D:strips")) == n_in
    legend = _static(data["/junction/legend/text"], "Points2D:labels")
    for name, _ in STATUS_STYLE.values():
        assert any(label.startswith(name) for label in legend)
    assert any("margin" in label for label in legend)


def test_chart_lines_are_labelled_for_every_lane(recorded, ch45):
    path, _, _ = recorded
    data = _read(path)
    for lane in ch45.in_lanes:
        labels = _static(data[f"/charts/frame/lanes/{lane}/lines"], "LineStrips2D:labels")
        strips = _static(data[f"/charts/frame/lanes/{lane}/lines"], "LineStrips2D:strips")
        assert labels[:2] == [f"region start {-ch45.comm_length_m:g} m", "entry 0 m"]
        exits = sorted({round(r.cross_length_m, 1) for r in ch45.routes if r.in_lane == lane})
        assert [float(lb.split()[-2]) for lb in labels[2:]] == exits
        assert [-s[0][1] for s in strips] == pytest.approx(
            [-ch45.comm_length_m, 0.0, *exits], abs=1e-3
        )
        axis = _static(data[f"/charts/frame/lanes/{lane}/axis"], "Points2D:labels")
        assert "0 entry" in axis and "-20" in axis  # distances on the axis, in metres
    assert _static(data["/charts/frame/now/label"], "Points2D:labels") == ["now", "now"]


def _holding_oracle(conf: Confirmation, route, points) -> dict[int, tuple[float, float]]:
    """Per conflict point: the union of exhaustive occupancy intervals whose (shapely)
    footprint contains the point."""
    s, _ = route.project(np.stack([conf.tss.x_m, conf.tss.y_m], -1))
    traj = Trajectory(float(conf.tss.t_s[0]), 0.05, s)
    d = build_dtot(route, Shape.of(LENGTH_M, WIDTH_M), traj, MARGIN_M)
    polys = [shapely.Polygon(c) for c in d.rects.corners()]
    out = {}
    for p, xy in enumerate(points.xy):
        pt = shapely.Point(xy)
        hit = [k for k, poly in enumerate(polys) if poly.buffer(1e-9).contains(pt)]
        if hit:
            out[p] = (float(d.lb_s[hit].min()), float(d.ub_s[hit].max()))
    return out


def test_conflict_chart_has_one_bar_per_held_interval_and_none_overlap(recorded, ch45):
    path, confs, points = recorded
    data = _read(path)
    rows = _rows(data["/charts/data/zones/reserved"], "Boxes2D:centers")
    halves = _rows(data["/charts/data/zones/reserved"], "Boxes2D:half_sizes")
    labels = _rows(data["/charts/data/zones/reserved"], "Boxes2D:labels")
    bars = defaultdict(list)  # point -> [(lb, ub, vin)]
    for (_, cs), (_, hs), (_, ls) in zip(rows, halves, labels, strict=True):
        for c, h, lb in zip(cs, hs, ls, strict=True):
            p = round(c[1] / ROW_M - 0.5)
            bar = ((c[0] - h[0]) / K, (c[0] + h[0]) / K, lb.split()[0])
            if bar not in bars[p]:  # logged at the confirmation and again when it ends
                bars[p].append(bar)
    expected = defaultdict(list)
    for c in confs:
        for p, (lb, ub) in _holding_oracle(c, ch45.route_by_id(c.route_id), points).items():
            expected[p].append((lb, ub, c.vin))
    assert sum(len(v) for v in expected.values()) >= len(confs)
    assert set(bars) == set(expected)
    for p in expected:
        got, want = sorted(bars[p]), sorted(expected[p])
        assert [v for *_, v in got] == [v for *_, v in want]
        np.testing.assert_allclose([g[:2] for g in got], [w[:2] for w in want], atol=1e-3)
        for (_, ub, _), (lb, _, _) in itertools.pairwise(got):  # DICA: one vehicle at a time
            assert ub <= lb + 1e-6, (p, got)
    assert any(len(v) > 1 for v in bars.values())  # a point two of them share


def test_a_real_run_has_no_two_bars_overlapping_at_any_conflict_point(tmp_path):
    """SUMO, the vehicle machines and the core in one process: a collision-free run's
    reservations never share a conflict point in time, and every vehicle holds its
    points only while they are reserved for it."""
    import json

    out = tmp_path / "run"
    args = ["run", "--volume", "500", "--duration", "60", "--seed", "5", "--quiet"]
    assert dica([*args, "--record", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    data = _read(out / "spacetime.rrd")
    rows = _rows(data["/charts/data/zones/reserved"], "Boxes2D:centers")
    halves = _rows(data["/charts/data/zones/reserved"], "Boxes2D:half_sizes")
    bars = defaultdict(list)
    for (_, cs), (_, hs) in zip(rows, halves, strict=True):
        for c, h in zip(cs, hs, strict=True):
            bar = ((c[0] - h[0]) / K, (c[0] + h[0]) / K)
            if bar not in bars[round(c[1] / ROW_M - 0.5)]:  # each is logged twice
                bars[round(c[1] / ROW_M - 0.5)].append(bar)
    assert sum(len(b) for b in bars.values()) > 25
    for p, b in bars.items():
        b.sort()
        for (_, ub), (lb, _) in itertools.pairwise(b):
            assert ub <= lb + 1e-4, (p, ub, lb)
    held = [lb for _, ls in _rows(data["/charts/data/zones/held"], "Points2D:labels") for lb in ls]
    assert len(held) > 25 and not any("outside" in lb for lb in held)


def test_held_dots_sit_inside_the_reserved_bars_when_plans_are_flown(recorded):
    path, _, _ = recorded
    data = _read(path)
    colors = [c for _, cs in _rows(data["/charts/data/zones/held"], "Points2D:colors") for c in cs]
    labels = [
        lb for _, ls in _rows(data["/charts/data/zones/held"], "Points2D:labels") for lb in ls
    ]
    assert len(colors) > 4
    assert not any("outside" in lb for lb in labels)
    assert 0xDC1E1EFF not in colors


def test_an_actual_footprint_outside_its_reservation_is_red(ch45, tmp_path):
    """A vehicle that holds a point late (it waited 2 s longer than planned) shows red."""
    conf = _confirmations(ch45)[1]  # its real footprint covers two conflict points
    rec = SpaceTimeRecorder(ch45, tmp_path / "late.rrd")
    t = conf.tss
    rec.confirmed(conf.vin, conf.route_id, t.t_s, t.x_m, t.y_m, t.heading_rad,
                  LENGTH_M, WIDTH_M, conf.entry_time_s, conf.exit_time_s)  # fmt: skip
    late = 40  # steps behind its plan
    for i in range(len(t) + late):
        j = min(max(i - late, 0), len(t) - 1)
        rec.footprints(i * 0.05, [conf.vin], t.x_m[j : j + 1], t.y_m[j : j + 1],
                       _sumo_angle_deg(t.heading_rad[j : j + 1]), LENGTH_M, WIDTH_M,
                       route_ids=[conf.route_id])  # fmt: skip
    rec.close()
    labels = [
        lb
        for _, ls in _rows(
            _read(tmp_path / "late.rrd")["/charts/data/zones/held"], "Points2D:labels"
        )
        for lb in ls
    ]
    assert any("outside its reservation" in lb for lb in labels)


def test_reserved_footprints_are_margin_bands_of_the_dtot(recorded, ch45):
    path, confs, _ = recorded
    data = _read(path)
    rows = _rows(data["/junction/reserved"], "LineStrips2D:strips")
    c = confs[0]
    route = ch45.route_by_id(c.route_id)
    s, _ = route.project(np.stack([c.tss.x_m, c.tss.y_m], -1))
    d = build_dtot(route, Shape.of(LENGTH_M, WIDTH_M), Trajectory(0.0, 0.05, s), MARGIN_M)
    k = next(k for k in range(len(d)) if round(d.t_s[k] / 0.05) % TOP_EVERY == 0)
    (strips,) = [v for t, v in rows if abs(t - d.t_s[k]) < 1e-6]
    grown = shapely.Polygon(np.array(d.rects.corners()[k]) * [1, -1])
    middle = grown.buffer(-MARGIN_M / 2, join_style="mitre")  # the band's middle line
    assert min(shapely.Polygon(st).symmetric_difference(middle).area for st in strips) < 1e-3
    radii = [r for _, rs in _rows(data["/junction/reserved"], "LineStrips2D:radii") for r in rs]
    assert radii and all(r == pytest.approx(MARGIN_M / 2) for r in radii)  # one per row


def test_actual_footprints_states_and_names(recorded, ch45):
    path, confs, _ = recorded
    data = _read(path)
    rows = _rows(data["/junction/vehicles"], "LineStrips2D:strips")
    classes = _rows(data["/junction/vehicles"], "LineStrips2D:colors")
    rgba = {
        st: (r << 24) | (g << 16) | (b << 8) | 0xFF for st, (_, (r, g, b)) in STATUS_STYLE.items()
    }
    assert len(rows) == math.ceil((N_STEPS + 1) / TOP_EVERY)
    assert all(len(strips) == len(confs) for _, strips in rows[:-1])
    assert rows[-1][1] == []  # the empty step clears the view
    t, strips = rows[5]
    i = round(t / 0.05)
    c = confs[1]
    np.testing.assert_allclose(
        strips[1],
        rectangles(
            c.tss.x_m[i : i + 1],
            c.tss.y_m[i : i + 1],
            c.tss.heading_rad[i : i + 1],
            LENGTH_M,
            WIDTH_M,
        )[0],
        atol=1e-3,
    )
    for (t, ids), _ in zip(classes, rows, strict=True):
        for cid, c in zip(ids or [], confs, strict=False):
            i = min(round(t / 0.05), len(c.tss) - 1)
            s = ch45.route_by_id(c.route_id).project(np.array([[c.tss.x_m[i], c.tss.y_m[i]]]))[0][0]
            want = (
                Status.CONFIRMED
                if s <= 0
                else Status.CROSSING
                if s < ch45.route_by_id(c.route_id).cross_length_m + LENGTH_M
                else Status.CLEARED
            )
            assert cid == rgba[want], (t, c.vin, s)
    names = _rows(data["/junction/names"], "Points2D:labels")
    assert {n for _, ns in names for n in ns} <= {c.vin for c in confs}
    assert any(ns for _, ns in names)


def test_an_emergency_vehicle_has_its_own_colour_until_it_has_cleared():
    confirmed = np.array([True, True, True, False, True])
    s_m = np.array([-5.0, 3.0, 40.0, -10.0, -5.0])
    out_m = np.full(5, 30.0)
    ev = np.array([False, True, True, True, False])
    st = vehicle_statuses(confirmed, s_m, out_m, ev)
    assert list(st) == [
        Status.CONFIRMED, Status.EMERGENCY, Status.CLEARED, Status.EMERGENCY, Status.CONFIRMED
    ]  # fmt: skip
    assert "emergency vehicle" in {name for name, _ in STATUS_STYLE.values()}


def test_an_emergency_vehicle_is_drawn_in_its_colour(ch45, tmp_path):
    confs = _confirmations(ch45)
    path = tmp_path / "ev.rrd"
    rec = SpaceTimeRecorder(ch45, path)
    rec.geometry()
    _confirm(rec, confs)
    rec.emergency(confs[0].vin)
    _fly(rec, confs, 10)
    rec.close()
    r, g, b = STATUS_STYLE[Status.EMERGENCY][1]
    red = (r << 24) | (g << 16) | (b << 8) | 0xFF
    colours = _rows(_read(path)["/junction/vehicles"], "LineStrips2D:colors")
    assert colours and all(ids[0] == red and red not in ids[1:] for _, ids in colours if ids)


def test_an_emergency_vehicle_s_plan_and_progress_are_in_its_colour_in_the_charts(ch45, tmp_path):
    confs = _confirmations(ch45)
    path = tmp_path / "ev-charts.rrd"
    rec = SpaceTimeRecorder(ch45, path)
    rec.geometry()
    rec.emergency(confs[0].vin)  # told before its confirmation, as the runners do
    _confirm(rec, confs)
    _fly(rec, confs, 10)
    rec.close()
    data = _read(path)
    r, g, b = STATUS_STYLE[Status.EMERGENCY][1]
    red = (r << 24) | (g << 16) | (b << 8)
    lane = ch45.route_by_id(confs[0].route_id).in_lane
    plans = _rows(data[f"/charts/data/lanes/{lane}/plans"], "LineStrips2D:colors")
    labels = _rows(data[f"/charts/data/lanes/{lane}/plans"], "LineStrips2D:labels")
    mine = [
        c[0] for (_, c), (_, (lb,)) in zip(plans, labels, strict=True) if lb.startswith("veh/0")
    ]
    assert mine and all(c & 0xFFFFFF00 == red for c in mine)
    dots = _rows(data[f"/charts/data/lanes/{lane}/actual"], "Points2D:colors")
    names = _rows(data[f"/charts/data/lanes/{lane}/actual"], "Points2D:labels")
    ev_dots = [c for (_, cs), (_, ns) in zip(dots, names, strict=True)
               for c, n in zip(cs, ns, strict=True) if n == confs[0].vin]  # fmt: skip
    assert ev_dots and set(ev_dots) == {red | 0xFF}


def test_no_other_vehicle_is_drawn_near_the_emergency_red():
    for i in range(2000):
        c = vehicle_color(f"v{i:05d}")
        r, g, b = ((c >> s) & 0xFF for s in (24, 16, 8))
        hue = colorsys.rgb_to_hsv(r / 255, g / 255, b / 255)[0] * 360
        assert 24.0 <= hue <= 336.0, (i, hue)


def test_a_reordering_is_marked_on_the_ev_s_lane_chart_and_in_its_table(ch45, tmp_path):
    confs = _confirmations(ch45)
    ev = confs[0]
    lane = ch45.route_by_id(ev.route_id).in_lane
    path = tmp_path / "reorder.rrd"
    rec = SpaceTimeRecorder(ch45, path)
    rec.geometry()
    rec.emergency(ev.vin)
    _confirm(rec, confs)
    _fly(rec, confs, 20)
    rec.reordered(1.0, ev.vin, lane, "exact", ["w1", ev.vin, "w2"], 9.0, 5.5, revoked=["w1"])
    rec.reordered(1.5, ev.vin, lane, "ga", [ev.vin], math.nan, math.nan, refused="too many")
    rec.kept(2.0, "w1", "kept its plan: it could not stop")
    for i in range(20, 200):  # past the EV's old entry: the mark is logged again then
        t = round(i * 0.05, 10)
        rec.footprints(t, [], np.zeros(0), np.zeros(0), np.zeros(0), LENGTH_M, WIDTH_M)
    rec.close()
    data = _read(path)
    marks = _rows(data[f"/charts/data/lanes/{lane}/reorders"], "LineStrips2D:strips")
    labels = _rows(data[f"/charts/data/lanes/{lane}/reorders"], "LineStrips2D:labels")
    assert [t for t, _ in marks] == [1.0, 1.5, 9.0]  # the first again when its last part ends
    (t, (across, entries)), (_, lbs) = marks[0], labels[0]
    assert [x for x, _ in across] == [pytest.approx(K * 1.0)] * 2  # a line across at 1 s
    assert [x for x, _ in entries] == [pytest.approx(K * 9.0), pytest.approx(K * 5.5)]
    assert lbs == [f"reorder for {ev.vin} (exact)", f"{ev.vin} entry 5.5 s (was 9.0 s)"]
    assert len(marks[1][1]) == 1  # refused: no entries to compare, only the mark
    rows = [text for _, (text,) in _rows(data["/tables/reorders"], "TextLog:text")]
    assert rows[0].split() == [ev.vin, "exact", "9.00", "5.50", "w1*", ev.vin, "w2"]
    assert "present order kept: too many" in rows[1]
    assert rows[2].split()[:3] == ["w1", "kept", "its"]
    with pytest.raises(ValueError, match="unknown lane"):
        SpaceTimeRecorder(ch45, tmp_path / "x.rrd").reordered(0, "ev", "nowhere", "exact", [], 1, 1)


@pytest.mark.parametrize("told_at_step", [40, 46])  # at its time, or a little later
def test_a_withdrawn_plan_is_drawn_in_force_until_its_withdrawal(ch45, tmp_path, told_at_step):
    """Steps are drawn in batches: those before a withdrawal keep the plan, those after
    lose it, even when the withdrawal is told after they were buffered."""

    def record(path: Path, withdraw: bool) -> tuple[dict, dict]:
        confs = _confirmations(ch45)
        rec = SpaceTimeRecorder(ch45, path, flush_s=100.0)  # nothing drawn before the end
        rec.geometry()
        _confirm(rec, confs)
        for i in range(60):
            if withdraw and i == told_at_step:
                rec.withdrawn(2.0, confs[0].vin, "revoked")
            j = [min(i, len(c.tss) - 1) for c in confs]
            rec.footprints(
                round(i * 0.05, 10), [c.vin for c in confs],
                np.array([c.tss.x_m[k] for c, k in zip(confs, j, strict=True)]),
                np.array([c.tss.y_m[k] for c, k in zip(confs, j, strict=True)]),
                _sumo_angle_deg(np.array([c.tss.heading_rad[k] for c, k in zip(confs, j,
                                                                               strict=True)])),
                LENGTH_M, WIDTH_M, route_ids=[c.route_id for c in confs],
            )  # fmt: skip
        rec.close()
        data = _read(path)
        bands = {t: len(st) for t, st in _rows(data["/junction/reserved"], "LineStrips2D:strips")}
        colours = dict(_rows(data["/junction/vehicles"], "LineStrips2D:colors"))
        return bands, colours

    (kept, kept_c), (gone, gone_c) = (
        record(tmp_path / "k.rrd", False),
        record(tmp_path / "g.rrd", True),
    )
    assert kept.keys() == gone.keys()
    assert all(gone[t] == kept[t] for t in kept if t < 2.0)  # in force until withdrawn
    assert all(gone[t] == kept[t] - 1 for t in kept if t >= 2.0)
    # and its vehicle is drawn confirmed until then, requesting from then on
    orange = _rgba_of(STATUS_STYLE[Status.REQUESTING][1])
    assert all((gone_c[t][0] == orange) == (t >= 2.0) for t in gone_c)
    assert orange not in {kept_c[t][0] for t in kept_c}


def _rgba_of(rgb: tuple[int, int, int]) -> int:
    r, g, b = rgb
    return (r << 24) | (g << 16) | (b << 8) | 0xFF


def test_a_withdrawn_plan_leaves_the_charts_and_the_top_view(ch45, tmp_path):
    def record(path: Path, withdraw: bool) -> dict:
        confs = _confirmations(ch45)
        rec = SpaceTimeRecorder(ch45, path)
        rec.geometry()
        _confirm(rec, confs)
        _fly(rec, confs, 5)
        if withdraw:
            rec.withdrawn(0.25, confs[0].vin, "revoked")
        _fly(rec, confs, N_STEPS)
        rec.close()
        return _read(path)

    kept, gone = record(tmp_path / "kept.rrd", False), record(tmp_path / "gone.rrd", True)
    vin = _confirmations(ch45)[0].vin

    def labels(data: dict, column: str) -> list[str]:
        return [lb for key, b in data.items() if key.endswith("/plans") or key.endswith(
            "reserved") for _, lbs in _rows(b, column) for lb in lbs or []]  # fmt: skip

    # the plan and its intervals are logged again when they end, unless withdrawn
    n_kept = sum(lb.startswith(f"{vin} ") for lb in labels(kept, "LineStrips2D:labels"))
    n_gone = sum(lb.startswith(f"{vin} ") for lb in labels(gone, "LineStrips2D:labels"))
    assert n_gone < n_kept
    # the reserved footprints in the top view: one fewer vehicle after the withdrawal
    after = [strips for t, strips in _rows(gone["/junction/reserved"], "LineStrips2D:strips")
             if t > 0.3]  # fmt: skip
    before = [strips for t, strips in _rows(kept["/junction/reserved"], "LineStrips2D:strips")
              if t > 0.3]  # fmt: skip
    assert after and sum(map(len, after)) < sum(map(len, before))
    rows = [txt for _, txts in _rows(gone["/tables/rejected"], "TextLog:text") for txt in txts]
    assert any(txt.startswith(vin) and "revoked" in txt for txt in rows)


def test_charts_move_with_time_and_show_plan_and_progress(recorded, ch45):
    path, confs, _ = recorded
    data = _read(path)
    shift = _rows(data["/charts/data"], "Transform3D:translation")
    assert shift and all(v[0][0] == pytest.approx(-K * t, abs=1e-3) for t, v in shift)
    for c in confs:
        route = ch45.route_by_id(c.route_id)
        lane = route.in_lane
        plans = _rows(data[f"/charts/data/lanes/{lane}/plans"], "LineStrips2D:strips")
        names = _rows(data[f"/charts/data/lanes/{lane}/plans"], "LineStrips2D:labels")
        mine = [
            (t, st) for (t, st), (_, (n,)) in zip(plans, names, strict=True) if n == f"{c.vin} plan"
        ]
        # logged at the confirmation and again when the plan ends (if the run got there)
        assert [t for t, _ in mine] == [0.0, pytest.approx(c.tss.t_s[-1])][: len(mine)]
        line = np.array(mine[0][1][0])
        s_plan = route.project(np.stack([c.tss.x_m, c.tss.y_m], -1))[0]
        keep = [*range(0, len(s_plan) - 1, CHART_EVERY), len(s_plan) - 1]  # and the last
        np.testing.assert_allclose(line[:, 0] / K, c.tss.t_s[keep], atol=1e-4)
        np.testing.assert_allclose(-line[:, 1], s_plan[keep], atol=1e-3)
        actual = _rows(data[f"/charts/data/lanes/{lane}/actual"], "Points2D:positions")
        names = _rows(data[f"/charts/data/lanes/{lane}/actual"], "Points2D:labels")
        assert len(actual) == math.ceil((N_STEPS + 1) / CHART_EVERY)  # and the empty step
        seen = 0
        for (t, pts), (_, labels) in zip(actual, names, strict=True):
            i = round(t / 0.05)
            assert i % CHART_EVERY == 0
            for p, name in zip(pts, labels, strict=True):
                if name == c.vin:
                    seen += 1
                    np.testing.assert_allclose(
                        p, [K * t, -s_plan[min(i, len(s_plan) - 1)]], atol=1e-3
                    )
        assert seen == math.ceil(N_STEPS / CHART_EVERY)
    ticks = _rows(data["/charts/data/ticks/lane_labels"], "Points2D:labels")
    # each tick is logged when it enters the window (FUTURE_S ahead) and again at its
    # time, but never after the last step (6 s here)
    got = sorted((t, lb) for t, (lb,) in ticks)
    assert got == [(0.0, "0 s"), (0.0, "0 s"), (0.0, "10 s"), (0.0, "20 s")]


def test_tables_list_confirmations_and_rejections_as_columns(recorded):
    path, confs, _ = recorded
    data = _read(path)
    rows = [text for _, (text,) in _rows(data["/tables/confirmed"], "TextLog:text")]
    assert len(rows) == len(confs)
    for c, row in zip(confs, rows, strict=True):
        vin, route, entry, exit_, _delay, rounds = row.split()
        assert (vin, route) == (c.vin, c.route_id)
        assert float(entry) == pytest.approx(c.entry_time_s, abs=0.01)
        assert float(exit_) == pytest.approx(c.exit_time_s, abs=0.01)
        assert int(rounds) == c.iterations
    (rej,) = [text for _, (text,) in _rows(data["/tables/rejected"], "TextLog:text")]
    assert rej.split()[:2] == ["veh/9", "not_head"]
    counts = _rows(data["/counts/confirmed"], "Scalars:scalars")
    assert [v for _, (v,) in counts] == list(range(1, len(confs) + 1))


def test_conflict_points_cover_what_shapely_covers(ch45):
    points = find_conflict_points(ch45, ConflictTables(ch45, MARGIN_M), Shape(LENGTH_M, WIDTH_M))
    assert 5 <= len(points) <= 30
    rng = np.random.default_rng(3)
    centre = rng.uniform(-15, 15, (200, 2))
    ang = rng.uniform(-np.pi, np.pi, 200)
    heading = np.stack([np.cos(ang), np.sin(ang)], -1)
    got = covers(centre, heading, 2.75, 1.15, points.xy)
    for n in range(200):
        u, v = heading[n] * 2.75, np.array([-heading[n][1], heading[n][0]]) * 1.15
        poly = shapely.Polygon(
            [centre[n] + u + v, centre[n] - u + v, centre[n] - u - v, centre[n] + u - v]
        )
        want = [poly.buffer(1e-9).contains(shapely.Point(p)) for p in points.xy]
        assert list(got[n]) == want


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
            rec.footprints(0.0, ["a"], z[:1], z[:1], z[:1], 5.0, 1.8, route_ids=["nowhere"])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _port_closes(port: int, within_s: float = 5.0) -> bool:
    """Whether nothing listens on ``port`` any more within ``within_s``."""
    deadline = time.monotonic() + within_s
    while _port_open(port) and time.monotonic() < deadline:
        time.sleep(0.1)
    return not _port_open(port)


def test_live_recording_serves_on_loopback_and_writes_the_same_file(ch45, tmp_path):
    port = _free_port()
    confs = _confirmations(ch45)[:1]
    rec = SpaceTimeRecorder(ch45, tmp_path / "live.rrd", live_port=port)
    rec.geometry()
    assert _port_open(port)
    c = confs[0]
    rec.confirmed(c.vin, c.route_id, c.tss.t_s, c.tss.x_m, c.tss.y_m, c.tss.heading_rad,
                  LENGTH_M, WIDTH_M, c.entry_time_s, c.exit_time_s)  # fmt: skip
    _fly(rec, confs, 60)
    rec.close()
    assert _port_closes(port)
    data = _read(tmp_path / "live.rrd")
    assert len(_rows(data["/junction/vehicles"], "LineStrips2D:strips")) == 60 // TOP_EVERY


def test_the_network_view_serves_live_and_writes_the_same_file(ch45, tmp_path):
    from dica.sim_gateway.recording.network_view import TopDrawing

    port = _free_port()
    top = TopDrawing([ch45], tmp_path / "network.rrd", live_port=port)
    top.geometry([r.points(np.linspace(0.0, r.cross_length_m, 8)) for r in ch45.routes])
    assert _port_open(port)
    for k in range(10):
        top.moment(k * 0.5, np.array([[0.0, 0.0]]), np.array([90.0]), np.array([5.0]),
                   np.array([1.8]), [(0, 0, 0, 255)], [], [])  # fmt: skip
    top.close()
    assert _port_closes(port)
    data = _read(tmp_path / "network.rrd")
    assert len(_rows(data["/network/vehicles"], "LineStrips2D:strips")) == 10


# -- dica view ---------------------------------------------------------------------
@pytest.mark.parametrize("case", ["missing", "empty", "not_rrd", "live_nothing", "none"])
def test_view_without_a_recording_is_one_line_and_status_2(case, tmp_path, capsys):
    target = {"missing": tmp_path / "nope", "empty": tmp_path, "not_rrd": tmp_path / "a.txt"}
    if case == "not_rrd":
        target["not_rrd"].write_text("x")
    if case == "live_nothing":
        args = ["view", "--live", "--grpc-port", str(_free_port())]
    elif case == "none":
        args = ["view"]
    else:
        args = ["view", str(target[case])]
    assert dica(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("dica: ") and err.count("\n") == 1, err
    assert "Traceback" not in err


def test_view_web_serves_on_loopback_and_stops_its_viewer(recorded):
    path, _, _ = recorded
    port, grpc = _free_port(), _free_port()
    cmd = [sys.executable, "-m", "dica.tools.cli", "view", "--web", "--port", str(port)]
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


def test_view_live_web_points_the_page_at_the_live_observer(ch45, tmp_path):
    live = _free_port()
    rec = SpaceTimeRecorder(ch45, tmp_path / "live.rrd", live_port=live)
    port = _free_port()
    cmd = [sys.executable, "-m", "dica.tools.cli", "view", "--live", "--web", "--port", str(port)]
    cmd += ["--grpc-port", str(live)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith(f"web viewer: http://127.0.0.1:{port}/"), line
        assert f"rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{live}%2Fproxy" in line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as resp:
            assert resp.status == 200
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        rec.close()


def test_time_padding_widens_every_reserved_box(ch45, tmp_path):
    """With the ICA's time padding the boxes show what it reserved: that much wider."""
    conf = _confirmations(ch45)[1]
    widths = {}
    for pad in (0.0, 0.5):
        rec = SpaceTimeRecorder(ch45, tmp_path / f"pad{pad}.rrd")
        t = conf.tss
        rec.confirmed(conf.vin, conf.route_id, t.t_s, t.x_m, t.y_m, t.heading_rad,
                      LENGTH_M, WIDTH_M, conf.entry_time_s, conf.exit_time_s,
                      time_pad_s=pad)  # fmt: skip
        rec.close()
        data = _read(tmp_path / f"pad{pad}.rrd")
        ((_, halves),) = _rows(data["/charts/data/zones/reserved"], "Boxes2D:half_sizes")[:1]
        widths[pad] = np.array([2 * h[0] / K for h in halves])
    np.testing.assert_allclose(widths[0.5], widths[0.0] + 1.0, atol=1e-4)


def test_a_live_view_on_a_taken_port_is_refused_before_the_run(ch45, tmp_path):
    """Another run's live view holds the port: Rerun only logged that it could not
    listen, then the observer's last flush raised and its file went without its end.
    The port is checked first; the file is never started."""
    import socket

    from dica.sim_gateway.recording.network_view import TopDrawing

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(OSError, match="another live view"):
            SpaceTimeRecorder(ch45, tmp_path / "live.rrd", live_port=port)
        with pytest.raises(OSError, match="another live view"):
            TopDrawing([ch45], tmp_path / "network.rrd", live_port=port)
