"""The dissertation's two intersections and two of our own, built from plain XML
with ``netconvert``.

The dissertation's are a 4-way junction ``C`` at the origin with straight
approaches along the axes (``N_in``, ``N_out``, ``E_in``, ...; ``_in`` drives
towards ``C``). Only the movements listed in an explicit connections file
exist, so the ICA sees exactly the routes of the reference layouts:

- ``ch3``: 2 incoming lanes, 1 outgoing lane; lane 0 turns right or goes
  through, lane 1 goes through or turns left.
- ``ch45``: 3 incoming lanes, 2 outgoing lanes; lane 0 right and through to
  out lane 0, lane 1 through to out lane 1, lane 2 left only to out lane 1.

Ours, for heavy traffic on junctions the dissertation did not try, leave the
movements to netconvert's guess (2 lanes each way on every arm):

- ``skewed``: a west-east road crossed at 60 degrees (arms ``W``, ``E``,
  ``A`` to the north-east, ``B`` to the south-west);
- ``tee``: a west-east road with a road from the south ending at ``C``.

Each has a ``-walk`` variant (``ch45-walk``, ...): a 2 m sidewalk along every
road and a crossing over every arm, each with SUMO's walking areas at its ends.
The crossings have priority (``priority="true"``), so SUMO's persons never
wait for a gap on their own: at a signal-free junction the roadside holds them
at the kerb until the ICA gives them the crossing (:mod:`sim_gateway.walkers`).
Vehicle lanes count from 1 there (lane 0 is the sidewalk).

Every approach is ``APPROACH_M`` long, so vehicles enter SUMO a few hundred
metres before the 50 m communication region and a queue longer than the
region is one SUMO drives.

The junction type is ``priority``: with speed mode 32 on every vehicle SUMO
leaves right of way to the ICA but still reports junction collisions. For the
traffic-light baselines the same layout is built with a ``traffic_light``
junction, ``static`` (its phases are re-timed at run time) or ``actuated``
(SUMO's own actuated control).
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from dica.sim_gateway.xml_source import xml_source

DISSERTATION_LAYOUTS: tuple[str, ...] = ("ch3", "ch45")
OWN_LAYOUTS: tuple[str, ...] = ("skewed", "tee")
WALK = "-walk"  # a layout's variant with sidewalks and crossings
LAYOUTS: tuple[str, ...] = tuple(
    x + w for w in ("", WALK) for x in DISSERTATION_LAYOUTS + OWN_LAYOUTS
)
SIDEWALK_M = 2.0  # [m] width of the -walk layouts' sidewalks
JUNCTION_ID = "C"
ROAD_SPEED_MPS = 70.0 / 3.6
APPROACH_M = 400.0  # [m] junction centre to the far end of every arm

# Flags every network of this project is built with (see STACK-NOTES): keep the
# junction at the origin, no U-turns, no traffic lights, smooth internal lanes.
NETCONVERT_FLAGS: tuple[str, ...] = (
    "--offset.disable-normalization",
    "true",
    "--no-turnarounds",
    "true",
    "--tls.guess",
    "false",
    "--junctions.internal-link-detail",
    "20",
)
NETCONVERT_TIMEOUT_S = 120.0
_STDERR_TAIL_CHARS = 600

# Approaches clockwise; for a vehicle coming from APPROACHES[i], the right turn
# leaves towards APPROACHES[i - 1], through towards i + 2 and left towards i + 1.
APPROACHES: tuple[str, ...] = ("N", "E", "S", "W")
_FAR_NODE_UNIT = {"N": (0.0, 1.0), "E": (1.0, 0.0), "S": (0.0, -1.0), "W": (-1.0, 0.0)}

# layout -> (incoming lanes, outgoing lanes, [(from lane, movement, to lane)])
_LAYOUT_SPEC: dict[str, tuple[int, int, tuple[tuple[int, str, int], ...]]] = {
    "ch3": (2, 1, ((0, "right", 0), (0, "through", 0), (1, "through", 0), (1, "left", 0))),
    "ch45": (3, 2, ((0, "right", 0), (0, "through", 0), (1, "through", 1), (2, "left", 1))),
}
_TURN_OFFSET = {"right": -1, "through": 2, "left": 1}
# our layouts: arm -> (bearing [deg, counter-clockwise from east], lanes each way, priority)
_OWN_ARMS: dict[str, tuple[tuple[str, float, int, int], ...]] = {
    "skewed": (("W", 180.0, 2, 2), ("E", 0.0, 2, 2), ("A", 60.0, 2, 1), ("B", 240.0, 2, 1)),
    "tee": (("W", 180.0, 2, 2), ("E", 0.0, 2, 2), ("S", 270.0, 2, 1)),
}


class ScenarioError(Exception):
    """A scenario could not be built; the message is one line meant for a person."""


@dataclass(frozen=True)
class Scenario:
    layout: str
    net_path: Path
    junction_id: str


def netconvert_binary() -> str:
    """Path of ``netconvert``: the venv's first, so the version matches sumolib/libsumo."""
    exe_names = ("netconvert.exe", "netconvert") if os.name == "nt" else ("netconvert",)
    candidates = [Path(sys.executable).parent / n for n in exe_names]
    try:
        import sumo  # eclipse-sumo wheel

        candidates += [Path(sumo.SUMO_HOME) / "bin" / n for n in exe_names]
    except (ImportError, AttributeError):
        pass
    for cand in candidates:
        if cand.is_file() and os.access(cand, os.X_OK):
            return str(cand)
    found = shutil.which("netconvert")
    if found:
        return found
    raise ScenarioError(
        "netconvert not found (looked next to the Python interpreter, in sumo.SUMO_HOME/bin "
        "and on PATH); install eclipse-sumo"
    )


