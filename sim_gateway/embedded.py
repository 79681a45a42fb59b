"""Embedded run: one process, SUMO through libsumo, the ICA core called directly.

The world (:mod:`sim_gateway.world`) is the same as the cluster gateway's; the
vehicles are the same state machines as in a vehicle-agent process
(:mod:`vehicle_agent.machine`), and they reach the ICA core by a direct call
instead of a Zenoh query. It is the fast default for experiments.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ica.core.baselines import controller_config, make_controller
from ica.core.config import IcaConfig
from ica.core.dica import Dica
from ica.core.intersection import Intersection
from ica.core.request import Confirmation, Rejection, Request, RequestError
from sim_gateway.demand import DemandSpec, expected_lane_flows, make_arrivals
from sim_gateway.runconfig import LIGHTS, RunConfig, RunError, RunResult
from sim_gateway.signals import retime
from sim_gateway.world import Seen, World, import_libsumo, start_sumo
from vehicle_agent.machine import Command, Vehicle

__all__ = ["LIGHTS", "RunConfig", "RunError", "RunResult", "run", "schedule_for"]


class LocalLink:
    """A vehicle's link to an ICA in the same process: a direct, timed call."""

    def __init__(self, ica: Dica) -> None:
        self.ica = ica
        self.compute_s: list[float] = []

    def detect(self, vin: str, lane: str, t_s: float) -> Rejection | None:
        try:
            self.ica.detect(vin, lane, t_s)
        except RequestError as e:
            return Rejection(vin, -1, e.reason, e.detail)
        return None

    def request(self, req: Request, now_s: float) -> Confirmation | Rejection:
        t_c = time.perf_counter()
        answer = self.ica.handle(req, now_s)
        self.compute_s.append(time.perf_counter() - t_c)
        return answer

    def cancel(self, vin: str, seq: int) -> None:
        self.ica.cancel(vin, seq)


class LocalDrivers:
    """The vehicles' machines, all in this process, with the ICA beside them."""

    def __init__(self, ica: Dica, cfg: RunConfig) -> None:
        self.ica = ica
        self.cfg = cfg
        self.link = LocalLink(ica)
        self.vehicles: dict[str, Vehicle] = {}
        self.rejections: dict[str, int] = {}
        self.recorded: set[str] = set()  # VINs whose confirmation is in the recording

    def step(self, t: float, seen: list[Seen]) -> list[Command]:
        self.ica.advance(t)
        out = []
        for s in seen:
            v = self.vehicles.get(s.car.vin)
            if v is None:
                c = s.car
                v = Vehicle(
                    c.vin,
                    c.route,
                    self.cfg.length_m,
                    self.cfg.width_m,
                    c.entry_speed_mps,
                    self.ica.config,
                    self.cfg.retry_s,
                    lead_s=self.cfg.lead_s,
                )
                v.rejections = self.rejections  # one tally for the run
                self.vehicles[c.vin] = v
            cmd = v.step(s.obs, self.link)
            if cmd is not None:
                out.append(cmd)
            if s.obs.exited:
                del self.vehicles[s.car.vin]
        return out

    def requests(self) -> dict:
        rt = np.array(self.link.compute_s) if self.link.compute_s else np.zeros(1)
        return {
            "count": len(self.link.compute_s),
            "rejections": dict(self.rejections),
            "median_ms": float(np.median(rt) * 1e3),
            "p99_ms": float(np.percentile(rt, 99) * 1e3),
        }


