"""Several junctions of a user's net, each signal-free under its own ICA core, with a
route file's vehicles passing from one junction's region to the next (``dica run
--junctions``): zero collisions by both checks at every junction, every crossing
accounted for, and a link too short to stop on refused before the run."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import pytest

from dica.ica.netfile import crossing_junctions, load_intersection
from dica.sim_gateway import embedded
from dica.sim_gateway.actuator import FLYING_DECEL_MPS2
from dica.sim_gateway.embedded import LocalDrivers
from dica.sim_gateway.network import run_network
from dica.sim_gateway.runconfig import RunConfig, RunError
from dica.sim_gateway.sumo_io import import_libsumo, start_sumo
from dica.sim_gateway.world import World
from tests.dica_cli import DICA, dica_run
from tests.user_nets import build_nets

ROOT = Path(__file__).resolve().parents[1]
GRID = ("A0", "A1", "A2", "B0", "B1", "B2", "C0", "C1", "C2")

# across the grid: flows through two and three junctions each way, turning on the way,
# heavy enough that queues from one junction reach back to the one before it
ACROSS = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" width="1.8" sigma="0.5"/>
  <vType id="van" accel="2.0" decel="4.5" length="7.0" width="2.2"/>
  <flow id="east" type="car" begin="0" end="300" vehsPerHour="900" from="A1B1" to="C1C2"
        departLane="best"/>
  <flow id="west" type="van" begin="0" end="300" vehsPerHour="300" from="C1B1" to="A1A0"/>
  <flow id="north" type="car" begin="0" end="300" vehsPerHour="600" from="B0B1" to="B2C2"
        departLane="best"/>
  <flow id="south" type="car" begin="0" end="300" vehsPerHour="400" from="B2B1" to="A0B0"/>
  <flow id="round" type="car" begin="0" end="300" vehsPerHour="300" from="A0A1"
        to="C1C0" departLane="best"/>
</routes>"""


@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return build_nets(tmp_path_factory.mktemp("network"))


def _config(nets, tmp_path: Path, junctions: tuple[str, ...], **kw) -> RunConfig:
    routes = tmp_path / "across.rou.xml"
    routes.write_text(ACROSS)
    return RunConfig(
        net_path=str(nets["grid"]), junction_id=junctions[0], routes_path=str(routes),
        junction_ids=junctions, **kw,
    )  # fmt: skip


def test_all_means_every_junction_where_two_roads_come_in(nets):
    assert crossing_junctions(nets["grid"]) == GRID
    # the twins' outer ends are dead ends: only the two junctions count
    assert crossing_junctions(nets["twins"]) == ("A", "B")


def test_a_grid_of_signal_free_junctions_is_collision_free_and_whole(nets, tmp_path):
    cfg = _config(nets, tmp_path, GRID, duration_s=360.0)
    res = run_network(cfg, [load_intersection(cfg.net_path, j) for j in GRID])
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0
    per = res.extra["junctions"]
    assert set(per) == set(GRID)
    acc = res.extra["accounted"]
    assert acc["lost"] == 0 and acc["crossed"] + acc["in_region"] == acc["generated"]
    assert acc == {k: sum(j["accounted"][k] for j in per.values()) for k in acc}
    assert res.requests["count"] == sum(j["requests"]["count"] for j in per.values())
    # vehicles go on from one junction to the next: later crossings by their own names
    trips = res.trips.trips
    third = [v for v in trips if v.endswith("+3")]
    assert third and all(trips[v].confirmed_s is not None for v in third if trips[v].exited_s)
    # the queues reached back: some junction held vehicles for room beyond it
    assert res.requests["rejections"].get("no_room", 0) > 0
    busy = [j for j, x in per.items() if x["crossed"] >= 20]
    assert len(busy) >= 5, per


