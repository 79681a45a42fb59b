"""The dissertation's metrics, and the whole delay, from what the simulation
reports about each trip.

Where each clock starts:

* trip time tau (the dissertation's): from the front crossing the
  communication region's entry line until the rear leaves the junction.
  Throughput rho = crossed / generated (generated: scheduled to reach the
  region by the end); stopped rate eta = stopped in the region / crossed
  (below SUMO's halting speed, 0.1 m/s), and beside it the crawled rate
  (below 1 m/s, a creeping plan's 0.5 m/s included);
  effective mean trip time tau_e = mean tau / rho. Delay: tau over the
  free-flow time (the fastest plan from the speed it entered the region with,
  alone at the junction).
* time in the system: from the vehicle's *scheduled* arrival at the region's
  entry line until its rear leaves the junction. It also counts the wait in a
  queue upstream of the region (SUMO drives vehicles there from up to a few
  hundred metres upstream) and a wait for room to enter SUMO at all, which
  tau does not see. Delay from the scheduled arrival: that time over the
  free-flow time from the scheduled entry speed.
* vehicles not yet in the region at the end: generated but still upstream
  (or not even in SUMO); the means above leave them out, so the report gives
  their number beside them.
* delay from the scheduled arrival by thirds of the run (by scheduled
  arrival), counting a vehicle still in the system at the end with its delay
  so far (a lower bound): stable traffic keeps the last third near the
  middle one, an oversaturated junction does not (see ``tools/report.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CRAWL_MPS = 1.0  # [m/s] slower than this in the region counts as crawling (walking pace)


@dataclass(slots=True)
class Trip:
    vin: str
    route_id: str
    turn: str
    depart_s: float  # scheduled arrival at the communication region's entry line
    entered_s: float | None = None  # front crossed the communication region's entry line
    exited_s: float | None = None  # rear left the junction
    free_flow_s: float | None = None  # from the entry line at the speed it entered with
    stopped: bool = False
    # below CRAWL_MPS in the region, stopped or not: a plan may creep at 0.5 m/s, which
    # the stopped rate (SUMO's halting speed, 0.1 m/s) does not count
    crawled: bool = False
    confirmed_s: float | None = None
    inserted_s: float | None = None  # SUMO placed it on the road, upstream of the region
    free_flow_scheduled_s: float | None = None  # from the entry line at its scheduled speed

    @property
    def system_time_s(self) -> float | None:
        """From the scheduled arrival at the region's entry line until out of the junction."""
        return None if self.exited_s is None else self.exited_s - self.depart_s

    @property
    def system_delay_s(self) -> float | None:
        st, ff = self.system_time_s, self.free_flow_scheduled_s
        return None if st is None or ff is None else st - ff

    ev: bool = False  # an emergency vehicle
    human: bool = False  # driven by SUMO's own driver (--cav-share below 1)


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

    def longest_standstill_s(self) -> float:
        """The longest time [s] vehicles stood waiting in the regions while none crossed:
        a network that locks shows it growing to the end of the run."""
        longest, since = 0.0, None
        for t, w, n, prev in zip(
            self.t_s[1:], self.waiting[1:], self.crossed_cum[1:], self.crossed_cum[:-1], strict=True
        ):
            if w > 0 and n == prev:
                since = t if since is None else since
                longest = max(longest, t - since)
            else:
                since = None
        return longest


def _trips(gen: list[Trip]) -> tuple[list[Trip], np.ndarray, np.ndarray]:
    """The crossed trips of ``gen``, their trip times and their delays (the
    dissertation's clock, from the region's entry line)."""
    crossed = [tr for tr in gen if tr.exited_s is not None and tr.entered_s is not None]
    tau = np.array([tr.exited_s - tr.entered_s for tr in crossed], dtype=float)
    free = [tr for tr in crossed if tr.free_flow_s is not None]
    delay = np.array([tr.exited_s - tr.entered_s - tr.free_flow_s for tr in free], dtype=float)
    return crossed, tau, delay


