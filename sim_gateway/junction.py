"""One junction's share of the world: its intersection, its routes in SUMO, its region and
the cars scheduled to cross it.

The world's jobs (:mod:`sim_gateway.traffic` inserts, detects and accounts;
:mod:`sim_gateway.actuator` drives) keep no state of a junction themselves:
they act on a :class:`Junction`. A world of several junctions holds several of
these, each with its own cars, queues and safety monitor.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route
from dica.ica.netfile import SERVED_CLASSES
from dica.sim_gateway.demand import Arrival
from dica.sim_gateway.safety import PersonCheck, SafetyMonitor
from dica.sim_gateway.sumo_io import Reads, Watch
from dica.vehicle_agent.actuation import NO_PLAN
from dica.vehicle_agent.machine import Observation


@dataclass(slots=True)
class Car:
    """The world's record of one scheduled vehicle."""

    vin: str
    route: Route
    lane_index: int
    entry_speed_mps: float
    detected_s: float = math.nan
    exited: bool = False
    entered: bool = False
    speed_mode: int = -1
    head: bool = False  # nothing ahead of it on its incoming lane
    ahead: Car | None = None  # the vehicle just ahead of it on its incoming lane
    behind: Car | None = None  # the vehicle just behind it there
    released: bool = False
    # the actuator's plan: route positions [m] every step from plan_t0_s
    plan_seq: int = NO_PLAN
    plan_t0_s: float = math.nan
    plan_s: np.ndarray | None = None
    refused_seq: int = NO_PLAN
    kept_seq: int = NO_PLAN  # the last plan it was told to drop but kept (it could not stop)
    # where the front is along the route [m] (0 at the entry line) and how fast, this step
    s_m: float = math.nan
    speed_mps: float = 0.0
    odo_ref: float = math.nan  # SUMO's odometer at the last step on the incoming lane
    s_ref: float = math.nan  # the route position then
    ev: bool = False  # inserted as an emergency vehicle
    length_m: float = 5.0
    width_m: float = 1.8
    # a vehicle of the user's route file, driven by SUMO until it reached the region
    # (None: one of ours, inserted at the region's entry line); its lane-change mode
    # is given back once it is out of the junction
    adopted_lcm: int | None = None
    reroute_to: str | None = None  # beyond the junction, SUMO routes it on to this edge
    # the way on to ``reroute_to`` whose rooms the network gate took for it: driven as is
    # (a route SUMO chose later may pass a guarded link it never had room on)
    reroute_way: tuple[str, ...] | None = None
    # its id in SUMO; ``vin`` names this crossing to the ICA, the agents and the trip log
    # and differs only for a route-file vehicle's second and later pass (``<id>+2``, ...)
    # or an id that cannot be a key chunk (:func:`sim_gateway.traffic.crossing_name`)
    sumo: str = ""
    # its braking as SUMO knows it, kept while it flies a plan (Actuator._set_mode)
    decel_mps2: float = math.nan
    human: bool = False  # SUMO's own driver drives it: no plan, a signal head of its own

    def __post_init__(self) -> None:
        if not self.sumo:
            self.sumo = self.vin

    @classmethod
    def of(cls, v: Arrival) -> Car:
        """One of the demand's vehicles, to be inserted at the region's entry line."""
        lane = lane_index(v.route.in_lane)
        return cls(v.vin, v.route, lane, v.speed_mps, length_m=v.length_m, width_m=v.width_m,
                   human=v.human)  # fmt: skip

    def locate(self, lane: str, lane_pos_m: float, lane_len_m: float, odo_m: float) -> None:
        """Where the front is along the route: from the lane position while on the
        incoming lane, then by SUMO's odometer (internal lanes have no route position)."""
        if lane == self.route.in_lane:
            self.s_m = lane_pos_m - lane_len_m
            self.odo_ref, self.s_ref = odo_m, self.s_m
        elif not math.isnan(self.odo_ref):
            self.s_m = self.s_ref + (odo_m - self.odo_ref)


@dataclass(slots=True)
class Seen:
    """One vehicle as observed this step, with what an observer needs to draw it."""

    car: Car
    obs: Observation
    xy: tuple[float, float] = (math.nan, math.nan)
    angle_deg: float = math.nan


HALTED_MPS = 1.0  # [m/s] slower than this, a vehicle on an exit lane may stay where it is
STANDSTILL_GAP_M = 2.5  # [m] SUMO's default minGap


