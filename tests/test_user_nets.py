"""Nets as users bring them, built here the ways netgenerate and netconvert build
them: their own speed limits and lane counts, sidewalks and bike lanes, lights
with ids of their own, junctions a few metres apart. Each runs signal-free with
zero collisions by both checks, nothing lost, and no vehicle above the net's
limit by SUMO's own record of speeds.
"""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from dica.ica.core.limits import Kinematics, SpeedCaps, Turn
from dica.ica.netfile import load_intersection, stop_room_m
from dica.sim_gateway import embedded
from dica.sim_gateway.demand import unserved
from dica.sim_gateway.runconfig import RunConfig, RunError
from dica.sim_gateway.scenario import light_id
from tests.dica_cli import DICA, dica_run
from tests.user_nets import (
    BUS_ROUTES,
    CITY_MPS,
    JAM_ROUTES,
    ROUTES,
    SLOW_MPS,
    build_nets,
    make,
    plain_net,
    tool,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return build_nets(tmp_path_factory.mktemp("usernets"))


def _cli(out: Path, *args: str):
    """``dica run ARGS --out OUT --quiet`` as a user runs it: its completed process, and
    its metrics (None if it wrote none)."""
    p = dica_run([*DICA, "run", *args, "--out", str(out), "--quiet"],
                 capture_output=True, text=True, cwd=ROOT, timeout=300)  # fmt: skip
    metrics = out / "metrics.json"
    return p, json.loads(metrics.read_text()) if metrics.is_file() else None


def test_routes_keep_the_nets_own_limits_and_only_car_lanes(nets):
    grid = load_intersection(nets["grid"], "B1")
    assert grid.routes
    for r in grid.routes:
        assert r.road_mps == CITY_MPS and r.exit_mps == CITY_MPS
        assert r.speed_cap_mps == min(SpeedCaps().for_turn(r.turn), CITY_MPS)
    walk = load_intersection(nets["walk"], "B1")
    # sidewalks (lane 0) and bike lanes (lane 1) carry no vehicle route
    assert {r.in_lane.rsplit("_", 1)[1] for r in walk.routes} == {"2", "3"}
    assert all(r.road_mps == SLOW_MPS for r in walk.routes)
    # the slower side road caps the approach from it and the crossing into it
    joined = load_intersection(nets["joined"], "cluster_A_B")
    side = [r for r in joined.routes if r.in_lane.startswith("NAA")]
    assert side and all(r.road_mps == 8.33 for r in side)
    into_side = [r for r in joined.routes if r.out_lane.startswith("ASA")]
    assert into_side and all(r.speed_cap_mps <= 8.33 and r.exit_mps == 8.33 for r in into_side)


def test_the_dissertations_roads_keep_its_limit_exactly(ch45_net):
    """70 km/h written as 19.44 by SUMO is 70 km/h, so built-in runs plan as before."""
    for r in load_intersection(ch45_net.net_path, "C").routes:
        assert r.road_mps == SpeedCaps().road_mps
        assert r.speed_cap_mps == SpeedCaps().for_turn(r.turn)


def test_short_links_carry_no_demand_and_the_joined_light_is_found(nets):
    twins = load_intersection(nets["twins"], "A")
    skip = unserved(twins, 5.0)
    assert {r.id for r in twins.routes if r.in_lane.startswith("BA_")} <= set(skip)
    assert {r.id for r in twins.routes if r.out_lane.startswith("AB_")} <= set(skip)
    assert all("communication region" in skip[r] or "too short" in skip[r] for r in skip)
    assert len(skip) < len(twins.routes)
    assert light_id(nets["twins"], "A") == "joinedS_A_B"
    assert light_id(nets["joined"], "W") == "W"  # no light: its own id


def _max_speed_off_junctions(fcd: Path) -> float:
    """The highest speed SUMO recorded on any normal lane (internal lanes start with ':')."""
    top = 0.0
    for _, el in ET.iterparse(fcd):
        if el.tag == "vehicle" and not el.get("lane", ":").startswith(":"):
            top = max(top, float(el.get("speed", 0.0)))
        el.clear()
    return top


@pytest.mark.parametrize(
    ("net", "junction", "algorithm", "volume", "limit"),
    [
        ("grid", "B1", "enhanced", 400, CITY_MPS),
        ("walk", "B1", "enhanced", 400, SLOW_MPS),
        # all of the demand on two approaches, one a single lane at 30 km/h
        ("twins", "A", "enhanced", 200, CITY_MPS),
        ("joined", "cluster_A_B", "fifo", 150, CITY_MPS),
        ("twins", "A", "actuated", 200, CITY_MPS),
    ],
)
def test_a_user_net_runs_collision_free_within_its_limits(
    nets, tmp_path, net, junction, algorithm, volume, limit
):
    fcd = tmp_path / "fcd.xml"
    cfg = RunConfig(
        net_path=str(nets[net]), junction_id=junction, algorithm=algorithm,
        volume_per_10min=float(volume), duration_s=180.0, seed=21,
        sumo_args=("--fcd-output", str(fcd), "--fcd-output.attributes", "speed,lane"),
    )  # fmt: skip
    inter = load_intersection(cfg.net_path, junction)
    res = embedded.run(cfg, inter, run_dir=tmp_path)
    assert res.safety["overlaps"] == 0
    assert res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0
    accounted = res.extra["accounted"]
    assert accounted["lost"] == 0 and accounted["generated"] > 40
    # nothing stuck: at this demand the run serves most of it (a joined light's long
    # cycle and FIFO's one-at-a-time crossing less of it than DICA)
    share = 0.8 if algorithm == "enhanced" else 0.5
    assert accounted["crossed"] >= share * accounted["generated"]
    # SUMO's own record: nobody faster than the net's limit on its roads
    assert _max_speed_off_junctions(fcd) <= limit + 0.01
    turns = {res.trips.trips[v].turn for v in res.trips.trips}
    assert len(turns) >= 2 and Turn.THROUGH.value in turns


def test_the_command_line_runs_a_city_grid_without_a_traceback(nets, tmp_path):
    p = dica_run(
        [*DICA, "run", "--net", str(nets["twins"]),
         "--junction", "A", "--duration", "30", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "no demand on its" in p.stderr  # the short links are named
    assert (tmp_path / "run" / "metrics.json").is_file()


def _routes_run(nets, tmp_path, text: str = ROUTES, **cfg_kw):
    routes = tmp_path / "demand.rou.xml"
    routes.write_text(text)
    cfg = RunConfig(net_path=str(nets["grid"]), junction_id="B1", routes_path=str(routes), **cfg_kw)
    return embedded.run(cfg, load_intersection(cfg.net_path, "B1"), run_dir=tmp_path)


def test_a_route_files_vehicles_are_taken_over_in_the_region_and_kept_safe(nets, tmp_path):
    res = _routes_run(nets, tmp_path, duration_s=240.0)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0
    acc = res.extra["accounted"]
    assert acc["lost"] == 0 and acc["generated"] >= 60
    assert acc["crossed"] + acc["in_region"] == acc["generated"]
    trips = res.trips.trips
    # the loop comes back through B1: a crossing of its own, planned like the first
    again = [v for v in trips if v.endswith("+2")]
    assert again and all(trips[v].confirmed_s is not None for v in again if trips[v].exited_s)
    # the ones that will not change lanes cross from where they are and are rerouted
    assert res.extra["rerouted"] > 0
    # a flow that ends before the junction is SUMO's: never the junction's
    assert not [v for v in trips if v.startswith("ends")]


def test_a_route_file_can_start_later(nets, tmp_path):
    res = _routes_run(nets, tmp_path, duration_s=120.0, begin_s=200.0)
    assert res.sim_time_s == pytest.approx(320.0)  # SUMO's clock at the end
    assert res.simulated_s == pytest.approx(120.0)  # the span run: what "simulated" says
    assert min(t.depart_s for t in res.trips.trips.values()) >= 200.0
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0


def test_a_type_defined_late_in_the_file_is_known_and_unsorted_departures_are_kept(nets, tmp_path):
    text = """<routes>
  <flow id="b" begin="1" end="30" period="5" from="B2B1" to="B1A1"/>
  <flow id="w" begin="0" end="30" period="5" from="A1B1" to="B1C1"/>
  <vehicle id="late" depart="20"><route edges="C1B1 B1B0"/></vehicle>
  <vType id="amb" vClass="emergency"/>
  <vehicle id="early" type="amb" depart="5"><route edges="B0B1 B1B2"/></vehicle>
</routes>"""
    res = _routes_run(nets, tmp_path, text=text, duration_s=60.0)
    trips = res.trips.trips
    # SUMO reading the file ahead in steps drops what is out of departure order, and
    # knows a type only once it reaches it: neither may be lost or refused
    assert [v for v in trips if v.startswith("w.")] and "early" in trips
    assert res.extra["accounted"]["lost"] == 0


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ('<routes><vType id="truck" vClass="truck"/><flow id="f" type="truck" begin="0" '
         'end="9" number="2" from="A1B1" to="B1C1"/></routes>', "brakes at"),
        ('<routes><vType id="bike" vClass="bicycle"/><flow id="f" type="bike" begin="0" '
         'end="9" number="2" from="A1B1" to="B1C1"/></routes>', "is a bicycle"),
        ('<routes><vType id="bus" vClass="passenger" length="15"/><trip id="t" type="bus" '
         'depart="0" from="A1B1" to="B1C1"/></routes>', "15 m long"),
        ('<routes><person id="p" depart="0"><ride from="A1B1" to="B1C1" lines="ANY"/>'
         '</person><trip id="t" depart="0" from="A1B1" to="B1C1"/></routes>', "more than walk"),
        ('<routes><container id="c" depart="0"><transport from="A1B1" to="B1C1"/>'
         '</container><trip id="t" depart="0" from="A1B1" to="B1C1"/></routes>', "containers"),
        # a stop (parking too) inside the region, or just past the line where the vehicles
        # let go behind it come at speed; on a vehicle's own route or a shared one
        ('<routes><flow id="f" begin="0" end="9" number="2" from="A1B1" to="B1C1">'
         '<stop lane="A1B1_0" endPos="-20" duration="5"/></flow></routes>',
         "flow 'f' stops on A1B1_0 20 m before junction B1's line"),
        ('<routes><route id="r" edges="A1B1 B1C1"><stop lane="B1C1_1" endPos="10" '
         'parking="true" duration="5"/></route><vehicle id="v" depart="0" route="r"/></routes>',
         "route 'r' stops on B1C1_1 10 m past junction B1"),
        ('<routes><vehicle id="v" depart="0"><route edges="A1B1 B1C1"/>'
         '<stop edge="A1B1" endPos="-5" duration="5"/></vehicle></routes>',
         "vehicle 'v' stops on A1B1_0 5 m before"),
        # a departure at speed inside the region, or where it may land inside it
        ('<routes><flow id="b" begin="0" end="9" number="2" from="A1B1" to="B1C1" '
         'departPos="-10" departSpeed="max"/></routes>', "flow 'b' starts inside junction B1's"),
        ('<routes><trip id="t" depart="0" from="A1B1" to="B1C1" departPos="random" '
         'departSpeed="desired"/></routes>', "trip 't' may start inside junction B1's"),
        ('<routes><route id="r" edges="A1B1 B1C1"/><vehicle id="v" depart="0" route="r" '
         'departPos="last" departSpeed="5"/></routes>', "vehicle 'v' may start inside"),
        # the speed its type gives (SUMO takes a vType's departSpeed for its vehicles),
        # also through a distribution
        ('<routes><vType id="fast" departSpeed="max"/><flow id="f" type="fast" begin="0" '
         'end="9" number="2" from="A1B1" to="B1C1" departPos="-25"/></routes>',
         r"flow 'f' starts inside .* at departSpeed 'max' \(from its type 'fast'\)"),
        ('<routes><vTypeDistribution id="mix"><vType id="slow" probability="1"/><vType '
         'id="quick" departSpeed="8" probability="1"/></vTypeDistribution><trip id="t" '
         'type="mix" depart="0" from="A1B1" to="B1C1" departPos="-25"/></routes>',
         "trip 't' starts inside .* at departSpeed '8'"),
        ("<routes></routes>", "no vehicle, trip or flow"),
        # a vehicle leaving SUMO before its rear is out of the junction would be lost
        ('<routes><flow id="f" begin="0" end="9" number="2" from="A1B1" to="B1C1" '
         'arrivalPos="3"/></routes>', "arrivalPos 3 on B1C1"),
        # the same with its own route inside it, as duarouter and randomTrips -r write it
        ('<routes><flow id="f" begin="0" end="9" number="2" arrivalPos="2"><route '
         'edges="A1B1 B1C1"/></flow></routes>', "arrivalPos 2 on B1C1"),
        # SUMO stops the whole run when it meets the second of one id
        ('<routes><vehicle id="x.1" depart="0"><route edges="A1B1 B1C1"/></vehicle>'
         '<flow id="x" begin="1" end="9" number="2" from="A1B1" to="B1C1"/></routes>',
         "ids must be unique"),
        ('<routes><flow id="x" begin="0" end="9" number="2" from="A1B1" to="B1C1"/>'
         '<trip id="x" depart="1" from="A1B1" to="B1C1"/></routes>', "used twice"),
        # a type defined at its first use late in the file (duarouter writes them so) is
        # checked like the others
        ('<routes><trip id="t" depart="0" from="A1B1" to="B1C1"/><vType id="bike" '
         'vClass="bicycle"/><trip id="u" type="bike" depart="400" from="A1B1" to="B1C1"/>'
         '</routes>', "is a bicycle"),
        ("<routes><trip id=", "cannot read route file"),
    ],
)  # fmt: skip
def test_a_route_file_the_ica_cannot_serve_is_refused_in_one_line(nets, tmp_path, text, says):
    from dica.sim_gateway.runconfig import RunError

    with pytest.raises(RunError, match=says) as e:
        _routes_run(nets, tmp_path, text=text, duration_s=10.0)
    assert "\n" not in str(e.value)


def test_a_start_the_file_does_not_place_counts_as_any_road(nets, tmp_path):
    """A trip from a junction (or a TAZ, or on a route of another file) starts on a road
    the file does not name: at speed, anywhere on it, it is refused as if it could start
    on any approach; standing, the same trip runs."""
    from dica.sim_gateway.runconfig import RunError

    trip = '<routes><trip id="j" depart="0" fromJunction="A1" toJunction="C1"{}/></routes>'
    taz = ("--junction-taz",)
    with pytest.raises(RunError, match=r"trip 'j' may start .*\(its first road is not in the file"):
        _routes_run(nets, tmp_path, text=trip.format(' departPos="random" departSpeed="max"'),
                    duration_s=10.0, sumo_args=taz)  # fmt: skip
    res = _routes_run(nets, tmp_path, text=trip.format(""), duration_s=30.0, sumo_args=taz)
    assert res.extra["accounted"]["crossed"] == 1 and res.safety["overlaps"] == 0


_RB_NODES = """<nodes>
  <node id="r0" x="20" y="0"/><node id="r1" x="0" y="20"/><node id="r2" x="-20" y="0"/>
  <node id="r3" x="0" y="-20"/><node id="e" x="200" y="0"/><node id="n" x="0" y="200"/>
  <node id="w" x="-200" y="0"/><node id="s" x="0" y="-200"/>
</nodes>"""
_RB_EDGES = """<edges>
  <edge id="c01" from="r0" to="r1" speed="8.33" shape="20,0 14.1,14.1 0,20"/>
  <edge id="c12" from="r1" to="r2" speed="8.33" shape="0,20 -14.1,14.1 -20,0"/>
  <edge id="c23" from="r2" to="r3" speed="8.33" shape="-20,0 -14.1,-14.1 0,-20"/>
  <edge id="c30" from="r3" to="r0" speed="8.33" shape="0,-20 14.1,-14.1 20,0"/>
  <edge id="ei" from="e" to="r0" speed="13.89"/><edge id="eo" from="r0" to="e" speed="13.89"/>
  <edge id="ni" from="n" to="r1" speed="13.89"/><edge id="no" from="r1" to="n" speed="13.89"/>
  <edge id="wi" from="w" to="r2" speed="13.89"/><edge id="wo" from="r2" to="w" speed="13.89"/>
  <edge id="si" from="s" to="r3" speed="13.89"/><edge id="so" from="r3" to="s" speed="13.89"/>
</edges>"""


def test_a_junction_whose_exit_is_short_crosses_onto_it_slower(tmp_path):
    """A roundabout's 22.3 m ring links: a car let onto one at the ring's 30 km/h needs
    22.7 m of room beyond the junction to stop in, so none was ever let on and those
    bound for it waited at the line for good (20 of 30 stood for 300 s; then the junction
    was refused). The crossings onto it are capped at the speed that stops in what the
    link leaves (29 km/h), and the node runs; all four nodes, whose ring links form a
    cycle too short to hold one more vehicle standing, are refused in one line."""
    from dica.ica.core.gridlock import short_exits

    net = plain_net(tmp_path, "rb", _RB_NODES, _RB_EDGES, "--roundabouts.guess", "true")
    r0 = load_intersection(net, "r0", fleet=(5.0, 1.8))
    onto = [r for r in r0.routes if r.out_lane.startswith("c01_")]
    assert onto and all(r.speed_cap_mps <= 8.1 for r in onto)  # the turn was slower still
    assert max(r.speed_cap_mps for r in onto) == pytest.approx(8.1, abs=0.01)
    assert short_exits(r0, 5.0, 4.5, 2.5, 7.5) == []
    routes = tmp_path / "rb.rou.xml"
    routes.write_text('<routes><flow id="f" begin="0" end="60" number="5" from="ei" '
                      'to="wo"/></routes>')  # fmt: skip
    for where in (["--junction", "r0"], ["--junctions", "r0,r2"]):
        p, m = _cli(tmp_path / "x", "--net", str(net), *where, "--routes", str(routes),
                    "--duration", "120")  # fmt: skip
        assert p.returncode == 0, p.stdout + p.stderr
        assert m["accounted"]["crossed"] >= 5 and m["accounted"]["lost"] == 0
        assert m["unconfirmed_entries"] == 0 and m.get("stood_inside", 0) == 0
    p, _ = _cli(tmp_path / "y", "--net", str(net), "--junctions", "all", "--routes",
                str(routes), "--duration", "30")  # fmt: skip
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    said = [ln for ln in p.stderr.strip().splitlines() if not ln.startswith("note: ")]
    assert len(said) == 1 and "a link on a cycle of links needs" in said[0], p.stderr


def test_a_vehicle_with_no_way_back_to_its_destination_leaves_at_the_road_s_end(tmp_path):
    """A star of five dead-end arms without turnarounds: a vehicle that will not change
    lanes, on a lane that does not lead where its route goes, crosses from where it is;
    no road beyond leads back to its destination (SUMO's rerouting raised and the run
    ended in a traceback), so it leaves the net at the end of the road it took, and the
    run says how many did."""
    import math

    nodes = ['<node id="C" x="0" y="0"/>'] + [
        f'<node id="o{k}" x="{250 * math.cos(1.2566 * k + 0.3):.1f}" '
        f'y="{250 * math.sin(1.2566 * k + 0.3):.1f}"/>'
        for k in range(5)
    ]
    edges = []
    for k in range(5):
        for a, f, t in (("i", f"o{k}", "C"), ("x", "C", f"o{k}")):
            edges.append(f'<edge id="{a}{k}" from="{f}" to="{t}" numLanes="2" speed="13.89"/>')
    net = plain_net(tmp_path, "star", f"<nodes>{''.join(nodes)}</nodes>",
                    f"<edges>{''.join(edges)}</edges>")  # fmt: skip
    lanes = {r.in_lane for r in load_intersection(net, "C").routes if r.out_lane == "x4_1"}
    wrong = ({"i0_0", "i0_1"} - lanes).pop()  # i0's lane with no way onto x4
    routes = tmp_path / "star.rou.xml"
    routes.write_text(
        '<routes><vType id="stubborn" accel="2.6" decel="4.5" lcStrategic="-1"/>'
        f'<flow id="f" type="stubborn" begin="0" end="60" number="4" from="i0" to="x4" '
        f'departLane="{wrong[-1]}"/></routes>'
    )
    p = dica_run(
        [*DICA, "run", "--net", str(net), "--junction", "C", "--routes", str(routes),
         "--duration", "120", "--out", str(tmp_path / "run"), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0 and "Traceback" not in p.stderr, p.stderr
    assert "note: 4 vehicles had no way on to their destination" in p.stdout
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["accounted"]["crossed"] == 4 and m["accounted"]["lost"] == 0
    assert m["collisions"] == 0 and m["unconfirmed_entries"] == 0


def test_stops_and_standing_starts_clear_of_the_plans_still_run(nets, tmp_path):
    """A stop well before the region or well past the line, and a start inside the region
    standing (departSpeed 0, SUMO's default), are the file's own and run safe."""
    text = (
        '<routes><flow id="s" begin="0" end="60" period="6" from="A1B1" to="B1C1">'
        '<stop lane="A1B1_0" endPos="30" duration="3"/><stop lane="B1C1_0" endPos="-20" '
        'duration="3"/></flow><flow id="d" begin="1" end="60" period="7" from="B2B1" '
        'to="B1B0" departPos="-10"/><flow id="e" begin="2" end="60" period="7" from="C1B1" '
        'to="B1A1" departPos="-5" departSpeed="0"/></routes>'
    )
    res = _routes_run(nets, tmp_path, text=text, duration_s=90.0)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0
    assert res.extra["accounted"]["crossed"] >= 10


def test_the_command_line_refuses_a_route_file_with_status_2(nets, tmp_path):
    bad = tmp_path / "trucks.rou.xml"
    bad.write_text(
        '<routes><vType id="truck" vClass="truck"/><flow id="f" type="truck" begin="0" '
        'end="9" number="2" from="A1B1" to="B1C1"/></routes>'
    )
    unknown = tmp_path / "unknown.rou.xml"
    unknown.write_text('<routes><trip id="t" depart="0" from="NOPE" to="B1C1"/></routes>')
    stop = tmp_path / "stop.rou.xml"
    stop.write_text(
        '<routes><flow id="f" begin="0" end="9" number="2" from="A1B1" to="B1C1">'
        '<stop lane="A1B1_0" endPos="-20" duration="5"/></flow></routes>'
    )
    for args, says in (
        (["--net", str(nets["grid"]), "--junction", "B1", "--routes", str(bad)], "truck"),
        (["--routes", str(bad)], "--routes needs --net"),
        (["--net", str(nets["grid"]), "--junction", "B1", "--routes", str(tmp_path / "no.xml")],
         "route file not found"),
        (["--net", str(nets["grid"]), "--junction", "B1", "--routes", str(unknown)],
         "'NOPE' within the route for trip 't' is not known. The route"),  # SUMO's, one line
        (["--net", str(nets["grid"]), "--junction", "B1", "--routes", str(stop)],
         "flow 'f' stops on A1B1_0 20 m before junction B1's line"),
    ):  # fmt: skip
        p = dica_run(
            [*DICA, "run", *args, "--duration", "10",
             "--out", str(tmp_path / "run")],
            capture_output=True, text=True, cwd=ROOT, timeout=300,
        )  # fmt: skip
        assert p.returncode == 2, p.stderr
        assert says in p.stderr and "Traceback" not in p.stderr
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_a_crossing_name_is_a_key_chunk_and_never_anothers():
    from dica.schemas.keys import chunk
    from dica.sim_gateway.traffic import crossing_name

    assert crossing_name("veh.7", 1, {}) == "veh.7"
    assert crossing_name("veh.7", 2, {}) == "veh.7+2"
    odd = [crossing_name(s, 1, {}) for s in ("a b", "a/b", "a#b", "ä" * 300)]
    assert all(chunk(n) == n for n in odd) and len(set(odd)) == len(odd)
    assert crossing_name("x", 2, {"x+2": None}) == "x+2+"


def test_buses_on_their_own_lanes_are_planned_like_cars(nets, tmp_path):
    from dica.sim_gateway.route_file import fleet_size

    routes = tmp_path / "buses.rou.xml"
    routes.write_text(BUS_ROUTES)
    # a 12 m bus turning would sweep over waiting places: the lines are placed for it
    inter = load_intersection(nets["bus"], "X", fleet=fleet_size(routes))
    assert any(r.line_back_m > 0.0 for r in inter.routes)
    bus_lane = [r for r in inter.routes if r.in_lane == "WX_0"]
    assert bus_lane and not any(r.cars for r in bus_lane)  # covered, but no car's
    assert all("not for cars" in unserved(inter, 5.0)[r.id] for r in bus_lane)
    cfg = RunConfig(
        net_path=str(nets["bus"]), junction_id="X", routes_path=str(routes), duration_s=330.0
    )
    res = embedded.run(cfg, inter, run_dir=tmp_path)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0 and res.extra["accounted"]["lost"] == 0
    buses = [t for v, t in res.trips.trips.items() if v.startswith("bus.")]
    assert len(buses) >= 10 and all(t.route_id.startswith("WX_0>") for t in buses)
    assert all(t.confirmed_s is not None for t in buses if t.exited_s is not None)


def test_a_queue_beyond_the_junction_holds_vehicles_short_of_it(nets, tmp_path):
    """Downstream space: with the exit lane full up to the junction, vehicles wait before
    their line, and nothing runs into the queue (SUMO sees every collision, on any lane)."""
    res = _routes_run(nets, tmp_path, text=JAM_ROUTES, duration_s=220.0)
    assert res.requests["rejections"].get("no_room", 0) > 0  # the queue did reach B1
    assert res.sumo_collisions == 0 and res.safety["overlaps"] == 0
    assert res.extra["unconfirmed_entries"] == 0 and res.extra["accounted"]["lost"] == 0


def test_a_junction_too_close_to_the_next_is_refused_with_a_route_file(nets, tmp_path):
    """From the 4 m link between the twins a vehicle could not stop before A's line."""
    from dica.sim_gateway.runconfig import RunError

    routes = tmp_path / "twins.rou.xml"
    routes.write_text(
        '<routes><flow id="f" begin="0" end="60" number="5" from="EB" to="AW"/></routes>'
    )
    cfg = RunConfig(net_path=str(nets["twins"]), junction_id="A", routes_path=str(routes))
    with pytest.raises(RunError, match=r"BA_.* m long.*junctions\.join"):
        embedded.run(cfg, load_intersection(cfg.net_path, "A"), run_dir=tmp_path)


def test_a_collision_counts_against_the_junction_on_its_own_lanes_only(nets):
    """SUMO's drivers alone run the rest of a user's net, and may collide there (SUMO's own
    model on odd junctions does): those are reported apart, never hidden."""
    from dica.sim_gateway.junction import Junction

    inter = load_intersection(nets["grid"], "B1")
    j = Junction(inter, False, [], {}, {}, {}, None, None)
    r = inter.routes[0]
    assert j.covers(r.in_lane) and j.covers(r.out_lane) and j.covers(":B1_0_0")
    assert all(j.covers(v) for v in r.via_lanes)
    assert not j.covers("A1A2_0") and not j.covers(":A1_0_0") and not j.covers(":B11_0_0")


FAST_NODES = """<nodes><node id="T" x="0" y="0" type="priority"/><node id="w" x="-300" y="0"/>
 <node id="e" x="300" y="0"/><node id="s" x="0" y="-300"/></nodes>"""
FAST_EDGES = """<edges>
 <edge id="wi" from="w" to="T" numLanes="1" speed="22.22"/>
 <edge id="wo" from="T" to="w" numLanes="1" speed="22.22"/>
 <edge id="ei" from="e" to="T" numLanes="1" speed="25.00"/>
 <edge id="eo" from="T" to="e" numLanes="1" speed="25.00"/>
 <edge id="si" from="s" to="T" numLanes="1" speed="13.89"/>
 <edge id="so" from="T" to="s" numLanes="1" speed="13.89"/>
</edges>"""
FAST_ROUTES = """<routes>
 <flow id="we" begin="0" end="150" period="4" from="wi" to="eo" departSpeed="max"/>
 <flow id="ew" begin="1" end="150" period="5" from="ei" to="wo" departSpeed="max"/>
 <flow id="ws" begin="2" end="150" period="6" from="wi" to="so" departSpeed="max"/>
 <flow id="es" begin="0" end="150" period="7" from="ei" to="so" departSpeed="max"/>
 <flow id="sw" begin="3" end="150" period="6" from="si" to="wo" departSpeed="max"/>
 <flow id="se" begin="0" end="150" period="5" from="si" to="eo" departSpeed="max"/>
</routes>"""


def test_a_fast_road_gets_a_region_long_enough_to_stop_in(tmp_path):
    """On roads faster than about 74 km/h a vehicle SUMO brings to a 50 m region at the
    limit cannot stop short of the line there: the region grows to what the fastest
    approach needs (90 km/h: 73 m), and a route file's vehicles at 80 and 90 km/h cross
    a busy T junction with no plan missed and nothing touched."""
    net = plain_net(tmp_path, "t", FAST_NODES, FAST_EDGES)
    inter = load_intersection(net, "T")
    assert inter.comm_length_m >= stop_room_m(25.0, Kinematics()) + 25.0 * 0.05
    assert max(r.arrival_mps for r in inter.routes) == pytest.approx(25.0)
    routes = tmp_path / "t.rou.xml"
    routes.write_text(FAST_ROUTES)
    cfg = RunConfig(net_path=str(net), junction_id="T", routes_path=str(routes), duration_s=180.0)
    res = embedded.run(cfg, inter, run_dir=tmp_path)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0
    acc = res.extra["accounted"]
    assert acc["lost"] == 0 and acc["crossed"] >= 80


def test_a_route_files_fast_type_keeps_the_limit_once_flown_through_a_junction(tmp_path):
    """SUMO's emergency class drives 1.5 x the limit. A route file's vehicle keeps the
    limit from its departure, but a vehicle flown through a junction gets limits of its
    own, and with them SUMO gave it its type's speed factor back: between junctions it
    then drove half again the limit and reached the next region too fast to be planned
    (on this 60 km/h grid: unconfirmed entries, and a lane it could not leave, so it
    looped round the grid)."""
    net = tmp_path / "g.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
          "--grid.attach-length", "150", "--default.lanenumber", "3", "--default.speed",
          "16.67", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    routes = tmp_path / "amb.rou.xml"
    routes.write_text(
        '<routes><vType id="amb" vClass="emergency" speedFactor="1.5"/>'
        '<flow id="e" type="amb" begin="0" end="60" period="12" departSpeed="max">'
        '<route edges="left1A1 A1A2 A2B2 B2top1"/></flow></routes>'
    )
    out = tmp_path / "run"
    p = dica_run(
        [*DICA, "run", "--net", str(net), "--junctions", "all", "--routes", str(routes),
         "--duration", "150", "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["unconfirmed_entries"] == 0 and m["accounted"]["lost"] == 0
    rows = list(csv.DictReader((out / "vehicles.csv").open()))
    assert rows and all(r["confirmed_s"] for r in rows)
    assert not [r for r in rows if r["vin"].endswith("+4")]  # three crossings, none round again
    assert {r["route"].split(">")[0].rsplit("_", 1)[0] for r in rows} == {"left1A1", "A1A2", "A2B2"}


def test_a_long_wide_turner_moves_back_the_line_of_the_lane_it_sweeps(nets):
    """On netgenerate's tight corners a 12 m x 2.55 m vehicle turning right from the kerb
    lane sweeps over where a vehicle waits at the line of the lane beside it (outside the
    junction, so outside every reservation); a car and a 7 m van do not. Loaded for such
    a fleet, that lane's line moves back until nothing swept reaches a vehicle waiting
    behind it: the stretch in between is the crossing's, in every route from the lane."""
    from dica.ica.core.waiting import line_backs

    grid = load_intersection(nets["grid"], "B1")
    assert line_backs(grid.routes, 5.0, 1.8, 0.5) == {}
    assert line_backs(grid.routes, 7.0, 2.2, 0.5) == {}
    backs = line_backs(grid.routes, 12.0, 2.55, 0.5)
    assert backs and all(lane.endswith("_1") for lane in backs)  # beside the kerb lane
    moved = load_intersection(nets["grid"], "B1", fleet=(12.0, 2.55))
    assert line_backs(moved.routes, 12.0, 2.55, 0.5) == {}  # half a metre short of it: not
    assert line_backs(moved.routes, 12.0, 2.55, 0.0)  # less room than the stop gap: swept
    for r, m in zip(grid.routes, moved.routes, strict=True):
        back = backs.get(r.in_lane, 0.0)
        assert m.line_back_m == back
        assert m.cross_length_m == pytest.approx(r.cross_length_m + back)
        assert m.in_lane_m == pytest.approx(r.in_lane_m - back)
        # the same place on the ground, the polyline reaching as far up the new line
        assert np.allclose(m.points(np.array([back, m.cross_length_m])),
                           r.points(np.array([0.0, r.cross_length_m])))  # fmt: skip
        assert m.s_min <= r.s_min + back + 1e-9
    cars = load_intersection(nets["grid"], "B1", fleet=(5.0, 1.8))
    assert all(r.line_back_m == 0.0 for r in cars.routes)


def test_the_room_rule_keeps_a_queue_clear_of_a_long_turner_s_sweep(nets):
    """On the tight 2-arm corner A0 a 12 m x 2.55 m vehicle turning sweeps up to 4 m
    over the first metres of the exit lane beside its own. No line moves there: a queue's
    last vehicle stands at least its route's braking distance from the cap past the exit
    line (5.4 m at 25 km/h), since the room rule lets none on with less; so nothing is
    refused. With a gentler braking (a queue that may reach nearer the line) the same
    sweep reaches a standing vehicle, and those turns are refused."""
    from dica.ica.core.waiting import exit_clearance_m, exit_sweeps

    corner = load_intersection(nets["grid"], "A0", fleet=(12.0, 2.55))  # entry lines moved
    clear = exit_clearance_m(corner.routes, 4.5)
    assert min(clear.values()) == pytest.approx(6.94**2 / 9.0, abs=0.05)
    assert exit_sweeps(corner.routes, 12.0, 2.55, 4.5) == []
    assert corner.sweeping(12.0, 2.55, 0.5, 4.5) == frozenset()
    soft = exit_sweeps(corner.routes, 12.0, 2.55, 12.0)  # 2 m clear: the 4 m sweep reaches
    assert ("A0A1_0", "B0A0_1>A0A1_1") in {(lane, r) for lane, r, _ in soft}
    assert {r for _, r, _ in soft} <= corner.sweeping(12.0, 2.55, 0.5, 12.0)
    assert exit_sweeps(corner.routes, 5.0, 1.8, 12.0) == []  # a car's sweep is shallower
    from dica.ica.core.limits import Kinematics
    from dica.ica.netfile import NetworkError

    with pytest.raises(NetworkError, match=r"sweep over A0A1_0 more than 2\.0 m past"):
        load_intersection(nets["grid"], "A0", fleet=(12.0, 2.55), kin=Kinematics(decel_mps2=12.0))


def test_no_built_in_layout_moves_a_line_for_its_cars():
    """The drawn demand's cars sweep over no waiting place on the built-in layouts, so
    their lines stand at the lanes' ends and every built-in result is as it was."""
    from dica.sim_gateway.route_file import CAR_SIZE
    from dica.sim_gateway.scenario import LAYOUTS, default_scenario

    for layout in LAYOUTS:
        sc = default_scenario(layout)
        inter = load_intersection(sc.net_path, sc.junction_id, fleet=CAR_SIZE)
        assert all(r.line_back_m == 0.0 for r in inter.routes), layout


def test_a_start_inside_a_region_grown_by_a_moved_line_is_refused(nets, tmp_path):
    """With the lines placed for the trucks, A1B1_1's line stands 4 m short of the lane's
    end and its region begins 54 m before that end: a car put in 52 m before the end at
    speed starts inside it (counted from the lane's end, a departPos must be measured on
    the lane's own length, not up to the moved line); 56 m before the end it does not."""
    for pos, refused in (("-52", True), ("-56", False)):
        routes = tmp_path / f"start{pos}.rou.xml"
        routes.write_text(TRUCKS.replace("</routes>", (
            f'<flow id="in" type="car" begin="0" end="20" number="2" from="A1B1" to="B1C1" '
            f'departLane="1" departPos="{pos}" departSpeed="max"/></routes>')))  # fmt: skip
        p = dica_run(
            [*DICA, "run", "--net", str(nets["grid"]), "--junction", "B1", "--routes",
             str(routes), "--duration", "20", "--out", str(tmp_path / pos), "--quiet"],
            capture_output=True, text=True, cwd=ROOT, timeout=300,
        )  # fmt: skip
        assert "Traceback" not in p.stderr, p.stderr
        if refused:
            assert p.returncode == 2, p.stderr
            assert "flow 'in' starts inside junction B1's region on A1B1_1" in p.stderr
            assert "before the last 54 m of the lane" in p.stderr
        else:
            assert p.returncode == 0, p.stderr


def test_the_ica_refuses_a_turner_its_lines_were_not_placed_for(nets):
    """An ICA whose lines stand where cars need them (a role not told the run's route
    file) refuses a 12 m truck on a turn that would sweep over a waiting place, and only
    there; one whose lines were placed for trucks confirms it."""
    from dica.ica.core.config import IcaConfig
    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.ica.core.request import Confirmation, Reason

    def ask(inter, route_id: str, length: float, width: float):
        ica = Dica(inter, IcaConfig())
        route = inter.route_by_id(route_id)
        ica.detect("v", route.in_lane, 0.0)
        req = propose(route, vin="v", seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=10.0,
                      length_m=length, width_m=width)  # fmt: skip
        return ica.handle(req, 0.0)

    cars = load_intersection(nets["grid"], "B1", fleet=(5.0, 1.8))
    turn, straight = "A1B1_0>B1B0_0", "A1B1_1>B1C1_1"
    refused = ask(cars, turn, 12.0, 2.55)
    assert refused.reason == Reason.TOO_LARGE and "sweep" in refused.detail
    assert isinstance(ask(cars, turn, 5.0, 1.8), Confirmation)
    assert isinstance(ask(cars, straight, 12.0, 2.55), Confirmation)
    trucks = load_intersection(nets["grid"], "B1", fleet=(12.0, 2.55))
    assert isinstance(ask(trucks, turn, 12.0, 2.55), Confirmation)


TRUCKS = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" width="1.8" sigma="0.5"/>
  <vType id="truck" vClass="truck" accel="2.6" decel="4.5" length="12" width="2.55"/>
  <flow id="t1" type="truck" begin="0" end="150" vehsPerHour="240" from="A1B1" to="B1B0"
        departLane="0"/>
  <flow id="t2" type="truck" begin="0" end="150" vehsPerHour="240" from="C1B1" to="B1B2"
        departLane="0"/>
  <flow id="c1" type="car" begin="0" end="150" vehsPerHour="900" from="A1B1" to="B1C1"
        departLane="1"/>
  <flow id="c2" type="car" begin="0" end="150" vehsPerHour="900" from="C1B1" to="B1A1"
        departLane="1"/>
  <flow id="c3" type="car" begin="0" end="150" vehsPerHour="900" from="B0B1" to="B1B2"
        departLane="1"/>
  <flow id="c4" type="car" begin="0" end="150" vehsPerHour="900" from="B2B1" to="B1B0"
        departLane="1"/>
</routes>"""


def test_trucks_turning_beside_waiting_cars_touch_none(nets, tmp_path):
    """12 m trucks turning right from the kerb lane while cars wait beside them: with the
    lines where such a fleet needs them, neither check counts a touch; lines placed for
    cars alone are refused in one line before the run, never run into touches."""
    routes = tmp_path / "trucks.rou.xml"
    routes.write_text(TRUCKS)
    p = dica_run(
        [*DICA, "run", "--net", str(nets["grid"]), "--junction", "B1", "--routes", str(routes),
         "--duration", "150", "--out", str(tmp_path / "run"), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert "junction B1: lines moved back (A1B1_1 4 m" in p.stderr
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["accounted"]["lost"] == 0 and m["accounted"]["crossed"] > 100
    rows = list(csv.DictReader((tmp_path / "run" / "vehicles.csv").open()))
    assert any(r["vin"].startswith("t1") for r in rows)
    cfg = RunConfig(net_path=str(nets["grid"]), junction_id="B1", routes_path=str(routes),
                    duration_s=10.0)  # fmt: skip
    with pytest.raises(RunError, match="would sweep over where a vehicle waits at A1B1_1"):
        embedded.run(cfg, load_intersection(cfg.net_path, "B1"), run_dir=tmp_path / "cars")


def test_the_region_grows_from_the_first_speed_a_vehicle_could_not_stop_in_50_m():
    """On either side of the limit: 50 m up to the speed whose room to stop, and a step's
    travel, fills it; a metre more just past it; a fast road's need in whole metres."""
    from dica.ica.netfile import STEP_S, region_m

    def need(v: float) -> float:
        return stop_room_m(v) + v * STEP_S

    lo, hi = 10.0, 30.0  # the speed whose need is exactly 50 m, by bisection
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if need(mid) < 50.0 else (lo, mid)
    assert 73.5 < lo * 3.6 < 75.0  # "about 74 km/h" in the docs
    assert region_m(lo - 0.01, 50.0) == 50.0
    assert region_m(lo + 0.01, 50.0) == 51.0
    assert region_m(22.22, 50.0) == 58.0 and region_m(25.0, 50.0) == 73.0
    assert region_m(25.0, 80.0) == 80.0  # never shorter than asked


@pytest.mark.parametrize("lane", ["A1B1_0", "B1C1_0"])  # B1's approach, B1's exit
def test_a_stop_a_metre_either_side_of_its_limit_is_refused_or_served(nets, tmp_path, lane):
    """The refusal names the nearest a stop may be to the junction; a metre nearer is
    refused as well, a metre farther is the file's own (the run starts and is safe)."""
    import re

    from dica.sim_gateway.runconfig import RunError

    inter = load_intersection(nets["grid"], "B1")
    approach = any(r.in_lane == lane for r in inter.routes)
    n = next(r.in_lane_m if approach else r.out_lane_m for r in inter.routes
             if lane in (r.in_lane, r.out_lane))  # fmt: skip

    def run(from_line_m: float):
        end = n - from_line_m if approach else from_line_m + 0.2  # (a stop is 0.2 m long)
        d = tmp_path / f"{from_line_m:g}"
        d.mkdir()
        text = (
            '<routes><flow id="s" begin="0" end="20" period="10" from="A1B1" to="B1C1">'
            f'<stop lane="{lane}" endPos="{end:.2f}" duration="1"/></flow></routes>'
        )
        return _routes_run(nets, d, text=text, duration_s=5.0)

    with pytest.raises(RunError) as near:
        run(1.0)
    limit = float(re.search(r"at least (\d+) m", str(near.value)).group(1))
    with pytest.raises(RunError, match="move the stop"):
        run(limit - 1.0)
    assert run(limit + 1.0).safety["overlaps"] == 0


_FAST_NODES = """<nodes><node id="C" x="0" y="0" type="priority"/>
  <node id="N" x="0" y="500"/><node id="S" x="0" y="-500"/>
  <node id="E" x="500" y="0"/><node id="W" x="-500" y="0"/></nodes>"""
_FAST_EDGES = (
    "<edges>"
    + "".join(
        f'<edge id="{a}_in" from="{a}" to="C" numLanes="2" speed="30"/>'
        f'<edge id="C_{a}" from="C" to="{a}" numLanes="2" speed="30"/>'
        for a in "NSEW"
    )
    + "</edges>"
)


def test_a_hard_braking_type_taken_over_at_speed_behind_a_queue_stops_short_of_it(tmp_path):
    """Motorcycles (SUMO's class brakes at 10 m/s^2) at 108 km/h among a few slow
    trucks: SUMO's driver brings one to the region behind a queue in it at a speed only
    its own braking can stop from; the stop law braked at the plans' 4.5 m/s^2 and ran
    into the queue (61 SUMO collisions on the approach in 130 s, outside the junction
    area the independent check watches). It brakes as hard as it can there, and the run
    says how often."""
    net = plain_net(tmp_path, "fast", _FAST_NODES, _FAST_EDGES)
    turns = {"N": "SEW", "S": "NEW", "E": "WNS", "W": "ENS"}
    flows = "".join(
        f'<flow id="{a}{b}{k}" type="{t}" from="{a}_in" to="C_{b}" begin="0" end="300" '
        f'probability="{p}" departSpeed="max" departLane="best"/>'
        for a, (ahead, left, right) in turns.items()
        for k, (t, b, p) in enumerate((("moto", ahead, 0.2), ("moto", left, 0.08),
                                       ("moto", right, 0.08), ("truck", ahead, 0.01)))
    )  # fmt: skip
    routes = tmp_path / "moto.rou.xml"
    routes.write_text(
        '<routes><vType id="moto" vClass="motorcycle"/><vType id="truck" vClass="truck" '
        'length="12" width="2.55" accel="2.5" decel="4.5" speedFactor="1.1" speedDev="0"/>'
        f"{flows}</routes>"
    )
    out = tmp_path / "run"
    p, m = _cli(out, "--net", str(net), "--junction", "C", "--routes", str(routes),
                "--duration", "130")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert m["sumo_collisions"] == 0 and m["safety"]["overlaps"] == 0, m["sumo_collision_log"][:2]
    assert m["unconfirmed_entries"] == 0 and m["crossed"] > 100
    assert m["timing"]["hard_braking_steps"] > 0  # it did come to that


def test_lanes_that_run_into_each_other_before_the_junction_are_refused(tmp_path):
    """A ramp drawn straight to the merge node overlaps the main road's left lane before
    the junction: no line moved back keeps a car waiting there clear of one coming off
    the ramp (both lines 5 m back, still swept), so every crossing from those lanes
    would be refused for ever (10 of 37 cars crossed in 120 s, 374 refusals). The net is
    refused in one line naming the lanes."""
    from dica.ica.netfile import NetworkError

    nodes = """<nodes><node id="A" x="-600" y="0"/><node id="M" x="0" y="0" type="priority"/>
      <node id="X" x="150" y="0" type="priority"/><node id="B" x="1000" y="0"/>
      <node id="R" x="-400" y="-30"/></nodes>"""
    edges = """<edges><edge id="main1" from="A" to="M" numLanes="3" speed="36.11"/>
      <edge id="ramp" from="R" to="M" numLanes="1" speed="22.22"/>
      <edge id="main2" from="M" to="X" numLanes="3" speed="36.11"/>
      <edge id="main3" from="X" to="B" numLanes="3" speed="36.11"/></edges>"""
    net = plain_net(tmp_path, "merge", nodes, edges)
    load_intersection(net, "M")  # as the net has it, the routes load
    with pytest.raises(
        NetworkError,
        match=r"on ramp_0>main2_0 sweeps over where one waits on "
        r"main1_2, however far back its line moves .* run into each other",
    ):
        load_intersection(net, "M", fleet=(5.0, 1.8))


def test_a_route_ending_in_a_u_turn_the_junction_does_not_serve_does_not_go_round_for_ever(
    tmp_path,
):
    """netgenerate's grid with its turnarounds: a route that ends by turning back at C1.
    The junction serves no U-turn, so it sends the vehicle another way, and SUMO's way on
    turned back at the next junction or came round the block to the same U-turn (24
    crossings in 300 s, never arriving). The way on turns back at no junction an ICA
    serves: the vehicle arrives where its route ends."""
    net = tmp_path / "turns.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "150",
          "--default.lanenumber", "1", "-o", str(net)])  # fmt: skip
    routes = tmp_path / "uturn.rou.xml"
    routes.write_text('<routes><vehicle id="u" depart="0"><route edges="B0A0 A0A1 A1B1 B1C1 '
                      'C1B1"/></vehicle></routes>')  # fmt: skip
    out = tmp_path / "run"
    p, m = _cli(out, "--net", str(net), "--junctions", "all", "--routes", str(routes),
                "--duration", "300")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert m["ended_short"] == 0 and m["accounted"]["lost"] == 0
    rows = list(csv.DictReader((out / "vehicles.csv").open()))
    assert 4 <= len(rows) <= 10, [r["vin"] for r in rows]
    trip = ET.parse(out / "tripinfo.xml").getroot().find("tripinfo")
    assert trip is not None and trip.get("arrivalLane", "").startswith("C1B1_"), trip


def test_a_route_file_s_emergency_vehicles_are_measured_apart(nets, tmp_path):
    """Under rdica a route file's vehicles of the emergency class are its EVs; the run
    measures them apart from the others, as it does drawn ones (it did not: the figures
    were written only for --ev-prob)."""
    routes = tmp_path / "ev.rou.xml"
    routes.write_text(
        '<routes><vType id="amb" vClass="emergency"/>'
        '<flow id="ev" type="amb" begin="0" end="80" period="20" from="A1B1" to="B1C1"/>'
        '<flow id="car" begin="0" end="80" period="3" from="B0B1" to="B1B2"/></routes>'
    )
    out = tmp_path / "run"
    p, m = _cli(out, "--net", str(nets["grid"]), "--junction", "B1", "--routes", str(routes),
                "--algorithm", "rdica", "--duration", "90")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert m["ev"]["generated"] == 4 and m["normal"]["generated"] > 20
    rows = list(csv.DictReader((out / "vehicles.csv").open()))
    assert sum(r["ev"] == "1" for r in rows) == 4, rows[:2]


def test_delay_on_a_fast_road_is_counted_from_the_speed_a_vehicle_arrives_at(tmp_path):
    """At 108 km/h SUMO brings a route file's cars to the region faster than the plans'
    road speed; free flow from that road speed made nearly every delay negative (mean
    -0.42 s on a 120 km/h merge). From the speed they arrive at, none is."""
    net = plain_net(tmp_path, "fast", _FAST_NODES, _FAST_EDGES)
    routes = tmp_path / "cars.rou.xml"
    routes.write_text(
        '<routes><flow id="ns" begin="0" end="100" period="6" from="N_in" to="C_S" '
        'departSpeed="max"/><flow id="ew" begin="3" end="100" period="6" from="E_in" '
        'to="C_W" departSpeed="max"/></routes>'
    )
    out = tmp_path / "run"
    p, _ = _cli(out, "--net", str(net), "--junction", "C", "--routes", str(routes),
                "--duration", "120")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    rows = [r for r in csv.DictReader((out / "vehicles.csv").open()) if r["system_delay_s"]]
    assert len(rows) > 20
    assert min(float(r["system_delay_s"]) for r in rows) > -0.1, rows[:3]


def test_trips_from_junctions_run_without_asking_for_sumo_s_option(nets, tmp_path):
    """SUMO reads trips from and to junctions only with --junction-taz: the run gives it
    when the route file has them ("dica network", which takes no SUMO options, could not
    run such a file at all)."""
    text = (
        '<routes><trip id="j" depart="0" fromJunction="A1" toJunction="C1"/><flow id="k" '
        'begin="0" end="40" period="5" fromJunction="B0" toJunction="B2"/></routes>'
    )
    res = _routes_run(nets, tmp_path, text=text, duration_s=60.0)
    assert "--junction-taz" in res.sumo_command
    assert res.extra["accounted"]["crossed"] >= 5 and res.safety["overlaps"] == 0


def test_a_way_on_turns_back_at_no_served_junction(tmp_path):
    """The detour router: SUMO's way from C1C0 back to C1B1 turns back at C0; with C0
    served the way found goes round without turning back there (nor anywhere served);
    a road not in the net has no way to it."""
    from dica.sim_gateway.detour import Detours

    net = tmp_path / "turns.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "150",
          "--default.lanenumber", "1", "-o", str(net)])  # fmt: skip
    served = frozenset(f"{c}{r}" for c in "ABC" for r in "012")
    d = Detours(str(net), served)
    assert d.turns_back(("C1C0", "C0C1", "C1B1"))
    assert not d.turns_back(("C1C0", "C0B0"))
    way = d.way("C1C0", "C1B1", "passenger")
    assert way is not None and way[0] == "C1C0" and way[-1] == "C1B1"
    assert not d.turns_back(way) and len(way) > 3
    # the road back the other way is reached round a block; a road not in the net never
    assert Detours(str(net), served).way("C1B1", "B1C1", "passenger") is not None
    assert Detours(str(net), served).way("C1B1", "nope", "passenger") is None
