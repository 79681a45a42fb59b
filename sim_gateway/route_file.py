"""A user's SUMO demand file (``--routes``): what it asks of the junction, checked before
a run trusts it.

SUMO drives the file's vehicles (routes, trips, flows, each of its vehicle
type) through the whole net; the world takes one over when it reaches the
junction's communication region (:meth:`sim_gateway.traffic.Traffic.adopt`).
From there the ICA plans it with one set of kinematics, and the vehicle
flies the plan as SUMO is told, so every vehicle type the file uses must be
able to: accelerate and brake at least as hard as the ICA plans, be no
longer than the routes are drawn for, and be a vehicle the ICA serves.
Walkers and cyclists cross outside the ICA's routes, so a file with them is
refused rather than run unprotected.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M
from dica.ica.core.gridlock import (
    LINE_GAP_M,
    QUEUE_GAP_M,
    edge_of,
    full_need_m,
    link_arcs,
    link_length_m,
    on_cycles,
    short_exits,
)
from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Kinematics
from dica.ica.core.waiting import exit_sweeps, line_backs
from dica.ica.netfile import MAX_VEHICLE_LENGTH_M, SERVED_CLASSES, stop_room_m
from dica.sim_gateway.runconfig import RunError
from dica.sim_gateway.xml_source import xml_source

MAX_LENGTH_M = MAX_VEHICLE_LENGTH_M
DEFAULT_TYPE = "DEFAULT_VEHTYPE"
_TRAFFIC = ("vehicle", "trip", "flow")
_PEOPLE = ("person", "personFlow")
_GOODS = ("container", "containerFlow")
# what a person of a route file may do: walk (a walk-only personTrip is a walk too)
HELD_KEYS = ("departLane", "departPos", "departSpeed", "arrivalLane", "arrivalPos", "color",
               "arrivalSpeed")  # fmt: skip


@dataclass(frozen=True, slots=True)
class RouteFile:
    """What a route file holds: the vehicle types its traffic uses and how much of it."""

    path: Path
    types: frozenset[str]  # used by its vehicles, trips and flows (distributions opened)
    traffic: int  # vehicles, trips and flows (a flow counts once)
    # per vehicle, trip or flow id: how the file has it depart and arrive (the attributes
    # a vehicle keeps if its insertion is held back; see sim_gateway/insertion.py), or
    # None if it carries more than a route (stops, parameters), which a hold would lose
    departs: dict[str, dict[str, str] | None] = field(default_factory=dict)
    people: int = 0  # persons and person flows (on foot only)
    # per vehicle, trip or flow id with an arrivalPos: its last edge and that arrivalPos
    arrivals: dict[str, tuple[str, str]] = field(default_factory=dict)
    # each stop the file gives (on a vehicle, trip, flow or route): who makes it, its
    # attributes (lane or edge and positions, or the stopping place it names) and the
    # roads its maker may start on
    stops: list[tuple[str, dict[str, str], frozenset[str]]] = field(default_factory=list)
    # each vehicle, trip or flow: who it is, where it starts on its first road
    # (departPos, departSpeed) and the roads it may start on
    starts: list[tuple[str, dict[str, str], frozenset[str]]] = field(default_factory=list)


# SUMO's own length and width [m] per vehicle class (a vType that sets neither takes its
# class's); the world checks them against SUMO's when it has loaded the file
CLASS_SIZES: dict[str, tuple[float, float]] = {
    "bus": (12.0, 2.5), "coach": (14.0, 2.6), "delivery": (6.5, 2.16),
    "emergency": (6.5, 2.16), "moped": (2.1, 0.78), "motorcycle": (2.2, 0.9),
    "trailer": (16.5, 2.55), "truck": (7.1, 2.4),
}  # fmt: skip
CAR_SIZE = (5.0, 1.8)  # every other class served, and a vehicle without a type


def fleet_size(path: Path) -> tuple[float, float]:
    """The longest and the widest vehicle [m] a route file's types may bring (every
    type it defines, and SUMO's default car), the length no more than the routes allow:
    where such a vehicle turning sweeps over a waiting place, that lane's line moves back
    (:mod:`ica.core.waiting`). A file that cannot be read is refused in one line."""
    if not Path(path).is_file():
        raise RunError(f"route file not found: {path}")
    length, width = CAR_SIZE
    try:
        for _, el in ET.iterparse(xml_source(path)):
            if el.tag == "vType":
                own = CLASS_SIZES.get(el.get("vClass", "passenger"), CAR_SIZE)
                length = max(length, float(el.get("length", own[0])))
                width = max(width, float(el.get("width", own[1])))
            el.clear()
    except (OSError, ET.ParseError, ValueError) as e:
        raise RunError(f"route file {path}: cannot be read ({e})") from None
    return min(length, MAX_LENGTH_M), width


def read_route_file(path: Path) -> RouteFile:
    """The file's traffic and the types it uses, and how many people on foot it has; a
    file that cannot be read, holds no traffic, or holds containers or people who do
    more than walk is refused in one line."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"route file not found: {path}")
    distributions: dict[str, set[str]] = {}
    used: set[str] = set()
    traffic = people = 0
    riders: list[str] = []
    goods = 0
    open_dist: list[str] = []
    departs: dict[str, dict[str, str] | None] = {}
    ids: list[tuple[str, str]] = []
    named_routes: dict[str, str] = {}  # a top-level route's id: its last edge
    arrivals: dict[str, tuple[str, str]] = {}
    stops: list[tuple[str, dict[str, str], frozenset[str]]] = []
    starts: list[tuple[str, dict[str, str], frozenset[str]]] = []
    first: dict[str, set[str]] = {}  # a route's or route distribution's first roads
    open_routes: list[str] = []  # route distributions open
    owner: list[tuple[str, set[str]]] = []  # the vehicle, trip or flow open: its own route
    own_last: list[str | None] = []  # and the last road of that route (read as it ends)
    type_speed: dict[str, str] = {}  # a vType's departSpeed: its vehicles' unless they set one
    start_types: list[str] = []  # each start's type
    try:
        for event, el in ET.iterparse(xml_source(path), events=("start", "end")):
            tag = el.tag
            if event == "start":
                if tag in _TRAFFIC:
                    owner.append((f"{tag} {el.get('id', '?')!r}", set()))
                    own_last.append(None)
                elif tag == "routeDistribution":
                    open_routes.append(el.get("id", ""))
                if tag == "vTypeDistribution":
                    open_dist.append(el.get("id", ""))
                    members = el.get("vTypes", "").split()
                    distributions.setdefault(open_dist[-1], set()).update(members)
                elif tag == "vType" and open_dist:
                    distributions[open_dist[-1]].add(el.get("id", ""))
                continue
            if tag == "vType" and el.get("departSpeed") is not None:
                type_speed[el.get("id", "")] = el.get("departSpeed", "")
            if tag == "vTypeDistribution":
                open_dist.pop()
            elif tag == "routeDistribution":
                open_routes.pop()
            elif tag == "stop":
                who = owner[-1][0] if owner else "a stop outside any vehicle"
                stops.append((who, dict(el.attrib), frozenset()))
            elif tag == "route":
                edges = el.get("edges", "").split()
                heads = {edges[0]} if edges else set(first.get(el.get("refId", ""), ()))
                if owner:  # its vehicle's own (cleared once read: its last road kept)
                    owner[-1][1].update(heads)
                    if edges:
                        own_last[-1] = edges[-1]
                else:
                    rid = el.get("id", "")
                    first.setdefault(rid, set()).update(heads)
                    if open_routes:
                        first.setdefault(open_routes[-1], set()).update(heads)
                    for k in range(len(stops) - 1, -1, -1):  # its stops, read before it ended
                        if stops[k][0] != "a stop outside any vehicle":
                            break
                        stops[k] = (f"route {rid!r}", stops[k][1], frozenset(heads))
            if tag in _TRAFFIC:
                who, own = owner.pop()
                heads = set(own)
                if el.get("from"):
                    heads.add(el.get("from"))
                if el.get("route"):
                    heads |= first.get(el.get("route"), set())
                if not heads:  # from a TAZ or a junction, or a route of another file
                    heads.add(ANY_ROAD)
                starts.append((who, {k: el.get(k) for k in ("departPos", "departSpeed")
                                     if el.get(k) is not None}, frozenset(heads)))  # fmt: skip
                start_types.append(el.get("type", DEFAULT_TYPE))
                for k in range(len(stops) - 1, -1, -1):  # its own stops
                    if stops[k][0] != who:
                        break
                    stops[k] = (who, stops[k][1], frozenset(heads))
                traffic += 1
                ids.append((tag, el.get("id", "")))
                nested = own_last.pop()
                if el.get("arrivalPos") is not None:
                    last = nested or _last_edge(el, named_routes)
                    if last:
                        arrivals[el.get("id", "")] = (last, el.get("arrivalPos", ""))
                used.add(el.get("type", DEFAULT_TYPE))
                plain = all(child.tag == "route" for child in el)
                departs[el.get("id", "")] = (
                    {k: el.get(k) for k in HELD_KEYS if el.get(k) is not None} if plain else None
                )
            elif tag in _PEOPLE:
                people += 1
                if not _on_foot(el):
                    riders.append(el.get("id", "?"))
            elif tag in _GOODS:
                goods += 1
            if tag == "route" and el.get("id") and el.get("edges"):
                named_routes[el.get("id", "")] = el.get("edges", "").split()[-1]
            if tag in (*_TRAFFIC, *_PEOPLE, *_GOODS, "route"):
                el.clear()
    except (OSError, ET.ParseError) as exc:
        detail = " ".join(str(exc).split())
        raise RunError(f"cannot read route file {path}: {detail}") from None
    if goods:
        raise RunError(
            f"route file {path} has {goods} containers: they are not served; leave them out"
        )
    if riders:
        raise RunError(
            f"route file {path} has {len(riders)} persons who do more than walk (first: "
            f"{riders[0]}): people ride and stop at a signal-free junction not yet; give "
            "them walks only"
        )
    if not traffic:
        raise RunError(f"route file {path} has no vehicle, trip or flow")
    _check_ids(path, ids)
    types: set[str] = set()
    for t in used:
        types |= distributions.get(t, {t})
    for (_, dep, _), t in zip(starts, start_types, strict=True):
        if "departSpeed" not in dep:  # a moving start its type gives (any of a distribution's)
            given = (type_speed.get(m, "0").strip() for m in sorted(distributions.get(t, {t})))
            moving = [v for v in given if not _is_zero(v)]
            if moving:
                dep["departSpeed"], dep["speedOf"] = moving[0], t
    return RouteFile(path, frozenset(types), traffic, departs, people, arrivals, stops, starts)


