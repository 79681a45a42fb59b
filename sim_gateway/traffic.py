"""The traffic through a junction: vehicles put into SUMO on schedule, detected at the
region's entry line, seen out of the junction, and every one of them accounted for.

Each scheduled vehicle is inserted at the communication region's entry line
at its arrival time and speed; if SUMO finds no room there (the vehicles
ahead have not moved on), it joins the tail of its lane's queue upstream,
which SUMO drives, so a spill-back is a queue on the road (the approaches
are a few hundred metres long) and not a waiting list. The trip log gets
each vehicle's times (inserted, detected, out) and its free-flow time, the
yardstick of its delay.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.envelope import ROLL_DECEL_MPS2, STOP_SHORT_M
from dica.ica.core.planner import Planner
from dica.ica.core.route import Route
from dica.schemas.keys import safe_chunk
from dica.sim_gateway.actuator import MIN_GAP_M
from dica.sim_gateway.detour import Detours
from dica.sim_gateway.junction import Car, Junction, lane_index, route_edges
from dica.sim_gateway.metrics import CRAWL_MPS, Trip, TripLog
from dica.sim_gateway.sumo_io import Reads

VTYPE = "cav"
HUMAN_VTYPE = "human"  # a human driver's (sim_gateway.humans defines it)
EV_VTYPE = "cav_emergency"  # same size and limits, SUMO vClass emergency
EV_COLOR = (230, 30, 30, 255)  # red, as in the dissertation's screenshots
HEADWAY_S = 1.0  # [s] SUMO's desired time headway (Krauss tau), kept behind a queue's tail


def define_vehicle_types(ls, ica_cfg: IcaConfig, length_m: float, width_m: float, ev: bool):
    """Our vehicle type in SUMO, with the ICA's kinematics (and its EV twin if ``ev``)."""
    ls.vehicletype.copy("DEFAULT_VEHTYPE", VTYPE)
    kin = ica_cfg.kinematics
    for setter, value in (
        ("setLength", length_m),
        ("setWidth", width_m),
        ("setAccel", kin.accel_mps2),
        ("setDecel", kin.decel_mps2),
        ("setEmergencyDecel", 9.0),
        ("setMaxSpeed", ica_cfg.caps.road_mps),
        ("setMinGap", MIN_GAP_M),
        ("setImperfection", 0.0),
        ("setSpeedFactor", 1.0),  # it keeps its own entry speed, not a random share of the limit
        ("setSpeedDeviation", 0.0),
    ):
        getattr(ls.vehicletype, setter)(VTYPE, value)
    if ev:
        ls.vehicletype.copy(VTYPE, EV_VTYPE)
        ls.vehicletype.setVehicleClass(EV_VTYPE, "emergency")
        ls.vehicletype.setColor(EV_VTYPE, EV_COLOR)


def crossing_name(sumo_id: str, n: int, taken: Mapping[str, object]) -> str:
    """The name of a route-file vehicle's ``n``-th crossing: its SUMO id, then ``<id>+2``
    and so on. Names travel as Zenoh key chunks, so an id with other characters than
    letters, digits and ``_.:-+`` becomes one that has only those, kept apart from every
    other by a hash of the id."""
    name = safe_chunk(sumo_id, short=100)
    if n > 1:
        name = f"{name}+{n}"
    while name in taken:  # a file's own id that looks like another's later crossing
        name += "+"
    return name