def lane_room(ls, lane: str) -> float:
    """How far from its start the next vehicle's front could have to stop were the
    lane's vehicles to brake. A vehicle standing (or nearly) may stay where it is; a
    moving one may brake to a stop from where it is (at its own deceleration: SUMO's
    drivers brake harder only to avoid a collision, so that point never moves back),
    or stop sooner behind the one ahead of it or at the lane's end (the next
    junction), each at SUMO's standstill gap. A vehicle let out of the junction with
    this room ahead never has to brake harder than it can."""
    ahead = ls.lane.getLength(lane)  # the lane's end: where a queue may start
    v = ls.vehicle
    cars = [
        (v.getLanePosition(x), v.getSpeed(x), v.getLength(x), v.getDecel(x))
        for x in ls.lane.getLastStepVehicleIDs(lane)
    ]
    for pos, speed, length, decel in sorted(cars, reverse=True):  # front to rear
        front = pos if speed < HALTED_MPS else pos + speed * speed / (2.0 * decel)
        ahead = min(ahead, front) - length - STANDSTILL_GAP_M
    return max(ahead, 0.0)


def _for_vehicles(ls, lane: str) -> bool:
    """Whether a road vehicle may drive on ``lane`` (not a sidewalk or a bike lane)."""
    allowed = ls.lane.getAllowed(lane)
    return not allowed or any(c in SERVED_CLASSES for c in allowed)


def lane_index(lane: str) -> int:
    return int(lane.rsplit("_", 1)[1])


def route_edges(r: Route) -> tuple[str, str]:
    """The route's incoming and outgoing SUMO edges."""
    return r.in_lane.rsplit("_", 1)[0], r.out_lane.rsplit("_", 1)[0]