def _last_edge(el: ET.Element, named_routes: dict[str, str]) -> str | None:
    """The edge a vehicle, trip or flow ends on, if the file says it plainly."""
    for child in el:
        if child.tag == "route" and child.get("edges"):
            return child.get("edges", "").split()[-1]
    if el.get("route") in named_routes:
        return named_routes[el.get("route", "")]
    return el.get("to")


# how far past the rear-out point an arrivalPos must be: a step's travel at up to 200 km/h
# (a vehicle that passes both in one step is gone before it is seen out)
ARRIVAL_MARGIN_M = 3.0


def check_arrivals(ls, rf: RouteFile, inters: Sequence[Intersection]) -> None:
    """Refuse a vehicle that would leave SUMO (its arrivalPos) on a junction's exit before
    its rear is out of the junction: the world lets a vehicle go once its rear is past
    the exit line, so one that vanishes sooner would be lost to the count and to the
    links' room it was given."""
    need = MAX_LENGTH_M + ARRIVAL_MARGIN_M
    exits: dict[str, tuple[str, float]] = {}
    for x in inters:
        for r in x.routes:
            edge = edge_of(r.out_lane)
            length = ls.lane.getLength(r.out_lane)
            if edge not in exits or length < exits[edge][1]:
                exits[edge] = (x.junction_id, length)
    for vid, (edge, pos) in sorted(rf.arrivals.items()):
        if edge not in exits:
            continue
        junction, length = exits[edge]
        try:
            at = float(pos)
        except ValueError:
            at = None if pos == "random" else length  # "max" (or SUMO's own refusal)
        else:
            at = length + at if at < 0 else at
        if at is None or at < min(need, length):
            where = "a random arrivalPos" if at is None else f"arrivalPos {pos}"
            raise RunError(
                f"route file {rf.path}: {vid!r} has {where} on {edge}, the exit of junction "
                f"{junction}: it would leave before its rear is out of the junction; give "
                f"an arrivalPos of at least {need:g} m there, or none"
            )


