"""The network gate: how much queue the links between signal-free junctions hold, and
how much more may come in.

A network of junctions whose links form cycles can stand still for ever once a
cycle of links is full (every vehicle at a link's head waiting for room on the
next). The gate bounds what the links hold, counting every vehicle on a link and
every one confirmed onto a link from outside at its length plus
:data:`~ica.core.gridlock.QUEUE_GAP_M`, by one of two rules:

* ``route`` (the default): a few links are chosen that every cycle of links
  passes through (:func:`~ica.core.gridlock.feedback_links`); each vehicle holds
  room on every one of them on its route ahead, from the moment it is let in
  until it leaves that link, and none is ever promised more than its capacity
  (:func:`~ica.core.gridlock.link_capacity_m`): so none of them fills, and a
  cycle of full links cannot form;
* ``cycle``: the whole network holds at most its smallest cycle's capacity
  (:func:`~ica.core.gridlock.cycle_capacity_m`), whatever the routes: a cycle
  of full links would hold more.

Either way the ICAs let a vehicle in from outside only while it fits
(``Observation.network_room_m``, the least room on what it would hold), and a
route file's vehicles that would start on a link wait out of SUMO until they
fit (:class:`~sim_gateway.insertion.InsertionHold`). Moving from link to link
along its route, a vehicle takes no room it did not hold already; one sent round
to its destination from a lane that does not go its way takes the rooms of its
new way it did not hold, and is let across only while they have room too
(:meth:`NetworkGate.takes`). So the bound holds for the whole run
(``docs/architecture.md``, "Gridlock").
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M
from dica.ica.core.gridlock import (
    QUEUE_GAP_M,
    cycle_capacity_m,
    edge_of,
    feedback_links,
    full_need_m,
    internal_roads,
    link_arcs,
    link_capacity_m,
)
from dica.ica.core.intersection import Intersection
from dica.sim_gateway.junction import Car, Junction
from dica.sim_gateway.runconfig import GATE_RULES

WHOLE = "*"  # the cycle rule's one room: the whole network's


class NetworkGate:
    """What the links hold this step, and the room left on what a vehicle would hold."""

    def __init__(
        self,
        inters: Sequence[Intersection],
        max_length_m: float,
        decel_mps2: float,
        rule: str = "route",
    ) -> None:
        if rule not in GATE_RULES:
            raise ValueError(f"network gate rule {rule!r}: use one of {', '.join(GATE_RULES)}")
        self.rule = rule
        self.links = internal_roads(inters)
        need = full_need_m(inters, max_length_m, decel_mps2, ROOM_GAP_M, ROOM_SLACK_M)
        self.link_capacity_m = link_capacity_m(inters, need)
        self.capacity_m = cycle_capacity_m(inters, self.link_capacity_m)
        # the links every cycle passes through: the ones the route rule keeps from filling
        self.guarded = feedback_links(link_arcs(inters, self.links), self.link_capacity_m)
        # the rooms a vehicle may hold: each guarded link's (route), or the network's (cycle)
        self.room_cap_m: dict[str, float] = (
            {e: self.link_capacity_m[e] for e in self.guarded}
            if rule == "route"
            else {WHOLE: self.capacity_m}
        )
        self.held_m: dict[str, float] = {}  # per room, what the vehicles hold of it now
        self.used_m = 0.0  # the queue length inside the network (every vehicle once)
        self.peak_m = 0.0  # the most queue the network held at once
        self.peak_share = 0.0  # the most any room was held, as a share of its capacity
        # SUMO ids inside the network this step, each with the road it was counted from
        self.counted: dict[str, str] = {}
        # crossings sent round whose new rooms are counted this step (their vin)
        self.counted_more: set[str] = set()
        self._takes: dict[str, tuple[str, ...]] = {}  # per crossing: the rooms it takes
        self._length: dict[str, float] = {}
        self._enters: dict[tuple[str, str], bool] = {}  # per (in, out) lane: it enters
        self._runs: dict[str, dict[str, tuple[str, ...]]] = {}  # vehicle -> road -> rooms

    @property
    def closes(self) -> bool:
        """Whether the links form a cycle at all (else the gate never closes)."""
        return math.isfinite(self.capacity_m)

    def rooms(self, edges: Sequence[str], start: int) -> tuple[str, ...]:
        """The rooms a vehicle holds whose route is ``edges``, from ``edges[start]`` on:
        every guarded link of the run of links starting there (route), or the network's
        (cycle); none if it does not start on a link."""
        links = self.links
        if start >= len(edges) or edges[start] not in links:
            return ()
        if self.rule == "cycle":
            return (WHOLE,)
        run = []
        for e in edges[start:]:
            if e not in links:
                break
            if e in self.guarded:
                run.append(e)
        return tuple(dict.fromkeys(run))

    def room_on(self, rooms: Iterable[str], extra: Mapping[str, float] | None = None) -> float:
        """The least room left on ``rooms`` (less ``extra`` taken of each; inf: none)."""
        cap, held = self.room_cap_m, self.held_m
        least = math.inf
        for r in rooms:
            left = cap[r] - held.get(r, 0.0) - (extra.get(r, 0.0) if extra else 0.0)
            least = min(least, left)
        return least

    def rooms_of(self, ls, vid: str, road: str) -> tuple[str, ...]:
        """The rooms vehicle ``vid`` holds from ``road`` on (the next time its route
        comes to it); read from SUMO once per vehicle and road."""
        runs = self._runs.get(vid)
        if runs is None:
            runs = self._runs[vid] = {}
        run = runs.get(road)
        if run is None:
            route = ls.vehicle.getRoute(vid)
            i = max(0, ls.vehicle.getRouteIndex(vid))
            k = next((n for n in range(i, len(route)) if route[n] == road), None)
            if k is None:  # not on its route (never for a crossing it was confirmed for)
                run = self.rooms((road,), 0) if self.rule == "cycle" else tuple(self.guarded)
            else:
                run = self.rooms(route, k)
            runs[road] = run
        return run

    def room_for(self, ls, c: Car) -> float:
        """The room left for ``c``'s crossing: the least on the rooms it would take."""
        return self.room_on(self.takes(ls, c))

    def takes(self, ls, c: Car) -> tuple[str, ...]:
        """The rooms ``c``'s crossing adds to what it holds: entering from outside, every
        room of its run from the road it crosses onto; crossing from a link onto one off
        its route (a vehicle in a lane that does not go its way, sent round to its
        destination, ``Car.reroute_to``), the rooms of its new way it did not hold. A
        vehicle sent round holds the rooms of the way it is then sent on
        (``Car.reroute_way``), whether it came from outside or from a link. One moving
        from link to link along its route takes nothing new. Worked out once per
        crossing."""
        got = self._takes.get(c.vin)
        if got is not None:
            return got
        out = edge_of(c.route.out_lane)
        way = self._way_round(ls, c, out)
        if way is not None:  # its run from ``out`` on is the way it is sent
            self._runs.setdefault(c.sumo, {})[out] = self.rooms(way, 0)
        if self.entering(c):
            got = self.rooms_of(ls, c.sumo, out)
        elif way is not None:
            new = self.rooms_of(ls, c.sumo, out)
            # the run it holds from here on, and the one it will hold once sent round
            old = self.rooms_of(ls, c.sumo, edge_of(c.route.in_lane))
            got = tuple(r for r in new if r not in old)
        else:
            got = ()
        self._takes[c.vin] = got
        return got

    @staticmethod
    def _way_round(ls, c: Car, out: str) -> tuple[str, ...] | None:
        """The way from ``out`` to the destination of a vehicle sent round onto a link
        (None for any other crossing), chosen once and kept on the car, which is sent
        on exactly that way once it is out (``Actuator``): a way SUMO found later
        might pass a guarded link it was never given room on."""
        if c.reroute_to is None:
            return None
        if c.reroute_way is None:
            way = tuple(ls.simulation.findRoute(out, c.reroute_to).edges)
            if not way or way[0] != out:  # no way on from here: SUMO's own, as before
                return (out,)
            c.reroute_way = way
        return c.reroute_way

    def holds(self, c: Car) -> bool:
        """Whether what ``c``'s crossing takes is counted this step: entering, once it
        is counted at all; sent round from a link, once its new rooms are counted on
        top of its old run, or it is counted from the road it crosses onto (whose run
        is its new way)."""
        if self.entering(c):
            return c.sumo in self.counted
        return c.vin in self.counted_more or self.counted.get(c.sumo) == edge_of(c.route.out_lane)

    def entering(self, c: Car) -> bool:
        """Whether ``c``'s crossing takes it into the network from outside."""
        r = c.route
        key = (r.in_lane, r.out_lane)
        enters = self._enters.get(key)
        if enters is None:
            links = self.links
            enters = edge_of(r.out_lane) in links and edge_of(r.in_lane) not in links
            self._enters[key] = enters
        return enters

    def measure(self, ls, junctions: Iterable[Junction]) -> None:
        """Count what the network holds: the vehicles on its links, and those confirmed
        onto one that are not on it yet."""
        if not self.closes:
            return
        self.counted = {}
        self.counted_more = set()
        self.held_m = {}
        self.used_m = 0.0
        for e in self.links:
            for x in ls.edge.getLastStepVehicleIDs(e):
                self._count(ls, x, e)
        for j in junctions:
            self.count_confirmed(ls, j)
        self._peaks()  # once more: the vehicles on the links alone

    def count_confirmed(self, ls, j: Junction) -> None:
        """Count ``j``'s vehicles confirmed onto a link and not counted yet (after its
        ICA's answers this step, before the next junction's ask)."""
        if not self.closes:
            return
        more = False
        for c in j.active:
            if c.plan_s is None or c.exited or c.sumo not in j.present:
                continue
            road = edge_of(c.route.out_lane)
            if road not in self.links:
                continue
            if c.sumo not in self.counted:
                self._count(ls, c.sumo, road)
                more = True
            elif c.reroute_to is not None and not self.holds(c):
                extra = self.takes(ls, c)  # counted from its old run: its new rooms on top
                if extra:
                    self.counted_more.add(c.vin)
                    n = self.need_m(ls, c.sumo)
                    for r in extra:
                        self.held_m[r] = self.held_m.get(r, 0.0) + n
                    more = True
        if more:
            self._peaks()

    def need_m(self, ls, vid: str) -> float:
        """The queue length ``vid`` takes inside the network."""
        n = self._length.get(vid)
        if n is None:
            n = self._length[vid] = ls.vehicle.getLength(vid)
        return n + QUEUE_GAP_M

    def pending_rooms(self, ls, cars: Iterable[Car]) -> dict[str, float]:
        """Per room, the queue length of the vehicles among ``cars`` entering the network
        and not counted yet: where answers travel while the world moves on (the real-time
        cluster), any of them may be being let in right now by an ICA whose answer has not
        come, so each holds its room from the moment it may ask, not once it is told yes."""
        out: dict[str, float] = {}
        if not self.closes:
            return out
        for c in cars:
            if c.exited or self.holds(c):
                continue
            rooms = self.takes(ls, c)
            if rooms:
                n = self.need_m(ls, c.sumo)
                for r in rooms:
                    out[r] = out.get(r, 0.0) + n
        return out

    def room_besides(self, ls, c: Car, pending: Mapping[str, float]) -> float:
        """The room left for ``c`` entering the network, less what the other vehicles in
        ``pending`` (:meth:`pending_rooms`, ``c`` among them or not) may be taking now."""
        rooms = self.takes(ls, c)
        if not pending:
            return self.room_on(rooms)
        own = 0.0 if c.exited or self.holds(c) else self.need_m(ls, c.sumo)
        others = {r: max(pending.get(r, 0.0) - own, 0.0) for r in rooms}
        return self.room_on(rooms, others)

    def _count(self, ls, vid: str, road: str) -> None:
        self.counted[vid] = road
        n = self.need_m(ls, vid)
        self.used_m += n
        held = self.held_m
        for r in self.rooms_of(ls, vid, road):
            held[r] = held.get(r, 0.0) + n

    def _peaks(self) -> None:
        self.peak_m = max(self.peak_m, self.used_m)
        cap = self.room_cap_m
        for r, m in self.held_m.items():
            if cap[r] > 0.0:
                self.peak_share = max(self.peak_share, m / cap[r])

    def forget(self, gone: Iterable[str]) -> None:
        for vid in gone:
            self._length.pop(vid, None)
            self._runs.pop(vid, None)
        if len(self._takes) > 4096:  # crossings long over: worked out again if ever asked
            self._takes.clear()
