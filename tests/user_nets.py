"""Nets and demand files as users bring them, built the ways netgenerate and netconvert
build them (shared by the user-net and cluster tests)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from dica.sim_gateway.scenario import netconvert_binary

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


def plain_net(d: Path, name: str, nodes: str, edges: str, *flags: str) -> Path:
    """A net netconvert builds from plain XML (``nodes``, ``edges``; no turnarounds, with
    ``flags``) as ``d/<name>.net.xml``."""
    (d / f"{name}.nod.xml").write_text(nodes)
    (d / f"{name}.edg.xml").write_text(edges)
    net = d / f"{name}.net.xml"
    make([netconvert_binary(), "-n", str(d / f"{name}.nod.xml"), "-e",
          str(d / f"{name}.edg.xml"), "--no-turnarounds", "true", *flags,
          "-o", str(net)])  # fmt: skip
    return net


def build_nets(d: Path) -> dict[str, Path]:
    """grid: 3 lanes at 50 km/h, 200 m blocks, no lights; walk: 40 km/h, sidewalks, bike
    lanes, lights, 80 m blocks; twins: two junctions 12 m apart under one joined light;
    joined: the same two joined into one cluster junction; bus: one junction X whose
    east-west road has a bus lane each way."""
    out = {k: d / f"{k}.net.xml" for k in ("grid", "walk", "twins", "joined", "bus")}
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
    plain_net(d, "twins", NODES, EDGES, "--tls.join", "true", "--tls.join-dist", "20")
    plain_net(d, "joined", NODES, EDGES, "--junctions.join", "true", "--junctions.join-dist", "15")
    plain_net(d, "bus", BUS_NODES, BUS_EDGES)
    return out


BUS_NODES = """<nodes>
 <node id="X" x="0" y="0" type="priority"/>
 <node id="W" x="-250" y="0"/> <node id="E" x="250" y="0"/>
 <node id="N" x="0" y="250"/> <node id="S" x="0" y="-250"/>
</nodes>"""
_BUS_LANE = '<lane index="0" allow="bus"/>'
BUS_EDGES = f"""<edges>
 <edge id="WX" from="W" to="X" numLanes="3" speed="13.89">{_BUS_LANE}</edge>
 <edge id="XE" from="X" to="E" numLanes="3" speed="13.89">{_BUS_LANE}</edge>
 <edge id="EX" from="E" to="X" numLanes="3" speed="13.89">{_BUS_LANE}</edge>
 <edge id="XW" from="X" to="W" numLanes="3" speed="13.89">{_BUS_LANE}</edge>
 <edge id="NX" from="N" to="X" numLanes="1" speed="13.89"/>
 <edge id="XS" from="X" to="S" numLanes="1" speed="13.89"/>
 <edge id="SX" from="S" to="X" numLanes="1" speed="13.89"/>
 <edge id="XN" from="X" to="N" numLanes="1" speed="13.89"/>
</edges>"""
# buses on their own lanes beside cars, and cars across them
BUS_ROUTES = """<routes>
  <vType id="bus" vClass="bus" accel="2.0" decel="4.5" length="12" width="2.5"/>
  <flow id="bus" type="bus" begin="0" end="300" vehsPerHour="240" from="WX" to="XE"
        departLane="0"/>
  <flow id="car" begin="0" end="300" vehsPerHour="600" from="WX" to="XE"/>
  <flow id="cross" begin="0" end="300" vehsPerHour="360" from="NX" to="XS"/>
  <flow id="back" begin="0" end="300" vehsPerHour="300" from="EX" to="XW"/>
