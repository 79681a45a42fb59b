"""The dissertation's metrics, from what the simulation reports about each trip.

Trip time tau: from entering the communication region until fully out of the
intersection. Throughput rho = crossed / generated; stopped rate eta =
stopped / crossed; effective mean trip time tau_e = mean tau / rho. Delay is
a trip's time over its free-flow time (the fastest plan from the speed it
entered the region with, alone at the junction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(slots=True)
class Trip:
    vin: str
    route_id: str
    turn: str
    depart_s: float  # scheduled arrival at the communication region
    entered_s: float | None = None  # front crossed the communication region's entry line
    exited_s: float | None = None  # rear left the junction
    free_flow_s: float | None = None
    stopped: bool = False
    confirmed_s: float | None = None
    ev: bool = False  # an emergency vehicle


@dataclass(slots=True)
class TripLog:
    """Trips by VIN plus the time series the report plots."""

    trips: dict[str, Trip] = field(default_factory=dict)
    t_s: list[float] = field(default_factory=list)
    waiting: list[int] = field(default_factory=list)
    crossed_cum: list[int] = field(default_factory=list)
    generated_cum: list[int] = field(default_factory=list)

    def sample(self, t_s: float, waiting: int, crossed: int, generated: int) -> None:
        self.t_s.append(t_s)
        self.waiting.append(waiting)
        self.crossed_cum.append(crossed)
        self.generated_cum.append(generated)


def summarize(log: TripLog, end_s: float) -> dict[str, float | int | None]:
    """The metrics of one run; vehicles due after ``end_s`` are not counted as generated."""
    gen = [tr for tr in log.trips.values() if tr.depart_s <= end_s]
    crossed = [tr for tr in gen if tr.exited_s is not None and tr.entered_s is not None]
    tau = np.array([tr.exited_s - tr.entered_s for tr in crossed], dtype=float)
    delay = np.array(
        [
            tr.exited_s - tr.entered_s - tr.free_flow_s
            for tr in crossed
            if tr.free_flow_s is not None
        ],
        dtype=float,
    )
    rho = len(crossed) / len(gen) if gen else 0.0
    mean = float(tau.mean()) if len(tau) else math.nan
    out: dict[str, float | int | None] = {
        "generated": len(gen),
        "crossed": len(crossed),
        "throughput": rho,
        "mean_trip_time_s": mean,
        "std_trip_time_s": float(tau.std()) if len(tau) else math.nan,
        "max_trip_time_s": float(tau.max()) if len(tau) else math.nan,
        "stopped_rate": (sum(tr.stopped for tr in crossed) / len(crossed)) if crossed else math.nan,
        "effective_mean_trip_time_s": mean / rho if rho > 0 else math.nan,
        "mean_delay_s": float(delay.mean()) if len(delay) else math.nan,
    }
    for turn in ("left", "through", "right"):
        sel = np.array([tr.exited_s - tr.entered_s for tr in crossed if tr.turn == turn])
        out[f"mean_trip_time_{turn}_s"] = float(sel.mean()) if len(sel) else math.nan
    result = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in out.items()}
    by_approach: dict[str, list[float]] = {}
    for tr in crossed:
        approach = tr.route_id.split(">")[0].rsplit("_", 1)[0]
        by_approach.setdefault(approach, []).append(tr.exited_s - tr.entered_s)
    result["mean_trip_time_by_approach_s"] = {
        a: float(np.mean(v)) for a, v in sorted(by_approach.items())
    }
    return result


def summarize_ev(log: TripLog, end_s: float) -> dict[str, dict[str, float | int | None]]:
    """Emergency vehicles and the others apart: count, trip time (mean, std, max), delay
    and stopped rate of each group, with the clock of :func:`summarize`; and the mean
    trip time counted from the scheduled arrival instead."""
    out: dict[str, dict[str, float | int | None]] = {}
    for name, want in (("ev", True), ("normal", False)):
        gen = [tr for tr in log.trips.values() if tr.depart_s <= end_s and tr.ev == want]
        crossed = [tr for tr in gen if tr.exited_s is not None and tr.entered_s is not None]
        tau = np.array([tr.exited_s - tr.entered_s for tr in crossed], dtype=float)
        delay = np.array(
            [
                tr.exited_s - tr.entered_s - tr.free_flow_s
                for tr in crossed
                if tr.free_flow_s is not None
            ],
            dtype=float,
        )
        # the same trips on a clock that starts at the scheduled arrival at the region's
        # entry line: it also counts a wait to get in when the lane is backed up beyond it
        from_arrival = np.array([tr.exited_s - tr.depart_s for tr in crossed], dtype=float)
        group = {
            "generated": len(gen),
            "crossed": len(crossed),
            "mean_trip_time_s": float(tau.mean()) if len(tau) else None,
            "mean_trip_time_from_arrival_s": (
                float(from_arrival.mean()) if len(from_arrival) else None
            ),
            "std_trip_time_s": float(tau.std()) if len(tau) else None,
            "max_trip_time_s": float(tau.max()) if len(tau) else None,
            "mean_delay_s": float(delay.mean()) if len(delay) else None,
            "stopped_rate": (sum(tr.stopped for tr in crossed) / len(crossed)) if crossed else None,
        }
        out[name] = group
    return out