def summarize(log: TripLog, end_s: float) -> dict[str, float | int | None]:
    """The metrics of one run; vehicles due after ``end_s`` are not counted as generated."""
    gen = [tr for tr in log.trips.values() if tr.depart_s <= end_s]
    crossed, tau, delay = _trips(gen)
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
        "crawled_rate": (sum(tr.crawled for tr in crossed) / len(crossed)) if crossed else math.nan,
        "effective_mean_trip_time_s": mean / rho if rho > 0 else math.nan,
        "mean_delay_s": float(delay.mean()) if len(delay) else math.nan,
    }
    system = np.array([tr.system_time_s for tr in crossed], dtype=float)
    system_delay = np.array(
        [tr.system_delay_s for tr in crossed if tr.system_delay_s is not None], dtype=float
    )
    out |= {
        "mean_system_time_s": float(system.mean()) if len(system) else math.nan,
        "max_system_time_s": float(system.max()) if len(system) else math.nan,
        "mean_system_delay_s": float(system_delay.mean()) if len(system_delay) else math.nan,
        "p95_system_delay_s": float(np.percentile(system_delay, 95))
        if len(system_delay)
        else math.nan,
        "not_in_region_at_end": sum(tr.entered_s is None for tr in gen),
        "not_inserted_at_end": sum(tr.inserted_s is None for tr in gen),
    }
    thirds = _delay_thirds(gen, end_s)
    for turn in ("left", "through", "right"):
        sel = np.array([tr.exited_s - tr.entered_s for tr in crossed if tr.turn == turn])
        out[f"mean_trip_time_{turn}_s"] = float(sel.mean()) if len(sel) else math.nan
    result = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in out.items()}
    result["system_delay_by_third_s"] = thirds
    by_approach: dict[str, list[float]] = {}
    for tr in crossed:
        approach = tr.route_id.split(">")[0].rsplit("_", 1)[0]
        by_approach.setdefault(approach, []).append(tr.exited_s - tr.entered_s)
    result["mean_trip_time_by_approach_s"] = {
        a: float(np.mean(v)) for a, v in sorted(by_approach.items())
    }
    return result


def _delay_thirds(gen: list[Trip], end_s: float) -> list[float | None]:
    """Mean delay from the scheduled arrival per third of the run; a vehicle not out
    by ``end_s`` counts with its delay so far."""
    if not gen or not math.isfinite(end_s):
        return [None, None, None]
    start = min(tr.depart_s for tr in gen)
    span = max(end_s - start, 1e-9)
    parts: list[list[float]] = [[], [], []]
    for tr in gen:
        out = tr.exited_s if tr.exited_s is not None else max(end_s, tr.depart_s)
        delay = out - tr.depart_s - (tr.free_flow_scheduled_s or 0.0)
        if tr.exited_s is None:
            delay = max(delay, 0.0)
        k = min(int(3 * (tr.depart_s - start) / span), 2)
        parts[k].append(delay)
    return [float(np.mean(p)) if p else None for p in parts]


def summarize_ev(log: TripLog, end_s: float) -> dict[str, dict[str, float | int | None]]:
    """Emergency vehicles and the others apart: count, trip time (mean, std, max), delay
    and stopped rate of each group, with the clock of :func:`summarize`; and the mean
    trip time counted from the scheduled arrival instead."""
    return _groups(log, end_s, lambda tr: "ev" if tr.ev else "normal", ("ev", "normal"))


def summarize_mixed(log: TripLog, end_s: float) -> dict[str, dict[str, float | int | None]]:
    """Human drivers and connected vehicles apart, as :func:`summarize_ev` does, with
    each group's mean delay from the scheduled arrival."""
    groups = ("human", "connected")
    return {"by_driver": _groups(log, end_s, lambda tr: groups[not tr.human], groups)}


def _groups(log: TripLog, end_s: float, group_of, names) -> dict[str, dict]:
    """Per group (``group_of(trip)`` one of ``names``): the trips' figures."""
    out: dict[str, dict[str, float | int | None]] = {}
    for name in names:
        gen = [tr for tr in log.trips.values() if tr.depart_s <= end_s and group_of(tr) == name]
        crossed, tau, delay = _trips(gen)
        system_delay = [tr.system_delay_s for tr in crossed if tr.system_delay_s is not None]
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
            "mean_system_delay_s": float(np.mean(system_delay)) if system_delay else None,
        }
        out[name] = group
    return out
