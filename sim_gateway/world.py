"""The SUMO side of a run, shared by the embedded runner and the cluster gateway.

The world inserts the scheduled vehicles at the communication region's entry
line, steps SUMO, notes each vehicle's detection and exit, observes it for its
driver, applies the drivers' commands, and feeds the independent safety
monitor and the trip log. Who decides the commands (vehicle machines in this
process, or vehicle-agent processes over Zenoh) is not its business, so both
modes measure and check with exactly this code.

Nothing here trusts the ICA for safety: every step the monitor rebuilds
rectangles from SUMO's own positions, and SUMO's junction collision detection
gives a second opinion.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from ica.core.config import IcaConfig
from ica.core.intersection import Intersection
from ica.core.planner import Planner
from ica.core.route import Route
from sim_gateway.demand import Arrival
from sim_gateway.metrics import Trip, TripLog, summarize
from sim_gateway.runconfig import RunConfig, RunError, RunResult
from sim_gateway.safety import SafetyMonitor
from vehicle_agent.machine import MODE_CONFIRMED, RELEASE, Command, Observation

VTYPE = "cav"
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
    command: Command | None = None
    speed_mode: int = -1
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
        self.log = TripLog()
        self.cars: dict[str, Car] = {}
        self.active: list[Car] = []
        self.t = 0.0
        self.crossed = 0
        self.waiting = 0
        self.sumo_collisions = 0
        self.unconfirmed_entries: list[str] = []
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
        for v in self.schedule:
            lane_index = int(v.route.in_lane.rsplit("_", 1)[1])
            self.cars[v.vin] = Car(v.vin, v.route, lane_index, v.speed_mps)
            self.log.trips[v.vin] = Trip(v.vin, v.route.id, v.route.turn.value, v.arrival_s)
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
        while self._next < len(self.schedule) and self.schedule[self._next].arrival_s <= (
            self.t + 1e-9
        ):
            arrival = self.schedule[self._next]
            c = self.cars[arrival.vin]
            ln = self._lane_len[c.route.in_lane]
            # an EV candidate is an EV only if no other EV is in the region (inserted, not out)
            c.ev = arrival.ev and not any(o.ev and not o.exited for o in self.active)
            self.log.trips[c.vin].ev = c.ev
            ls.vehicle.add(
                c.vin,
                self._edge_routes[_edges(c.route)],
                typeID=EV_VTYPE if c.ev else VTYPE,
                depart="now",
                departLane=str(c.lane_index),
                departPos=str(max(ln - comm - 0.05, 0.0)),
                departSpeed=str(c.entry_speed_mps),
            )
            self.active.append(c)
            self._next += 1

        ls.simulation.step()
        t = self.t = ls.simulation.getTime()
        self.sumo_collisions += len(ls.simulation.getCollisions())
        present = set(ls.vehicle.getIDList())
        for vid in ls.simulation.getDepartedIDList():
            ls.vehicle.setLaneChangeMode(vid, 0)
            _Reads.subscribe(ls, vid, self.want_xy)
        vw = _Reads(ls)

        heads: dict[str, tuple[float, str]] = {}
        for c in self.active:
            if c.vin in present and vw.getLaneID(c.vin) == c.route.in_lane:
                pos = vw.getLanePosition(c.vin)
                if c.route.in_lane not in heads or pos > heads[c.route.in_lane][0]:
                    heads[c.route.in_lane] = (pos, c.vin)

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
                else:
                    continue
            if not c.entered and lane != c.route.in_lane:
                c.entered = True  # the front is past the entry line
                if not self.signalised and c.speed_mode != MODE_CONFIRMED:
                    self.unconfirmed_entries.append(c.vin)  # never: the vehicles must stop
            speed = vw.getSpeed(c.vin)
            if speed < 0.1:
                self.log.trips[c.vin].stopped = True  # stopped in the region before leaving
                self.waiting += 1
            if self._left_junction(vw, c, t):
                self.crossed += 1
            d = self._lane_len[c.route.in_lane] - vw.getLanePosition(c.vin)
            obs = Observation(
                t_s=t,
                lane=lane,
                dist_to_entry_m=d if lane == c.route.in_lane else -1.0,
                speed_mps=speed,
                head=heads.get(c.route.in_lane, (0.0, ""))[1] == c.vin,
                detected_s=c.detected_s,
                exited=c.exited,
            )
            seen.append(Seen(c, obs))
        if self.want_xy:
            for s in seen:
                s.xy = vw.getPosition(s.car.vin)
                s.angle_deg = vw.getAngle(s.car.vin)
        self._present = present
        return seen

    def apply(self, commands: Iterable[Command]) -> None:
        """Take the drivers' new commands; every commanded vehicle gets its speed for now."""
        ls = self.ls
        for cmd in commands:
            c = self.cars.get(cmd.vin)
            if c is None or len(cmd.speeds) == 0:
                continue
            if cmd.speed_mode >= 0 and cmd.speed_mode != c.speed_mode:
                ls.vehicle.setSpeedMode(c.vin, cmd.speed_mode)
                c.speed_mode = cmd.speed_mode
                trip = self.log.trips[c.vin]
                if cmd.speed_mode == MODE_CONFIRMED and trip.confirmed_s is None:
                    trip.confirmed_s = self.t
            c.command = cmd
        for c in self.active:
            cmd = c.command
            if cmd is None or c.vin not in self._present:
                continue
            k = round((self.t - cmd.t0_s) / self.h)
            v = float(cmd.speeds[min(max(k, 0), len(cmd.speeds) - 1)])
            ls.vehicle.setSpeed(c.vin, v)
            if v == RELEASE:
                c.command = None

    def end_step(self, progress: Callable[[float, int, int], None] | None = None) -> None:
        """Check and log this step. Needs nothing from the drivers, so the cluster
        gateway runs it while the agents are deciding."""
        _observe(self.ls, self.monitor, self._watch, self.t)
        if self.t - self._last_sample >= 1.0 - 1e-9:
            self.log.sample(self.t, self.waiting, self.crossed, self._next)
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
            extra={"unconfirmed_entries": len(self.unconfirmed_entries)},
        )

    # -- bookkeeping -----------------------------------------------------------
    def _detect(self, c: Car, d: float, v: float, t: float) -> None:
        comm = self.inter.comm_length_m
        trip = self.log.trips[c.vin]
        trip.entered_s = t - (comm - d) / v if v > 0.1 else t
        c.detected_s = trip.entered_s
        length = self.cfg.length_m
        pl = Planner(
            comm,
            v,
            self.ica_cfg.caps.road_mps,
            c.route.speed_cap_mps,
            c.route.cross_length_m + length,
            self.ica_cfg.kinematics,
        )
        p = pl.fastest()
        trip.free_flow_s = p.time_at(c.route.cross_length_m + length) if p else None

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


def _edges(r: Route) -> tuple[str, str]:
    return r.in_lane.rsplit("_", 1)[0], r.out_lane.rsplit("_", 1)[0]


class _Reads:
    """This step's lane, position, speed and road of every vehicle, from one SUMO call.

    Each vehicle is subscribed to those four values when it departs; a vehicle
    missing from the results (not delivered yet) is read directly.
    """

    __slots__ = ("_ls", "_rows")

    def __init__(self, ls) -> None:
        self._ls = ls
        self._rows = ls.vehicle.getAllSubscriptionResults()

    @staticmethod
    def subscribe(ls, vin: str, xy: bool = False) -> None:
        c = ls.constants
        wanted = [c.VAR_LANE_ID, c.VAR_LANEPOSITION, c.VAR_SPEED, c.VAR_ROAD_ID]
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
