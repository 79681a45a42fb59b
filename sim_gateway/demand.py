"""Traffic demand: who arrives at the communication region, when, on which route.

Arrivals are a Poisson process whose expected count matches the volume (the
dissertation's definition: vehicles per 10 minutes over all approaches),
possibly ramped, split over approaches by weight, over turns by the
left/through/right probabilities and uniformly over a turn's lanes. The same
draw gives the expected flow per lane, which the light baselines are timed to.
Both simulation modes and the request-stream tool take their vehicles from here.

Each arrival is an emergency-vehicle candidate with probability ``ev_prob``,
drawn from a random stream of its own, so the rest of the demand is the same
with or without EVs. The world makes a candidate an EV only if no other EV is
in the communication region when it arrives (the dissertation's "at most one
EV at a time"), which depends on how fast the previous one got through.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Turn
from dica.ica.core.route import Route
from dica.sim_gateway.runconfig import RunConfig, RunError

ROAD_LIMIT_MPS = 70.0 / 3.6  # [m/s] the dissertation's road speed limit v_m


@dataclass(frozen=True, slots=True)
class DemandSpec:
    volume_per_10min: float = 300.0
    n_vehicles: int = 100
    seed: int = 12
    turn_probs: tuple[float, float, float] = (0.2, 0.6, 0.2)  # left, through, right
    speed_range: tuple[float, float] = (0.4, 1.0)  # of the road limit
    length_range_m: tuple[float, float] = (5.0, 5.0)
    width_range_m: tuple[float, float] = (1.8, 1.8)
    # relative arrival weight per approach (incoming edge id); missing ones weigh 1
    approach_weights: tuple[tuple[str, float], ...] = ()
    # volume rising (or falling) linearly to this by ``ramp_s``, then held
    volume_end_per_10min: float | None = None
    ramp_s: float = 1200.0
    ev_prob: float = 0.0  # each arrival an emergency-vehicle candidate with this probability

    def __post_init__(self) -> None:
        if not 0.0 <= self.ev_prob <= 1.0:
            raise ValueError(f"the EV probability {self.ev_prob:g} is not in [0, 1]")


@dataclass(frozen=True, slots=True)
class Arrival:
    """One vehicle of the demand: it reaches the region's entry line at ``arrival_s``."""

    vin: str
    route: Route
    arrival_s: float
    speed_mps: float
    length_m: float
    width_m: float
    ev: bool = False  # an emergency-vehicle candidate (see the module's note)
    human: bool = False  # driven by SUMO's own driver, not connected (--cav-share)


def entry_limit(route: Route) -> float:
    """The speed a share of which a vehicle keeps on its way in: the dissertation's
    road limit, or the net's on the approach where that is lower."""
    return min(ROAD_LIMIT_MPS, route.road_mps)


def approach_of(lane: str) -> str:
    return lane.rsplit("_", 1)[0]


def _weights(approaches: list[str], spec: DemandSpec) -> np.ndarray:
    given = dict(spec.approach_weights)
    unknown = set(given) - set(approaches)
    if unknown:
        raise ValueError(f"unknown approach(es) {sorted(unknown)}; known: {approaches}")
    w = np.array([given.get(a, 1.0) for a in approaches], dtype=float)
    if (w < 0).any() or w.sum() <= 0:
        raise ValueError("approach weights must be non-negative and not all zero")
    return w / w.sum()


def unserved(inter: Intersection, length_m: float) -> dict[str, str]:
    """The routes no vehicle of the demand takes, and why (one line each).

    A vehicle is put in at the communication region's entry line, so its incoming lane
    must hold the whole region; and it is seen out once its rear has left the junction,
    so its outgoing lane must hold the vehicle: on a net with short links (junctions a
    few metres apart) the routes over them carry no demand of their own.
    """
    comm = inter.comm_length_m
    out = {}
    for r in inter.routes:
        if not r.cars:
            out[r.id] = f"lane {r.in_lane} or {r.out_lane} is not for cars"
        elif r.in_lane_m < comm:
            out[r.id] = (
                f"incoming lane {r.in_lane} is {r.in_lane_m:.0f} m long, "
                f"shorter than the {comm:g} m communication region"
            )
        elif r.out_lane_m < length_m + 1.0:
            out[r.id] = (
                f"outgoing lane {r.out_lane} is {r.out_lane_m:.0f} m long, "
                f"too short to see a {length_m:g} m vehicle out"
            )
    return out


def _by_approach(inter: Intersection, length_m: float = 0.0) -> dict[str, dict[Turn, list[Route]]]:
    skip = unserved(inter, length_m)
    out: dict[str, dict[Turn, list[Route]]] = {}
    for r in inter.routes:
        if r.id in skip:
            continue
        out.setdefault(approach_of(r.in_lane), {}).setdefault(r.turn, []).append(r)
    return out


