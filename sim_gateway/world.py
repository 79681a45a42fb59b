"""The SUMO side of a run, shared by the embedded runner and the cluster gateway.

The world inserts each scheduled vehicle at the communication region's entry
line at its arrival time and speed; if SUMO finds no room there (the
vehicles ahead have not moved on), the vehicle joins the tail of its lane's
queue upstream, which SUMO drives, so a spill-back is a queue on the road
(the approaches are a few hundred metres long) and not a waiting list. The
world steps SUMO, notes each vehicle's detection and exit, observes it for its
driver, applies the drivers' commands, and feeds the independent safety
monitor and the trip log. Who decides the commands (vehicle machines in this
process, or vehicle-agent processes over Zenoh) is not its business, so both
modes measure and check with exactly this code.

The world is also each vehicle's actuator, the part of a connected vehicle
that runs on board whatever its links do. A vehicle without a plan it may
fly stops short of the junction's entry line by its own control law; a plan
is taken only if it arrives before its start (a late one is refused, and the
next observation says so), and is flown by position against time, closing
the loop on where the vehicle really is; once out of the junction the
vehicle is handed back to SUMO's driver. So a late, lost or repeated message
can cost time but cannot put a vehicle into the junction without a
reservation it can keep.

Nothing here trusts the ICA for safety: every step the monitor rebuilds
rectangles from SUMO's own positions, and SUMO's junction collision detection
gives a second opinion.
"""

from __future__ import annotations

import bisect
import itertools
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.intersection import Intersection
from dica.ica.core.planner import Planner
from dica.ica.core.route import Route
from dica.sim_gateway.demand import Arrival
from dica.sim_gateway.metrics import CRAWL_MPS, Trip, TripLog, summarize
from dica.sim_gateway.runconfig import RunConfig, RunError, RunResult
from dica.sim_gateway.safety import SafetyMonitor
from dica.vehicle_agent.actuation import (
    MODE_CONFIRMED,
    MODE_DEFAULT,
    MODE_HEAD,
    MODE_QUEUED,
    NO_PLAN,
    RELEASE,
    Actuation,
)
from dica.vehicle_agent.control import can_stop_short, entry_time, stop_speed, track_speed
from dica.vehicle_agent.machine import Observation

VTYPE = "cav"
# [m] how far from its plan's first position a vehicle may be when the plan starts; within
# it the position loop catches up in a few steps and the ICA's margin covers the gap
START_TOL_M = 0.1
MIN_GAP_M = 2.5  # [m] SUMO's standstill gap of our vehicle type, also kept short of the line
HEADWAY_S = 1.0  # [s] SUMO's desired time headway (Krauss tau), kept behind a queue's tail
EV_VTYPE = "cav_emergency"  # same size and limits, SUMO vClass emergency
EV_COLOR = (230, 30, 30, 255)  # red, as in the dissertation's screenshots


def import_libsumo():
    """libsumo, without the pyarrow version notice it prints on import.

    libsumo bundles its own arrow, so the notice is harmless (checked on this
    stack), but it would otherwise open every run's output.
    """
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


def sumo_command(net_path: str, step_s: float, extra: tuple[str, ...]) -> list[str]:
    return [
        "sumo",
        "-n",
        net_path,
        "--step-length",
        str(step_s),
        "--no-step-log",
        "true",
        "--collision.check-junctions",
        "true",
        "--collision.action",
        "warn",
        # a collision is bodies touching, not a gap below a driver's preferred minimum
        # (SUMO's default counts any gap under the vehicle type's minGap)
        "--collision.mingap-factor",
        "0",
        # a vehicle that waits long at the line (a lost link, a dead ICA) waits; it is not
        # teleported out of the run
        "--time-to-teleport",
        "-1",
        "--no-warnings",
        "true",
        "--seed",
        "1",
        *extra,
    ]


def start_sumo(ls, cfg: RunConfig, step_s: float) -> list[str]:
    cmd = sumo_command(cfg.net_path, step_s, cfg.sumo_args)
    try:
        ls.start(cmd)
    except Exception as e:  # libsumo raises its own TraCIException or a plain error
        raise RunError(f"SUMO would not start: {e}") from None
    return cmd


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


@dataclass(slots=True)
class Seen:
    """One vehicle as observed this step, with what an observer needs to draw it."""

    car: Car
    obs: Observation
    xy: tuple[float, float] = (math.nan, math.nan)
    angle_deg: float = math.nan


