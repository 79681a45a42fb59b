"""Streams of REQUESTs through the DICA core, without a traffic simulator.

Vehicles arrive at random (Poisson, so that the expected count matches the
volume), cross the communication region's entry line, and request when they
become head of their lane, from a plausible state: at the region's entry if
the lane was free, else queued behind the vehicle ahead. A rejected vehicle
stops at the line and asks again a second later. This drives the pure core
hard and reproducibly for property tests, the liveness test and benchmarks;
SUMO runs come on top of the same core.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.controller import Controller, ControllerSpec, build_controller
from dica.ica.core.intersection import Intersection
from dica.ica.core.planner import Planner
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Reason, Rejection, Request, RequestError
from dica.ica.core.route import Route
from dica.sim_gateway.audit import Flown
from dica.sim_gateway.demand import DemandSpec, make_arrivals

QUEUE_SPACING_M = 2.5  # [m] standstill gap behind the vehicle ahead

StreamSpec = DemandSpec  # a stream's vehicles are the simulation's demand, without SUMO


@dataclass(slots=True)
class Vehicle:
    vin: str
    route: Route
    arrival_s: float
    speed_mps: float
    length_m: float
    width_m: float
    seq: int = 0
    earliest_entry_s: float = math.nan
    stop_entry_s: float = math.nan
    busy_until_s: float = -math.inf  # latest end of the confirmed set at its request
    confirmation: Confirmation | None = None
    rejections: list[Reason] = field(default_factory=list)


@dataclass(slots=True)
class StreamResult:
    vehicles: list[Vehicle]
    request_times_s: list[float]  # wall time of each handle() call
    rejections: dict[str, int]
    sim_end_s: float

    @property
    def confirmed(self) -> list[Vehicle]:
        return [v for v in self.vehicles if v.confirmation is not None]

    def summary(self) -> dict[str, float | int | dict[str, int]]:
        conf = self.confirmed
        delays = np.array([v.confirmation.delay_s for v in conf]) if conf else np.zeros(1)
        waits = (
            np.array([v.confirmation.entry_time_s - v.arrival_s for v in conf])
            if conf
            else np.zeros(1)
        )
        rt = np.array(self.request_times_s) if self.request_times_s else np.zeros(1)
        return {
            "generated": len(self.vehicles),
            "confirmed": len(conf),
            "requests": len(self.request_times_s),
            "rejections": dict(self.rejections),
            "mean_delay_s": float(delays.mean()),
            "max_delay_s": float(delays.max()),
            "mean_arrival_to_entry_s": float(waits.mean()),
            "max_arrival_to_entry_s": float(waits.max()),
            "request_median_ms": float(np.median(rt) * 1e3),
            "request_p99_ms": float(np.percentile(rt, 99) * 1e3),
            "sim_end_s": self.sim_end_s,
        }


def _ceil_step(t: float, step_s: float) -> float:
    return math.ceil(t / step_s - 1e-9) * step_s


def run_stream(
    inter: Intersection,
    config: IcaConfig,
    spec: StreamSpec,
    *,
    progress: Callable[[int], None] | None = None,
    before_request: Callable[[Controller, Request, float], None] | None = None,
    controller: str | None = None,
    tile_m: float = 1.0,
) -> StreamResult:
    """Feed a stream through one controller until every vehicle is confirmed.

    ``controller`` names a baseline (fifo, concurrent, tiles); by default the
    DICA variant of ``config`` decides.
    """
    ica = build_controller(ControllerSpec(controller or "dica", config, tile_m), inter)
    h = config.step_s
    vehicles = [
        Vehicle(a.vin, a.route, a.arrival_s, a.speed_mps, a.length_m, a.width_m)
        for a in make_arrivals(inter, spec, h)
    ]
    by_vin = {v.vin: v for v in vehicles}
    lanes: dict[str, list[Vehicle]] = {}
    events: list[tuple[float, float, str, str]] = []  # (time, arrival, kind, vin)
    for v in vehicles:
        heapq.heappush(events, (v.arrival_s, v.arrival_s, "arrive", v.vin))
    rejections: dict[str, int] = {}
    request_times: list[float] = []
    now = 0.0

    lane_tail: dict[str, Vehicle] = {}  # last confirmed vehicle per lane

    def lead_s(lead: Vehicle) -> np.ndarray:
        tss = lead.confirmation.tss
        s, _ = lead.route.project(np.stack([tss.x_m, tss.y_m], -1))
        return s

    def free_at(lead: Vehicle) -> float:
        """When the vehicle behind ``lead`` becomes head of the lane."""
        return max(_ceil_step(lead.confirmation.entry_time_s, h), now)

    def state_at(v: Vehicle, t: float, queued: bool) -> tuple[float, float]:
        """Where a vehicle plausibly is when it becomes head at time t."""
        comm = inter.comm_length_m
        if v.rejections:  # stopped at the line, or behind the vehicle ahead
            d = config.kinematics.stop_gap_m
            lead = lane_tail.get(v.route.in_lane)
            if lead is not None:
                s_lead = float(np.interp(t, lead.confirmation.tss.t_s, lead_s(lead)))
                d = max(d, lead.length_m - s_lead + QUEUE_SPACING_M)
            return min(d, comm), 0.0
        if not queued:
            return comm, v.speed_mps
        travelled = v.speed_mps * (t - v.arrival_s)
        d = comm - travelled
        floor = v.length_m + QUEUE_SPACING_M
        if d <= floor:
            return floor, 0.0
        # still rolling: slow enough to stop before the queue ahead
        v_max = math.sqrt(2 * config.kinematics.decel_mps2 * (d - floor))
        return d, min(v.speed_mps, v_max)

    def ask(v: Vehicle, queued: bool) -> None:
        d, speed = state_at(v, now, queued)
        _request(ica, v, now, d, speed, config, events, rejections, request_times, before_request)
        if v.confirmation is None:
            return
        lane = lanes[v.route.in_lane]
        lane.pop(0)
        lane_tail[v.route.in_lane] = v
        if lane:
            heapq.heappush(events, (free_at(v), lane[0].arrival_s, "head", lane[0].vin))
        if progress is not None:
            progress(1)

    while events:
        now, _, kind, vin = heapq.heappop(events)
        v = by_vin[vin]
        ica.advance(now)
        if kind == "arrive":
            ica.detect(vin, v.route.in_lane, now)
            lane = lanes.setdefault(v.route.in_lane, [])
            lane.append(v)
            if len(lane) == 1:
                lead = lane_tail.get(v.route.in_lane)
                at = free_at(lead) if lead is not None else now
                if at <= now:
                    ask(v, queued=False)
                else:
                    heapq.heappush(events, (at, v.arrival_s, "head", v.vin))
        elif kind == "head" or v.confirmation is None:  # newly head, or a retry after a rejection
            ask(v, queued=True)

    return StreamResult(vehicles, request_times, rejections, now)


def _request(
    ica: Controller,
    v: Vehicle,
    now: float,
    d: float,
    speed: float,
    config: IcaConfig,
    events: list[tuple[float, float, str, str]],
    rejections: dict[str, int],
    request_times: list[float],
    before_request: Callable[[Controller, Request, float], None] | None = None,
) -> None:
    h = config.step_s
    try:
        req = propose(
            v.route,
            vin=v.vin,
            seq=v.seq,
            t0_s=now,
            dist_to_entry_m=d,
            speed_mps=speed,
            length_m=v.length_m,
            width_m=v.width_m,
            config=config,
        )
    except RequestError as e:
        out: Confirmation | Rejection = Rejection(v.vin, v.seq, e.reason, e.detail)
    else:
        if before_request is not None:
            before_request(ica, req, now)
        busy = max((c.dtot.end_s for c in ica.confirmed.values()), default=-math.inf)
        t = time.perf_counter()
        out = ica.handle(req, now)
        request_times.append(time.perf_counter() - t)
        if isinstance(out, Confirmation):
            planner = Planner(
                d, speed, v.route.road_mps, v.route.speed_cap_mps, 0.0, config.kinematics
            )
            v.earliest_entry_s = now + planner.earliest_entry_s()
            v.stop_entry_s = now + planner.stop_entry_s()
            v.busy_until_s = busy
    v.seq += 1
    if isinstance(out, Confirmation):
        v.confirmation = out
        return
    v.rejections.append(out.reason)
    rejections[out.reason.value] = rejections.get(out.reason.value, 0) + 1
    heapq.heappush(events, (_ceil_step(now + 1.0, h), v.arrival_s, "retry", v.vin))


def flown(res: StreamResult) -> list[Flown]:
    """The confirmed vehicles as the audit sees them: their TSS and nothing else."""
    return [
        Flown(
            v.vin,
            v.route,
            v.length_m,
            v.width_m,
            v.confirmation.tss.t_s,
            v.confirmation.tss.x_m,
            v.confirmation.tss.y_m,
            v.confirmation.tss.heading_rad,
        )
        for v in res.confirmed
    ]
