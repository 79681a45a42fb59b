"""An emergency vehicle's event in reactive DICA: the settings, the log of one
event as it goes, the vehicles it may reorder, and how a run reports it.

Plain data, kept apart from the controller (:mod:`dica.ica.core.reactive`)
that fills it in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.config import MAX_ADDED_DELAY_S, SOLVERS, IcaConfig
from dica.ica.core.intersection import Intersection
from dica.ica.core.ordering import EXHAUSTIVE_LIMIT, GaParams
from dica.ica.core.planner import Planner
from dica.ica.core.request import Confirmation
from dica.ica.core.revocation import Reorder
from dica.ica.core.route import Route
from dica.ica.core.separation import SeparationModel
from dica.ica.core.zones import Shape


@dataclass(frozen=True, slots=True)
class ReactiveConfig:
    """How reactive DICA orders (``solver``: exact, ga or exhaustive) and when a
    revocation takes effect after it is decided (``revoke_latency_s``)."""

    solver: str = "exact"
    seed: int = 0  # the GA's seed; each event draws from (seed, event number)
    ga: GaParams = field(default_factory=GaParams)
    exhaustive_limit: int = EXHAUSTIVE_LIMIT
    revoke_latency_s: float = 0.0
    # when an EV's event starts: "head", when the EV asks as head of its lane;
    # "detection", as soon as it is detected (the dissertation's choice)
    start_at: str = "head"
    # True: revoked vehicles are re-confirmed by the ICA in the solver's order (in process,
    # where a revocation reaches its vehicle at once). False: over a real link, each
    # revoked vehicle drops its plan, stops short of the line and asks again like any
    # head of lane; revocations go out together, each lane's from the back (due_revocations)
    replan_revoked: bool = True
    # [s] the most delay reorderings may add to any one normal vehicle, summed over every
    # reordering it meets (each re-plan's entry less its revoked plan's); inf: no bound (the
    # dissertation's). The solvers take it as a deadline, checked on a copy's real re-plans
    max_added_delay_s: float = MAX_ADDED_DELAY_S

    def __post_init__(self) -> None:
        if not self.max_added_delay_s >= 0:  # (NaN too)
            raise ValueError("max_added_delay_s must be 0 or more")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}: use {', '.join(SOLVERS)}")
        if self.revoke_latency_s < 0:
            raise ValueError("revoke_latency_s must not be negative")
        if self.start_at not in ("head", "detection"):
            raise ValueError(f"start_at must be 'head' or 'detection', not {self.start_at!r}")


@dataclass(slots=True)
class EvEvent:
    """The log of one EV event (mutable: filled in as it goes)."""

    ev: str
    lane: str
    detected_s: float
    started_s: float
    reorder: Reorder | None = None
    confirmations: list[Confirmation] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)  # revoked, but no new plan was found
    unplanned: list[str] = field(default_factory=list)  # revoked behind the EV, to ask again
    ev_confirmed_s: float | None = None
    ev_entry_s: float | None = None  # the EV's confirmed entry
    closed_s: float | None = None


@dataclass(frozen=True, slots=True)
class Replan:
    vin: str
    seq: int
    route: Route
    shape: Shape
    t0_s: float
    dist_m: float
    speed_mps: float


@dataclass(frozen=True, slots=True)
class Candidate:
    vin: str
    lane: str
    routes: tuple[Route, ...]  # its route, or every route of its lane if not known yet
    release_s: float
    entry_mps: float  # expected entry speed, for the separations
    state: Replan | None  # a confirmed vehicle's state at the effective time


def event_log(e: EvEvent) -> dict:
    """One EV event as a run's report lists it."""
    o = e.reorder
    return {
        "ev": e.ev,
        "detected_s": round(e.detected_s, 3),
        "candidates": len(o.order) if o else 0,
        "revoked": len(o.revoked) if o else 0,
        "solve_ms": round(o.solve_s * 1e3, 3) if o else None,
        "prepare_ms": round(o.prepare_s * 1e3, 3) if o else None,
        "unplanned": len(e.unplanned),
        "refused": o.refused if o else "",
        "ev_entry_model_before_s": _rounded(o.ev_entry_before_s) if o else None,
        "ev_entry_model_after_s": _rounded(o.ev_entry_after_s) if o else None,
        "ev_entry_s": _rounded(e.ev_entry_s),
        "replan_failed": len(e.failed),
    }


def _rounded(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, 3)


def event_figures(solver: str, events: list[EvEvent]) -> dict:
    """A run's events in figures: counts, the solver's time, the EV's entries by the
    ordering model (the gain of the new order over the present one)."""
    done = [e.reorder for e in events if e.reorder is not None]
    arr = np.array([o.solve_s * 1e3 for o in done]) if done else np.zeros(0)
    gains = [o.ev_entry_before_s - o.ev_entry_after_s for o in done if not o.refused]
    return {
        "solver": solver,
        "events": len(events),
        "reordered": sum(1 for o in done if not o.refused),
        "refused": sum(1 for o in done if o.refused),
        "revoked": sum(len(o.revoked) for o in done),
        "replan_failed": sum(len(e.failed) for e in events),
        "candidates_max": max((len(o.order) for o in done), default=0),
        "solve_ms_mean": float(arr.mean()) if len(arr) else None,
        "solve_ms_max": float(arr.max()) if len(arr) else None,
        "solve_s_total": float(arr.sum() / 1e3),
        "prepare_s_total": float(sum(o.prepare_s for o in done)),
        "unplanned": sum(len(e.unplanned) for e in events),
        "ev_entry_model_gain_s_mean": float(np.mean(gains)) if gains else None,
    }


def lane_candidates(
    ev: EvEvent,
    t_eff: float,
    queue: list[str],
    confirmed: list[bool],
    detected: Mapping[str, tuple[int, float, float | None]],
    intersection: Intersection,
    config: IcaConfig,
    shape: Shape,
    separations: SeparationModel,
) -> list[Candidate]:
    """The unconfirmed vehicles ahead of the EV in its lane, and the EV, with
    releases estimated from their detection (their state is not known here).

    ``queue`` is the EV's lane's queue and ``confirmed`` whether each of it holds a
    plan; ``detected`` each vehicle's (detection number, time, speed or None)."""
    routes = intersection.routes_from(ev.lane)
    comm = intersection.comm_length_m
    out = []
    waiting = [v for v, c in zip(queue, confirmed, strict=True) if not c]
    nothing_ahead = waiting[:1] == [ev.ev] and not any(confirmed)
    for vin in waiting:
        _, t_det, v_det = detected.get(vin, (0, t_eff, None))
        earliest = -math.inf
        entry_mps = math.inf
        for r in routes:
            v0 = r.road_mps if v_det is None else max(v_det, 0.0)
            pl = Planner(
                comm, v0, r.road_mps, r.speed_cap_mps,
                r.cross_length_m + shape.length_m, config.kinematics,
            )  # fmt: skip
            e = pl.earliest_entry_s()
            earliest = max(earliest, t_det + e if math.isfinite(e) else t_eff)
            fast = pl.fastest()
            entry_mps = min(entry_mps, fast.entry_speed_mps if fast else 0.0)
        if not (vin == ev.ev and nothing_ahead):  # waiting unconfirmed: stop and go
            entry_mps = min(separations.stop_and_go_entry_mps(r) for r in routes)
        out.append(Candidate(vin, ev.lane, routes, max(earliest, t_eff), entry_mps, None))
        if vin == ev.ev:
            break
    return out