def schedule_for(cfg: RunConfig, inter: Intersection, step_s: float):
    """The vehicles of this run in arrival order, cut at the horizon; and its stream spec."""
    peak = max(cfg.volume_per_10min, cfg.volume_end_per_10min or 0.0)
    # enough arrivals to outlast the horizon; the schedule is cut at the horizon below
    n = cfg.until_left or max(1, math.ceil(peak / 600.0 * cfg.duration_s * 2 + 20))
    spec = DemandSpec(
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
        schedule = make_arrivals(inter, spec, step_s)
    except ValueError as e:
        raise RunError(str(e)) from None
    horizon = math.inf if cfg.until_left else cfg.duration_s
    return [v for v in schedule if v.arrival_s <= horizon], spec, horizon


def ica_config(cfg: RunConfig) -> IcaConfig:
    return controller_config(cfg.algorithm, cfg.margin_m, cfg.time_pad_s)


def run(
    cfg: RunConfig,
    inter: Intersection,
    progress: Callable[[float, int, int], None] | None = None,
    rrd_path: Path | None = None,
) -> RunResult:
    """Run one simulation to the end and return its metrics and safety report.

    With ``rrd_path`` the run is also recorded as Rerun space-time visuals
    (the same recorder the cluster's observer uses).
    """
    ls = import_libsumo()
    light = cfg.algorithm in LIGHTS
    ica_cfg = ica_config(cfg)
    ica = make_controller("fifo" if light else cfg.algorithm, inter, ica_cfg, cfg.tile_m)
    schedule, spec, horizon = schedule_for(cfg, inter, ica_cfg.step_s)
    cmd = start_sumo(ls, cfg, ica_cfg.step_s)
    try:
        signal = _setup_signal(ls, cfg, inter, spec) if light else None
        recorder = _recorder(inter, rrd_path)
        world = World(
            ls, cfg, inter, ica_cfg, schedule, horizon, signalised=light, want_xy=bool(recorder)
        )
        drivers = LocalDrivers(ica, cfg)
        try:
            while True:
                seen = world.step()
                if not light:
                    world.apply(drivers.step(world.t, seen))
                if recorder is not None:
                    _record(recorder, drivers, seen, cfg, world.t)
                world.end_step(progress)
                if world.done():
                    break
        finally:
            if recorder is not None:
                recorder.close()
        result = world.result(drivers.requests(), cmd)
        result.signal = signal
        return result
    finally:
        ls.close()


def _recorder(inter: Intersection, rrd_path: Path | None):
    if rrd_path is None:
        return None
    from sim_gateway.recording import SpaceTimeRecorder

    try:
        rec = SpaceTimeRecorder(inter, rrd_path)
    except OSError as e:
        raise RunError(f"cannot write {rrd_path}: {e}") from None
    rec.geometry()
    return _Recording(rec)


class _Recording:
    """The recorder and what it has already been told: confirmations, rejections."""

    def __init__(self, rec) -> None:
        self.rec = rec
        self.wake: dict[str, float] = {}  # when each vehicle may ask again, as last seen
        self.tally: dict[str, int] = {}  # rejections per reason, as last seen

    def close(self) -> None:
        self.rec.close()


def _record(
    r: _Recording, drivers: LocalDrivers, seen: list[Seen], cfg: RunConfig, t: float
) -> None:
    """This step's new confirmations and rejections, and every observed vehicle's footprint."""
    rec = r.rec
    rejected = []
    for s in seen:
        v = drivers.vehicles.get(s.car.vin)
        if v is None:
            continue
        conf = v.confirmation
        if conf is not None and s.car.vin not in drivers.recorded:
            drivers.recorded.add(s.car.vin)
            tss = conf.tss
            rec.confirmed(
                conf.vin,
                conf.route_id,
                tss.t_s,
                tss.x_m,
                tss.y_m,
                tss.heading_rad,
                cfg.length_m,
                cfg.width_m,
                conf.entry_time_s,
                conf.exit_time_s,
                now_s=s.obs.t_s,
                delay_s=conf.delay_s,
                rounds=conf.iterations,
                margin_m=cfg.margin_m,
                time_pad_s=cfg.time_pad_s,
            )
        elif conf is None and v.next_request_s != r.wake.get(v.vin, v.next_request_s):
            rejected.append(v.vin)  # told to wait: its request was answered with a no
        r.wake[v.vin] = v.next_request_s
    if drivers.rejections != r.tally:
        new = {k: n - r.tally.get(k, 0) for k, n in drivers.rejections.items()}
        reasons = [k for k, n in new.items() if n > 0]
        r.tally = dict(drivers.rejections)
        for vin in rejected or ["-"]:
            rec.rejected(t, vin, "/".join(reasons))
    rec.footprints(
        t,
        [s.car.vin for s in seen],
        np.array([s.xy[0] for s in seen]),
        np.array([s.xy[1] for s in seen]),
        np.array([s.angle_deg for s in seen]),
        cfg.length_m,
        cfg.width_m,
        route_ids=[s.car.route.id for s in seen],
    )


def _setup_signal(ls, cfg: RunConfig, inter: Intersection, spec: DemandSpec) -> dict:
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