class Traffic:
    """Insertion, detection, exit and accounting for the junctions of one run."""

    def __init__(self, ls, ica_cfg: IcaConfig, length_m: float, log: TripLog) -> None:
        self.ls = ls
        self.ica_cfg = ica_cfg
        self.length_m = length_m
        self.log = log
        self.rerouted = 0  # route-file vehicles sent another way (see adopt)
        # --cav-share with a route file: the share of its vehicles driven by SUMO's own
        # driver, each drawn from the run's seed and its id (the same in every run of it)
        self.human_share = 0.0
        self.seed = 0
        self.humans_drawn: set[str] = set()  # SUMO ids of those drawn human as they departed
        self.humans_too_fast = 0  # drawn human, but too fast to stop at a head when seen
        # of those, the ones with no way on to their destination from the road their lane
        # led to: they leave the net at that road's end
        self.ended_short = 0
        # route-file vehicles by SUMO id: how many crossings each has begun, at any of the
        # run's junctions (a route may loop back, or go on to the next junction)
        self.passes: dict[str, int] = {}
        # route-file vehicles by SUMO id: the junctions each was sent another way at for a
        # U-turn the junction does not serve. Sent round for it there again, it would go
        # round for ever (SUMO's way back to the road it wanted turns back there too): it
        # ends its trip short instead
        self.detoured: dict[str, set[str]] = {}
        # ways on that turn back at no junction of the run (set by the world: its net and
        # junctions); None: SUMO's router alone
        self.detours: Detours | None = None

    def register(self, j: Junction) -> None:
        """A trip record for each of the junction's scheduled vehicles."""
        comm = j.inter.comm_length_m
        for v in j.schedule:
            self.log.trips[v.vin] = Trip(
                v.vin,
                v.route.id,
                v.route.turn.value,
                v.arrival_s,
                free_flow_scheduled_s=self.free_flow_s(v.route, comm, v.speed_mps, v.length_m),
                human=v.human,
            )

    # -- insertion -------------------------------------------------------------
    def insert_due(self, j: Junction, t: float) -> list[Car]:
        """Queue up who SUMO had no room for, and put in who is due by ``t``; return those."""
        for c in j.blocked:
            self.join_queue(j, c)
        fresh = []
        while j.next < len(j.schedule) and j.schedule[j.next].arrival_s <= t + 1e-9:
            arrival = j.schedule[j.next]
            c = j.cars[arrival.vin]
            # an EV candidate is an EV only if no other EV is in the region (inserted, not out)
            c.ev = arrival.ev and not any(o.ev and not o.exited for o in j.active)
            self.log.trips[c.vin].ev = c.ev
            self.add(j, c, self._entry_pos(j, c), c.entry_speed_mps)
            j.active.append(c)
            fresh.append(c)
            j.next += 1
        return fresh

    def note_blocked(self, j: Junction, fresh: list[Car]) -> None:
        """After SUMO's step: which of ``fresh`` it found no room for."""
        pending = set(self.ls.simulation.getPendingVehicles()) if fresh else set()
        j.blocked = [c for c in fresh if c.sumo in pending]

    def departed(self, j: Junction, vin: str, t: float) -> bool:
        """``vin`` is on the road: if it is one of ours, until the region it keeps its lane
        and its speed (a route file's vehicle is SUMO's until it reaches the region)."""
        if vin not in j.cars:
            # a route file's: a connected automated vehicle keeps the limits (SUMO's own
            # drivers take a random share above them), so that it reaches the region
            # at a speed the ICA plans from
            if self.ls.vehicle.getSpeedFactor(vin) > 1.0:
                self.ls.vehicle.setSpeedFactor(vin, 1.0)
            return False
        if j.cars[vin].human:  # SUMO's driver drives it (sim_gateway.humans)
            self.log.trips[vin].inserted_s = t
            return True
        self.ls.vehicle.setLaneChangeMode(vin, 0)
        # until the region, SUMO's driver keeps the scheduled speed (the speed the
        # vehicle keeps when free), or less behind a slower vehicle
        self.ls.vehicle.setSpeed(vin, j.cars[vin].entry_speed_mps)
        self.log.trips[vin].inserted_s = t
        return True

    def adopt(self, j: Junction, t: float, held: set[str] = frozenset()) -> list[Car]:
        """A route file's vehicles that reached the region on their way through the
        junction this step: from now on they are the junction's, as if inserted there.

        Its way through is the connection SUMO's driver has chosen from its lane (its
        next link, onto the lane its route continues on). A vehicle whose route ends
        before the junction passes by; one in a lane that does not lead where its route
        goes takes the road of the lane's first way through, over the link SUMO takes
        onto it, and is sent on to its destination from beyond it (SUMO reroutes it),
        rather than wait for a gap it cannot have.
        One that another junction ``held`` still drives is taken once it lets go.
        """
        ls, comm = self.ls, j.inter.comm_length_m
        out = []
        for lane in j.inter.in_lanes:
            # front first (SUMO lists a lane's vehicles rear first): the ICA queues a lane's
            # vehicles in the order it hears of them, which must be the order they stand in
            for vin in reversed(ls.lane.getLastStepVehicleIDs(lane)):
                now = j.by_sumo.get(vin)
                if (now is not None and not now.exited) or vin in j.passing or vin in held:
                    continue
                if j.lane_len_m[lane] - ls.vehicle.getLanePosition(vin) > comm:
                    continue
                dest = ls.vehicle.getRoute(vin)[-1]
                links = ls.vehicle.getNextLinks(vin)
                u_turn = bool(links) and links[0][6] == "t"  # its route turns back next
                route = self._way_through(j, vin, lane, links)
                if route is None:
                    j.passing.add(vin)
                    continue
                n = self.passes[vin] = self.passes.get(vin, 0) + 1
                c = Car(
                    crossing_name(vin, n, self.log.trips), route, lane_index(lane),
                    min(route.road_mps, ls.vehicle.getMaxSpeed(vin)),
                    length_m=ls.vehicle.getLength(vin), width_m=ls.vehicle.getWidth(vin),
                    adopted_lcm=ls.vehicle.getLaneChangeMode(vin), sumo=vin,
                )  # fmt: skip
                beyond = route_edges(route)[1]
                if beyond != dest and ls.vehicle.getRoute(vin)[-1] != dest:
                    jid = j.inter.junction_id
                    again = u_turn and jid in self.detoured.get(vin, ())
                    if u_turn:
                        self.detoured.setdefault(vin, set()).add(jid)
                    way = None if again else self._way_on(vin, beyond, dest)
                    if way is not None:
                        c.reroute_to = dest
                        if way:  # SUMO's own way would turn back at a junction of the run
                            c.reroute_way = way
                    else:  # no way back from beyond (or round again): it leaves the net at
                        self.ended_short += 1  # that road's end
                # of SUMO's emergency class: an EV to the junction, unless one is in its
                # region already (one at a time, as the random demand has them)
                c.ev = ls.vehicle.getVehicleClass(vin) == "emergency" and not any(
                    o.ev and not o.exited for o in j.active
                )
                c.human = not c.ev and self._human_here(vin, j.lane_len_m[lane])
                ls.vehicle.setLaneChangeMode(vin, 0)
                j.cars[c.vin] = j.by_sumo[vin] = c
                j.active.append(c)
                # free flow from the road speed, or from the speed SUMO brought it at where
                # that is higher (a net's limit above the plans' road speed): slower arrivals
                # count as delay (a queue reaching back past the region is the junction's)
                arrived = ls.vehicle.getSpeed(vin)
                free = None
                if arrived > c.entry_speed_mps:
                    free = self.free_flow_s(route, comm, arrived, c.length_m)
                if free is None:
                    free = self.free_flow_s(route, comm, c.entry_speed_mps, c.length_m)
                self.log.trips[c.vin] = Trip(
                    c.vin, route.id, route.turn.value, t, free_flow_scheduled_s=free,
                    inserted_s=t, ev=c.ev, human=c.human,
                )  # fmt: skip
                out.append(c)
        return out

    def draws_human(self, vin: str) -> bool:
        """Whether a route file's vehicle departing is a human driver (:attr:`human_share`,
        drawn from the seed and its id, so every run of the file draws alike)."""
        if self.human_share <= 0.0:
            return False
        draw = np.random.default_rng([self.seed, 27, zlib.crc32(vin.encode())]).random()
        if draw >= self.human_share:
            return False
        self.humans_drawn.add(vin)
        return True

    def _human_here(self, vin: str, lane_m: float) -> bool:
        """Whether a route file's vehicle reaching the region is a human driver: drawn so
        as it departed, and still able to stop at its head's line braking as a human
        stops for a red there. One that could not stays connected (and is counted):
        its head could not hold it."""
        if vin not in self.humans_drawn:
            return False
        ls = self.ls
        room = lane_m - ls.vehicle.getLanePosition(vin) - STOP_SHORT_M
        v = ls.vehicle.getSpeed(vin)
        if v * v > 2.0 * ROLL_DECEL_MPS2 * room:
            self.humans_too_fast += 1
            return False
        return True

    def _way_through(self, j: Junction, vin: str, lane: str, links) -> Route | None:
        """The way ``vin`` crosses from ``lane``, its next ``links`` as SUMO has them."""
        ls = self.ls
        if not links:
            return None  # its route ends on this lane
        route = j.inter.route(lane, links[0][0])
        if route is not None:
            return route
        edges = ls.vehicle.getRoute(vin)
        k = ls.vehicle.getRouteIndex(vin)
        if k + 1 >= len(edges):
            return None
        ways = sorted(j.inter.routes_from(lane), key=lambda r: r.id)
        if not ways:
            return None
        # the first way from which it can be routed on to its destination, if any
        route = next(
            (r for r in ways if self._way_on(vin, route_edges(r)[1], edges[-1]) is not None),
            ways[0],
        )
        here, beyond = route_edges(route)
        ls.vehicle.setRoute(vin, [here, beyond])
        self.rerouted += 1
        # the route names roads: where the lane has several links onto ``beyond``, SUMO
        # takes one of its own choosing, and that is the one the ICA must plan
        links = ls.vehicle.getNextLinks(vin)
        taken = j.inter.route(lane, links[0][0]) if links else None
        return route if taken is None else taken

    def _way_on(self, vin: str, edge: str, dest: str) -> tuple[str, ...] | None:
        """How ``vin`` goes on from road ``edge`` to road ``dest``: () by SUMO's own way,
        the way (:mod:`sim_gateway.detour`) where SUMO's turns back at a junction of the
        run (none serves a U-turn), None where there is no way (a net without
        turnarounds may have none back from a road that leads away)."""
        if edge == dest:
            return ()
        found = tuple(self.ls.simulation.findRoute(edge, dest).edges)
        if not found:
            return None
        if self.detours is None or not self.detours.turns_back(found):
            return ()
        return self.detours.way(edge, dest, self.ls.vehicle.getVehicleClass(vin))

    def note_tails(self, j: Junction, vw: Reads, present: set[str]) -> None:
        """Per incoming lane, where its rearmost car is and how fast (for join_queue)."""
        j.tails = {}
        for c in j.active:
            if c.sumo in present and vw.getLaneID(c.sumo) == c.route.in_lane:
                pos = vw.getLanePosition(c.sumo)
                tail = j.tails.get(c.route.in_lane)
                if tail is None or pos < tail[0]:
                    j.tails[c.route.in_lane] = (pos, vw.getSpeed(c.sumo))

    def add(self, j: Junction, c: Car, pos_m: float, speed_mps: float) -> None:
        """Put ``c`` into SUMO on its incoming lane, bound for its route's outgoing lane.

        The route SUMO is given names roads, not lanes; where the incoming lane has
        several links onto the outgoing road (a multi-lane grid's through lanes), SUMO
        would take one of its own choosing, across the internal lane of another route
        the ICA never reserved. Its arrival lane on that road, the last of its route,
        makes SUMO take the link the ICA plans for.
        """
        self.ls.vehicle.add(
            c.vin,
            j.edge_routes[route_edges(c.route)],
            typeID=EV_VTYPE if c.ev else HUMAN_VTYPE if c.human else VTYPE,
            depart="now",
            departLane=str(c.lane_index),
            departPos=str(pos_m),
            departSpeed=str(speed_mps),
            arrivalLane=str(lane_index(c.route.out_lane)),
        )

    def join_queue(self, j: Junction, c: Car) -> None:
        """Place a vehicle SUMO had no room for at the entry line behind its lane's last one.

        It keeps SUMO's standstill gap and a second's headway behind the tail
        at the tail's speed (or its own, if lower). With no room left on the
        lane it waits at the lane's start, where SUMO inserts it when it can.
        """
        self.ls.vehicle.remove(c.sumo)  # from SUMO's insertion queue
        entry = self._entry_pos(j, c)
        tail = j.tails.get(c.route.in_lane)
        if tail is None:  # the blocker has left the lane already: the entry line again
            self.add(j, c, entry, c.entry_speed_mps)
            return
        pos, v_tail = tail
        v = min(c.entry_speed_mps, v_tail)
        behind = min(pos - self.length_m - MIN_GAP_M - HEADWAY_S * v - 0.5, entry)
        if behind < 0.0:
            self.add(j, c, 0.0, 0.0)
        else:
            self.add(j, c, behind, v)
            j.tails[c.route.in_lane] = (behind, v)  # the next one goes behind this one

    @staticmethod
    def _entry_pos(j: Junction, c: Car) -> float:
        """The region's entry line on ``c``'s incoming lane [m, lane position]."""
        return max(j.lane_len_m[c.route.in_lane] - j.inter.comm_length_m - 0.05, 0.0)

    # -- detection and exit ----------------------------------------------------
    def detect(self, j: Junction, c: Car, lane: str, vw: Reads, t: float) -> bool:
        """Note ``c`` in the region once its front is past the entry line; False while not.

        The time it crossed the line is interpolated back from where it is now. A route
        file's vehicle may appear in the region without crossing it (inserted on a road
        shorter than the region, or let go there by the junction before): it arrives now,
        at most a step back, never before a vehicle already ahead of it in its lane (the
        ICA queues a lane's vehicles in the order they arrive, and a queue that
        disagrees with the road holds the lane up for ever)."""
        comm = j.inter.comm_length_m
        d = j.lane_len_m.get(lane, math.inf) - vw.getLanePosition(c.sumo)
        if lane != c.route.in_lane or d > comm:
            return False
        v = vw.getSpeed(c.sumo)
        trip = self.log.trips[c.vin]
        back = (comm - d) / v if v > 0.1 else 0.0
        if c.adopted_lcm is not None:
            back = min(back, self.ica_cfg.step_s)
        trip.entered_s = t - back
        c.detected_s = trip.entered_s
        trip.free_flow_s = self.free_flow_s(c.route, comm, v, c.length_m)
        return True

    def note_speed(self, j: Junction, c: Car, speed_mps: float) -> None:
        """Whether ``c`` crawled or stood in the region (and count who stands now)."""
        if speed_mps < CRAWL_MPS:
            self.log.trips[c.vin].crawled = True
        if speed_mps < 0.1:
            self.log.trips[c.vin].stopped = True  # stopped in the region before leaving
            j.waiting += 1
            if c.entered and not c.exited:  # never: no vehicle stands inside a junction
                j.stood_inside.add(c.vin)

    def left_junction(self, j: Junction, vw: Reads, c: Car, t: float) -> bool:
        """Rear past the exit line: note the time (interpolated), mark the car exited and
        count it crossed."""
        if vw.getRoadID(c.sumo) != route_edges(c.route)[1]:
            return False
        over = vw.getLanePosition(c.sumo) - c.length_m
        if over < 0:
            return False
        self.log.trips[c.vin].exited_s = t - over / max(vw.getSpeed(c.sumo), 0.1)
        c.exited = True
        j.crossed += 1
        return True

    def free_flow_s(self, route: Route, comm_m: float, v_mps: float, length: float) -> float | None:
        """From the region's entry line at ``v_mps`` until fully out, alone at the junction."""
        pl = Planner(
            comm_m,
            v_mps,
            route.road_mps,
            route.speed_cap_mps,
            route.cross_length_m + length,
            self.ica_cfg.kinematics,
        )
        p = pl.fastest()
        return p.time_at(route.cross_length_m + length) if p else None

    # -- accounting ------------------------------------------------------------
    def accounting(self, j: Junction, end_s: float) -> dict[str, int]:
        """Where every vehicle due by ``end_s`` is: none may be lost."""
        out = {"generated": 0, "crossed": 0, "in_region": 0, "not_yet_in_region": 0, "lost": 0}
        for c in j.cars.values():
            trip = self.log.trips[c.vin]
            if trip.depart_s > end_s:
                continue
            out["generated"] += 1
            if c.exited:
                out["crossed"] += 1
            elif math.isnan(c.detected_s):
                out["not_yet_in_region"] += 1
            elif c.sumo in j.present:
                out["in_region"] += 1
            else:
                out["lost"] += 1  # gone from SUMO without leaving the junction: never
        return out