def run_netconvert(
    nodes_xml: Path,
    edges_xml: Path,
    out_net: Path,
    connections_xml: Path | None = None,
    extra_args: Sequence[str] = (),
) -> None:
    """Run netconvert on plain XML with the project's standard flags."""
    cmd = [
        netconvert_binary(),
        "--node-files",
        str(nodes_xml),
        "--edge-files",
        str(edges_xml),
    ]
    if connections_xml is not None:
        cmd += ["--connection-files", str(connections_xml)]
    _netconvert([*cmd, *NETCONVERT_FLAGS, *extra_args, "--output-file", str(out_net)], out_net)


def junction_type(net_path: Path, junction_id: str) -> str | None:
    """The ``type`` SUMO's net file gives the junction, or None if it has no such junction."""
    import xml.etree.ElementTree as ET

    try:
        for _, el in ET.iterparse(xml_source(net_path), events=("end",)):
            if el.tag == "junction" and el.get("id") == junction_id:
                return el.get("type")
            if el.tag in ("edge", "junction", "connection"):
                el.clear()
    except (OSError, ET.ParseError) as exc:
        raise ScenarioError(f"cannot read {net_path}: {exc}") from exc
    return None


def signalise(net_path: Path, junction_id: str, tls: str, out_dir: Path) -> Path:
    """A copy of the net with ``junction_id`` signalised by netconvert (``--tls.set``).

    netconvert builds its own phase plan for the junction; the light baselines
    then set its clearance and timing (:mod:`sim_gateway.signals`).
    """
    _check_tls(tls)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out_net = out_dir / f"{Path(net_path).name.removesuffix('.net.xml')}-tls-{tls}.net.xml"
    cmd = [
        netconvert_binary(),
        "--sumo-net-file",
        str(net_path),
        "--tls.set",
        junction_id,
        "--tls.default-type",
        tls,
        *NETCONVERT_FLAGS,
        "--output-file",
        str(out_net),
    ]
    _netconvert(cmd, out_net)
    return out_net


def tls_program_type(net_path: Path, tls_id: str) -> str | None:
    """The ``type`` of the net's first program for traffic light ``tls_id`` (None: none)."""
    import xml.etree.ElementTree as ET

    try:
        for _, el in ET.iterparse(xml_source(net_path), events=("end",)):
            if el.tag == "tlLogic" and el.get("id") == tls_id:
                return el.get("type", "static")
            if el.tag in ("edge", "junction", "connection"):
                el.clear()
    except (OSError, ET.ParseError) as exc:
        raise ScenarioError(f"cannot read {net_path}: {exc}") from exc
    return None


def light_id(net_path: Path, junction_id: str) -> str:
    """The id of the light over a signalised junction, from its incoming connections' ``tl``
    (a joined cluster's light has an id of its own; with none, the junction's id)."""
    import xml.etree.ElementTree as ET

    incoming: set[str] = set()
    try:
        for _, el in ET.iterparse(xml_source(net_path), events=("end",)):
            if el.tag == "edge" and el.get("to") == junction_id:
                incoming.add(el.get("id", ""))  # internal edges have no "to"
            elif el.tag == "connection" and el.get("from") in incoming and el.get("tl"):
                return el.get("tl", junction_id)
            if el.tag in ("edge", "junction", "connection"):
                el.clear()
    except (OSError, ET.ParseError) as exc:
        raise ScenarioError(f"cannot read {net_path}: {exc}") from exc
    return junction_id


