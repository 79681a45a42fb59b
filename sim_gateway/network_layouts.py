"""The built-in networks: a corridor of four junctions and a 3x3 grid, from plain XML.

City streets at 50 km/h, two lanes each way (so two lanes on every approach),
250 m blocks, and 250 m arms beyond the outer junctions where vehicles come in
and leave. Built signal-free (priority junctions, every junction under its own
ICA) or with SUMO's lights (``static``: the programs netconvert makes;
``actuated``: SUMO's gap-based actuation), from the same nodes and edges, so a
comparison differs in the control alone. The lights get safe clearances: a
yellow and an all-red after every green from the usual formulas
(:mod:`sim_gateway.signals`) over the junctions' own ways through.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from dica.sim_gateway.scenario import (
    NETCONVERT_FLAGS,
    ScenarioError,
    _netconvert,
    netconvert_binary,
)
from dica.sim_gateway.signals import all_red_time_s, yellow_time_s

CAR_M = 5.0  # the demand's vehicles' length (sim_gateway.od_demand)

NETWORKS: tuple[str, ...] = ("corridor", "grid")
LIGHTS: tuple[str, ...] = ("static", "actuated")
BLOCK_M = 250.0
ARM_M = 250.0
LANES = 2
CITY_MPS = 13.89  # 50 km/h


@dataclass(frozen=True)
class BuiltNetwork:
    name: str
    net_path: Path
    junctions: tuple[str, ...]  # every junction of the network, west to east, south to north
    clearance_s: tuple[float, float] | None = None  # the lights' yellow and all-red


def _layout(name: str) -> list[tuple[int, int]]:
    """The junctions' grid cells (column, row)."""
    if name == "corridor":
        return [(i, 0) for i in range(4)]
    if name == "grid":
        return [(i, j) for j in range(3) for i in range(3)]
    raise ScenarioError(f"unknown network {name!r}; built-in networks: {', '.join(NETWORKS)}")


def junction_name(i: int, j: int) -> str:
    """``J<col><row>``: J00 is the south-west junction."""
    return f"J{i}{j}"


def build_network(
    name: str, out_dir: Path, lights: str | None = None, free: BuiltNetwork | None = None
) -> BuiltNetwork:
    """Write ``<name>[-<lights>].{nod,edg}.xml`` and build the net in ``out_dir``. The
    lights' clearances come from the signal-free net of the same name: ``free`` if
    already built, else it is built too."""
    cells = _layout(name)
    if lights is not None and lights not in LIGHTS:
        raise ScenarioError(f"unknown lights {lights!r}; known: {', '.join(LIGHTS)}")
    kind = "priority" if lights is None else "traffic_light"
    nodes, edges = [], []
    ids = {c: junction_name(*c) for c in cells}
    for (i, j), jid in ids.items():
        nodes.append(
            f'  <node id="{jid}" x="{i * BLOCK_M:.1f}" y="{j * BLOCK_M:.1f}" type="{kind}"/>'
        )
    # each junction's four neighbours: another junction or an arm's far end
    ends: dict[str, tuple[float, float]] = {}
    links: set[tuple[str, str]] = set()
    for (i, j), jid in ids.items():
        for di, dj, side in ((1, 0, "E"), (-1, 0, "W"), (0, 1, "N"), (0, -1, "S")):
            other = ids.get((i + di, j + dj))
            if other is None:
                end = f"{side}{i}{j}"
                ends[end] = (i * BLOCK_M + di * ARM_M, j * BLOCK_M + dj * ARM_M)
                links.add((end, jid))
                links.add((jid, end))
            else:
                links.add((jid, other))
    for end, (x, y) in sorted(ends.items()):
        nodes.append(f'  <node id="{end}" x="{x:.1f}" y="{y:.1f}"/>')
    for a, b in sorted(links):
        edges.append(
            f'  <edge id="{a}_{b}" from="{a}" to="{b}" numLanes="{LANES}" speed="{CITY_MPS}"/>'
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = name if lights is None else f"{name}-{lights}"
    nod, edg, net = (out_dir / f"{stem}.{k}.xml" for k in ("nod", "edg", "net"))
    nod.write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    edg.write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    flags = list(NETCONVERT_FLAGS)
    clearance = None
    if lights is not None:
        if free is None or free.name != name or free.clearance_s is not None:
            free = build_network(name, out_dir)  # the same ways through, without lights
        clearance = clearance_s(free.net_path, free.junctions)
        flags += ["--tls.default-type", lights, "--tls.yellow.time", f"{clearance[0]:g}",
                  "--tls.allred.time", f"{clearance[1]:g}"]  # fmt: skip
    cmd = [netconvert_binary(), "-n", str(nod), "-e", str(edg), *flags, "-o", str(net)]
    _netconvert(cmd, net)
    return BuiltNetwork(name, net, tuple(ids[c] for c in cells), clearance)


def clearance_s(net_path: Path, junctions: tuple[str, ...]) -> tuple[float, float]:
    """Yellow and all-red for every light of the network, rounded up to whole seconds
    (netconvert takes no fractions): the
    longest the formulas ask over the junctions' links (a vehicle too close to stop
    when the yellow starts reaches the line before it ends; one that crossed the line
    as it ended is out of the junction before a conflicting link turns green)."""
    import sumolib

    net = sumolib.net.readNet(str(net_path), withInternal=True)
    yellow = red = 0.0
    for jid in junctions:
        for c in net.getNode(jid).getConnections():
            approach = c.getFromLane().getSpeed()
            yellow = max(yellow, yellow_time_s(approach))
            way, speed, lane = 0.0, approach, c.getViaLaneID()
            while lane:
                internal = net.getLane(lane)
                way += internal.getLength()
                speed = min(speed, internal.getSpeed())
                nxt = [x for x in internal.getOutgoing() if x.getViaLaneID()]
                lane = nxt[0].getViaLaneID() if nxt else ""
            red = max(red, all_red_time_s(way, CAR_M, speed))
    return float(math.ceil(yellow)), float(math.ceil(red))