def make_arrivals(inter: Intersection, spec: DemandSpec, step_s: float) -> list[Arrival]:
    """Arrivals in time order: approach by weight, turn by ``turn_probs``, lane uniform.

    Arrivals are a Poisson process whose rate follows the (possibly ramped)
    volume, drawn by thinning so the expected count matches exactly.
    """
    rng = np.random.default_rng(spec.seed)
    by_approach = _by_approach(inter, spec.length_range_m[1])
    if not by_approach:
        raise ValueError(f"no route through junction {inter.junction_id} can carry demand")
    approaches = sorted(by_approach)
    weights = _weights(approaches, spec)
    probs = dict(zip((Turn.LEFT, Turn.THROUGH, Turn.RIGHT), spec.turn_probs, strict=True))
    v0 = spec.volume_per_10min
    v1 = v0 if spec.volume_end_per_10min is None else spec.volume_end_per_10min

    def rate(t: float) -> float:
        return (v0 + (v1 - v0) * min(t / spec.ramp_s, 1.0)) / 600.0

    rate_max = max(v0, v1) / 600.0
    # EV candidates from a stream of their own: the others' draws never change
    ev_draws = np.random.default_rng([spec.seed, 0xE7]).uniform(size=spec.n_vehicles)
    t = 0.0
    out: list[Arrival] = []
    for k in range(spec.n_vehicles):
        while True:
            t += rng.exponential(1.0 / rate_max)
            if rng.uniform() * rate_max <= rate(t):
                break
        turns = by_approach[approaches[rng.choice(len(approaches), p=weights)]]
        options = sorted(turns, key=str)
        p = np.array([probs[x] for x in options])
        turn = options[rng.choice(len(options), p=p / p.sum())]
        route = turns[turn][rng.integers(len(turns[turn]))]
        out.append(
            Arrival(
                vin=f"v{k:05d}",
                route=route,
                arrival_s=round(t / step_s) * step_s,
                speed_mps=float(rng.uniform(*spec.speed_range)) * entry_limit(route),
                length_m=float(rng.uniform(*spec.length_range_m)),
                width_m=float(rng.uniform(*spec.width_range_m)),
                ev=bool(ev_draws[k] < spec.ev_prob),
            )
        )
    return out


def expected_lane_flows(inter: Intersection, spec: DemandSpec) -> dict[str, float]:
    """Expected demand per incoming lane [veh/h], by the same draw as make_arrivals."""
    by_approach = _by_approach(inter, spec.length_range_m[1])
    probs = dict(zip((Turn.LEFT, Turn.THROUGH, Turn.RIGHT), spec.turn_probs, strict=True))
    weights = dict(zip(sorted(by_approach), _weights(sorted(by_approach), spec), strict=True))
    flows: dict[str, float] = {}
    for approach, turns in by_approach.items():
        per_approach = spec.volume_per_10min * 6.0 * weights[approach]
        total = sum(probs[t] for t in turns)
        for turn, routes in turns.items():
            for r in routes:
                share = probs[turn] / total / len(routes)
                flows[r.in_lane] = flows.get(r.in_lane, 0.0) + per_approach * share
    return flows


def _unserved_lines(skip: dict[str, str]) -> list[str]:
    """One line per reason, naming how many routes it keeps out of the demand."""
    by_why: dict[str, int] = {}
    for why in skip.values():
        by_why[why] = by_why.get(why, 0) + 1
    return [f"{why}: no demand on its {n} route{'s' * (n > 1)}" for why, n in by_why.items()]


def schedule_for(cfg: RunConfig, inter: Intersection, step_s: float):
    """The vehicles of this run in arrival order, cut at the horizon; and its stream spec."""
    if cfg.routes_path:  # SUMO drives the file's vehicles to the region (Traffic.adopt)
        from dica.sim_gateway.route_file import check_approaches, read_route_file

        # refused here, before SUMO and the peers
        read_route_file(Path(cfg.routes_path))
        check_approaches(inter, cfg.controller_spec().config.kinematics)
        return [], None, cfg.begin_s + cfg.duration_s
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
        ev_prob=cfg.ev_prob,
    )
    for line in _unserved_lines(unserved(inter, cfg.length_m)):
        print(f"note: {line}", file=sys.stderr)
    try:
        schedule = make_arrivals(inter, spec, step_s)
    except ValueError as e:
        raise RunError(str(e)) from None
    horizon = math.inf if cfg.until_left else cfg.duration_s
    if cfg.cav_share < 1.0:
        schedule = with_humans(schedule, cfg.cav_share, cfg.seed)
    return [v for v in schedule if v.arrival_s <= horizon], spec, horizon


def with_humans(schedule: list[Arrival], cav_share: float, seed: int) -> list[Arrival]:
    """Each arrival but an emergency-vehicle candidate driven by a human with probability
    ``1 - cav_share``, from a stream of its own: the demand itself is the same at every
    share, and a share of 1 leaves it as it was."""
    draws = np.random.default_rng([seed, 27]).random(len(schedule))
    return [
        dataclasses.replace(v, human=True) if not v.ev and u >= cav_share else v
        for v, u in zip(schedule, draws, strict=True)
    ]
