"""The built-in networks and their origin-destination demand, and ``dica network``: every
junction signal-free or by lights on the same roads and the same vehicles, measured per
vehicle from SUMO's own trip records, zero collisions by both checks."""

from __future__ import annotations

import csv
import itertools
import json
import subprocess
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import pytest

from dica.ica.netfile import crossing_junctions
from dica.sim_gateway.network_layouts import build_network
from dica.sim_gateway.od_demand import OdDemand, read_turns, write_od_routes
from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory):
    d = tmp_path_factory.mktemp("networks")
    return {n: build_network(n, d) for n in ("corridor", "grid")}


def _routes(path: Path) -> list[tuple[float, list[str]]]:
    return [
        (float(v.get("depart")), v.find("route").get("edges").split())
        for v in ET.parse(path).getroot().iter("vehicle")
    ]


def test_the_networks_are_a_corridor_of_four_and_a_3x3_grid(built):
    assert crossing_junctions(built["corridor"].net_path) == ("J00", "J10", "J20", "J30")
    assert len(crossing_junctions(built["grid"].net_path)) == 9
    turns = read_turns(built["grid"].net_path, built["grid"].junctions)
    assert len(turns.entries) == 12  # three roads in on each side
    assert len(read_turns(built["corridor"].net_path, built["corridor"].junctions).entries) == 10


def test_the_demand_comes_in_at_every_entry_at_its_volume_and_turns_by_the_ratios(built, tmp_path):
    g = built["grid"]
    out = tmp_path / "od.rou.xml"
    n = write_od_routes(g.net_path, g.junctions, OdDemand(600.0, 1800.0, seed=3), out)
    routes = _routes(out)
    assert n == len(routes)
    per_entry = Counter(edges[0] for _, edges in routes)
    assert len(per_entry) == 12
    for entry, count in per_entry.items():  # Poisson, 300 expected: within 4 sigma
        assert abs(count - 300) < 4 * 300**0.5, (entry, count)
    departs = [t for t, _ in routes]
    assert departs == sorted(departs) and departs[0] > 0.0 and departs[-1] < 1800.0
    # at the first junction: through where the road goes on, by the ratios
    turns = read_turns(g.net_path, g.junctions)
    first = Counter()
    for _, edges in routes:
        for t in ("left", "through", "right"):
            if edges[1] in turns.next.get((edges[0], t), ()):
                first[t] += 1
    total = sum(first.values())
    assert total == len(routes)
    assert abs(first["through"] / total - 0.6) < 0.03
    assert abs(first["left"] / total - 0.2) < 0.03
    # every route is connected road to road and ends on a road out of the network
    for _, edges in routes:
        assert edges[-1] not in turns.inside
        for a, b in itertools.pairwise(edges):
            assert any(b in turns.next.get((a, t), ()) for t in ("left", "through", "right"))


def test_the_same_seed_draws_the_same_vehicles(built, tmp_path):
    g = built["corridor"]
    a, b, c = (tmp_path / f"{k}.rou.xml" for k in "abc")
    write_od_routes(g.net_path, g.junctions, OdDemand(300.0, 300.0, seed=21), a)
    write_od_routes(g.net_path, g.junctions, OdDemand(300.0, 300.0, seed=21), b)
    write_od_routes(g.net_path, g.junctions, OdDemand(300.0, 300.0, seed=66), c)
    assert a.read_text() == b.read_text() != c.read_text()