@dataclass(slots=True)
class Junction:
    """One junction in SUMO and everything the world keeps about it."""

    inter: Intersection
    signalised: bool  # SUMO's light decides; the vehicles do not fly plans here
    schedule: list[Arrival]  # its vehicles in arrival order at the region's entry line
    cars: dict[str, Car]
    edge_routes: dict[tuple[str, str], str]  # (in edge, out edge): SUMO's route id
    lane_len_m: dict[str, float]  # where each incoming lane's line stands on it [m]
    monitor: SafetyMonitor  # the collision check over its region
    watch: Watch  # the monitor's feed
    person_check: PersonCheck | None = None  # vehicles touching people (with --peds)
    active: list[Car] = field(default_factory=list)  # inserted, not yet forgotten
    present: set[str] = field(default_factory=set)  # in SUMO at the last step
    last_in: dict[str, Car] = field(default_factory=dict)  # per lane, the last car to enter
    # insertion: the next arrival due, the cars SUMO found no room for at the entry line
    # last step, and per lane the position and speed of its last car
    next: int = 0
    blocked: list[Car] = field(default_factory=list)
    tails: dict[str, tuple[float, float]] = field(default_factory=dict)
    # accounting
    crossed: int = 0
    waiting: int = 0  # stopped in the region this step
    unconfirmed_entries: list[str] = field(default_factory=list)
    # vehicles seen standing with the front past the entry line and the rear not out: the
    # downstream-space rule says never (a standing vehicle there blocks the junction)
    stood_inside: set[str] = field(default_factory=set)
    # route-file vehicles seen in the region that do not cross the junction (their route
    # ends here): SUMO drives them
    passing: set[str] = field(default_factory=set)
    # route-file vehicles by SUMO id: the crossing it is on now (or made last)
    by_sumo: dict[str, Car] = field(default_factory=dict)
    # per exit road, the room beyond the junction this step [m] (measured only where
    # vehicles go on past the exit lane, a route file's, and on demand: room_of)
    room: dict[str, float] = field(default_factory=dict)
    measuring: bool = False  # room is measured (a route file's vehicles go on beyond)
    road_lanes: dict[str, list[str]] = field(default_factory=dict)  # exit road: its lanes
    own_lanes: frozenset[str] = frozenset()  # its incoming, internal and exit lanes (covers)
    # per incoming lane, the vehicles on it that are not the junction's (a route file's
    # whose route ends there, or one the junction before has not let go yet): their
    # fronts and rears [m, route position]; the junction's own stop short of them
    strangers: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    def covers(self, lane: str) -> bool:
        """Whether ``lane`` is one of the junction's: an incoming, internal or exit lane."""
        if not self.own_lanes:
            routes = self.inter.routes
            self.own_lanes = frozenset(
                {r.in_lane for r in routes} | {r.out_lane for r in routes}
                | {v for r in routes for v in r.via_lanes}
            )  # fmt: skip
        return lane.startswith(f":{self.inter.junction_id}_") or lane in self.own_lanes

    def borders(self, lane: str) -> bool:
        """Whether ``lane`` lies on one of the junction's roads (a sidewalk beside its
        incoming or exit lanes counts: a vehicle turning there may reach over it)."""
        edge = lane.rsplit("_", 1)[0]
        return any(edge in route_edges(r) for r in self.inter.routes)

    def measure_room(self) -> None:
        """Measure the room beyond the junction this step (:meth:`room_of`, on demand)."""
        self.measuring = True
        self.room = {}

    def room_of(self, ls, out_lane: str) -> float:
        """An exit lane's room this step: how far from the exit line the next vehicle's
        front could have to stop were the vehicles beyond to brake (:func:`lane_room`),
        over every lane of the exit road a vehicle may change from: a vehicle changing
        lanes beyond the junction takes its stopping point with it, so the least room over
        the road's lanes is one no lane change can shrink (only a vehicle entering the
        road can, as the ICA's one car more allows). inf where it is not measured (the
        random demand's exit lanes end where vehicles leave the net)."""
        if not self.measuring:
            return math.inf
        edge = out_lane.rsplit("_", 1)[0]
        room = self.room.get(edge)
        if room is None:
            road = self.road_lanes.get(edge)
            if road is None:
                lanes = [f"{edge}_{i}" for i in range(ls.edge.getLaneNumber(edge))]
                road = self.road_lanes[edge] = [x for x in lanes if _for_vehicles(ls, x)]
            room = self.room[edge] = min(lane_room(ls, x) for x in road)
        return room

    @classmethod
    def open(
        cls,
        ls,
        inter: Intersection,
        schedule: list[Arrival],
        *,
        signalised: bool,
        length_m: float,
        width_m: float = 1.8,
        max_length_m: float | None = None,
    ) -> Junction:
        """Add the junction's routes to SUMO and watch its region."""
        edge_routes: dict[tuple[str, str], str] = {}
        for r in inter.routes:
            key = route_edges(r)
            if key not in edge_routes:
                edge_routes[key] = f"r_{key[0]}_{key[1]}"
                ls.route.add(edge_routes[key], list(key))
        # where each incoming lane's line stands on it: its end, or further back where a long
        # vehicle turning from another lane sweeps over the place one waits (Route.line_back_m)
        back = {r.in_lane: r.line_back_m for r in inter.routes}
        lane_len = {lane: ls.lane.getLength(lane) - back[lane] for lane in inter.in_lanes}
        if not signalised:
            # inside the junction vehicles fly their plans (speed mode 32), which hold the
            # turn caps; SUMO's own lower turn speed limits would only make a vehicle that
            # is stopping short of the line slow down early, off its predictable stop law
            via_mps: dict[str, float] = {}
            for r in inter.routes:
                for v in r.via_lanes:
                    via_mps[v] = max(via_mps.get(v, 0.0), r.road_mps)
            for lane, mps in via_mps.items():
                ls.lane.setMaxSpeed(lane, mps)
        cars = {v.vin: Car.of(v) for v in schedule}
        monitor = SafetyMonitor(inter.region, watch_margin_m=2.0)
        junction_xy = np.asarray(ls.junction.getPosition(inter.junction_id))
        reach = float(np.max(np.linalg.norm(inter.region - junction_xy, axis=1)))
        # a rectangle can touch the watched area only if its front is within its length of it
        longest = max(length_m, max_length_m or 0.0)
        watch = Watch(inter.junction_id, reach + 2.0 + longest + 1.0)
        watch.subscribe(ls)
        return cls(inter, signalised, schedule, cars, edge_routes, lane_len, monitor, watch)

    def note_strangers(self, ls) -> None:
        """Which vehicles on the incoming lanes are not the junction's (see strangers)."""
        self.strangers = {}
        v = ls.vehicle
        for lane in self.inter.in_lanes:
            end = self.lane_len_m[lane]
            for x in ls.lane.getLastStepVehicleIDs(lane):
                c = self.by_sumo.get(x)
                if c is not None and not c.exited and c.route.in_lane == lane:
                    continue
                front = v.getLanePosition(x) - end
                self.strangers.setdefault(lane, []).append((front, front - v.getLength(x)))

    def stranger_ahead(self, c: Car) -> bool:
        """Whether a vehicle not the junction's is ahead of ``c`` on its incoming lane."""
        return any(f > c.s_m for f, _ in self.strangers.get(c.route.in_lane, ()))

    def forget_gone(self) -> None:
        """Forget who left last step; a car SUMO has not inserted yet (its spot is taken)
        stays tracked."""
        self.active = [
            c
            for c in self.active
            if not c.exited and (c.sumo in self.present or math.isnan(c.detected_s))
        ]

    def order_lanes(self, vw: Reads, present: set[str]) -> None:
        """Link each car on its incoming lane to the ones just ahead and behind it."""
        on_lane: dict[str, list[tuple[float, Car]]] = {}
        for c in self.active:
            c.ahead = c.behind = None
            if c.sumo in present and vw.getLaneID(c.sumo) == c.route.in_lane:
                on_lane.setdefault(c.route.in_lane, []).append((vw.getLanePosition(c.sumo), c))
        for cars in on_lane.values():
            cars.sort(key=lambda pc: -pc[0])
            for (_, front), (_, back) in itertools.pairwise(cars):
                front.behind, back.ahead = back, front

    def short_of_line(self) -> dict[str, list[Car]]:
        """Per incoming lane, its cars in SUMO whose fronts have not passed the entry line."""
        lanes: dict[str, list[Car]] = {}
        for c in self.active:
            if c.sumo in self.present and not c.entered and not math.isnan(c.s_m):
                lanes.setdefault(c.route.in_lane, []).append(c)
        return lanes
