"""Nets as users bring them, built here the ways netgenerate and netconvert build
them: their own speed limits and lane counts, sidewalks and bike lanes, lights
with ids of their own, junctions a few metres apart. Each runs signal-free with
zero collisions by both checks, nothing lost, and no vehicle above the net's
limit by SUMO's own record of speeds.
"""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from dica.ica.core.limits import SpeedCaps, Turn
from dica.ica.netfile import load_intersection
from dica.sim_gateway import embedded
from dica.sim_gateway.demand import unserved
from dica.sim_gateway.runconfig import RunConfig
from dica.sim_gateway.scenario import light_id, netconvert_binary

ROOT = Path(__file__).resolve().parents[1]
CITY_MPS = 13.89  # 50 km/h as SUMO writes it
SLOW_MPS = 11.11  # 40 km/h

NODES = """<nodes>
 <node id="A" x="0" y="0" type="traffic_light"/> <node id="B" x="12" y="0" type="traffic_light"/>
 <node id="W" x="-250" y="0"/> <node id="E" x="262" y="0"/>
 <node id="NA" x="0" y="250"/> <node id="SA" x="0" y="-250"/>
 <node id="NB" x="12" y="250"/> <node id="SB" x="12" y="-250"/>
</nodes>"""
EDGES = """<edges>
 <edge id="WA" from="W" to="A" numLanes="2" speed="13.89"/>
 <edge id="AW" from="A" to="W" numLanes="2" speed="13.89"/>
 <edge id="AB" from="A" to="B" numLanes="2" speed="13.89"/>
 <edge id="BA" from="B" to="A" numLanes="2" speed="13.89"/>
 <edge id="BE" from="B" to="E" numLanes="2" speed="13.89"/>
 <edge id="EB" from="E" to="B" numLanes="2" speed="13.89"/>
 <edge id="NAA" from="NA" to="A" numLanes="1" speed="8.33"/>
 <edge id="ASA" from="A" to="SA" numLanes="1" speed="8.33"/>
 <edge id="SBB" from="SB" to="B" numLanes="1" speed="8.33"/>
 <edge id="BNB" from="B" to="NB" numLanes="1" speed="8.33"/>
</edges>"""


def tool(name: str) -> str:
    return str(Path(netconvert_binary()).with_name(name))


def make(cmd: list[str]) -> None:
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr


@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("usernets")
    out = {k: d / f"{k}.net.xml" for k in ("grid", "walk", "twins", "joined")}
    # a city grid: 3 lanes each way at 50 km/h, 200 m blocks, no lights
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
          "--default.lanenumber", "3", "--default.speed", str(CITY_MPS),
          "--no-turnarounds", "true", "-o", str(out["grid"])])  # fmt: skip
    # 40 km/h, 2 lanes, sidewalks and bike lanes, lights guessed, 80 m blocks
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "80",
          "--default.lanenumber", "2", "--default.speed", str(SLOW_MPS), "--tls.guess", "true",
          "--sidewalks.guess", "true", "--bikelanes.guess", "true",
          "--no-turnarounds", "true", "-o", str(out["walk"])])  # fmt: skip
    # two junctions 12 m apart under one joined light (its id is neither's), and the
    # same two joined into one cluster junction
    (d / "j.nod.xml").write_text(NODES)
    (d / "j.edg.xml").write_text(EDGES)
    plain = ["-n", str(d / "j.nod.xml"), "-e", str(d / "j.edg.xml"), "--no-turnarounds", "true"]
    make([netconvert_binary(), *plain, "--tls.join", "true", "--tls.join-dist", "20",
          "-o", str(out["twins"])])  # fmt: skip
    make([netconvert_binary(), *plain, "--junctions.join", "true", "--junctions.join-dist", "15",
          "-o", str(out["joined"])])  # fmt: skip
    return out


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
        volume_per_10min=float(volume), duration_s=240.0, seed=21,
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
    p = subprocess.run(
        [sys.executable, "-m", "dica.tools.cli", "run", "--net", str(nets["twins"]),
         "--junction", "A", "--duration", "30", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "no demand on its" in p.stderr  # the short links are named
    assert (tmp_path / "run" / "metrics.json").is_file()