def test_a_vehicle_flying_its_plan_is_one_sumo_cannot_expect_to_brake(nets, tmp_path):
    """Where SUMO's own drivers share the exit lanes, SUMO is told a vehicle flying its
    plan brakes at FLYING_DECEL_MPS2 (it inserts none and changes none in just ahead
    of it), and once the vehicle is out SUMO knows its own braking again."""
    cfg = _config(nets, tmp_path, ("B1",), duration_s=60.0)
    inter = load_intersection(cfg.net_path, "B1")
    spec = cfg.controller_spec()
    from dica.ica.core.controller import build_controller

    ica = build_controller(spec, inter)
    ls = import_libsumo()
    start_sumo(ls, cfg, spec.config.step_s)
    try:
        world = World(ls, cfg, inter, spec.config, [], cfg.duration_s)
        drivers = LocalDrivers(ica, cfg)
        flying = released = 0
        while not world.done():
            world.apply(drivers.step(world.t, world.step()))
            for c in world.junction.active:
                if c.sumo not in world.junction.present:
                    continue
                decel = ls.vehicle.getDecel(c.sumo)
                if c.released:
                    released += 1
                    want = 4.5  # both types of the file brake at 4.5
                    assert decel == pytest.approx(want), (c.vin, decel)
                elif c.speed_mode == 32:
                    flying += 1
                    assert decel == pytest.approx(FLYING_DECEL_MPS2), (c.vin, decel)
            world.end_step()
        assert flying > 50 and released > 5
    finally:
        ls.close()


PAIR_NODES = """<nodes>
 <node id="A" x="0" y="0" type="priority"/> <node id="B" x="{dx}" y="0" type="priority"/>
 <node id="W" x="-250" y="0"/> <node id="E" x="{east}" y="0"/>
 <node id="NA" x="0" y="250"/> <node id="SA" x="0" y="-250"/>
 <node id="NB" x="{dx}" y="250"/> <node id="SB" x="{dx}" y="-250"/>
</nodes>"""
PAIR_ROUTES = """<routes>
  <flow id="east" begin="0" end="120" vehsPerHour="600" from="WA" to="BE"/>
  <flow id="west" begin="0" end="120" vehsPerHour="300" from="EB" to="AW"/>
  <flow id="turn" begin="0" end="120" vehsPerHour="200" from="NAA" to="BNB"/>
</routes>"""


def _pair(tmp_path: Path, dx: int) -> RunConfig:
    """Two priority junctions ``dx`` m apart on a 50 km/h road (the link is dx - 8 m)."""
    from tests.user_nets import EDGES, plain_net

    net = plain_net(tmp_path, f"pair{dx}", PAIR_NODES.format(dx=dx, east=dx + 250), EDGES)
    routes = tmp_path / "pair.rou.xml"
    routes.write_text(PAIR_ROUTES)
    return RunConfig(
        net_path=str(net), junction_id="A", routes_path=str(routes), junction_ids=("A", "B"),
        duration_s=150.0,
    )  # fmt: skip


def test_a_link_too_short_to_stop_on_after_the_junction_before_is_refused(tmp_path):
    """32 m: long enough to stop on from its start (one junction), not from a vehicle's
    length into it, where the junction before lets its vehicles go."""
    cfg = _pair(tmp_path, 40)
    inters = [load_intersection(cfg.net_path, j) for j in ("A", "B")]
    with pytest.raises(RunError, match=r"junctions . and .: the link .* 32 m long.*leave one"):
        run_network(cfg, inters)


def test_a_short_link_shrinks_the_next_region_and_the_run_says_so(tmp_path, capfd):
    cfg = _pair(tmp_path, 55)  # a 47 m link: the region beyond it is 35 m long
    res = run_network(cfg, [load_intersection(cfg.net_path, j) for j in ("A", "B")])
    err = capfd.readouterr().err
    assert "from A to B is 47 m long: B's region there shrinks to 35 m" in err
    assert "from B to A is 47 m long" in err
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["unconfirmed_entries"] == 0 and res.extra["accounted"]["lost"] == 0
    per = res.extra["junctions"]
    assert per["A"]["crossed"] > 20 and per["B"]["crossed"] > 20


