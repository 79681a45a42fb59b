"""Embedded run: one process, SUMO through libsumo, the ICA core called directly.

Vehicles are inserted at the communication region's entry line at their
random entry speed and are detected there. An unconfirmed vehicle drives
under SUMO's own car following and brakes to stop before the entry line; the
head vehicle of each lane requests (again every ``retry_s`` after a
rejection). A confirmed vehicle flies its confirmed TSS exactly: speed mode 32
(SUMO's own checks off, so it does not yield inside the junction) and, each
step, the speed that carries it to the next sample. Once its rear has left the
junction SUMO takes over again.

Nothing here trusts the ICA for safety: every step the independent monitor
rebuilds rectangles from SUMO's own positions, and SUMO's junction collision
detection gives a second opinion.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ica.core.baselines import BASELINES, make_controller
from ica.core.config import ENHANCED, IcaConfig, Techniques
from ica.core.intersection import Intersection
from ica.core.planner import Planner
from ica.core.proposal import propose
from ica.core.request import Confirmation, RequestError
from ica.core.route import Route
from sim_gateway.metrics import Trip, TripLog, summarize
from sim_gateway.safety import SafetyMonitor
from sim_gateway.signals import retime
from tools.stream import StreamSpec, expected_lane_flows, make_vehicles

VTYPE = "cav"
LIGHTS = ("fixed", "actuated")  # SUMO drives; the junction is signalised
STOP_DECEL_MPS2 = 4.0  # [m/s^2] braking an unconfirmed vehicle plans with (below SUMO's 4.5)


class RunError(Exception):
    """A run that cannot start or cannot go on (bad input, SUMO refused)."""


@dataclass(frozen=True, slots=True)
class RunConfig:
    """One embedded run, as given on the command line (written beside the outputs)."""

    net_path: str
    junction_id: str
    algorithm: str = "enhanced"
    volume_per_10min: float = 300.0
    seed: int = 12
    duration_s: float = 600.0
    until_left: int | None = None
    margin_m: float = 0.25
    retry_s: float = 0.5
    length_m: float = 5.0
    width_m: float = 1.8
    sumo_args: tuple[str, ...] = ()
    tile_m: float = 1.0
    approach_weights: tuple[tuple[str, float], ...] = ()
    volume_end_per_10min: float | None = None
    ramp_s: float = 1200.0

    def __post_init__(self) -> None:
        if not 1.0 <= self.volume_per_10min <= 2000.0:
            raise RunError(
                f"volume {self.volume_per_10min:g} is out of range: 1 to 2000 vehicles per 10 min"
            )
        if self.duration_s <= 0:
            raise RunError("duration must be positive")
        if self.until_left is not None and self.until_left < 1:
            raise RunError("--until-left must be at least 1")
        if self.algorithm not in BASELINES + LIGHTS:
            try:
                Techniques.parse(self.algorithm)
            except ValueError:
                raise RunError(
                    f"unknown algorithm {self.algorithm!r}: use basic, enhanced, t1..t4 (t2+4), "
                    + ", ".join(BASELINES + LIGHTS)
                ) from None
        if self.volume_end_per_10min is not None and not 1.0 <= self.volume_end_per_10min <= 2000:
            raise RunError("--volume-end is out of range: 1 to 2000 vehicles per 10 min")
        if not 0.1 <= self.tile_m <= 10.0:
            raise RunError("--tile-size must be between 0.1 and 10 m")


@dataclass(slots=True)
class Car:
    vin: str
    route: Route
    lane_index: int
    entry_speed_mps: float
    state: str = "pending"  # pending, approaching, waiting, confirmed, exited
    seq: int = 0
    next_request_s: float = 0.0
    t0_s: float = 0.0
    speeds: np.ndarray | None = None


@dataclass(slots=True)
class RunResult:
    metrics: dict
    trips: TripLog
    safety: dict
    requests: dict
    sumo_collisions: int
    sim_time_s: float
    wall_s: float
    sumo_command: list[str] = field(default_factory=list)
    signal: dict | None = None


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


def run(
    cfg: RunConfig,
    inter: Intersection,
    progress: Callable[[float, int, int], None] | None = None,
) -> RunResult:
    """Run one simulation to the end and return its metrics and safety report."""
    ls = import_libsumo()

    light = cfg.algorithm in LIGHTS
    named = cfg.algorithm in BASELINES or light
    tech = ENHANCED if named else Techniques.parse(cfg.algorithm)
    ica_cfg = IcaConfig(techniques=tech, margin_m=cfg.margin_m)
    h = ica_cfg.step_s
    ica = make_controller("fifo" if light else cfg.algorithm, inter, ica_cfg, cfg.tile_m)
    peak = max(cfg.volume_per_10min, cfg.volume_end_per_10min or 0.0)
    # enough arrivals to outlast the horizon; the schedule is cut at the horizon below
    n = cfg.until_left or max(1, math.ceil(peak / 600.0 * cfg.duration_s * 2 + 20))
    spec = StreamSpec(
        volume_per_10min=cfg.volume_per_10min,
        n_vehicles=n,
        seed=cfg.seed,
        length_range_m=(cfg.length_m, cfg.length_m),
        width_range_m=(cfg.width_m, cfg.width_m),
        approach_weights=cfg.approach_weights,
        volume_end_per_10min=cfg.volume_end_per_10min,
        ramp_s=cfg.ramp_s,
    )
    try:
        schedule = make_vehicles(inter, spec, h)
    except ValueError as e:
        raise RunError(str(e)) from None
    horizon = math.inf if cfg.until_left else cfg.duration_s
    schedule = [v for v in schedule if v.arrival_s <= horizon]

    cmd = sumo_command(cfg.net_path, h, cfg.sumo_args)
    try:
        ls.start(cmd)
    except Exception as e:  # libsumo raises its own TraCIException or a plain error
        raise RunError(f"SUMO would not start: {e}") from None
    try:
        signal = _setup_signal(ls, cfg, inter, spec) if light else None
        result = _loop(ls, cfg, inter, ica, schedule, horizon, progress, cmd, light)
        result.signal = signal
        return result
    finally:
        ls.close()


def _setup_signal(ls, cfg: RunConfig, inter: Intersection, spec: StreamSpec) -> dict:
    """Check the junction is signalised; re-time a fixed program to the expected demand."""
    if inter.junction_id not in ls.trafficlight.getIDList():
        raise RunError(
            f"junction {inter.junction_id} has no traffic light; the light baselines need a "
            "signalised net (the built-in layouts are built with one automatically)"
        )
    tls = inter.junction_id
    logic = ls.trafficlight.getAllProgramLogics(tls)[0]
    if cfg.algorithm == "actuated":
        return {"type": "actuated", "phases": [(p.duration, p.state) for p in logic.phases]}
    links = ls.trafficlight.getControlledLinks(tls)
    link_lanes = [group[0][0] if group else "" for group in links]
    states = [p.state for p in logic.phases]
    durations, timing = retime(states, link_lanes, expected_lane_flows(inter, spec))
    for p, d in zip(logic.phases, durations, strict=True):
        p.duration = p.minDur = p.maxDur = d
    ls.trafficlight.setProgramLogic(tls, logic)
    ls.trafficlight.setProgram(tls, logic.programID)
    return {
        "type": "fixed",
        "cycle_s": timing.cycle_s,
        "flow_ratio_sum": timing.flow_ratio_sum,
        "phases": list(zip(durations, states, strict=True)),
    }


def _loop(ls, cfg, inter, ica, schedule, horizon, progress, cmd, light) -> RunResult:
    h = ica.config.step_s
    comm = inter.comm_length_m
    ls.vehicletype.copy("DEFAULT_VEHTYPE", VTYPE)
    for setter, value in (
        ("setLength", cfg.length_m),
        ("setWidth", cfg.width_m),
        ("setAccel", ica.config.kinematics.accel_mps2),
        ("setDecel", ica.config.kinematics.decel_mps2),
        ("setEmergencyDecel", 9.0),
        ("setMaxSpeed", ica.config.caps.road_mps),
        ("setMinGap", 2.5),
        ("setImperfection", 0.0),
    ):
        getattr(ls.vehicletype, setter)(VTYPE, value)
    edge_routes: dict[tuple[str, str], str] = {}
    for r in inter.routes:
        key = (r.in_lane.rsplit("_", 1)[0], r.out_lane.rsplit("_", 1)[0])
        if key not in edge_routes:
            edge_routes[key] = f"r_{key[0]}_{key[1]}"
            ls.route.add(edge_routes[key], list(key))
    lane_len = {lane: ls.lane.getLength(lane) for lane in inter.in_lanes}

    log = TripLog()
    cars: dict[str, Car] = {}
    for v in schedule:
        cars[v.vin] = Car(v.vin, v.route, int(v.route.in_lane.rsplit("_", 1)[1]), v.speed_mps)
        log.trips[v.vin] = Trip(v.vin, v.route.id, v.route.turn.value, v.arrival_s)
    monitor = SafetyMonitor(inter.region, watch_margin_m=2.0)
    junction_xy = np.asarray(ls.junction.getPosition(inter.junction_id))
    reach = float(np.max(np.linalg.norm(inter.region - junction_xy, axis=1)))
    # a rectangle can touch the watched area only if its front is within its length of it
    watch = _Watch(inter.junction_id, reach + 2.0 + cfg.length_m + 1.0)
    watch.subscribe(ls)
    compute: list[float] = []
    rejections: dict[str, int] = {}
    sumo_collisions = 0
    crossed = 0
    next_car = 0
    active: list[Car] = []
    t_wall = time.perf_counter()
    t = 0.0
    last_sample = -1.0

    while True:
        while next_car < len(schedule) and schedule[next_car].arrival_s <= t + 1e-9:
            c = cars[schedule[next_car].vin]
            ln = lane_len[c.route.in_lane]
            key = (c.route.in_lane.rsplit("_", 1)[0], c.route.out_lane.rsplit("_", 1)[0])
            ls.vehicle.add(
                c.vin,
                edge_routes[key],
                typeID=VTYPE,
                depart="now",
                departLane=str(c.lane_index),
                departPos=str(max(ln - comm - 0.05, 0.0)),
                departSpeed=str(c.entry_speed_mps),
            )
            c.state = "approaching"
            active.append(c)
            next_car += 1

        ls.simulation.step()
        t = ls.simulation.getTime()
        sumo_collisions += len(ls.simulation.getCollisions())
        ica.advance(t)
        present = set(ls.vehicle.getIDList())
        for vid in ls.simulation.getDepartedIDList():
            ls.vehicle.setLaneChangeMode(vid, 0)
            _Reads.subscribe(ls, vid)
        vw = _Reads(ls)

        waiting = 0
        for c in active:
            if c.vin not in present:
                continue
            if c.state == "approaching":
                lane = vw.getLaneID(c.vin)
                d = lane_len.get(lane, math.inf) - vw.getLanePosition(c.vin)
                if lane == c.route.in_lane and d <= comm:
                    v = vw.getSpeed(c.vin)
                    trip = log.trips[c.vin]
                    trip.entered_s = t - (comm - d) / v if v > 0.1 else t
                    ica.detect(c.vin, c.route.in_lane, trip.entered_s)
                    pl = Planner(
                        comm,
                        v,
                        ica.config.caps.road_mps,
                        c.route.speed_cap_mps,
                        c.route.cross_length_m + cfg.length_m,
                        ica.config.kinematics,
                    )
                    p = pl.fastest()
                    trip.free_flow_s = (
                        p.time_at(c.route.cross_length_m + cfg.length_m) if p else None
                    )
                    c.state = "free" if light else "waiting"
            if c.state in ("free", "waiting", "confirmed") and vw.getSpeed(c.vin) < 0.1:
                log.trips[c.vin].stopped = True  # stopped in the region before leaving
                waiting += 1
            if c.state == "free":  # a signalised junction: SUMO drives
                if _left_junction(vw, c, t, cfg, log):
                    crossed += 1
                continue
            if c.state == "waiting":
                _drive_waiting(ls, vw, ica, c, t, lane_len, log, compute, rejections, cfg)
            if c.state == "confirmed":
                _drive_confirmed(ls, vw, c, t, h, cfg, log)
                if c.state == "exited":
                    crossed += 1
        # a car SUMO has not inserted yet (its spot is taken) stays tracked
        active = [
            c
            for c in active
            if c.state != "exited" and (c.vin in present or c.state == "approaching")
        ]

        _observe(ls, monitor, watch, t)
        if t - last_sample >= 1.0 - 1e-9:
            log.sample(t, waiting, crossed, next_car)
            last_sample = t
        if progress is not None:
            progress(t, waiting, crossed)
        if cfg.until_left:
            if crossed >= len(schedule):
                break
            if t > 20.0 * len(schedule) + 600.0:
                raise RunError(
                    f"{len(schedule) - crossed} vehicles never left (stopped at t={t:.0f} s)"
                )
        elif t >= horizon - 1e-9:
            break

    end = t if cfg.until_left else horizon
    rt = np.array(compute) if compute else np.zeros(1)
    return RunResult(
        metrics=summarize(log, end),
        trips=log,
        safety=monitor.report().as_dict(),
        requests={
            "count": len(compute),
            "rejections": rejections,
            "median_ms": float(np.median(rt) * 1e3),
            "p99_ms": float(np.percentile(rt, 99) * 1e3),
        },
        sumo_collisions=sumo_collisions,
        sim_time_s=t,
        wall_s=time.perf_counter() - t_wall,
        sumo_command=cmd,
    )


def _drive_waiting(ls, vw, ica, c: Car, t, lane_len, log, compute, rejections, cfg) -> None:
    """Unconfirmed in the region: ask when head, else brake to stop before the line."""
    ln = lane_len[c.route.in_lane]
    pos = vw.getLanePosition(c.vin)
    d = ln - pos
    v = vw.getSpeed(c.vin)
    if t >= c.next_request_s and ica.is_head(c.vin, t):
        try:
            req = propose(
                c.route,
                vin=c.vin,
                seq=c.seq,
                t0_s=t,
                dist_to_entry_m=max(d, 0.0),
                speed_mps=v,
                length_m=cfg.length_m,
                width_m=cfg.width_m,
                config=ica.config,
            )
            t_c = time.perf_counter()
            answer = ica.handle(req, t)
            compute.append(time.perf_counter() - t_c)
        except RequestError as e:
            answer = e
        c.seq += 1
        if isinstance(answer, Confirmation):
            tss = answer.tss
            s, _ = c.route.project(np.stack([tss.x_m, tss.y_m], -1))
            c.speeds = np.diff(np.maximum.accumulate(s)) / ica.config.step_s
            c.t0_s = float(tss.t_s[0])
            c.state = "confirmed"
            log.trips[c.vin].confirmed_s = t
            ls.vehicle.setSpeedMode(c.vin, 32)
            _drive_confirmed(ls, vw, c, t, ica.config.step_s, cfg, log)
            return
        reason = getattr(answer, "reason", None)
        key = reason.value if reason is not None else "error"
        rejections[key] = rejections.get(key, 0) + 1
        c.next_request_s = t + cfg.retry_s
    # brake so that the front stops before the entry line (SUMO's own discrete stop rule)
    gap = ica.config.kinematics.stop_gap_m
    room = max(d - gap, 0.0)
    b = STOP_DECEL_MPS2
    h = ica.config.step_s
    v_stop = math.sqrt(2 * b * room + (b * h / 2) ** 2) - b * h / 2
    ls.vehicle.setSpeed(c.vin, max(0.0, min(c.entry_speed_mps, v_stop, room / h)))


def _left_junction(vw, c: Car, t, cfg, log) -> bool:
    """Rear past the exit line: note the time (interpolated) and mark the car exited."""
    if vw.getRoadID(c.vin) != c.route.out_lane.rsplit("_", 1)[0]:
        return False
    over = vw.getLanePosition(c.vin) - cfg.length_m
    if over < 0:
        return False
    log.trips[c.vin].exited_s = t - over / max(vw.getSpeed(c.vin), 0.1)
    c.state = "exited"
    return True


def _drive_confirmed(ls, vw, c: Car, t, h, cfg, log) -> None:
    """Fly the confirmed TSS: the speed that reaches the next sample; release once out."""
    if _left_junction(vw, c, t, cfg, log):
        ls.vehicle.setSpeedMode(c.vin, 31)
        ls.vehicle.setSpeed(c.vin, -1)
        return
    k = round((t - c.t0_s) / h)
    speeds = c.speeds
    ls.vehicle.setSpeed(c.vin, float(speeds[min(max(k, 0), len(speeds) - 1)]))


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
    def subscribe(ls, vin: str) -> None:
        c = ls.constants
        ls.vehicle.subscribe(vin, [c.VAR_LANE_ID, c.VAR_LANEPOSITION, c.VAR_SPEED, c.VAR_ROAD_ID])

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


def write_outputs(out: Path, cfg: RunConfig, result: RunResult) -> None:
    """metrics.json, vehicles.csv, timeseries.csv and the configuration actually used."""
    import csv
    import dataclasses
    import json

    out.mkdir(parents=True, exist_ok=True)
    metrics = dict(result.metrics)
    metrics["collisions"] = result.safety["overlaps"]
    metrics["min_gap_m"] = result.safety["min_gap_m"]
    metrics["sumo_collisions"] = result.sumo_collisions
    metrics["requests"] = result.requests
    metrics["safety"] = result.safety
    metrics["sim_time_s"] = result.sim_time_s
    metrics["wall_s"] = result.wall_s
    metrics["real_time_factor"] = result.sim_time_s / result.wall_s if result.wall_s > 0 else None
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    config = {
        "run": dataclasses.asdict(cfg),
        "sumo_command": result.sumo_command,
        "signal": result.signal,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2, default=list))
    with (out / "vehicles.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "vin",
                "route",
                "turn",
                "depart_s",
                "entered_s",
                "confirmed_s",
                "exited_s",
                "trip_time_s",
                "free_flow_s",
                "stopped",
            ]
        )
        for tr in result.trips.trips.values():
            tau = tr.exited_s - tr.entered_s if tr.exited_s and tr.entered_s is not None else None
            w.writerow(
                [
                    tr.vin,
                    tr.route_id,
                    tr.turn,
                    f"{tr.depart_s:.2f}",
                    _f(tr.entered_s),
                    _f(tr.confirmed_s),
                    _f(tr.exited_s),
                    _f(tau),
                    _f(tr.free_flow_s),
                    int(tr.stopped),
                ]
            )
    with (out / "timeseries.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "waiting", "crossed", "generated", "flow_ratio"])
        log = result.trips
        for row in zip(log.t_s, log.waiting, log.crossed_cum, log.generated_cum, strict=True):
            ratio = f"{row[2] / row[3]:.4f}" if row[3] else ""
            w.writerow([f"{row[0]:.2f}", *row[1:], ratio])


def _f(x: float | None) -> str:
    return "" if x is None else f"{x:.3f}"