class World:
    """SUMO through libsumo, for one junction and one vehicle schedule."""

    def __init__(
        self,
        ls,
        cfg: RunConfig,
        inter: Intersection,
        ica_cfg: IcaConfig,
        schedule: list[Arrival],
        horizon: float,
        *,
        signalised: bool = False,
        want_xy: bool = False,
        predict_s: float = 0.0,
    ) -> None:
        self.ls = ls
        self.cfg = cfg
        self.inter = inter
        self.ica_cfg = ica_cfg
        self.h = ica_cfg.step_s
        self.schedule = schedule
        self.horizon = horizon
        self.signalised = signalised
        self.want_xy = want_xy
        # how far ahead [s] each vehicle that may ask is told where its own control law will
        # take it (Observation.intent_m): as far as its agents plan ahead (their lead)
        self.predict_steps = max(round(predict_s / self.h), 0)
        self.log = TripLog()
        self.cars: dict[str, Car] = {}
        self.active: list[Car] = []
        self.t = 0.0
        self.crossed = 0
        self.waiting = 0
        self.sumo_collisions = 0
        self.unconfirmed_entries: list[str] = []
        self.timing = Timing()
        self._next = 0
        self._present: set[str] = set()
        self._last_sample = -1.0
        self._t_wall = time.perf_counter()
        self._setup()

    def _setup(self) -> None:
        ls, cfg, inter = self.ls, self.cfg, self.inter
        ls.vehicletype.copy("DEFAULT_VEHTYPE", VTYPE)
        kin = self.ica_cfg.kinematics
        for setter, value in (
            ("setLength", cfg.length_m),
            ("setWidth", cfg.width_m),
            ("setAccel", kin.accel_mps2),
            ("setDecel", kin.decel_mps2),
            ("setEmergencyDecel", 9.0),
            ("setMaxSpeed", self.ica_cfg.caps.road_mps),
            ("setMinGap", 2.5),
            ("setImperfection", 0.0),
            (
                "setSpeedFactor",
                1.0,
            ),  # it keeps its own entry speed, not a random share of the limit
            ("setSpeedDeviation", 0.0),
        ):
            getattr(ls.vehicletype, setter)(VTYPE, value)
        if any(v.ev for v in self.schedule):
            ls.vehicletype.copy(VTYPE, EV_VTYPE)
            ls.vehicletype.setVehicleClass(EV_VTYPE, "emergency")
            ls.vehicletype.setColor(EV_VTYPE, EV_COLOR)
        self._edge_routes: dict[tuple[str, str], str] = {}
        for r in inter.routes:
            key = _edges(r)
            if key not in self._edge_routes:
                self._edge_routes[key] = f"r_{key[0]}_{key[1]}"
                ls.route.add(self._edge_routes[key], list(key))
        self._lane_len = {lane: ls.lane.getLength(lane) for lane in inter.in_lanes}
        self._last_in: dict[str, Car] = {}  # per incoming lane, the last car that entered from it
        if not self.signalised:
            # inside the junction vehicles fly their plans (speed mode 32), which hold the
            # turn caps; SUMO's own lower turn speed limits would only make a vehicle that
            # is stopping short of the line slow down early, off its predictable stop law
            for lane in {v for r in inter.routes for v in r.via_lanes}:
                ls.lane.setMaxSpeed(lane, self.ica_cfg.caps.road_mps)
        comm = inter.comm_length_m
        for v in self.schedule:
            lane_index = int(v.route.in_lane.rsplit("_", 1)[1])
            self.cars[v.vin] = Car(v.vin, v.route, lane_index, v.speed_mps)
            self.log.trips[v.vin] = Trip(
                v.vin,
                v.route.id,
                v.route.turn.value,
                v.arrival_s,
                free_flow_scheduled_s=self._free_flow_s(v.route, comm, v.speed_mps),
            )
        self._arrivals = [v.arrival_s for v in self.schedule]
        self._blocked: list[Car] = []  # SUMO found no room at the entry line last step
        self._tails: dict[str, tuple[float, float]] = {}  # lane: its last car's position, speed
        self.monitor = SafetyMonitor(inter.region, watch_margin_m=2.0)
        junction_xy = np.asarray(ls.junction.getPosition(inter.junction_id))
        reach = float(np.max(np.linalg.norm(inter.region - junction_xy, axis=1)))
        # a rectangle can touch the watched area only if its front is within its length of it
        self._watch = _Watch(inter.junction_id, reach + 2.0 + cfg.length_m + 1.0)
        self._watch.subscribe(ls)

    # -- one step ------------------------------------------------------------
    def step(self) -> list[Seen]:
        """Insert who is due, step SUMO, and observe every vehicle in the region."""
        ls = self.ls
        comm = self.inter.comm_length_m
        # forget who left last step; a car SUMO has not inserted yet (its spot is taken)
        # stays tracked
        self.active = [
            c
            for c in self.active
            if not c.exited and (c.vin in self._present or math.isnan(c.detected_s))
        ]
        for c in self._blocked:
            self._join_queue(c)
        fresh = []
        while self._next < len(self.schedule) and self.schedule[self._next].arrival_s <= (
            self.t + 1e-9
        ):
            arrival = self.schedule[self._next]
            c = self.cars[arrival.vin]
            ln = self._lane_len[c.route.in_lane]
            # an EV candidate is an EV only if no other EV is in the region (inserted, not out)
            c.ev = arrival.ev and not any(o.ev and not o.exited for o in self.active)
            self.log.trips[c.vin].ev = c.ev
            self._add(c, max(ln - comm - 0.05, 0.0), c.entry_speed_mps)
            self.active.append(c)
            fresh.append(c)
            self._next += 1

        ls.simulation.step()
        pending = set(ls.simulation.getPendingVehicles()) if fresh else set()
        self._blocked = [c for c in fresh if c.vin in pending]
        t = self.t = ls.simulation.getTime()
        self.sumo_collisions += len(ls.simulation.getCollisions())
        present = set(ls.vehicle.getIDList())
        for vid in ls.simulation.getDepartedIDList():
            ls.vehicle.setLaneChangeMode(vid, 0)
            # until the region, SUMO's driver keeps the scheduled speed (the speed the
            # vehicle keeps when free), or less behind a slower vehicle
            ls.vehicle.setSpeed(vid, self.cars[vid].entry_speed_mps)
            self.log.trips[vid].inserted_s = t
            _Reads.subscribe(ls, vid, self.want_xy)
        vw = _Reads(ls)

        self._tails = {}
        for c in self.active:
            if c.vin in present and vw.getLaneID(c.vin) == c.route.in_lane:
                pos = vw.getLanePosition(c.vin)
                tail = self._tails.get(c.route.in_lane)
                if tail is None or pos < tail[0]:
                    self._tails[c.route.in_lane] = (pos, vw.getSpeed(c.vin))

        on_lane: dict[str, list[tuple[float, Car]]] = {}
        for c in self.active:
            c.ahead = c.behind = None
            if c.vin in present and vw.getLaneID(c.vin) == c.route.in_lane:
                on_lane.setdefault(c.route.in_lane, []).append((vw.getLanePosition(c.vin), c))
        for cars in on_lane.values():
            cars.sort(key=lambda pc: -pc[0])
            for (_, front), (_, back) in itertools.pairwise(cars):
                front.behind, back.ahead = back, front

        seen: list[Seen] = []
        self.waiting = 0
        for c in self.active:
            if c.vin not in present:
                continue
            lane = vw.getLaneID(c.vin)
            if math.isnan(c.detected_s):
                d = self._lane_len.get(lane, math.inf) - vw.getLanePosition(c.vin)
                if lane == c.route.in_lane and d <= comm:
                    self._detect(c, d, vw.getSpeed(c.vin), t)
                    if self.signalised:  # in the region SUMO's driver drives as it likes
                        ls.vehicle.setSpeed(c.vin, RELEASE)
                else:
                    continue
            speed = vw.getSpeed(c.vin)
            odo = vw.getDistance(c.vin)
            if lane == c.route.in_lane:
                c.s_m = vw.getLanePosition(c.vin) - self._lane_len[lane]
                c.odo_ref, c.s_ref = odo, c.s_m
            elif not math.isnan(c.odo_ref):
                c.s_m = c.s_ref + (odo - c.odo_ref)
            c.speed_mps = speed
            if not c.entered and lane != c.route.in_lane:
                c.entered = True  # the front is past the entry line
                self._last_in[c.route.in_lane] = c
                if not self.signalised and c.speed_mode != MODE_CONFIRMED:
                    self.unconfirmed_entries.append(c.vin)  # never: the vehicles must stop
                elif c.plan_s is not None:
                    actual = t - c.s_m / speed if speed > 0.1 else t
                    planned = entry_time(c.plan_t0_s, self.h, c.plan_s)
                    self.timing.adherence_s.append(actual - planned)
                    self.timing.worst.append((abs(actual - planned), c.vin, actual, planned))
            if speed < CRAWL_MPS:
                self.log.trips[c.vin].crawled = True
            if speed < 0.1:
                self.log.trips[c.vin].stopped = True  # stopped in the region before leaving
                self.waiting += 1
            if self._left_junction(vw, c, t):
                self.crossed += 1
            d = self._lane_len[c.route.in_lane] - vw.getLanePosition(c.vin)
            c.head = lane == c.route.in_lane and c.ahead is None
            follows = (
                self.ica_cfg.platoon
                and c.plan_s is None  # one that holds a plan does not ask
                and lane == c.route.in_lane
                and self._may_follow(c, speed, t)
            )
            obs = Observation(
                t_s=t,
                lane=lane,
                dist_to_entry_m=d if lane == c.route.in_lane else -1.0,
                speed_mps=speed,
                head=c.head,
                detected_s=c.detected_s,
                exited=c.exited,
                plan_seq=c.plan_seq,
                refused_seq=c.refused_seq,
                kept_seq=c.kept_seq,
                follows=follows,
            )
            seen.append(Seen(c, obs))
        if self.want_xy:
            for s in seen:
                s.xy = vw.getPosition(s.car.vin)
                s.angle_deg = vw.getAngle(s.car.vin)
        self._present = present
        if self.predict_steps:
            intents = self._intents(t)
            for s in seen:
                fut = intents.get(s.car.vin)
                if fut is not None and s.obs.may_ask and s.car.plan_s is None:
                    s.obs = replace(s.obs, intent_m=tuple(fut[1:].tolist()))
        return seen

    def apply(self, commands: Iterable[Actuation]) -> None:
        """Take the drivers' new plans, then drive every vehicle in the region for one step.

        A plan is taken only if it arrives no later than its start (and is
        newer than any plan the vehicle held or refused); a later one could
        not be flown from where the vehicle is, so it is refused, and the
        vehicle goes on stopping short of the line. Commands without a plan
        change nothing here.
        """
        ls, t = self.ls, self.t
        drops: list[tuple[Car, int]] = []
        for cmd in commands:
            c = self.cars.get(cmd.vin)
            if c is not None and cmd.drop:  # revoked: stop short of the line, if it can
                drops.append((c, cmd.seq))
                continue
            if c is None or c.entered or c.exited:
                continue
            if not cmd.has_plan:
                continue
            if cmd.seq <= max(c.plan_seq, c.refused_seq):
                continue  # a repeat, or older than what the vehicle holds
            if t > cmd.t0_s + 1e-6:
                c.refused_seq = cmd.seq
                self.timing.refused += 1
                continue
            c.plan_seq, c.plan_t0_s, c.plan_s = cmd.seq, cmd.t0_s, np.asarray(cmd.s_m, float)
            self.timing.accepted += 1
            self.timing.slack_s.append(cmd.t0_s - t)
        # the rearmost first: a platoon's follower drops before its leader is asked to
        for c, seq in sorted(drops, key=lambda d: _rank(d[0])):
            self._drop(c, seq)
        ahead = self._obstacles()
        for c in self.active:
            if c.vin not in self._present or c.released or math.isnan(c.detected_s):
                continue
            if c.plan_s is not None and t >= c.plan_t0_s - 1e-6:
                if abs(t - c.plan_t0_s) < 1e-6 and (
                    abs(c.s_m - c.plan_s[0]) > START_TOL_M
                    or (c.ahead is not None and not _flying(c.ahead, t))
                ):
                    # not where the plan starts (a leader held it back during the lead),
                    # or a platoon's leader is not flying the plan this one follows:
                    # a reservation it cannot keep is not flown; it stops and asks again
                    c.refused_seq, c.plan_seq, c.plan_s = c.plan_seq, NO_PLAN, None
                    self.timing.off_start += 1
                    self.timing.refused += 1
                    ls.vehicle.setSpeed(c.vin, self._stop_speed(c, ahead.get(c.vin, math.inf)))
                    continue
                if c.exited:
                    if c.speed_mode != MODE_DEFAULT:
                        ls.vehicle.setSpeedMode(c.vin, MODE_DEFAULT)
                        c.speed_mode = MODE_DEFAULT
                    ls.vehicle.setSpeed(c.vin, RELEASE)
                    c.released = True
                    continue
                if c.speed_mode != MODE_CONFIRMED:
                    ls.vehicle.setSpeedMode(c.vin, MODE_CONFIRMED)
                    c.speed_mode = MODE_CONFIRMED
                    trip = self.log.trips[c.vin]
                    if trip.confirmed_s is None:
                        trip.confirmed_s = t
                k = round((t - c.plan_t0_s) / self.h)
                plan = c.plan_s
                if k + 1 < len(plan):
                    v = track_speed(float(plan[k + 1]), c.s_m, c.speed_mps, self.h)
                else:  # past the plan's end (the vehicle is out): hold its last speed
                    v = float(plan[-1] - plan[-2]) / self.h if len(plan) > 1 else c.speed_mps
                ls.vehicle.setSpeed(c.vin, v)
            elif not c.entered:
                mode = MODE_HEAD if self._asks(c) else MODE_QUEUED
                if c.speed_mode != mode:
                    ls.vehicle.setSpeedMode(c.vin, mode)
                    c.speed_mode = mode
                ls.vehicle.setSpeed(c.vin, self._stop_speed(c, ahead.get(c.vin, math.inf)))

    def _may_follow(self, c: Car, speed_mps: float, t: float) -> bool:
        """A platoon's follower may ask: its leader holds a plan (flown, or to be flown
        from its start), it is as far behind that plan as the ICA will ask of it (twice
        the margin behind where the leader was a headway ago), and either it stands (it
        can wait where it is) or the leader's plan goes through without standing short
        of the line (else its own stop law must first stop it behind the leader)."""
        lead, h, cfg = c.ahead, self.h, self.ica_cfg
        if lead is None or lead.plan_s is None:
            return False
        t = max(t, lead.plan_t0_s)  # judged from the leader's start if it is still to come
        k = max(round((t - lead.plan_t0_s) / h), 0)
        behind = round((cfg.headway_s + 2.0 * cfg.time_pad_s) / h)
        lagged = float(lead.plan_s[min(max(k - behind, 0), len(lead.plan_s) - 1)])
        if c.s_m > lagged - self.cfg.length_m - 2.0 * cfg.margin_m:
            return False
        if speed_mps <= 0.0:
            return True
        ahead = lead.plan_s[k:]
        ahead = ahead[: int(np.searchsorted(ahead, 0.0)) + 1]
        return bool(np.all(np.diff(ahead) > 1e-6))

    def _asks(self, c: Car) -> bool:
        """``c`` may ask for a plan (head of its lane, or following a leader that holds
        one, flown already or still to start): it moves by its stop law alone and never
        speeds up, so where it will be when its plan starts is predictable
        (:meth:`_intents`)."""
        return c.head or (
            self.ica_cfg.platoon and c.ahead is not None and c.ahead.plan_s is not None
        )

    def _drop(self, c: Car, seq: int) -> None:
        """Give up every plan up to ``seq`` (revoked), if the vehicle can still stop.

        A plan not yet begun is always dropped (the stop law drives the vehicle
        until then). One being flown is dropped only if the stop law, from here,
        keeps the front short of the entry line; otherwise the vehicle flies on
        (its reservation is still the ICA's to keep) and ``kept_seq`` says so.
        Either way a plan up to ``seq`` that arrives later is never taken, and a
        repeated drop changes nothing.
        """
        if c.plan_seq == NO_PLAN or c.plan_seq > seq:
            c.refused_seq = max(c.refused_seq, seq)
            return
        kin = self.ica_cfg.kinematics
        flying = self.t >= c.plan_t0_s - 1e-6
        stoppable = not flying or can_stop_short(
            -c.s_m,
            c.speed_mps,
            gap_m=kin.stop_gap_m,
            h=self.h,
            accel_mps2=kin.accel_mps2,
            decel_mps2=kin.decel_mps2,
        )
        follower = c.behind
        if follower is not None and _flying(follower, self.t):
            stoppable = False  # a platoon's follower flies behind it: it cannot stop for it
        if c.entered or c.exited or not stoppable:
            if c.kept_seq < c.plan_seq:
                c.kept_seq = c.plan_seq
                self.timing.kept += 1
            return
        c.refused_seq = max(c.refused_seq, seq)
        c.plan_seq, c.plan_s = NO_PLAN, None
        self.timing.dropped += 1

    def _obstacles(self) -> dict[str, float]:
        """For each vehicle short of the junction, the rear of the vehicle ahead of it
        on its lane [m, route position] (that vehicle may have begun to enter)."""
        lanes: dict[str, list[Car]] = {}
        for c in self.active:
            if c.vin in self._present and not c.entered and not math.isnan(c.s_m):
                lanes.setdefault(c.route.in_lane, []).append(c)
        out: dict[str, float] = {}
        length = self.cfg.length_m
        for lane, cars in lanes.items():
            cars.sort(key=lambda c: c.s_m)
            prev = self._last_in.get(lane)
            rear = prev.s_m - length if prev is not None and not prev.exited else math.inf
            for c in reversed(cars):
                out[c.vin] = rear
                rear = c.s_m - length
        return out

    def _intents(self, t: float) -> dict[str, np.ndarray]:
        """Where each vehicle short of the junction will be over the next
        ``predict_steps`` steps if no new plan reaches it [route positions, m, now
        first]: on its plan from the plan's start, before that (or without one) by its
        stop law, run step by step as :meth:`apply` runs it against the future of the
        vehicle ahead (for the front one, the last to enter from its lane).

        A vehicle that may ask is told its own (``Observation.intent_m``), so that a
        plan asked for ahead of time starts where it will really be: by the head's law
        alone, one that follows a moving leader would be planned from where it never
        gets, found off its plan's start and refused. A lane's prediction stops at a
        vehicle that SUMO's car-following drives (one that may not ask)."""
        n = self.predict_steps
        length = self.cfg.length_m
        lanes: dict[str, list[Car]] = {}
        for c in self.active:
            if c.vin in self._present and not c.entered and not math.isnan(c.s_m):
                lanes.setdefault(c.route.in_lane, []).append(c)
        out: dict[str, np.ndarray] = {}
        free = np.full(n + 1, math.inf)
        for lane, cars in lanes.items():
            cars.sort(key=lambda c: -c.s_m)
            prev = self._last_in.get(lane)
            ahead = free if prev is None or prev.exited else self._future(prev, t, free)
            for c in cars:
                if ahead is None:
                    break
                fut = self._future(c, t, ahead - length)
                if fut is not None:
                    out[c.vin] = fut
                ahead = fut
        return out

    def _future(self, c: Car, t: float, rear_m: np.ndarray) -> np.ndarray | None:
        """``c``'s positions now and after each of the next steps, behind a vehicle whose
        rear will be at ``rear_m``; None if its own driver is SUMO's car-following."""
        n, h = self.predict_steps, self.h
        kin = self.ica_cfg.kinematics
        plan = c.plan_s
        asks = self._asks(c)
        if plan is None and not asks:
            return None
        k0 = round((t - c.plan_t0_s) / h) if plan is not None else 0
        p = np.empty(n + 1)
        p[0], v = c.s_m, c.speed_mps
        for j in range(n):
            if plan is not None and k0 + j >= 0:  # the plan is flown from its start
                k = k0 + j + 1
                if k < len(plan):
                    p[j + 1] = plan[k]
                else:  # past its end: the last speed held
                    p[j + 1] = p[j] + (plan[-1] - plan[-2] if len(plan) > 1 else v * h)
                continue
            cap = min(c.entry_speed_mps, v) if asks else c.entry_speed_mps
            room = min(-p[j] - kin.stop_gap_m, rear_m[j] - p[j] - MIN_GAP_M)
            v = stop_speed(room, v, cap, h, kin.accel_mps2, kin.decel_mps2)
            p[j + 1] = p[j] + v * h
        return p

    def _stop_speed(self, c: Car, rear_ahead_m: float) -> float:
        """The vehicle's own law without a plan to fly: stop short of the entry line,
        and short of the rear of the vehicle ahead as it is now.

        The vehicle ahead only moves forward, so a vehicle that can always stop
        short of where it is now never hits it. The head of a lane (the one that
        asks) moves by this law alone and does not speed up, so what it asks for
        starts where the law predictably takes it; SUMO's car-following, which
        also brakes for slow vehicles far beyond the junction, is off for it.
        Behind the head, SUMO's car-following closes the queue up as drivers do.
        """
        kin = self.ica_cfg.kinematics
        cap = min(c.entry_speed_mps, c.speed_mps) if self._asks(c) else c.entry_speed_mps
        room = min(-c.s_m - kin.stop_gap_m, rear_ahead_m - c.s_m - MIN_GAP_M)
        return stop_speed(room, c.speed_mps, cap, self.h, kin.accel_mps2, kin.decel_mps2)

    def end_step(self, progress: Callable[[float, int, int], None] | None = None) -> None:
        """Check and log this step. Needs nothing from the drivers, so the cluster
        gateway runs it while the agents are deciding."""
        _observe(self.ls, self.monitor, self._watch, self.t)
        if self.t - self._last_sample >= 1.0 - 1e-9:
            generated = bisect.bisect_right(self._arrivals, self.t + 1e-9)
            self.log.sample(self.t, self.waiting, self.crossed, generated)
            self._last_sample = self.t
        if progress is not None:
            progress(self.t, self.waiting, self.crossed)

    def done(self) -> bool:
        if self.cfg.until_left:
            if self.crossed >= len(self.schedule):
                return True
            if self.t > 20.0 * len(self.schedule) + 600.0:
                raise RunError(
                    f"{len(self.schedule) - self.crossed} vehicles never left "
                    f"(stopped at t={self.t:.0f} s)"
                )
            return False
        return self.t >= self.horizon - 1e-9

    def result(self, requests: dict, cmd: list[str]) -> RunResult:
        end = self.t if self.cfg.until_left else self.horizon
        return RunResult(
            metrics=summarize(self.log, end),
            trips=self.log,
            safety=self.monitor.report().as_dict(),
            requests=requests,
            sumo_collisions=self.sumo_collisions,
            sim_time_s=self.t,
            wall_s=time.perf_counter() - self._t_wall,
            sumo_command=cmd,
            extra={
                "unconfirmed_entries": len(self.unconfirmed_entries),
                "timing": self.timing.as_dict(),
                "accounted": self.accounting(end),
            },
        )

    def accounting(self, end_s: float) -> dict[str, int]:
        """Where every vehicle due by ``end_s`` is: none may be lost."""
        out = {"generated": 0, "crossed": 0, "in_region": 0, "not_yet_in_region": 0, "lost": 0}
        for c in self.cars.values():
            trip = self.log.trips[c.vin]
            if trip.depart_s > end_s:
                continue
            out["generated"] += 1
            if c.exited:
                out["crossed"] += 1
            elif math.isnan(c.detected_s):
                out["not_yet_in_region"] += 1
            elif c.vin in self._present:
                out["in_region"] += 1
            else:
                out["lost"] += 1  # gone from SUMO without leaving the junction: never
        return out

    # -- insertion -------------------------------------------------------------
    def _add(self, c: Car, pos_m: float, speed_mps: float) -> None:
        self.ls.vehicle.add(
            c.vin,
            self._edge_routes[_edges(c.route)],
            typeID=EV_VTYPE if c.ev else VTYPE,
            depart="now",
            departLane=str(c.lane_index),
            departPos=str(pos_m),
            departSpeed=str(speed_mps),
        )

    def _join_queue(self, c: Car) -> None:
        """Place a vehicle SUMO had no room for at the entry line behind its lane's last one.

        It keeps SUMO's standstill gap and a second's headway behind the tail
        at the tail's speed (or its own, if lower). With no room left on the
        lane it waits at the lane's start, where SUMO inserts it when it can.
        """
        self.ls.vehicle.remove(c.vin)  # from SUMO's insertion queue
        entry = max(self._lane_len[c.route.in_lane] - self.inter.comm_length_m - 0.05, 0.0)
        tail = self._tails.get(c.route.in_lane)
        if tail is None:  # the blocker has left the lane already: the entry line again
            self._add(c, entry, c.entry_speed_mps)
            return
        pos, v_tail = tail
        v = min(c.entry_speed_mps, v_tail)
        behind = min(pos - self.cfg.length_m - MIN_GAP_M - HEADWAY_S * v - 0.5, entry)
        if behind < 0.0:
            self._add(c, 0.0, 0.0)
        else:
            self._add(c, behind, v)
            self._tails[c.route.in_lane] = (behind, v)  # the next one goes behind this one

    # -- bookkeeping -----------------------------------------------------------
    def _detect(self, c: Car, d: float, v: float, t: float) -> None:
        comm = self.inter.comm_length_m
        trip = self.log.trips[c.vin]
        trip.entered_s = t - (comm - d) / v if v > 0.1 else t
        c.detected_s = trip.entered_s
        trip.free_flow_s = self._free_flow_s(c.route, comm, v)

    def _free_flow_s(self, route: Route, comm_m: float, v_mps: float) -> float | None:
        """From the region's entry line at ``v_mps`` until fully out, alone at the junction."""
        length = self.cfg.length_m
        pl = Planner(
            comm_m,
            v_mps,
            self.ica_cfg.caps.road_mps,
            route.speed_cap_mps,
            route.cross_length_m + length,
            self.ica_cfg.kinematics,
        )
        p = pl.fastest()
        return p.time_at(route.cross_length_m + length) if p else None

    def _left_junction(self, vw: _Reads, c: Car, t: float) -> bool:
        """Rear past the exit line: note the time (interpolated) and mark the car exited."""
        if vw.getRoadID(c.vin) != _edges(c.route)[1]:
            return False
        over = vw.getLanePosition(c.vin) - self.cfg.length_m
        if over < 0:
            return False
        self.log.trips[c.vin].exited_s = t - over / max(vw.getSpeed(c.vin), 0.1)
        c.exited = True
        return True


