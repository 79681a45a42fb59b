"""Read a junction of any SUMO ``.net.xml`` into the ICA's :class:`Intersection`.

Kept outside ``ica.core`` because it does file I/O and depends on sumolib; the
core only ever sees the resulting polylines. Nothing here is specific to the
dissertation's layouts: the routes are whatever connections the network has.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import sumolib

from dica.ica.core.config import IcaConfig
from dica.ica.core.crosswalk import Crosswalk
from dica.ica.core.gridlock import exit_caps
from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Kinematics, SpeedCaps, Turn
from dica.ica.core.occupancy import Rects
from dica.ica.core.route import Route, Via, build_route, classify_turn
from dica.ica.core.waiting import entry_sweeps, exit_sweeps, line_backs

_DIR_TO_TURN = {"l": Turn.LEFT, "L": Turn.LEFT, "r": Turn.RIGHT, "R": Turn.RIGHT, "s": Turn.THROUGH}
_VEHICLE_CLASS = "passenger"  # the random demand's
# classes that drive on the road's lanes through the junction as a car does: the routes
# cover every lane one of them may take (a bus lane too), so that none crosses unplanned
SERVED_CLASSES = frozenset((
    "passenger", "private", "taxi", "bus", "coach", "delivery", "truck", "trailer",
    "emergency", "authority", "army", "vip", "evehicle", "hov", "motorcycle", "moped",
    "custom1", "custom2",
))  # fmt: skip
_MAX_VIA_CHAIN = 16  # internal lanes per connection; SUMO uses at most a handful
_MARGIN_M = 5.0  # slack beyond the longest vehicle at both ends of a route
MAX_VEHICLE_LENGTH_M = 12.0  # routes reach this far beyond the region and the exit line
DEFAULT_CAPS = SpeedCaps()  # frozen, so one shared default is safe
STOP_SLACK_M = 1.0  # [m] on top of the braking distance: a step's travel, and some
STEP_S = IcaConfig().step_s  # [s] a vehicle is first seen up to a step's travel in


def stop_room_m(v_mps: float, kin: Kinematics = Kinematics()) -> float:
    """The room a vehicle at ``v_mps`` needs to stop short of a line, braking as hard as
    the ICA plans a vehicle may (``kin.decel_mps2``): what a region or a link between two
    junctions must give a vehicle that has no plan yet."""
    return v_mps * v_mps / (2.0 * kin.decel_mps2) + kin.stop_gap_m + STOP_SLACK_M


def region_m(fastest_mps: float, comm_length_m: float, kin: Kinematics = Kinematics()) -> float:
    """A junction's communication region: ``comm_length_m`` (the dissertation's 50 m), or
    longer where vehicles come in faster than they could stop within it once first seen
    (on a 50 m region, faster than about 74 km/h): the region on every approach is as
    long as what its fastest one needs, in whole metres."""
    need = stop_room_m(fastest_mps, kin) + fastest_mps * STEP_S
    return float(max(comm_length_m, math.ceil(need)))


class NetworkError(Exception):
    """The network file or junction cannot give routes; the message is one line."""


def load_intersection(
    net_path: str | Path,
    junction_id: str,
    *,
    comm_length_m: float = 50.0,
    caps: SpeedCaps = DEFAULT_CAPS,
    max_vehicle_length_m: float = MAX_VEHICLE_LENGTH_M,
    fleet: tuple[float, float] | None = None,
    kin: Kinematics = Kinematics(),
) -> Intersection:
    """Routes of ``junction_id``: one per (incoming lane, outgoing lane) connection.

    Each route joins the incoming lane, the chain of internal lanes SUMO drives
    through (on priority junctions a left turn may use two) and the outgoing
    lane. The polyline reaches ``comm_length_m`` plus a vehicle length upstream
    of the entry line so any accepted vehicle can be placed on it.

    ``fleet`` is the longest and the widest vehicle the run may bring (None: cars).
    Where one that size turning from another lane would sweep over the place a vehicle
    waits at a lane's end, that lane's line moves back (:mod:`ica.core.waiting`).
    """
    net = _read(Path(net_path))
    if not net.hasNode(junction_id):
        known = sorted(n.getID() for n in net.getNodes())
        shown = ", ".join(known[:8]) + (", ..." if len(known) > 8 else "")
        raise NetworkError(
            f"junction {junction_id!r} not in {net_path} (known junctions: {shown or 'none'})"
        )
    node = net.getNode(junction_id)
    incoming = [
        lane
        for edge in node.getIncoming()
        if not edge.isSpecial()
        for lane in edge.getLanes()
        if _serves(lane)
    ]
    # vehicles come in at the net's limit (a route file's are driven by SUMO until then)
    comm_length_m = region_m(max((ln.getSpeed() for ln in incoming), default=0.0), comm_length_m)
    approach_m = comm_length_m + max_vehicle_length_m + _MARGIN_M
    tail_m = max_vehicle_length_m + _MARGIN_M

    routes: list[Route] = []
    for edge in node.getIncoming():
        if edge.isSpecial():  # internal edges list the junction as both ends
            continue
        for lane in edge.getLanes():
            if not _serves(lane):
                continue
            for conn in lane.getOutgoing():
                if conn.getDirection() == "t" or not _serves(conn):
                    continue
                cars = all(x.allows(_VEHICLE_CLASS) for x in (lane, conn, conn.getToLane()))
                routes.append(_route(net, conn, caps, approach_m, tail_m, cars))

    if not routes:
        raise NetworkError(
            f"junction {junction_id!r} in {net_path} has no crossing routes for road vehicles"
        )
    routes.sort(key=lambda r: r.id)
    region = _region(node, routes)
    backs = line_backs(tuple(routes), *fleet, kin.stop_gap_m) if fleet else {}
    if backs:  # rebuilt to reach as far upstream of the moved line as of the lane's end
        conns = {
            f"{c.getFromLane().getID()}>{c.getToLane().getID()}": c
            for e in node.getIncoming()
            for ln in e.getLanes()
            for c in ln.getOutgoing()
        }
        routes = [
            r
            if r.in_lane not in backs
            else _route(
                net, conns[r.id], caps, approach_m + backs[r.in_lane], tail_m, r.cars
            ).moved_back(backs[r.in_lane])
            for r in routes
        ]
    if fleet:  # an exit too short to stop on from a route's cap: the crossing slower
        from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M

        caps_in = exit_caps(routes, fleet[0], kin.decel_mps2, ROOM_GAP_M, ROOM_SLACK_M,
                            kin.min_cross_mps)  # fmt: skip
        routes = [replace(r, speed_cap_mps=caps_in[r.id]) if r.id in caps_in else r for r in routes]
    inter = Intersection(
        junction_id=junction_id,
        routes=tuple(routes),
        region=region,
        comm_length_m=comm_length_m,
        crosswalks=_crosswalks(net, junction_id),
    )
    # worked out now, not in the first such vehicle's request
    if fleet and inter.sweeping(*fleet, kin.stop_gap_m, kin.decel_mps2):
        raise NetworkError(_still_swept(inter, fleet, kin))
    return inter


def _still_swept(inter: Intersection, fleet: tuple[float, float], kin: Kinematics) -> str:
    """Why a junction whose lines were placed for ``fleet`` still has a route whose
    vehicles would sweep over a waiting or standing one (its vehicles would be refused
    for ever): one line naming the lanes."""
    size = f"a {fleet[0]:g} m x {fleet[1]:g} m vehicle"
    entry = entry_sweeps(inter.routes, *fleet, kin.stop_gap_m)
    if entry:
        lane, route, _ = entry[0]
        back = max(r.line_back_m for r in inter.routes if r.in_lane == lane)
        return (
            f"junction {inter.junction_id!r}: {size} on {route} sweeps over where one waits "
            f"on {lane}, however far back its line moves ({back:g} m tried): the two lanes "
            "run into each other before the junction"
        )
    lane, route, clear = exit_sweeps(inter.routes, *fleet, kin.decel_mps2)[0]
    return (
        f"junction {inter.junction_id!r}: {size} turning on {route} would sweep over {lane} "
        f"more than {clear:.1f} m past its exit line, where the last of a queue may stand"
    )


def is_crossing_of(edge_id: str, junction_id: str) -> bool:
    """Whether ``edge_id`` names one of ``junction_id``'s crossings (``:<junction>_c<k>``;
    not junction ``A_1``'s ``:A_1_c0`` for junction ``A``)."""
    prefix = f":{junction_id}_c"
    return edge_id.startswith(prefix) and edge_id[len(prefix) :].isdigit()