def _check_ids(path: Path, ids: list[tuple[str, str]]) -> None:
    """Refuse two vehicles, trips or flows of one id, or a vehicle or trip named like one a
    flow makes (``<flow id>.<k>``): SUMO stops the whole run when it meets the second."""
    seen: set[str] = set()
    flows = {i for tag, i in ids if tag == "flow"}
    for tag, i in ids:
        if i in seen:
            raise RunError(f"route file {path}: the id {i!r} is used twice; ids must be unique")
        seen.add(i)
        head, dot, k = i.rpartition(".")
        if tag != "flow" and dot and k.isdigit() and head in flows:
            raise RunError(
                f"route file {path}: the {tag} {i!r} has an id flow {head!r} gives its "
                f"vehicles ({head}.0, {head}.1, ...); ids must be unique, rename it"
            )


def loaded_size(ls, rf: RouteFile) -> tuple[float, float]:
    """The longest and the widest vehicle [m] of the file's types as SUMO has loaded them
    (SUMO's default car among them)."""
    types = {*rf.types, DEFAULT_TYPE}
    return (max(ls.vehicletype.getLength(t) for t in types),
            max(ls.vehicletype.getWidth(t) for t in types))  # fmt: skip


def note_moved_lines(
    rf: RouteFile, inters: Sequence[Intersection], size: tuple[float, float], kin: Kinematics
) -> list[str]:
    """Check that the lanes' lines, as placed, keep every waiting place clear of the
    file's longest, widest vehicle as SUMO has it, and the room rule every queue's end
    beyond an exit line (``size``: :func:`fleet_size` read it
    from the file before SUMO ran); then say, one line per junction, which lines moved
    back."""
    length, width = size
    lines = []
    for x in inters:
        swept = line_backs(x.routes, length, width, kin.stop_gap_m)
        if swept:
            raise RunError(
                f"junction {x.junction_id}: a {length:g} m x {width:g} m vehicle of "
                f"{rf.path.name} turning would sweep over where a vehicle waits at "
                f"{', '.join(sorted(swept))}: the lines there were placed for a smaller one"
            )
        deep = exit_sweeps(x.routes, length, width, kin.decel_mps2)
        if deep:
            lane, route, clear = deep[0]
            raise RunError(
                f"junction {x.junction_id}: a {length:g} m x {width:g} m vehicle of "
                f"{rf.path.name} turning on {route} would sweep over {lane} more than "
                f"{clear:.1f} m past its exit line, where the last of a queue may stand"
            )
        moved = {r.in_lane: r.line_back_m for r in x.routes if r.line_back_m > 0.0}
        if moved:
            shown = ", ".join(f"{lane} {m:g} m" for lane, m in sorted(moved.items()))
            lines.append(
                f"junction {x.junction_id}: lines moved back ({shown}) so that a {length:g} m "
                f"x {width:g} m vehicle of {rf.path.name} turning does not sweep over the "
                "place a vehicle waits"
            )
    return lines