</routes>"""


# a demand file on the grid through its centre B1: cars and longer vans of their own
# sizes; a flow that loops back through B1 (no U-turns); cars that will not change lanes
# for their route (rerouted from the wrong lane); and a flow that ends before B1
ROUTES = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" width="1.8" sigma="0.5"/>
  <vType id="van" accel="2.0" decel="4.5" length="7.0" width="2.2"/>
  <vType id="stubborn" accel="2.6" decel="4.5" lcStrategic="-1"/>
  <flow id="through" type="car" begin="0" end="400" vehsPerHour="360" from="A1B1" to="B1C1"
        departLane="best" departSpeed="max"/>
  <flow id="loop" type="car" begin="0" end="400" vehsPerHour="120" from="A1B1" to="B1A1"/>
  <flow id="left" type="van" begin="0" end="400" vehsPerHour="180" from="C1B1" to="B1B2"/>
  <flow id="north" type="car" begin="0" end="400" vehsPerHour="240" from="B0B1" to="B1B2"
        departLane="random"/>
  <flow id="wrong" type="stubborn" begin="0" end="400" vehsPerHour="60" from="B0B1"
        to="B1A1" departLane="0"/>
  <flow id="ends" type="car" begin="0" end="400" vehsPerHour="120" from="A0A1" to="A1B1"/>
</routes>"""
# heavy traffic out of B1 eastwards into C1, where it yields to a heavier stream: the
# queue on B1C1 backs up to B1 (without downstream space, B1's confirmed vehicles fly
# into its tail)
JAM_ROUTES = """<routes>
  <vType id="car" accel="2.6" decel="4.5" length="4.5" sigma="0.5"/>
  <flow id="east" type="car" begin="0" end="400" vehsPerHour="1500" from="A1B1" to="C1C2"
        departLane="best"/>
  <flow id="northx" type="car" begin="0" end="400" vehsPerHour="1500" from="C0C1" to="C1C2"
        departLane="best"/>
  <flow id="cross" type="car" begin="0" end="400" vehsPerHour="400" from="B0B1" to="B1B2"/>
  <flow id="west" type="car" begin="0" end="400" vehsPerHour="300" from="C1B1" to="B1A1"/>
</routes>"""


# a one-way ring of four single-lane 150 m links, each junction with a road in from
# outside (straight on into the ring) and a road out (straight on from the ring)
_RING = [(0, 0), (150, 0), (150, 150), (0, 150)]
_OUTSIDE = [((-200, 0), (0, -200)), ((150, -200), (350, 0)),
            ((350, 150), (150, 350)), ((0, 350), (-200, 150))]  # fmt: skip


def build_ring(d: Path) -> Path:
    """R0..R3 in a one-way ring (links R0R1, R1R2, R2R3, R3R0); roads I<i>R<i> in and
    R<i>O<i> out; no lights, no U-turns."""
    nodes = ["<nodes>"]
    edges = ["<edges>"]
    for i, ((x, y), (inn, out)) in enumerate(zip(_RING, _OUTSIDE, strict=True)):
        nodes.append(f' <node id="R{i}" x="{x}" y="{y}" type="priority"/>')
        nodes.append(f' <node id="I{i}" x="{inn[0]}" y="{inn[1]}"/>')
        nodes.append(f' <node id="O{i}" x="{out[0]}" y="{out[1]}"/>')
        for a, b in ((f"R{i}", f"R{(i + 1) % 4}"), (f"I{i}", f"R{i}"), (f"R{i}", f"O{i}")):
            edges.append(f' <edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89"/>')
    (d / "ring.nod.xml").write_text("\n".join([*nodes, "</nodes>"]))
    (d / "ring.edg.xml").write_text("\n".join([*edges, "</edges>"]))
    net = d / "ring.net.xml"
    make([netconvert_binary(), "-n", str(d / "ring.nod.xml"), "-e", str(d / "ring.edg.xml"),
          "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    return net


def ring_routes(links: int, vehs_per_hour: int, end_s: int) -> str:
    """From each road in, round the ring for ``links`` links, then out."""
    out = ["<routes>", ' <vType id="car" accel="2.6" decel="4.5" length="5" sigma="0.5"/>']
    for i in range(4):
        ring = [f"R{(i + k) % 4}R{(i + k + 1) % 4}" for k in range(links)]
        last = (i + links) % 4
        out.append(f' <route id="round{i}" edges="I{i}R{i} {" ".join(ring)} R{last}O{last}"/>')
        out.append(f' <flow id="f{i}" type="car" begin="0" end="{end_s}" '
                   f'vehsPerHour="{vehs_per_hour}" route="round{i}"/>')  # fmt: skip
    return "\n".join([*out, "</routes>"])
