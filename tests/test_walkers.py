"""People on foot at a signal-free junction, in real SUMO: held at the kerb until the
ICA gives them the crossing, and checked against every vehicle's body."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from dica.ica.core.walk import WAIT_BOUND_S
from dica.sim_gateway.recording.style import rgba
from dica.sim_gateway.safety import PersonCheck
from tests.dica_cli import DICA, dica_run
from tests.test_recording import _read, _rows

ROOT = Path(__file__).resolve().parents[1]


def _run(out: Path, *args: str) -> dict:
    p = dica_run(
        [*DICA, "run", "--out", str(out), "--quiet", *args],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    return json.loads((out / "metrics.json").read_text())


def test_people_cross_and_no_vehicle_touches_one(tmp_path):
    """Vehicles and people at the chapter 4-5 junction with sidewalks: every person is
    accounted for, waited at the kerb for the ICA's go, and no vehicle came near a body
    by the independent check or by SUMO's own."""
    m = _run(tmp_path / "r", "--layout", "ch45-walk", "--volume", "150", "--peds", "200",
             "--duration", "400", "--seed", "21", "--record")  # fmt: skip
    w = m["walkers"]
    assert w["generated"] > 60 and w["crossed"] > 40
    parts = ("crossed", "at_kerb_at_end", "on_crossing_at_end", "not_at_a_kerb_yet",
             "walked_elsewhere")  # fmt: skip
    assert sum(w[k] for k in parts) == w["generated"]  # every person accounted for
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0
    assert w["min_person_gap_m"] > 0.0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["crossed"] > 80
    rows = list(csv.DictReader((tmp_path / "r" / "persons.csv").open()))
    assert len(rows) == w["generated"]
    crossed = [r for r in rows if r["off_s"]]
    for r in crossed:  # each stepped on only once its start had come
        assert float(r["go_s"]) >= float(r["kerb_s"]) - 1e-6
        assert float(r["on_s"]) >= float(r["go_s"]) - 1e-6
    assert any(float(r["go_s"]) > float(r["kerb_s"]) + 1.0 for r in crossed)  # some waited
    assert 1.0 < w["max_ask_to_go_s"] <= WAIT_BOUND_S + 1e-6
    # the top view shows them: a row of dots every 0.25 s; the crossing bands hold the
    # vehicles' and the walkers' reservations, and every person on a crossing was there
    # within its walker's (no red dot)
    data = _read(tmp_path / "r" / "spacetime.rrd")
    assert sum(b.num_rows for b in data["/junction/people"]) > 300
    assert _rows(data["/charts/data/zones/crossing_holds"], "Boxes2D:labels")
    assert len(_rows(data["/charts/data/zones/walks"], "Boxes2D:labels")) > 20
    dots = [c for _, row in _rows(data["/charts/data/zones/people"], "Points2D:colors")
            for c in row]  # fmt: skip
    assert len(dots) > 100 and rgba((220, 30, 30)) not in dots


def test_people_on_a_net_of_guessed_crossings_go_when_given_the_crossing(tmp_path):
    """A user's net: 40 km/h, two lanes, 100 m blocks, sidewalks and crossings guessed by
    netgenerate, without priority, where SUMO's own persons would wait for a gap in the
    traffic and step off after their slot. Given the crossing, they go: nobody is still
    on it after its slot, and nobody is touched."""
    from tests.user_nets import make, tool

    net = tmp_path / "grid.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
          "--default.lanenumber", "2", "--default.speed", "11.11", "--sidewalks.guess", "true",
          "--crossings.guess", "true", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    m = _run(tmp_path / "r", "--net", str(net), "--junction", "B1", "--volume", "100",
             "--peds", "200", "--duration", "400")  # fmt: skip
    w = m["walkers"]
    assert w["crossed"] > 60 and w["overran_slot"] == 0
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0