def _on_foot(el: ET.Element) -> bool:
    """Whether a person's plan is walks only (a personTrip without modes is a walk)."""
    for child in el:
        if child.tag in ("walk", "param"):
            continue
        if child.tag == "personTrip" and not child.get("modes", "").strip():
            continue
        return False
    return True


def check_approaches(inter: Intersection, kin: Kinematics) -> None:
    """Refuse a junction a route file's vehicles could reach too fast to stop before its
    line: the world takes a vehicle over once it is in the region, or, on an approach
    shorter than the region (the region shrinks to fit), as it enters the lane; from
    there it must be able to stop short of the line at the lane's limit."""
    for r in sorted(inter.routes, key=lambda r: r.id):
        need = stop_room_m(r.arrival_mps, kin)
        if r.in_lane_m < need:
            raise RunError(
                f"junction {inter.junction_id}: its approach {r.in_lane} is {r.in_lane_m:.0f} m "
                f"long, and a vehicle at its {r.arrival_mps * 3.6:.0f} km/h needs {need:.0f} m "
                "to stop before the line; join the junctions that close into one "
                "(netconvert --junctions.join) or choose another"
            )


def check_handovers(inters: Sequence[Intersection], kin: Kinematics) -> list[str]:
    """Refuse a link from one chosen junction to the next too short for a vehicle let go
    by the first (its rear out, so up to a vehicle's length into the link) to stop
    before the second's line; say where the second's region is shorter than its
    region length (it takes each vehicle as the first lets go). Returns those lines."""
    exits = {r.out_lane: x.junction_id for x in inters for r in x.routes}
    notes: dict[str, str] = {}
    for x in inters:
        for r in sorted(x.routes, key=lambda r: r.id):
            before = exits.get(r.in_lane)
            if before is None or r.in_lane in notes:
                continue
            room = r.in_lane_m - MAX_LENGTH_M
            need = stop_room_m(r.arrival_mps, kin)
            if room < need:
                raise RunError(
                    f"junctions {before} and {x.junction_id}: the link {r.in_lane} between "
                    f"them is {r.in_lane_m:.0f} m long, and a vehicle out of {before} at "
                    f"{r.arrival_mps * 3.6:.0f} km/h needs {need + MAX_LENGTH_M:.0f} m to stop "
                    f"before {x.junction_id}'s line; join the two (netconvert "
                    "--junctions.join) or leave one out"
                )
            if room < x.comm_length_m:
                notes[r.in_lane] = (
                    f"the link {r.in_lane} from {before} to {x.junction_id} is "
                    f"{r.in_lane_m:.0f} m long: {x.junction_id}'s region there shrinks to "
                    f"{room:.0f} m (it takes each vehicle as {before} lets go)"
                )
    return list(notes.values())