BORN_ROUTES = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" sigma="0.5"/>
  <flow id="east" type="car" begin="0" end="240" vehsPerHour="1200" from="WA" to="BE"
        departLane="best"/>
  <flow id="turn" type="car" begin="0" end="240" vehsPerHour="400" from="NAA" to="BE"/>
  <flow id="born" type="car" begin="0" end="240" number="40" from="AB" to="BE"
        departLane="1" departSpeed="0" color="0,0,1"/>
</routes>"""


def test_insertions_wait_while_a_vehicle_is_about_to_leave_the_junction_onto_their_road(
    tmp_path,
):
    """A file's vehicles starting on A's exit road are held while a confirmed vehicle
    is about to come out onto it, and are put back as the file has them: every one
    departs, on the file's lane, in the file's colour."""
    cfg = _pair(tmp_path, 80)
    routes = tmp_path / "born.rou.xml"
    routes.write_text(BORN_ROUTES)
    info = tmp_path / "tripinfo.xml"
    kept = tmp_path / "vehroutes.xml"
    cfg = replace(
        cfg, routes_path=str(routes), junction_ids=(), duration_s=420.0,
        sumo_args=("--tripinfo-output", str(info), "--vehroute-output", str(kept)),
    )  # fmt: skip
    res = embedded.run(cfg, load_intersection(cfg.net_path, "A"), run_dir=tmp_path)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    assert res.extra["insertions_held"] > 0 and res.extra["insertions_not_held"] == 0
    trips = [t for t in ET.parse(info).getroot() if t.get("id", "").startswith("born.")]
    # one taken back at once after SUMO's first try leaves a record SUMO marks vaporized
    born = [t for t in trips if not t.get("vaporized")]
    assert len(born) == 40 and len({t.get("id") for t in born}) == 40  # none lost
    assert all(float(t.get("routeLength")) > 300.0 for t in born)  # each went its way
    assert {t.get("departLane") for t in born} == {"AB_1"}
    out = [v for v in ET.parse(kept).getroot() if v.get("id", "").startswith("born.")]
    assert {v.get("color") for v in out} == {"blue"}  # 0,0,1 as SUMO writes it


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--junctions", "B1,B2"], "--junctions takes its vehicles from a route file"),
        (["--junctions", "B1,ZZ", "--routes", "ROUTES"], "junction 'ZZ' not in"),
        (["--junctions", "B1,B2", "--junction", "B1", "--routes", "ROUTES"], "give one"),
        (["--junctions", "B1,B2", "--routes", "ROUTES", "--algorithm", "fixed"],
         "signal-free algorithms"),
        (["--junctions", "B1,B1", "--routes", "ROUTES"], "names a junction twice"),
        (["--junctions", "B1,,B2", "--routes", "ROUTES"], "--junctions wants all or"),
    ],
)  # fmt: skip
def test_the_command_line_refuses_what_several_junctions_cannot_serve(nets, tmp_path, extra, says):
    routes = tmp_path / "across.rou.xml"
    routes.write_text(ACROSS)
    args = [str(routes) if a == "ROUTES" else a for a in extra]
    p = dica_run(
        [*DICA, "run", "--net", str(nets["grid"]), *args,
         "--duration", "10", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert says in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_the_command_line_runs_every_junction_of_a_grid(nets, tmp_path):
    routes = tmp_path / "across.rou.xml"
    routes.write_text(ACROSS)
    p = dica_run(
        [*DICA, "run", "--net", str(nets["grid"]),
         "--junctions", "all", "--routes", str(routes), "--duration", "60", "--quiet",
         "--out", str(tmp_path / "run")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr + p.stdout
    assert "0 overlaps" in p.stdout and "0 SUMO collisions" in p.stdout
    import json

    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert set(metrics["junctions"]) == set(GRID)
    assert metrics["network_gate"]["links"] == 24  # the grid's links form cycles: gated
    assert metrics["network"]["vehicles"] > 0  # each vehicle's whole trip, from SUMO's records
    assert (tmp_path / "run" / "trips.csv").is_file()
    q = dica_run(
        [*DICA, "run", "--net", str(nets["grid"]),
         "--junctions", "all", "--routes", str(routes), "--duration", "20", "--quiet",
         "--no-network-gate", "--out", str(tmp_path / "free")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert q.returncode == 0, q.stderr + q.stdout
    free = json.loads((tmp_path / "free" / "metrics.json").read_text())
    assert "network_gate" not in free


SHORT_NODES = """<nodes>
 <node id="A" x="0" y="0" type="priority"/> <node id="W" x="-45" y="0"/>
 <node id="E" x="250" y="0"/> <node id="N" x="0" y="250"/> <node id="S" x="0" y="-250"/>