@dataclass(slots=True)
class Timing:
    """How well the vehicles kept to their plans, as their actuators saw it."""

    accepted: int = 0  # plans taken before their start
    refused: int = 0  # plans never flown: arrived after their start, or found off it
    off_start: int = 0  # of those, found further than START_TOL_M off the plan at its start
    dropped: int = 0  # plans given up on a revocation (reactive DICA)
    kept: int = 0  # plans the vehicle was told to drop but flew on: it could not stop
    slack_s: list[float] = field(default_factory=list)  # plan start minus arrival [s]
    adherence_s: list[float] = field(default_factory=list)  # actual minus planned entry [s]
    worst: list[tuple[float, str, float, float]] = field(default_factory=list)

    def as_dict(self) -> dict:
        def pct(xs: list[float], q: float) -> float | None:
            return float(np.percentile(np.asarray(xs), q)) if xs else None

        adh = [abs(x) for x in self.adherence_s]
        return {
            "plans_accepted": self.accepted,
            "plans_refused": self.refused,
            "plans_refused_off_start": self.off_start,
            "plans_dropped": self.dropped,
            "plans_kept": self.kept,
            "plan_slack_p1_s": pct(self.slack_s, 1),
            "plan_slack_median_s": pct(self.slack_s, 50),
            "entry_adherence_p50_s": pct(adh, 50),
            "entry_adherence_p99_s": pct(adh, 99),
            "entry_adherence_max_s": max(adh) if adh else None,
            "entry_adherence_mean_signed_s": (
                float(np.mean(self.adherence_s)) if self.adherence_s else None
            ),
            "entry_adherence_worst": [
                {"vin": vin, "actual_s": round(a, 3), "planned_s": round(p, 3)}
                for _, vin, a, p in sorted(self.worst, reverse=True)[:5]
            ],
        }