def check_link_room(inters: Sequence[Intersection], longest_m: float, decel_mps2: float) -> None:
    """Refuse links between the chosen junctions that cannot hold a vehicle beyond the
    junction: the downstream-space rule (:meth:`DicaIca._check_room`) confirms a crossing
    onto a link only with room for the vehicle (``longest_m``), its gaps, one car more
    and its braking at the crossing's cap, so on a shorter link no vehicle is ever let
    on; and a link some cycle of links passes must keep that room with one more vehicle
    standing at its end (where it waits for the next junction), else one vehicle on each
    link of the cycle locks it for good (and the network gate, which lets in only what
    the links' capacity holds, lets no vehicle onto it). An exit road of any chosen
    junction as short is refused too: those bound for it would wait at the line for good."""
    between = link_length_m(inters) if len(inters) > 1 else {}  # checked below, cycles too
    for x in inters:
        short_out = [
            s
            for s in short_exits(x, longest_m, decel_mps2, ROOM_GAP_M, ROOM_SLACK_M)
            if s[0] not in between
        ]
        if short_out:
            e, m, want = short_out[0]
            raise RunError(
                f"junction {x.junction_id}: its exit {e} is {m:.1f} m long, and a "
                f"{longest_m:g} m vehicle let onto it needs {want:.1f} m of room beyond the "
                "junction to stop in: none could ever be let on, and those bound for it "
                "would wait for good; leave the junction to the net's own control"
            )
    if len(inters) < 2:
        return
    need = full_need_m(inters, longest_m, decel_mps2, ROOM_GAP_M, ROOM_SLACK_M)
    length = link_length_m(inters)
    cycled = on_cycles(link_arcs(inters, length))
    ends = {edge_of(r.out_lane): x.junction_id for x in inters for r in x.routes}
    starts = {edge_of(r.in_lane): x.junction_id for x in inters for r in x.routes}
    short = []
    for e in sorted(length):
        want = need[e] + (LINE_GAP_M + longest_m + QUEUE_GAP_M if e in cycled else 0.0)
        if length[e] < want:
            short.append((e, want))
    if not short:
        return
    e, want = short[0]
    cap = max(r.speed_cap_mps for x in inters for r in x.routes if edge_of(r.out_lane) == e)
    why = (
        f"room beyond {ends[e]} for a {longest_m:g} m vehicle let on at {cap * 3.6:.0f} km/h "
        "to stop in"
    )
    if e in cycled:
        why = f"a link on a cycle of links needs {want:.0f} m ({why}, and one more standing "
        why += "at its end)"
    else:
        why = f"it needs {want:.0f} m ({why})"
    more = ""
    if len(short) > 1:
        named = ", ".join(x for x, _ in short[1:4]) + (", ..." if len(short) > 4 else "")
        more = f"; {len(short) - 1} more links are too short ({named})"
    raise RunError(
        f"junctions {ends[e]} and {starts[e]}: the link {e} between them is {length[e]:.0f} m "
        f"long, and {why} to be served signal-free{more}; choose fewer junctions with "
        "--junctions, leaving the others to the net's own control"
    )