def _network(tmp_path: Path, *args: str) -> tuple[subprocess.CompletedProcess, Path]:
    out = tmp_path / "run"
    p = dica_run(
        [*DICA, "network", *args, "--out", str(out), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    return p, out


CONTROLS = ("dica", "static", "actuated", "coordinated", "max-pressure")


@pytest.fixture(scope="module")
def corridor_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple]:
    """The corridor under every control, the same vehicles (an arterial at 700 an hour each
    way, the side roads at 250), for 120 s."""
    d = tmp_path_factory.mktemp("corridor")
    runs = {}
    for control in CONTROLS:
        runs[control] = _network(
            d / control, "--layout", "corridor", "--control", control, "--volume", "250",
            "--entry-volume", "W00_J00=700", "--entry-volume", "E30_J30=700",
            "--duration", "120",
        )  # fmt: skip
    return runs


@pytest.mark.parametrize("control", CONTROLS)
def test_a_corridor_runs_signal_free_and_by_lights_and_every_vehicle_leaves(corridor_runs, control):
    p, out = corridor_runs[control]
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "metrics.json").read_text())
    net = m["network"]
    drawn = m["network_run"]["drawn_vehicles"]
    assert net["vehicles"] == net["finished"] == drawn > 80
    assert net["in_net_at_end"] == net["waiting_to_enter_at_end"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert m["sumo_collisions_elsewhere"] == 0 and m["unconfirmed_entries"] == 0
    assert set(m["junctions"]) == {"J00", "J10", "J20", "J30"}
    with (out / "trips.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == drawn
    assert all(float(r["delay_s"]) > -1.0 for r in rows)  # never faster than free flow
    assert min(float(r["scheduled_s"]) for r in rows) >= 0.0
    if control == "dica":
        assert m["stood_inside"] == 0 and m["requests"]["count"] > drawn
    else:
        assert m["requests"]["count"] == 0  # the lights decide: no ICA
    if control == "max-pressure":
        assert m["max_pressure_switches"] > 10
    if control == "coordinated":
        offsets = ET.parse(out / "offsets.add.xml").getroot().findall("tlLogic")
        assert len(offsets) == 4 and len({o.get("offset") for o in offsets}) > 1
    assert f"corridor, {control}: {drawn} vehicles, {drawn} finished" in p.stdout


def test_every_control_sees_the_same_vehicles(corridor_runs):
    demands = {c: (out / "od.rou.xml").read_text() for c, (_, out) in corridor_runs.items()}
    assert len(set(demands.values())) == 1


def test_the_lights_clear_every_green_with_a_yellow_and_an_all_red(tmp_path):
    lit = build_network("corridor", tmp_path, "static")
    assert lit.clearance_s == (4.0, 3.0)  # 1 s + 13.89 / 6; the longest left turn's way
    root = ET.parse(lit.net_path).getroot()
    for tl in root.iter("tlLogic"):
        states = [(float(p.get("duration")), p.get("state")) for p in tl.iter("phase")]
        for i, (_, state) in enumerate(states):
            if "G" in state:  # a green: then a yellow, then all red
                y, r = states[(i + 1) % len(states)], states[(i + 2) % len(states)]
                assert "y" in y[1] and y[0] == 4.0
                assert set(r[1]) == {"r"} and r[0] == 3.0


def test_the_report_puts_the_signal_free_network_beside_the_best_light(corridor_runs, tmp_path):
    root = next(iter(corridor_runs.values()))[1].parent.parent
    p = dica_run(
        [*DICA, "report", str(root), "--out", str(tmp_path)],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "5 network runs in 5 groups" in p.stdout
    md = (tmp_path / "networks.md").read_text()
    for control in CONTROLS:
        assert (
            f"| corridor | 250/h per entry, E30_J30 700/h, W00_J00 700/h, 120 s | {control} |" in md
        )
    best = [ln for ln in md.splitlines() if ln.startswith("| corridor |") and "/ " in ln]
    assert len(best) == 1  # one comparison row: DICA against the best of the three lights
    assert (tmp_path / "network-corridor-delay.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--turns", "1,2"], "--turns wants three ratios"),
        (["--turns", "0,0,0"], "--turns wants three ratios"),
        (["--junctions", "J00"], "a built-in layout runs all"),
        (["--control", "static", "--algorithm", "basic"], "--algorithm is DICA's"),
        (["--net", "nowhere.net.xml"], "network file not found"),
        (["--volume", "-3"], "--volume must be a number of vehicles per hour"),
        (["--routes", "nowhere.rou.xml"], "route file not found"),
        (["--entry-volume", "W00_J00"], "--entry-volume wants ROAD=VEHICLES_PER_HOUR"),
        (["--entry-volume", "NOWHERE=100"], "NOWHERE is not a road into the network"),
        (["--control", "static", "--record"], "--record draws the ICAs' reservations"),
    ],
)
def test_what_a_network_run_cannot_serve_is_refused_in_one_line(tmp_path, args, says):
    p, _ = _network(tmp_path, *args)
    assert p.returncode == 2, p.stderr
    assert says in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "Traceback" not in p.stderr


