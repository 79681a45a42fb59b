"""What the recorder remembers between draws: the plans in force and the SUMO steps
not drawn yet, and a batch of those steps as flat arrays with one row per
vehicle and step, carrying what every view needs (where the vehicle is on its
route, whether a plan holds it, its state), computed once for all of them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from dica.sim_gateway.conflict_points import Holding
from dica.sim_gateway.recording.geometry import LANE_WIDTH_M, RouteProjector, sumo_heading_rad
from dica.sim_gateway.recording.style import vehicle_statuses


@dataclass(slots=True)
class Plan:
    """What the recorder keeps of one confirmation."""

    t_confirmed_s: float
    route_idx: int
    out_m: float  # front distance at which the rear is out
    t0_s: float  # first DTOT sample time
    band: np.ndarray  # (K, 5, 2) reserved outlines at the DTOT samples, viewer frame
    hold: Holding
    until_s: float = math.inf  # withdrawn from this time on


@dataclass(slots=True)
class Step:
    """One SUMO step as :meth:`SpaceTimeRecorder.footprints` took it (SUMO's frame)."""

    t_s: float
    vins: list[str]
    x: np.ndarray
    y: np.ndarray
    angle: np.ndarray
    length: np.ndarray
    width: np.ndarray
    routes: np.ndarray  # route index per vehicle, -1 unknown


@dataclass(slots=True)
class StepBatch:
    """Steps drawn together: per step ``times`` and ``counts``, per row (vehicle and
    step) the rest; ``step_of`` maps a row to its step."""

    times: np.ndarray  # [s]
    counts: np.ndarray  # vehicles per step
    step_nos: np.ndarray  # each step's number since the recording started
    step_of: np.ndarray
    vins: list[str]
    x: np.ndarray  # [m] front-bumper centre
    y: np.ndarray
    cos: np.ndarray  # heading, counter-clockwise from +x
    sin: np.ndarray
    length: np.ndarray  # [m]
    width: np.ndarray
    route_idx: np.ndarray  # -1: unknown
    s: np.ndarray  # [m] front's distance along its route (NaN: route unknown)
    dist: np.ndarray  # [m] front's distance from its route (inf: route unknown)
    plans: list[Plan | None]  # the vehicle's latest plan, in force or not
    confirmed: np.ndarray  # a plan holds the vehicle at that step
    state: np.ndarray  # Status per row

    @classmethod
    def of(
        cls,
        steps: Sequence[Step],
        first_step_no: int,
        projector: RouteProjector,
        plans: Mapping[str, Plan],
        emergency: set[str],
        human: set[str] = frozenset(),
    ) -> StepBatch:
        counts = np.array([len(s.vins) for s in steps])
        times = np.array([s.t_s for s in steps])
        step_of = np.repeat(np.arange(len(steps)), counts)
        vins = [v for s in steps for v in s.vins]
        nrow = len(vins)
        x = np.concatenate([s.x for s in steps]) if nrow else np.zeros(0)
        y = np.concatenate([s.y for s in steps]) if nrow else np.zeros(0)
        heading = sumo_heading_rad(np.concatenate([s.angle for s in steps])) if nrow else x
        length = np.concatenate([s.length for s in steps]) if nrow else x
        width = np.concatenate([s.width for s in steps]) if nrow else x
        ridx = np.concatenate([s.routes for s in steps]) if nrow else np.zeros(0, int)
        t_row = times[step_of]

        known = ridx >= 0
        s = np.full(nrow, np.nan)
        dist = np.full(nrow, np.inf)
        if known.any():
            s[known], dist[known] = projector.project(
                ridx[known], np.stack([x[known], y[known]], -1)
            )
        mine = [plans.get(v) for v in vins]
        confirmed = np.array(
            [
                p is not None and p.t_confirmed_s - 1e-9 <= t < p.until_s - 1e-9
                for p, t in zip(mine, t_row, strict=True)
            ],
            dtype=bool,
        )
        out_m = np.array([p.out_m if p is not None else np.inf for p in mine])
        ev = np.array([v in emergency for v in vins], dtype=bool)
        on_route = np.where(dist <= LANE_WIDTH_M, s, np.nan)
        hum = np.array([v in human for v in vins], dtype=bool) if human else None
        if hum is not None:  # out by its route's own end: it holds no plan
            ends = np.where(ridx >= 0, projector.cross_m[np.maximum(ridx, 0)] + length, np.inf)
            out_m = np.where(hum, ends, out_m)
        state = vehicle_statuses(confirmed, on_route, out_m, ev, hum)
        step_nos = first_step_no + np.arange(len(steps))
        return cls(
            times, counts, step_nos, step_of, vins, x, y, np.cos(heading), np.sin(heading),
            length, width, ridx, s, dist, mine, confirmed, state,
        )  # fmt: skip

    def every(self, n: int) -> np.ndarray:
        """Per step: is it one of every ``n``th step since the recording started."""
        return self.step_nos % n == 0