def check_types(ls, rf: RouteFile, kin: Kinematics) -> None:
    """Refuse, once SUMO has loaded the file (so its defaults per vehicle class are SUMO's
    own), a vehicle type that could not fly the ICA's plans."""
    known = set(ls.vehicletype.getIDList())
    for t in sorted(rf.types):
        if t not in known:
            raise RunError(f"route file {rf.path}: vehicle type {t!r} is not defined")
        vclass = ls.vehicletype.getVehicleClass(t)
        accel, decel = ls.vehicletype.getAccel(t), ls.vehicletype.getDecel(t)
        length = ls.vehicletype.getLength(t)
        why = None
        if vclass not in SERVED_CLASSES:
            why = f"is a {vclass}, which crosses outside the ICA's routes"
        elif accel < kin.accel_mps2 - 1e-9 or decel < kin.decel_mps2 - 1e-9:
            why = (
                f"accelerates at {accel:g} and brakes at {decel:g} m/s^2, less than the "
                f"{kin.accel_mps2:g} and {kin.decel_mps2:g} the ICA plans with"
            )
        elif length > MAX_LENGTH_M:
            why = f"is {length:g} m long, longer than the {MAX_LENGTH_M:g} m the routes allow"
        if why is not None:
            raise RunError(
                f"route file {rf.path}: vehicle type {t!r} {why}: it could not fly its plans"
            )


# stopping places SUMO can say the lane and extent of, by the domain that knows them
_PLACES = {"busStop": "busstop", "trainStop": "busstop", "parkingArea": "parkingarea",
           "chargingStation": "chargingstation"}  # fmt: skip
_UNPLACED = ("containerStop",)  # no libsumo domain says where these are
# a start road the file does not name (fromTaz, fromJunction, a route of another file)
ANY_ROAD = "*"
# departPos values that may put a vehicle anywhere on its first road
_ANYWHERE = ("random", "random_free", "free", "last")


def _pos(value: str | None, lane_m: float, default: float) -> float:
    """A stop's or departure's position on a lane (negative counts from its end)."""
    if value is None:
        return default
    p = float(value)
    return lane_m + p if p < 0 else p


def exit_room_m(cap_mps: float, longest_m: float, kin: Kinematics) -> float:
    """How far past a junction a vehicle may stand (a stop) on an exit lane: the world lets
    a vehicle go once its rear is out (its front up to ``longest_m`` in), and a follower
    planned at the crossing's cap behind it flies its plan until its own rear is out; so
    the one standing must have its rear beyond a released follower's front, its braking
    from the cap and SUMO's standstill gap."""
    return 2.0 * longest_m + stop_room_m(cap_mps, kin) + ROOM_GAP_M