CORNER_REACH_M = 1.0  # [m] a walking area this close to a crossing's end is at that end


def _is_walking_area_of(edge_id: str, junction_id: str) -> bool:
    prefix = f":{junction_id}_w"
    return edge_id.startswith(prefix) and edge_id[len(prefix) :].isdigit()


def _distance(polygon: np.ndarray, point: np.ndarray) -> float:
    """From ``point`` to the nearest vertex or edge of ``polygon``'s outline."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    d = b - a
    t = np.clip(((point - a) * d).sum(1) / np.maximum((d * d).sum(1), 1e-12), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * d - point, axis=1)))


def _crosswalks(net: sumolib.net.Net, junction_id: str) -> tuple[Crosswalk, ...]:
    """The junction's pedestrian crossings: SUMO's crossing edges ``:<junction>_c<k>``,
    each one lane with a centre line and a width."""
    out = []
    areas = [
        _xy(e.getLanes()[0].getShape())
        for e in net.getEdges(withInternal=True)
        if e.getFunction() == "walkingarea" and _is_walking_area_of(e.getID(), junction_id)
    ]
    for e in net.getEdges(withInternal=True):
        if e.getFunction() != "crossing" or not is_crossing_of(e.getID(), junction_id):
            continue
        lane = e.getLanes()[0]
        crossed = tuple(x.getID() for x in e.getCrossingEdges())
        shape = _xy(lane.getShape())
        ends = (shape[0], shape[-1]) if len(shape) else ()
        corners = tuple(  # the walking areas its ends open onto
            a for a in areas
            if len(a) >= 3 and any(_distance(a, p) <= CORNER_REACH_M for p in ends)
        )  # fmt: skip
        try:
            out.append(Crosswalk(e.getID(), shape, float(lane.getWidth()), crossed, corners))
        except ValueError as exc:
            raise NetworkError(f"bad geometry for crossing {e.getID()}: {exc}") from exc
    return tuple(sorted(out, key=lambda c: c.id))


def crossing_junctions(net_path: str | Path) -> tuple[str, ...]:
    """Every junction of the net where two roads or more come in and road vehicles
    cross (a junction with one road in has nothing to keep apart), by id."""
    net = _read(Path(net_path))
    out = []
    for node in net.getNodes():
        if node.getType() in ("dead_end", "internal", "rail_crossing", "rail_signal"):
            continue
        roads = [
            e for e in node.getIncoming() if not e.isSpecial() and any(map(_serves, e.getLanes()))
        ]
        if len(roads) >= 2:
            out.append(node.getID())
    return tuple(sorted(out))


def read_net(path: str | Path) -> sumolib.net.Net:
    """The whole net as sumolib reads it (read once while the file is unchanged)."""
    return _read(Path(path))


def _read(path: Path) -> sumolib.net.Net:
    """The net as sumolib reads it, read once while the file stays as it is: every
    junction of a large net is loaded from the same file (``--junctions all``), and
    reading the whole net for each made that quadratic in the net's size."""
    if not path.is_file():
        raise NetworkError(f"network file not found: {path}")
    st = path.stat()
    return _read_once(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=2)
