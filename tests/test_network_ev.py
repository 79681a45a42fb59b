"""Emergency vehicles through a network of junctions: drawn into the demand or of a
route file's emergency class, let through first by every junction's reactive DICA,
and measured against their free flow, in real SUMO runs of the built-in corridor."""

from __future__ import annotations

import csv
import json
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from dica.sim_gateway.network_layouts import build_network
from dica.sim_gateway.od_demand import DemandError, OdDemand, write_od_routes
from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
ARTERIAL = ("--layout", "corridor", "--volume", "250", "--entry-volume", "W00_J00=700",
            "--entry-volume", "E30_J30=700", "--duration", "120")  # fmt: skip


def _vehicles(path: Path) -> list[tuple[str, str, str, str]]:
    return [
        (v.get("id"), v.get("type"), v.get("depart"), v.find("route").get("edges"))
        for v in ET.parse(path).getroot().iter("vehicle")
    ]


def test_emergency_vehicles_are_drawn_apart_and_move_no_other_vehicle(tmp_path):
    g = build_network("corridor", tmp_path / "net")
    plain, with_ev = tmp_path / "a.rou.xml", tmp_path / "b.rou.xml"
    n = write_od_routes(g.net_path, g.junctions, OdDemand(600.0, 1800.0, seed=5), plain)
    m = write_od_routes(g.net_path, g.junctions, OdDemand(600.0, 1800.0, 5, ev_prob=0.1), with_ev)
    a, b = _vehicles(plain), _vehicles(with_ev)
    assert n == m == len(a) == len(b) > 1000
    # the same vehicles at the same times on the same routes; some of them emergency
    assert [(i, t, r) for i, _, t, r in a] == [(i, t, r) for i, _, t, r in b]
    assert {k for _, k, _, _ in a} == {"car"}
    evs = sum(k == "emergency" for _, k, _, _ in b)
    assert abs(evs - 0.1 * n) < 4 * (0.09 * n) ** 0.5  # binomial: within 4 sigma
    assert 'vClass="emergency"' in with_ev.read_text()
    assert "emergency" not in plain.read_text()  # without EVs the file is as it was
    with pytest.raises(DemandError, match="0 to 1"):
        OdDemand(600.0, 60.0, ev_prob=1.5)