def test_people_cross_a_network_of_signal_free_junctions(tmp_path):
    """A 2x2 grid of a user's net with sidewalks and crossings guessed, every junction
    under its own ICA, people at every crossing: each junction's ICA gives its own
    crossings, every person is accounted for, and nobody is touched by either check."""
    import csv
    import xml.etree.ElementTree as ET

    from dica.sim_gateway.od_demand import OdDemand, write_od_routes
    from tests.user_nets import make, tool

    net = tmp_path / "grid.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "2", "--grid.length", "120",
          "--grid.attach-length", "80", "--default.lanenumber", "2", "--sidewalks.guess",
          "true", "--crossings.guess", "true", "--no-turnarounds", "true",
          "-o", str(net)])  # fmt: skip
    inner = [j.get("id") for j in ET.parse(net).getroot().iter("junction")
             if j.get("type") not in ("internal", "dead_end")]  # fmt: skip
    assert len(inner) == 4
    routes = tmp_path / "od.rou.xml"
    write_od_routes(net, inner, OdDemand(300, 100, 12), routes)
    m = _run(tmp_path / "r", "--net", str(net), "--routes", str(routes), "--junctions", "all",
             "--peds", "300", "--duration", "120", "--seed", "21", "--record")  # fmt: skip
    w = m["walkers"]
    parts = ("crossed", "at_kerb_at_end", "on_crossing_at_end", "not_at_a_kerb_yet",
             "walked_elsewhere")  # fmt: skip
    assert sum(w[k] for k in parts) == w["generated"] > 100  # every person accounted for
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0 and w["overran_slot"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["crossed"] > 100
    assert 0.0 < w["max_ask_to_go_s"] <= WAIT_BOUND_S + 1e-6
    rows = list(csv.DictReader((tmp_path / "r" / "persons.csv").open()))
    crossed_at = {r["crossing"].split("_")[0].lstrip(":") for r in rows if r["off_s"]}
    assert crossed_at == set(inner)  # every junction's ICA gave its crossings
    # the view from above shows the people; each junction's recording its walkers' slots
    top = _read(tmp_path / "r" / "network.rrd")
    assert sum(b.num_rows for b in top["/network/people"]) > 100
    for k, j in enumerate(sorted(inner)):
        rrd = tmp_path / "r" / ("spacetime.rrd" if k == 0 else f"spacetime-{j}.rrd")
        assert _rows(_read(rrd)["/charts/data/zones/walks"], "Boxes2D:labels"), j


ROUTES_WITH_PEOPLE = """<routes>
    <flow id="we" begin="0" end="300" vehsPerHour="360" from="A1B1" to="B1C1"/>
    <flow id="ns" begin="0" end="300" vehsPerHour="360" from="B2B1" to="B1B0"/>
    <flow id="left" begin="0" end="300" vehsPerHour="120" from="C1B1" to="B1B0"/>
    <personFlow id="pw" begin="0" end="300" period="12"><walk from="A1B1" to="B1A1"/></personFlow>
    <personFlow id="pn" begin="3" end="300" period="17"><walk from="B2B1" to="B1C1"/></personFlow>
    <personFlow id="pd" begin="5" end="300" period="23"><personTrip from="C1B1" to="B1A1"/>
    </personFlow>
</routes>
"""


def test_a_route_files_people_are_held_where_they_come_and_cross_untouched(tmp_path):
    """A user's route file with vehicles and people on foot (walks and walk-only person
    trips): each person coming to a crossing of the junction is held on the walking area
    until the ICA gives it the crossing; both checks stay at zero. People who ride are
    refused in one line."""
    from tests.user_nets import make, tool

    net = tmp_path / "grid.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
          "--default.lanenumber", "2", "--default.speed", "11.11", "--sidewalks.guess", "true",
          "--crossings.guess", "true", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    routes = tmp_path / "people.rou.xml"
    routes.write_text(ROUTES_WITH_PEOPLE)
    m = _run(tmp_path / "r", "--net", str(net), "--junction", "B1", "--routes", str(routes),
             "--duration", "400")  # fmt: skip
    w = m["walkers"]
    assert w["crossed"] > 20 and w["overran_slot"] == 0 and w["mean_wait_s"] is not None
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["crossed"] > 60
    # dica network says how the people fared too (and a touch would end it with status 1)
    p = dica_run(
        [*DICA, "network", "--net", str(net), "--junctions", "B1", "--routes", str(routes),
         "--duration", "60", "--out", str(tmp_path / "n"), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "people: 0 steps a vehicle touched a person" in p.stdout
    riders = tmp_path / "riders.rou.xml"
    riders.write_text(ROUTES_WITH_PEOPLE.replace(
        '<walk from="A1B1" to="B1A1"/>', '<ride from="A1B1" to="B1A1" lines="ANY"/>'))  # fmt: skip
    p = dica_run(
        [*DICA, "run", "--net", str(net), "--junction", "B1", "--routes", str(riders),
         "--duration", "10", "--out", str(tmp_path / "x")],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert p.returncode == 2 and "do more than walk" in p.stderr and "Traceback" not in p.stderr
    # a 12 m truck turning right cuts the corner over the sidewalk, where people walk
    # outside every reservation (792 steps of touches in 400 s): refused with people
    trucks = tmp_path / "trucks.rou.xml"
    trucks.write_text(ROUTES_WITH_PEOPLE.replace("<routes>", (
        '<routes><vType id="truck" vClass="truck" accel="2.6" decel="4.5" length="12" '
        'width="2.55"/><flow id="tr" type="truck" begin="0" end="300" vehsPerHour="200" '
        'from="B2B1" to="B1A1"/>'), 1))  # fmt: skip
    p = dica_run(
        [*DICA, "run", "--net", str(net), "--junction", "B1", "--routes", str(trucks),
         "--duration", "10", "--out", str(tmp_path / "t")],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert "12 m x 2.55 m vehicle turning on" in p.stderr
    assert "reaches over the sidewalk" in p.stderr


def test_the_built_in_layouts_cars_keep_off_the_sidewalks():
    """Where people walk along the roads, outside every crossing's reservation, no car
    of the drawn demand reaches, on any turn of the -walk layouts; a 12 m truck does."""
    from dica.ica.core.waiting import sidewalk_sweeps
    from dica.ica.netfile import load_intersection, sidewalks
    from dica.sim_gateway.scenario import LAYOUTS, default_scenario

    for layout in (x for x in LAYOUTS if x.endswith("-walk")):
        sc = default_scenario(layout)
        inter = load_intersection(sc.net_path, sc.junction_id)
        walks = sidewalks(sc.net_path, sc.junction_id)
        assert len(walks) >= 6, layout  # every arm's two sidewalks, a segment or more each
        assert sidewalk_sweeps(inter.routes, walks, 5.0, 1.8) == [], layout
        assert sidewalk_sweeps(inter.routes, walks, 12.0, 2.55), layout


def test_the_person_check_sees_what_a_light_lets_happen(tmp_path):
    """The check is not blind: under SUMO's own actuated light, whose drivers yield to
    walkers only by SUMO's model, turning cars brush walkers at the corners and the
    check counts it (SUMO's own, which looks at crossings only, does not), says so on
    its own line, and the run ends with status 1 as for any collision."""
    out = tmp_path / "a"
    p = dica_run(
        [*DICA, "run", "--out", str(out), "--layout", "ch45-walk", "--algorithm", "actuated",
         "--volume", "150", "--peds", "200", "--duration", "400", "--seed", "21"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["walkers"]["person_hits"] > 0 and m["walkers"]["crossed"] > 40
    assert p.returncode == 1, p.stderr
    said = f"people: {m['walkers']['person_hits']} steps a vehicle touched a person"
    assert said in p.stdout, p.stdout


def test_a_body_touching_a_car_is_a_hit():
    region = np.array([[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]])
    check = PersonCheck(region)
    car = (["v"], np.array([[0.0, 0.0]]), np.array([0.0]), np.array([5.0]), np.array([2.0]))
    # the car faces north, front bumper at the origin: x in [-1, 1], y in [-5, 0]
    assert check.observe(0.0, *car, ["p"], np.array([[1.2, -2.0]]), np.array([0.25])) == 1
    assert check.observe(0.1, *car, ["q"], np.array([[1.6, -2.0]]), np.array([0.25])) == 0
    far = check.observe(0.2, *car, ["r"], np.array([[30.0, 30.0]]), np.array([0.25]))
    assert far == 0  # beyond the junction: not watched
    r = check.report()
    assert r.hits == 1 and r.hit_pairs == [(0.0, "v", "p")] and r.min_gap_m == 0.0


@pytest.mark.parametrize(
    "args, says",
    [
        (["--layout", "ch45", "--peds", "100"], "has no pedestrian crossings"),
        (["--layout", "ch45-walk", "--peds", "-1"], "--peds must be between 0"),
        (["--layout", "ch45-walk", "--peds", "3601"], "and 3600 persons per hour"),
    ],
)
def test_people_where_the_junction_cannot_have_them_is_one_clear_line(tmp_path, args, says):
    p = dica_run(
        [*DICA, "run", "--out", str(tmp_path / "x"), "--duration", "10", *args],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert p.returncode == 2, p.stdout + p.stderr
    assert says in p.stderr and "Traceback" not in p.stderr


@pytest.mark.cluster
def test_a_lockstep_cluster_with_people_makes_the_embedded_decisions(tmp_path):
    """The gateway asks the ICA process for each walker over Zenoh (WALK -> GO) before the
    step's clock: the vehicles and the people cross as in one process, byte for byte. The
    observer draws what the embedded recording does: the walkers' slots the ICA publishes
    and the people the gateway sees."""
    from tests.test_cluster import _cluster

    common = ["--layout", "ch45-walk", "--volume", "150", "--peds", "200", "--duration", "120",
              "--seed", "21"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "1", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _run(tmp_path / "rec", *common, "--record")  # recording decides nothing
    for name in ("vehicles.csv", "persons.csv"):
        assert (tmp_path / "cl" / name).read_bytes() == (tmp_path / "rec" / name).read_bytes()
    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    assert m["walkers"]["crossed"] > 5 and m["walkers"]["person_hits"] == 0
    assert m["walks_unanswered"] == 0
    ica = json.loads((tmp_path / "cl" / "ica.json").read_text())
    assert ica["walks"] >= m["walkers"]["crossed"]
    drawn = {}
    for run in ("cl", "rec"):
        data = _read(tmp_path / run / "spacetime.rrd")
        walks = _rows(data["/charts/data/zones/walks"], "Boxes2D:labels")
        drawn[run] = {
            "walks": sorted(tuple(labels) for _, labels in walks),
            "people": _rows(data["/charts/data/zones/people"], "Points2D:positions"),
            "top": sum(b.num_rows for b in data["/junction/people"]),
        }
    assert len(drawn["cl"]["walks"]) >= ica["walks"] and drawn["cl"]["top"] > 100
    assert drawn["cl"] == drawn["rec"]


def test_a_person_hit_counts_against_the_junction_only_on_its_own_lanes_and_roads():
    """SUMO's person collisions at junctions the net's own control runs are reported
    apart (they are SUMO's drivers', not the ICA's); on the junction's crossings, walking
    areas and the roads it joins (their sidewalks too) they count against the run."""
    from dica.ica.netfile import load_intersection
    from dica.sim_gateway.junction import Junction
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario("ch45-walk")
    j = Junction(load_intersection(sc.net_path, sc.junction_id), False, [], {}, {}, {},
                 None, None)  # fmt: skip
    ours = [":C_c0_0", ":C_w1_0", "N_in_0", "E_out_1"]
    assert all(j.covers(x) or j.borders(x) for x in ours)
    assert not any(j.covers(x) or j.borders(x) for x in (":B0_c0_0", "B0B1_0", ":D_w0_0"))