def test_each_junction_is_recorded_with_its_own_views(tmp_path):
    """--record: one recording per junction, each with its own lanes' space-time charts
    and its own vehicles' plans, and the network from above with every vehicle and every
    junction's plans (dica view opens every .rrd of the run)."""
    from tests.test_recording import _read, _rows, _static

    p, out = _network(tmp_path, "--layout", "corridor", "--volume", "400", "--duration", "60",
                      "--record")  # fmt: skip
    assert p.returncode == 0, p.stderr
    files = {f.name for f in out.glob("*.rrd")}
    assert files == {"spacetime.rrd", "spacetime-J10.rrd", "spacetime-J20.rrd",
                     "spacetime-J30.rrd", "network.rrd"}  # fmt: skip
    for name, junction in (("spacetime.rrd", "J00"), ("spacetime-J20.rrd", "J20")):
        data = _read(out / name)
        plans = {e.split("/")[4] for e in data if e.endswith("/plans")}
        assert plans and all(lane.split("_")[1] == junction for lane in plans), plans
    top = _read(out / "network.rrd")
    names = _static(top["/network/names"], "Points2D:labels")
    assert sorted(names) == ["J00", "J10", "J20", "J30"]
    vehicles = _rows(top["/network/vehicles"], "LineStrips2D:strips")
    assert len(vehicles) >= 100  # every 0.5 s
    assert max(len(v) for _, v in vehicles) >= 10
    plans = _rows(top["/network/plans"], "LineStrips2D:strips")
    assert sum(1 for _, p in plans if p) >= 50  # confirmed plans, held at some junction


def test_max_pressure_keeps_green_where_the_vehicles_are(tmp_path):
    """Only the corridor's arterial carries traffic: max-pressure gives it green once at
    each junction and keeps it (the side roads never have the pressure), where the
    fixed-time lights go on cycling; its vehicles are delayed less."""
    args = ("--layout", "corridor", "--volume", "0", "--entry-volume", "W00_J00=600",
            "--entry-volume", "E30_J30=600", "--duration", "120")  # fmt: skip
    runs = {}
    for control in ("max-pressure", "static"):
        p, out = _network(tmp_path / control, *args, "--control", control)
        assert p.returncode == 0, p.stderr
        runs[control] = json.loads((out / "metrics.json").read_text())
    assert runs["max-pressure"]["max_pressure_switches"] <= 4  # one per junction at most
    delay = {c: m["network"]["mean_delay_s"] for c, m in runs.items()}
    assert delay["max-pressure"] < 0.5 * delay["static"], delay


def test_the_lights_of_a_net_without_lights_are_refused_and_missing_ones_named(tmp_path):
    """A control by lights on a user's net runs the net's own lights: a net with none at
    the chosen junctions is refused in one line (it ran signal-less under the lights'
    name before), and where only some junctions have lights the others are named, as
    keeping the net's right of way; max-pressure needs a light at each."""
    from tests.user_nets import make, tool

    net = tmp_path / "g.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "2", "--grid.length", "200",
          "--grid.attach-length", "150", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    for control in ("static", "coordinated", "actuated", "max-pressure"):
        p, _ = _network(tmp_path / control, "--net", str(net), "--control", control)
        assert p.returncode == 2, p.stderr
        assert "4 of the 4 chosen junctions have none" in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
    half = tmp_path / "half.net.xml"
    make([tool("netconvert"), "-s", str(net), "--tls.set", "A0,B1", "-o", str(half)])
    p, _ = _network(tmp_path / "mp", "--net", str(half), "--control", "max-pressure")
    assert p.returncode == 2 and "2 of the 4 chosen junctions have none (A1, B0)" in p.stderr
    p, _ = _network(tmp_path / "half", "--net", str(half), "--control", "static",
                      "--duration", "20", "--drain", "0")  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "note: 2 of the 4 junctions have no light in half.net.xml (A1, B0)" in p.stderr