def unlit(net_path: Path, junction_ids: Sequence[str]) -> list[str]:
    """Those of ``junction_ids`` that no light controls: none of their incoming
    connections names one (``tl``)."""
    import xml.etree.ElementTree as ET

    into: dict[str, str] = {}  # incoming edge -> junction
    lit: set[str] = set()
    wanted = set(junction_ids)
    try:
        for _, el in ET.iterparse(xml_source(net_path), events=("end",)):
            if el.tag == "edge" and el.get("to") in wanted:
                into[el.get("id", "")] = el.get("to", "")
            elif el.tag == "connection" and el.get("from") in into and el.get("tl"):
                lit.add(into[el.get("from", "")])
            if el.tag in ("edge", "junction", "connection"):
                el.clear()
    except (OSError, ET.ParseError) as exc:
        raise ScenarioError(f"cannot read {net_path}: {exc}") from exc
    return [j for j in junction_ids if j not in lit]


def light_net(net_path: Path, junction_id: str, tls: str, out_dir: Path) -> tuple[Path, str | None]:
    """A net whose ``junction_id`` carries a ``tls`` light (static or actuated), and a
    line saying what was built, or None when the net already has one.

    A junction without a light is signalised with netconvert; one whose
    program is static while an actuated light is wanted has the net's lights
    rebuilt as actuated (netconvert cannot change one junction's type).
    Either net is written to ``out_dir``.
    """
    _check_tls(tls)
    kind = junction_type(Path(net_path), junction_id)
    if kind is None:
        raise ScenarioError(f"junction {junction_id!r} not in {net_path}")
    if not kind.startswith("traffic_light"):
        out = signalise(Path(net_path), junction_id, tls, out_dir)
        return (
            out,
            f"junction {junction_id} had no traffic light: signalised by netconvert in {out}",
        )
    program = tls_program_type(Path(net_path), light_id(Path(net_path), junction_id))
    if tls == "actuated" and program != "actuated":
        out = rebuilt_actuated(Path(net_path), Path(out_dir), "-tls-actuated")
        return out, (
            f"junction {junction_id}'s light was {program or 'of no known type'}: "
            f"rebuilt actuated by netconvert in {out}"
        )
    return Path(net_path), None


def stop_net(net_path: Path, junction_id: str, out_dir: Path) -> tuple[Path, str]:
    """A copy of the net with ``junction_id`` an all-way stop (SUMO's ``allway_stop``:
    every vehicle stops at the line, then goes in the order they came), by netconvert,
    and a line saying so."""
    kind = junction_type(Path(net_path), junction_id)
    if kind is None:
        raise ScenarioError(f"junction {junction_id!r} not in {net_path}")
    if kind.startswith("traffic_light"):
        raise ScenarioError(f"junction {junction_id} has a traffic light; the all-way stop "
                            "baseline takes a net whose junction has none")  # fmt: skip
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = Path(net_path).name.removesuffix(".net.xml")
    patch = out_dir / f"{stem}-allway-stop.nod.xml"
    node = f'<node id={quoteattr(junction_id)} type="allway_stop"/>'
    patch.write_text(f"<nodes>\n    {node}\n</nodes>\n")
    out_net = out_dir / f"{stem}-allway-stop.net.xml"
    cmd = [netconvert_binary(), "--sumo-net-file", str(net_path), "--node-files", str(patch),
           *NETCONVERT_FLAGS, "--output-file", str(out_net)]  # fmt: skip
    _netconvert(cmd, out_net)
    return out_net, f"junction {junction_id} made an all-way stop by netconvert in {out_net}"