def _read_once(path: str, _mtime_ns: int, _size: int) -> sumolib.net.Net:
    try:
        return sumolib.net.readNet(path, withInternal=True)
    except Exception as exc:  # sumolib raises whatever its XML parser raises
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise NetworkError(f"cannot read SUMO network {path}: {detail}") from exc


def _via_chain(
    net: sumolib.net.Net, conn: sumolib.net.connection.Connection
) -> list[sumolib.net.lane.Lane]:
    """Internal lanes from the incoming to the outgoing lane, in driving order.

    An internal lane's own connection to the target lane may name a further
    internal lane (the second half of a left turn waiting inside the junction).
    """
    target = conn.getToLane()
    chain: list[sumolib.net.lane.Lane] = []
    via_id = conn.getViaLaneID()
    while via_id:
        if len(chain) >= _MAX_VIA_CHAIN:
            raise NetworkError(f"via chain of {_conn_name(conn)} does not end")
        try:
            via = net.getLane(via_id)
        except (KeyError, IndexError, ValueError) as exc:
            raise NetworkError(f"{_conn_name(conn)} uses unknown internal lane {via_id}") from exc
        chain.append(via)
        nxt = [c for c in via.getOutgoing() if c.getToLane() is target]
        via_id = nxt[0].getViaLaneID() if nxt else ""
    return chain