def _flying(c: Car, t: float) -> bool:
    """The actuator flies a plan for ``c`` now (its start has come)."""
    return c.plan_s is not None and t >= c.plan_t0_s - 1e-6


def _rank(c: Car) -> float:
    """Position along the route for ordering drops, rearmost first."""
    return c.s_m if not math.isnan(c.s_m) else -math.inf


def _edges(r: Route) -> tuple[str, str]:
    return r.in_lane.rsplit("_", 1)[0], r.out_lane.rsplit("_", 1)[0]


class _Reads:
    """This step's lane, position, speed, road and odometer of every vehicle, from one
    SUMO call.

    Each vehicle is subscribed to those values when it departs; a vehicle
    missing from the results (not delivered yet) is read directly.
    """

    __slots__ = ("_ls", "_rows")

    def __init__(self, ls) -> None:
        self._ls = ls
        self._rows = ls.vehicle.getAllSubscriptionResults()

    @staticmethod
    def subscribe(ls, vin: str, xy: bool = False) -> None:
        c = ls.constants
        wanted = [c.VAR_LANE_ID, c.VAR_LANEPOSITION, c.VAR_SPEED, c.VAR_ROAD_ID, c.VAR_DISTANCE]
        ls.vehicle.subscribe(vin, wanted + ([c.VAR_POSITION, c.VAR_ANGLE] if xy else []))

    def _get(self, vin: str, var: int, direct):
        row = self._rows.get(vin)
        return row[var] if row is not None and var in row else direct(vin)

    def getLaneID(self, vin: str) -> str:
        return self._get(vin, self._ls.constants.VAR_LANE_ID, self._ls.vehicle.getLaneID)

    def getLanePosition(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_LANEPOSITION, self._ls.vehicle.getLanePosition)

    def getSpeed(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_SPEED, self._ls.vehicle.getSpeed)

    def getDistance(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_DISTANCE, self._ls.vehicle.getDistance)

    def getRoadID(self, vin: str) -> str:
        return self._get(vin, self._ls.constants.VAR_ROAD_ID, self._ls.vehicle.getRoadID)

    def getPosition(self, vin: str) -> tuple[float, float]:
        return self._get(vin, self._ls.constants.VAR_POSITION, self._ls.vehicle.getPosition)

    def getAngle(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_ANGLE, self._ls.vehicle.getAngle)


