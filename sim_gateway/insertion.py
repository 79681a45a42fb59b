"""Holding a route file's insertions back from an exit road a vehicle is about to leave
a junction onto.

SUMO inserts a file's vehicle at the start of its first road once the road is
free there, without regard to a vehicle still inside the junction on its way
onto that road; a vehicle flying its plan does not brake for it, and runs into
it (on a 3x3 grid with every junction signal-free under randomTrips demand,
four such collisions in 900 s). So while a junction's confirmed vehicle is
inside the junction or about to enter it, the vehicles waiting to be inserted
on its exit road wait: before SUMO's step they are taken out of
its insertion queue, and one SUMO has just inserted there (its first try is not
seen coming) is taken back out at once, before anything moves; each is put back
as the file has it (type, route, how it departs and arrives, colour) once no
vehicle is about to come out onto its road. One the file gives more than a
route (stops, parameters) is not held, and is counted.

In a network of junctions whose links form a cycle, a vehicle that would start
on a link also waits while the network gate has no room for it
(:mod:`sim_gateway.network_gate`): it would enter the network as surely as one
let in by a junction.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from dica.ica.core.gridlock import QUEUE_GAP_M
from dica.sim_gateway.junction import Junction, route_edges
from dica.sim_gateway.network_gate import NetworkGate
from dica.sim_gateway.route_file import RouteFile

SOON_S = 2.0  # [s] a confirmed vehicle this close to its entry line is about to enter


GUARD_M = 30.0  # [m] a vehicle inserted this close to its road's start may be run into


@dataclass(slots=True)
class Held:
    """A vehicle taken out of SUMO: what it takes to put it back as the file has it."""

    vid: str
    edges: list[str]
    vtype: str
    attrs: dict[str, str]
    cost_m: float  # its length and standstill gap: what it takes of the network's room


class InsertionHold:
    """The vehicles held out of SUMO while their first road is threatened, and a tally."""

    def __init__(self, ls, rf: RouteFile, gate: NetworkGate | None = None) -> None:
        self.ls = ls
        self.rf = rf
        self.gate = gate if gate is not None and gate.closes else None
        self.held: list[Held] = []
        self.roads: set[str] = set()  # threatened this step
        self.first_road: dict[str, tuple[str, ...]] = {}  # a pending vehicle's route, read once
        self.holds = 0  # vehicles taken out of SUMO's insertion, once each time
        # each held vehicle's departure as the file scheduled it (put back, SUMO counts
        # from then): its trip counts from here (sim_gateway/network_trips.py)
        self.scheduled: dict[str, float] = {}
        self.unheld = 0  # insertions that could not be held (more than a route)
        self._routes = 0

    @staticmethod
    def threatened(junctions: Iterable[Junction]) -> set[str]:
        """Exit roads a confirmed vehicle is inside a junction on its way onto, or about
        to enter a junction for."""
        out: set[str] = set()
        for j in junctions:
            for c in j.active:
                if c.plan_s is None or c.exited or c.sumo not in j.present:
                    continue
                if c.entered or c.s_m > -(SOON_S * c.speed_mps + 5.0):
                    out.add(route_edges(c.route)[1])
        return out

    def before_step(
        self, junctions: Iterable[Junction], in_flight: Mapping[str, float] | None = None
    ) -> None:
        """Put back who may be inserted now; take out who waits for a threatened road or
        for room in the network (less ``in_flight``: per room, what vehicles whose ICA's
        answer may be travelling could be taking of it)."""
        self.roads = roads = self.threatened(junctions)
        gate = self.gate
        # of the gate's rooms, by those let go this step and those perhaps let in now
        taken: dict[str, float] = dict(in_flight or {})
        keep = []
        for h in self.held:
            if h.edges[0] in roads:
                keep.append(h)
            elif gate is not None and h.edges[0] in gate.links:
                if self._fits(gate.rooms(h.edges, 0), h.cost_m, taken):
                    self._put_back(h)
                else:
                    keep.append(h)
            else:
                self._put_back(h)
        self.held = keep
        if not roads and gate is None:
            return
        v, first = self.ls.vehicle, self.first_road
        pending = self.ls.simulation.getPendingVehicles()
        for p in pending:
            route = first.get(p)
            if route is None:
                route = first[p] = v.getRoute(p)
            road = route[0]
            if road in roads:
                self._take(p)
            elif gate is not None and road in gate.links:
                cost = v.getLength(p) + QUEUE_GAP_M
                if not self._fits(gate.rooms(route, 0), cost, taken):
                    self._take(p)
        if len(first) > 2 * len(pending) + 1024:  # forget the ones inserted since
            live = set(pending)
            self.first_road = {p: r for p, r in first.items() if p in live}

    def _fits(self, rooms: tuple[str, ...], cost_m: float, taken: dict[str, float]) -> bool:
        """Whether a vehicle that would hold ``rooms`` fits the gate after ``taken``; if
        so, it takes its share of them."""
        assert self.gate is not None
        if cost_m > self.gate.room_on(rooms, taken):
            return False
        for r in rooms:
            taken[r] = taken.get(r, 0.0) + cost_m
        return True

    def after_step(
        self, departed: Iterable[str], in_flight: Mapping[str, float] | None = None
    ) -> set[str]:
        """Take back who SUMO has just inserted at the start of a threatened road (it does
        not look for vehicles inside the junction), or onto a link of a network with no
        room left for it (one due this very step was never pending); return them."""
        taken: set[str] = set()
        gate = self.gate
        if not self.roads and gate is None:
            return taken
        room: dict[str, float] = dict(in_flight or {})
        v = self.ls.vehicle
        for vid in departed:
            road = v.getRoadID(vid)
            take = road in self.roads and v.getLanePosition(vid) < GUARD_M
            if not take and gate is not None and road in gate.links:
                cost = v.getLength(vid) + QUEUE_GAP_M
                take = not self._fits(gate.rooms(v.getRoute(vid), 0), cost, room)
            if take and self._take(vid):
                taken.add(vid)
        return taken

    def _take(self, vid: str) -> bool:
        attrs = self.rf.departs.get(_source(vid, self.rf))
        if attrs is None:
            self.unheld += 1
            return False
        v = self.ls.vehicle
        if vid not in self.scheduled:
            self.scheduled[vid] = self.ls.simulation.getTime() - v.getDepartDelay(vid)
        cost = v.getLength(vid) + QUEUE_GAP_M
        self.held.append(Held(vid, list(v.getRoute(vid)), v.getTypeID(vid), attrs, cost))
        v.remove(vid)
        self.holds += 1
        return True

    def _put_back(self, h: Held) -> None:
        self._routes += 1
        rid = f"dica_held_{self._routes}"
        self.ls.route.add(rid, h.edges)
        kw = {k: x for k, x in h.attrs.items() if k != "color"}
        self.ls.vehicle.add(h.vid, rid, typeID=h.vtype, depart="now", **kw)
        color = _color(h.attrs.get("color", ""))
        if color is not None:
            self.ls.vehicle.setColor(h.vid, color)


def _source(vid: str, rf: RouteFile) -> str:
    """The file's element a vehicle comes from: its own id, or its flow's (``flow.N``)."""
    if vid in rf.departs:
        return vid
    return vid.rsplit(".", 1)[0]


_NAMED = {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255),
          "yellow": (255, 255, 0), "cyan": (0, 255, 255), "magenta": (255, 0, 255),
          "white": (255, 255, 255), "black": (0, 0, 0), "grey": (128, 128, 128),
          "gray": (128, 128, 128), "orange": (255, 128, 0)}  # fmt: skip


def _color(text: str) -> tuple[int, ...] | None:
    """A SUMO colour attribute (a name, or ``r,g,b[,a]`` in 0-255 or 0-1) as TraCI wants
    it; None if there is none (or one SUMO's random colours stand for)."""
    text = text.strip()
    if text.lower() in _NAMED:
        return (*_NAMED[text.lower()], 255)
    try:
        parts = [float(x) for x in text.replace(" ", ",").split(",") if x]
    except ValueError:
        return None
    if len(parts) not in (3, 4):
        return None
    if max(parts) <= 1.0:
        parts = [x * 255.0 for x in parts]
    if len(parts) == 3:
        parts.append(255.0)
    return tuple(math.floor(x + 0.5) for x in parts)