def rebuilt_actuated(
    net_path: Path, out_dir: Path, suffix: str, flags: tuple[str, ...] = NETCONVERT_FLAGS
) -> Path:
    """``net_path`` with every light rebuilt actuated by netconvert (junctions without a
    light stay so), written to ``out_dir`` as ``<stem><suffix>.net.xml``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / f"{net_path.name.removesuffix('.net.xml')}{suffix}.net.xml"
    cmd = [
        netconvert_binary(),
        "--sumo-net-file",
        str(net_path),
        "--tls.rebuild",
        "--tls.default-type",
        "actuated",
        *flags,
        "--output-file",
        str(out),
    ]
    _netconvert(cmd, out)
    return out


def _netconvert(cmd: list[str], out_net: Path) -> None:
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=NETCONVERT_TIMEOUT_S, check=False
        )
    except subprocess.TimeoutExpired as exc:
        raise ScenarioError(
            f"netconvert timed out after {exc.timeout:.0f} s for {out_net}"
        ) from exc
    except OSError as exc:
        raise ScenarioError(f"netconvert could not be started: {exc}") from exc
    if proc.returncode != 0:
        raise ScenarioError(
            f"netconvert failed (exit {proc.returncode}) for {out_net}: {_tail(proc.stderr)}"
        )
    if not out_net.is_file():
        raise ScenarioError(f"netconvert wrote no network to {out_net}: {_tail(proc.stderr)}")


def _tail(text: str) -> str:
    """Last part of a multi-line tool output, squeezed onto one line."""
    flat = " | ".join(line.strip() for line in text.strip().splitlines() if line.strip())
    if not flat:
        return "(no output on stderr)"
    return flat if len(flat) <= _STDERR_TAIL_CHARS else "..." + flat[-_STDERR_TAIL_CHARS:]


def _check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise ScenarioError(f"unknown layout {layout!r}; known layouts: {', '.join(LAYOUTS)}")


TLS_TYPES: tuple[str, ...] = ("static", "actuated")


def _check_tls(tls: str | None) -> None:
    if tls is not None and tls not in TLS_TYPES:
        raise ScenarioError(f"unknown traffic light type {tls!r}; known: {', '.join(TLS_TYPES)}")


def _stem(layout: str, tls: str | None) -> str:
    return layout if tls is None else f"{layout}-tls-{tls}"


def _doc(root: str, lines: list[str]) -> str:
    return (
        f'<?xml version="1.0" encoding="UTF-8"?>\n<{root}>\n' + "\n".join(lines) + f"\n</{root}>\n"
    )


def _sidewalks(files: dict[str, str], arms: Sequence[str]) -> dict[str, str]:
    """``files`` with a sidewalk on every edge (vehicle lanes move up by one) and a
    priority crossing over each arm."""
    out = dict(files)
    out["edg"] = files["edg"].replace('"/>', f'" sidewalkWidth="{SIDEWALK_M:.1f}"/>')
    conns = files.get("con", _doc("connections", [])).splitlines()
    for i, line in enumerate(conns):
        if "fromLane=" in line:
            words = line.split(" ")
            for k, w in enumerate(words):
                for key in ("fromLane", "toLane"):
                    if w.startswith(f'{key}="'):
                        n = int(w.split('"')[1])
                        words[k] = w.replace(f'"{n}"', f'"{n + 1}"', 1)
            conns[i] = " ".join(words)
    crossings = [
        f'    <crossing node="{JUNCTION_ID}" edges="{a}_in {a}_out" priority="true"/>' for a in arms
    ]
    out["con"] = "\n".join(conns[:-1] + crossings + conns[-1:]) + "\n"
    return out


def _own_xml(layout: str, approach_length_m: float, kind: str) -> dict[str, str]:
    nodes = [f'    <node id="{JUNCTION_ID}" x="0.00" y="0.00" type="{kind}"/>']
    edges = []
    for arm, bearing, lanes, prio in _OWN_ARMS[layout]:
        x = approach_length_m * math.cos(math.radians(bearing))
        y = approach_length_m * math.sin(math.radians(bearing))
        nodes.append(f'    <node id="{arm}" x="{x:.2f}" y="{y:.2f}" type="dead_end"/>')
        for name, a, b in ((f"{arm}_in", arm, JUNCTION_ID), (f"{arm}_out", JUNCTION_ID, arm)):
            edges.append(
                f'    <edge id="{name}" from="{a}" to="{b}" numLanes="{lanes}" '
                f'speed="{ROAD_SPEED_MPS:.6f}" priority="{prio}"/>'
            )
    return {"nod": _doc("nodes", nodes), "edg": _doc("edges", edges)}


def plain_xml(
    layout: str, approach_length_m: float = APPROACH_M, tls: str | None = None
) -> dict[str, str]:
    """Node, edge and (for the dissertation's, and with sidewalks) connection files of a
    layout, keyed by suffix (``nod``, ``edg``, ``con``)."""
    _check_layout(layout)
    _check_tls(tls)
    if not approach_length_m > 30.0:
        raise ScenarioError(f"approach_length_m must exceed 30 m, got {approach_length_m}")
    if layout.endswith(WALK):
        base = layout.removesuffix(WALK)
        arms = [a[0] for a in _OWN_ARMS[base]] if base in OWN_LAYOUTS else list(APPROACHES)
        return _sidewalks(plain_xml(base, approach_length_m, tls), arms)
    kind = "priority" if tls is None else "traffic_light"
    if layout in OWN_LAYOUTS:
        return _own_xml(layout, approach_length_m, kind)
    n_in, n_out, movements = _LAYOUT_SPEC[layout]

    nodes = [f'    <node id="{JUNCTION_ID}" x="0.00" y="0.00" type="{kind}"/>']
    for a in APPROACHES:
        ux, uy = _FAR_NODE_UNIT[a]
        x, y = ux * approach_length_m, uy * approach_length_m
        nodes.append(f'    <node id="{a}" x="{x:.2f}" y="{y:.2f}" type="dead_end"/>')

    edges = []
    for a in APPROACHES:
        edges.append(
            f'    <edge id="{a}_in" from="{a}" to="{JUNCTION_ID}" numLanes="{n_in}" '
            f'speed="{ROAD_SPEED_MPS:.6f}" priority="1"/>'
        )
        edges.append(
            f'    <edge id="{a}_out" from="{JUNCTION_ID}" to="{a}" numLanes="{n_out}" '
            f'speed="{ROAD_SPEED_MPS:.6f}" priority="1"/>'
        )

    conns = []
    for i, a in enumerate(APPROACHES):
        for from_lane, movement, to_lane in movements:
            target = APPROACHES[(i + _TURN_OFFSET[movement]) % len(APPROACHES)]
            conns.append(
                f"    <connection from={quoteattr(a + '_in')} to={quoteattr(target + '_out')} "
                f'fromLane="{from_lane}" toLane="{to_lane}"/>'
            )

    return {
        "nod": _doc("nodes", nodes),
        "edg": _doc("edges", edges),
        "con": _doc("connections", conns),
    }


def build_scenario(
    layout: str, out_dir: Path, *, approach_length_m: float = APPROACH_M, tls: str | None = None
) -> Scenario:
    """Write ``<stem>.{nod,edg[,con]}.xml`` and build ``<stem>.net.xml`` in ``out_dir``.

    The stem is the layout, or ``<layout>-tls-<type>`` with a traffic light.
    """
    files = plain_xml(layout, approach_length_m, tls)
    stem = _stem(layout, tls)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {kind: out_dir / f"{stem}.{kind}.xml" for kind in files}
    for kind, text in files.items():
        paths[kind].write_text(text, encoding="utf-8")
    net = out_dir / f"{stem}.net.xml"
    extra = [] if tls is None else ["--tls.default-type", tls]
    run_netconvert(
        paths["nod"], paths["edg"], net, connections_xml=paths.get("con"), extra_args=extra
    )
    return Scenario(layout=layout, net_path=net, junction_id=JUNCTION_ID)


def repo_root() -> Path:
    return Path(__file__).resolve().parent.parent


def default_scenario(
    layout: str = "ch45", cache_dir: Path | None = None, tls: str | None = None
) -> Scenario:
    """The layout's network in ``<cache_dir or repo/build/scenarios>/<layout>/``, built once.

    Rebuilt only when the net is missing or the plain XML this code would write
    differs from the stored copy (so a change of layout code is not served stale).
    Concurrent callers each build in a private temp dir and move the results in
    with ``os.replace``; the net is moved first, so whoever sees the new plain
    files also sees the new net.
    """
    _check_layout(layout)
    _check_tls(tls)
    stem = _stem(layout, tls)
    base = Path(cache_dir) if cache_dir is not None else repo_root() / "build" / "scenarios"
    target = base / stem
    files = plain_xml(layout, tls=tls)
    net = target / f"{stem}.net.xml"
    if net.is_file() and _same_inputs(target, stem, files):
        return Scenario(layout=layout, net_path=net, junction_id=JUNCTION_ID)

    target.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{stem}-build-", dir=target))
    try:
        built = build_scenario(layout, tmp, tls=tls)
        os.replace(built.net_path, net)
        for kind in files:
            os.replace(tmp / f"{stem}.{kind}.xml", target / f"{stem}.{kind}.xml")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return Scenario(layout=layout, net_path=net, junction_id=JUNCTION_ID)


def _same_inputs(target: Path, layout: str, files: dict[str, str]) -> bool:
    for kind, text in files.items():
        try:
            if (target / f"{layout}.{kind}.xml").read_text(encoding="utf-8") != text:
                return False
        except OSError:
            return False
    return True