def _network(out: Path, *args: str) -> subprocess.CompletedProcess:
    return dica_run(
        [*DICA, "network", *args, "--out", str(out), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip


@pytest.fixture(scope="module")
def ev_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple]:
    """The corridor's arterial with one vehicle in ten an EV, for 120 s: plain enhanced
    DICA, reactive DICA without and with the EVs' notices ahead, and reactive DICA on the
    drawn demand given as a route file."""
    d = tmp_path_factory.mktemp("ev")
    runs = {}
    for name, algo, more in (
        ("dica", "enhanced", ()),
        ("rdica", "rdica", ()),
        ("rdica-ahead", "rdica", ("--ev-notices",)),  # each EV tells the junctions ahead
    ):
        out = d / name
        p = _network(out, *ARTERIAL, "--ev-prob", "0.1", "--algorithm", algo, *more)
        runs[name] = (p, out)
    for control in ("static", "preempt"):  # the same fixed-time lights, without and with
        out = d / control
        runs[control] = (_network(out, *ARTERIAL, "--ev-prob", "0.1", "--control", control), out)
    routes = d / "rdica" / "od.rou.xml"
    out = d / "file"
    p = _network(out, "--layout", "corridor", "--routes", str(routes), "--duration", "120",
                 "--algorithm", "rdica")  # fmt: skip
    runs["file"] = (p, out)
    return runs


@pytest.mark.parametrize("name", ["dica", "rdica", "rdica-ahead", "file", "static", "preempt"])
def test_emergency_vehicles_cross_the_corridor_safely_and_are_measured_apart(ev_runs, name):
    p, out = ev_runs[name]
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "metrics.json").read_text())
    drawn = _vehicles(ev_runs["rdica"][1] / "od.rou.xml")
    ev_ids = {i for i, k, _, _ in drawn if k == "emergency"}
    assert len(ev_ids) >= 8
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    if name not in ("static", "preempt"):  # a light's permissive turns wait inside
        assert m["stood_inside"] == 0
    net = m["network"]
    assert net["vehicles"] == net["finished"] == len(drawn)
    ev = net["emergency"]
    assert ev["vehicles"] == ev["finished"] == len(ev_ids)
    assert ev["mean_free_flow_s"] > 20.0  # they crossed the corridor, not a corner of it
    # no faster than free flow; signal-free, not much slower on a corridor this light (a
    # fixed-time light's red costs an EV a cycle's part)
    most = 5.0 if name in ("static", "preempt") else 2.0
    assert 1.0 - 1e-6 <= ev["mean_travel_to_free_flow"] <= ev["max_travel_to_free_flow"] < most
    assert net["normal"]["finished"] == len(drawn) - len(ev_ids)
    with (out / "trips.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["vid"] for r in rows if r["ev"] == "1"} == ev_ids
    assert "emergency vehicles: " in p.stdout
    if name not in ("rdica", "rdica-ahead", "file"):
        assert all("reactive" not in j for j in m["junctions"].values())
        return
    # every junction's ICA is reactive DICA, and the EVs started events at them
    reactive = {k: j["reactive"] for k, j in m["junctions"].items()}
    assert set(reactive) == {"J00", "J10", "J20", "J30"}
    assert sum(r["events"] for r in reactive.values()) >= len(ev_ids)
    assert all(r["added_delay_max_s"] <= r["max_added_delay_s"] + 1e-6 for r in reactive.values())
    notices = sum(r["notices"] for r in reactive.values())
    if name == "rdica-ahead":  # every EV told each junction ahead, every 2 s
        assert notices >= 2 * len(ev_ids)
    else:
        assert notices == 0


def test_reactive_dica_decides_otherwise_than_plain_dica_on_the_same_vehicles(ev_runs):
    """The same demand, the same SUMO: only the EVs' reorderings can tell the runs apart."""
    plain = (ev_runs["dica"][1] / "vehicles.csv").read_bytes()
    assert (ev_runs["rdica"][1] / "vehicles.csv").read_bytes() != plain
    assert (ev_runs["file"][1] / "vehicles.csv").read_bytes() == (
        ev_runs["rdica"][1] / "vehicles.csv"
    ).read_bytes()


def test_the_evs_notices_ahead_clear_their_lanes_at_the_junctions_ahead(ev_runs):
    """The same vehicles with and without the EVs' notices ahead: with them, junctions
    held vehicles across an EV's way before the EV reached their regions, and so decided
    otherwise."""
    m = json.loads((ev_runs["rdica-ahead"][1] / "metrics.json").read_text())
    held = {k: j["reactive"]["notice_held"] for k, j in m["junctions"].items()}
    assert sum(held.values()) > 0, held
    assert (ev_runs["rdica"][1] / "vehicles.csv").read_bytes() != (
        ev_runs["rdica-ahead"][1] / "vehicles.csv"
    ).read_bytes()


def test_pre_empting_lights_serve_the_evs_along_the_corridor(ev_runs):
    """The same fixed-time lights, the same vehicles: pre-empted 20 s ahead of each EV,
    they let the EVs through faster and with fewer stops, and serve each light an EV
    came within reach of."""
    fixed, pre = (json.loads((ev_runs[c][1] / "metrics.json").read_text()) for c in
                  ("static", "preempt"))  # fmt: skip
    a, b = fixed["network"]["emergency"], pre["network"]["emergency"]
    assert b["mean_travel_time_s"] < 0.9 * a["mean_travel_time_s"]
    assert b["mean_stops"] < a["mean_stops"]
    served = pre["preemption"]
    assert (
        served["lead_s"] == 20.0
        and served["served"] == served["extend"] + served["return"] + served["cut"]
    )
    assert b["vehicles"] <= served["served"] <= served["calls"]
    assert served["cut"] > 0  # some EVs came to a red: cut to their green with clearances
    assert "preemption" not in fixed


def test_a_run_without_emergency_vehicles_keeps_its_trip_file_as_it_was(tmp_path):
    p = _network(tmp_path / "run", "--layout", "corridor", "--volume", "100", "--duration", "30")
    assert p.returncode == 0, p.stderr
    head = (tmp_path / "run" / "trips.csv").read_text().splitlines()[0]
    assert head == "vid,scheduled_s,depart_s,arrival_s,travel_s,free_s,delay_s,stops,route_m"
    assert "emergency" not in json.loads((tmp_path / "run" / "metrics.json").read_text())["network"]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--ev-prob", "1.5"], "--ev-prob is a probability"),
        (["--ev-prob", "nan"], "--ev-prob is a probability"),
        (["--routes", "x.rou.xml", "--ev-prob", "0.1"], "a route file's are those of a vType"),
    ],
)
def test_a_bad_emergency_option_is_refused_in_one_line(tmp_path, args, says):
    p = _network(tmp_path / "run", "--layout", "corridor", *args)
    assert p.returncode == 2, p.stderr
    assert says in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_the_report_puts_the_evs_beside_the_pre_empting_lights(ev_runs, tmp_path):
    from dica.tools.network_report import load_network_runs, write_report

    runs = [
        r for n in ("dica", "rdica", "static", "preempt") for r in load_network_runs(ev_runs[n][1])
    ]
    write_report(runs, tmp_path)
    md = (tmp_path / "networks.md").read_text()
    table = md[md.index("## Emergency vehicles") :].splitlines()
    rows = {ln.split(" | ")[2]: ln.rstrip(" |").split(" | ") for ln in table if "EV p 0.1" in ln}
    assert set(rows) == {"dica", "dica-rdica", "static", "preempt"}  # rdica a control of its own
    assert rows["preempt"][8] == "1.00"  # the EVs' travel against the pre-empting lights'
    assert rows["dica"][10] == "1.00"  # the others' delay against plain DICA's
    fixed = json.loads((ev_runs["static"][1] / "metrics.json").read_text())
    assert rows["static"][3] == str(fixed["network"]["emergency"]["vehicles"])