def _route(
    net: sumolib.net.Net,
    conn: sumolib.net.connection.Connection,
    caps: SpeedCaps,
    approach_m: float,
    tail_m: float,
    cars: bool,
) -> Route:
    in_lane, out_lane = conn.getFromLane(), conn.getToLane()
    vias = _via_chain(net, conn)
    in_shape = _xy(in_lane.getShape())
    via_shapes = [Via(_xy(v.getShape()), float(v.getLength())) for v in vias]
    out_shape = _xy(out_lane.getShape())
    turn = _DIR_TO_TURN.get(conn.getDirection())
    if turn is None:
        # Headings just before the entry and just after the exit line.
        turn = classify_turn(
            _distinct(np.vstack([in_shape[-2:], *(v.shape for v in via_shapes), out_shape[:2]]))
        )
    route_id = f"{in_lane.getID()}>{out_lane.getID()}"
    try:
        route = build_route(
            route_id=route_id,
            in_lane=in_lane.getID(),
            out_lane=out_lane.getID(),
            via_lanes=tuple(v.getID() for v in vias),
            in_shape=in_shape,
            via_shapes=via_shapes,
            out_shape=out_shape,
            turn=turn,
            caps=caps,
            approach_m=approach_m,
            tail_m=tail_m,
            lane_limits_mps=(in_lane.getSpeed(), out_lane.getSpeed()),
        )
    except ValueError as exc:
        raise NetworkError(f"bad geometry for route {route_id}: {exc}") from exc
    via_mps = min((v.getSpeed() for v in vias), default=math.inf)
    return replace(route, cars=cars, via_mps=via_mps)


def _serves(lane_or_connection) -> bool:
    return any(lane_or_connection.allows(c) for c in SERVED_CLASSES)


def _region(node: sumolib.net.node.Node, routes: list[Route]) -> np.ndarray:
    """The junction polygon; the hull of the routes' junction parts if SUMO gave none."""
    shape = node.getShape() or []
    if len(shape) >= 3:
        return _xy(shape)
    import shapely

    pts = np.vstack([r.points(np.linspace(0.0, r.cross_length_m, 16)) for r in routes])
    hull = shapely.MultiPoint(pts).convex_hull.buffer(0.5)
    return np.asarray(hull.exterior.coords, dtype=float)[:-1]


def _xy(shape: list) -> np.ndarray:
    return np.asarray(shape, dtype=float).reshape(-1, 2)


def _distinct(xy: np.ndarray) -> np.ndarray:
    keep = np.ones(len(xy), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-6
    return xy[keep]


def _conn_name(conn: sumolib.net.connection.Connection) -> str:
    return f"connection {conn.getFromLane().getID()}->{conn.getToLane().getID()}"


def lane_shapes(net_path: str | Path, lanes: list[str]) -> list[np.ndarray]:
    """The shapes (K, 2) of ``lanes`` as the net draws them (lanes it lacks are left out)."""
    net = _read(Path(net_path))
    out = []
    for lane in lanes:
        try:
            out.append(_xy(net.getLane(lane).getShape()))
        except (KeyError, IndexError, ValueError):
            continue
    return out


def sidewalks(net_path: str | Path, junction_id: str) -> tuple[tuple[str, Rects], ...]:
    """The lanes only people may use on the roads into and out of ``junction_id``, each
    as rectangles (one per segment of its shape, as wide as the lane): where people walk
    that no crossing's reservation covers."""
    net = _read(Path(net_path))
    node = net.getNode(junction_id)
    out = []
    for edge in [*node.getIncoming(), *node.getOutgoing()]:
        if edge.isSpecial():  # its crossings and walking areas: the reservations cover them
            continue
        for lane in edge.getLanes():
            if not lane.allows("pedestrian") or lane.allows(_VEHICLE_CLASS):
                continue
            xy = _distinct(_xy(lane.getShape()))
            if len(xy) < 2:
                continue
            d = np.diff(xy, axis=0)
            n = np.linalg.norm(d, axis=1)
            keep = n > 1e-6
            heading = d[keep] / n[keep, None]
            centre = (xy[:-1][keep] + xy[1:][keep]) / 2.0
            half = n[keep] / 2.0
            # one Rects per segment: their half lengths differ
            for c, h, m in zip(centre, heading, half, strict=True):
                out.append((lane.getID(), Rects(c[None], h[None], float(m), lane.getWidth() / 2)))
    return tuple(out)