def check_stops_and_starts(
    ls, rf: RouteFile, inters: Sequence[Intersection], longest_m: float, kin: Kinematics
) -> None:
    """Refuse, in one line, a stop (parking too) or a departure at speed where the
    junctions' plans would run into it. On an approach the world takes each vehicle
    over in the region and flies it by its plan: a vehicle there halting for its stop,
    or inserted there at speed (adopted unplanned, in the middle of others' plans), is
    run into; so no stop within the region, the longest vehicle and the room to stop
    before it, and no departure inside the region at any speed but 0. Past the line a
    follower flies its plan behind a leader let go at speed: no stop nearer than
    :func:`exit_room_m`. Departures on an exit road are held back by the insertion hold
    (sim_gateway/insertion.py) while a vehicle is about to come out onto it."""
    # lane: (its length, stops refused from, its region from, J), from the lane's start (a
    # line moved back, Route.line_back_m, stands short of its end)
    approach: dict[str, tuple[float, float, float, str]] = {}
    exits: dict[str, tuple[float, str]] = {}  # lane: (room needed, J)
    for x in inters:
        for r in x.routes:
            line = r.in_lane_m - min(x.comm_length_m, r.in_lane_m)
            start = line - longest_m - stop_room_m(r.arrival_mps, kin)
            old = approach.get(r.in_lane)
            if old is None or start < old[1]:  # the lane's own length: positions count on it
                approach[r.in_lane] = (r.in_lane_m + r.line_back_m, start, line, x.junction_id)
            room = exit_room_m(r.speed_cap_mps, longest_m, kin)
            if r.out_lane not in exits or room > exits[r.out_lane][0]:
                exits[r.out_lane] = (room, x.junction_id)
    lanes_of: dict[str, list[str]] = {}
    for lane in dict.fromkeys((*approach, *exits)):  # a link is both
        lanes_of.setdefault(edge_of(lane), []).append(lane)
    where = f"route file {rf.path}"
    for who, st, heads in rf.stops:
        place = next((k for k in (*_PLACES, *_UNPLACED) if st.get(k)), None)
        what = f"{place} {st[place]!r}" if place else "stop"
        at = f"at {what} " if place else ""
        if place in _UNPLACED:
            raise RunError(
                f"{where}: {who} stops at {what}, which cannot be placed on the net before "
                "the run; give its stop a lane and position instead"
            )
        if place is not None:
            dom = getattr(ls, _PLACES[place])
            try:
                lanes = [dom.getLaneID(st[place])]
                spans = [(dom.getStartPos(st[place]), dom.getEndPos(st[place]))]
            except Exception:  # not in the additional files SUMO loaded
                raise RunError(f"{where}: {who} stops at unknown {what}") from None
        else:
            lanes = [st["lane"]] if st.get("lane") else lanes_of.get(st.get("edge", ""), [])
            spans = []
            for lane in lanes:
                n = ls.lane.getLength(lane) if lane in approach or lane in exits else 0.0
                end = _pos(st.get("endPos"), n, n)
                spans.append((_pos(st.get("startPos"), n, end - 0.2), end))
        for lane, (a, b) in zip(lanes, spans, strict=True):
            if lane in approach and b > approach[lane][1]:
                n, start, _, j = approach[lane]
                raise RunError(
                    f"{where}: {who} stops {at}on {lane} {n - b:.0f} m before junction {j}'s "
                    f"line, where {j} flies its vehicles by plan (a stop must be at least "
                    f"{n - start:.0f} m before it); move the stop"
                )
            # one that starts on the exit road (standing: departSpeed 0 or not) does not
            # come out of the junction ahead of the vehicles let go there, and the
            # downstream-space rule sees it standing
            if lane in exits and a < exits[lane][0] and edge_of(lane) not in heads:
                room, j = exits[lane]
                raise RunError(
                    f"{where}: {who} stops {at}on {lane} {a:.0f} m past junction {j}, where "
                    f"the vehicles {j} lets go behind it come at speed (a stop must be at "
                    f"least {room:.0f} m past it); move the stop"
                )
    for who, dep, heads in rf.starts:
        speed = dep.get("departSpeed", "0").strip()
        if _is_zero(speed):
            continue  # a standing start: the world plans it from where it stands
        pos = dep.get("departPos", "base").strip()
        lanes = approach if ANY_ROAD in heads else {
            ln for e in heads for ln in lanes_of.get(e, []) if ln in approach}  # fmt: skip
        for lane in sorted(lanes):
            n, _, line, j = approach[lane]
            if pos in _ANYWHERE:
                inside = "may start"
            elif _is_number(pos) and _pos(pos, n, 0.0) > line:
                inside = "starts"
            else:
                continue
            of = f" (from its type {dep['speedOf']!r})" if "speedOf" in dep else ""
            unnamed = (" (its first road is not in the file: a TAZ, a junction or a route "
                       "of another file, so any road)") if ANY_ROAD in heads else ""  # fmt: skip
            raise RunError(
                f"{where}: {who} {inside} inside junction {j}'s region on {lane}{unnamed} "
                f"(departPos {pos!r}) at departSpeed {speed!r}{of}, where {j} plans its vehicles "
                f"before they are in it; start it before the last {n - line:.0f} m of the "
                "lane or at departSpeed 0"
            )


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _is_zero(s: str) -> bool:
    return _is_number(s) and float(s) == 0.0