@dataclass(slots=True)
class _Watch:
    """What the monitor is fed: every vehicle within ``radius_m`` of the junction.

    SUMO hands these over in one call per step (a context subscription on the
    junction), positions and angles as it holds them. The monitor itself only
    checks vehicles touching the junction area plus its margin; the radius is
    well beyond that, so the cut changes no result. Sizes are read once per
    vehicle (they do not change).
    """

    junction_id: str
    radius_m: float
    sizes: dict[str, tuple[float, float]] = field(default_factory=dict)

    def subscribe(self, ls) -> None:
        c = ls.constants
        ls.junction.subscribeContext(
            self.junction_id,
            c.CMD_GET_VEHICLE_VARIABLE,
            self.radius_m,
            [c.VAR_POSITION, c.VAR_ANGLE],
        )


def _observe(ls, monitor: SafetyMonitor, watch: _Watch, t: float) -> None:
    c = ls.constants
    near = ls.junction.getContextSubscriptionResults(watch.junction_id) or {}
    vins = sorted(near)
    if not vins:
        monitor.observe(t, [], np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))
        return
    for v in vins:
        if v not in watch.sizes:
            watch.sizes[v] = (ls.vehicle.getLength(v), ls.vehicle.getWidth(v))
    xy = np.array([near[v][c.VAR_POSITION] for v in vins], dtype=float)
    ang = np.array([near[v][c.VAR_ANGLE] for v in vins], dtype=float)
    size = np.array([watch.sizes[v] for v in vins], dtype=float)
    monitor.observe(t, vins, xy, ang, size[:, 0], size[:, 1])