</nodes>"""
SHORT_EDGES = """<edges>
 <edge id="WA" from="W" to="A" numLanes="1" speed="13.89"/>
 <edge id="AE" from="A" to="E" numLanes="1" speed="13.89"/>
 <edge id="NA" from="N" to="A" numLanes="1" speed="13.89"/>
 <edge id="AS" from="A" to="S" numLanes="1" speed="13.89"/>
</edges>"""
# on a road in shorter than the region, a fast vehicle and a slow one just behind it: each
# appears in the region without crossing its line; the fast one waits for its exit road,
# where a vehicle stands for 15 s
SHORT_ROUTES = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="5" sigma="0"/>
  <vehicle id="block" type="car" depart="0" departSpeed="0">
    <route edges="AE"/><stop lane="AE_0" endPos="20" duration="15"/>
  </vehicle>
  <vehicle id="fast" type="car" depart="1" departSpeed="max"><route edges="WA AE"/></vehicle>
  <vehicle id="slow" type="car" depart="2" departSpeed="1"><route edges="WA AE"/></vehicle>
  <flow id="cross" type="car" begin="0" end="60" vehsPerHour="300" from="NA" to="AS"/>
</routes>"""


def test_vehicles_that_appear_in_the_region_are_queued_in_the_order_they_stand(tmp_path):
    """Interpolating each one's arrival back to a line it never crossed put the slow one
    first (by seconds): the fast one ahead of it was refused as not the head, and the slow
    one behind it never asked; the lane stood still for ever."""
    from tests.user_nets import plain_net

    net = plain_net(tmp_path, "short", SHORT_NODES, SHORT_EDGES)
    routes = tmp_path / "short.rou.xml"
    routes.write_text(SHORT_ROUTES)
    info = tmp_path / "tripinfo.xml"
    cfg = RunConfig(
        net_path=str(net), junction_id="A", routes_path=str(routes), duration_s=120.0,
        sumo_args=("--tripinfo-output", str(info)),
    )  # fmt: skip
    res = embedded.run(cfg, load_intersection(cfg.net_path, "A"), run_dir=tmp_path)
    assert res.safety["overlaps"] == 0 and res.sumo_collisions == 0
    arrived = {t.get("id") for t in ET.parse(info).getroot() if not t.get("vaporized")}
    assert {"fast", "slow"} <= arrived
    assert res.requests["rejections"].get("no_room", 0) > 0  # the fast one waited
    assert res.requests["rejections"].get("not_head", 0) == 0


def test_a_junction_id_with_a_slash_records_beside_the_others():
    """SUMO allows ``/`` in a junction id; its recording is a file beside the others,
    not a path into a directory that is not there (a traceback before)."""
    from types import SimpleNamespace

    from dica.sim_gateway.network import recording_path

    rrd = Path("/runs/x/spacetime.rrd")
    assert recording_path(rrd, SimpleNamespace(junction_id="a"), 0) == rrd
    got = recording_path(rrd, SimpleNamespace(junction_id="x/y%z"), 1)
    assert got == Path("/runs/x/spacetime-x%2Fy%25z.rrd") and got.parent == rrd.parent
