"""What one run is: the scenario inputs, checked, and what a run returns."""

from __future__ import annotations

from dataclasses import dataclass, field

from dica.ica.core.baselines import BASELINES, controller_config
from dica.ica.core.config import IcaConfig, Techniques
from dica.ica.core.ordering import SOLVERS
from dica.ica.core.reactive import ReactiveConfig
from dica.sim_gateway.metrics import TripLog

LIGHTS = ("fixed", "actuated", "reactive-light")  # SUMO drives; the junction is signalised
REACTIVE = ("rdica",)  # reactive DICA: emergency vehicles first (--solver)
REVOCATIONS = ("replan", "drop")  # how rdica's revoked vehicles get their next plan


class RunError(Exception):
    """A run that cannot start or cannot go on (bad input, SUMO refused, a peer died)."""


@dataclass(frozen=True, slots=True)
class RunConfig:
    """One run, as given on the command line (written beside the outputs)."""

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
    lead_s: float = 0.0  # [s] vehicles plan their REQUESTs this far ahead of what they observed
    time_pad_s: float = 0.0  # [s] the ICA's padding of every confirmed occupancy interval
    ev_prob: float = 0.0  # each arrival an emergency-vehicle candidate with this probability
    solver: str = "exact"  # reactive DICA's ordering solver
    # reactive DICA's revoked vehicles: "replan" (the ICA plans them again in the solver's
    # order; in process only) or "drop" (they drop their plans and ask again: the cluster)
    revocation: str = "replan"
    # a vehicle may ask once the vehicle ahead of it holds a plan, and follows it
    # across as a platoon (docs/architecture.md, "Platoons"); off: once it has entered
    platoon: bool = False
    headway_s: float = 0.0  # [s] a follower keeps its leader's plan this much later
    # a vehicle that must wait enters at speed: slows to as little as 0.5 m/s, or stands
    # back far enough to reach the crossing cap at the line (ica/core/planner.py)
    run_up: bool = True
    # a vehicle may leave the junction faster than a slower one ahead on its exit lane,
    # late enough that the road's driver never brakes behind it (ica/core/handover.py)
    exit_spacing: bool = True
    # [s] the ICA decides the REQUESTs of each window together, in the order that delays
    # them least (ica/core/window.py); 0: one by one as they come. Embedded runs only
    window_s: float = 0.0

    @property
    def plan_lead_s(self) -> float:
        """How far ahead vehicles plan: a windowed request is decided up to a window late."""
        return max(self.lead_s, self.window_s)

    def __post_init__(self) -> None:
        if not 1.0 <= self.volume_per_10min <= 2000.0:
            raise RunError(
                f"volume {self.volume_per_10min:g} is out of range: 1 to 2000 vehicles per 10 min"
            )
        if self.duration_s <= 0:
            raise RunError("duration must be positive")
        if self.until_left is not None and self.until_left < 1:
            raise RunError("--until-left must be at least 1")
        if self.algorithm not in BASELINES + LIGHTS + REACTIVE:
            try:
                Techniques.parse(self.algorithm)
            except ValueError:
                raise RunError(
                    f"unknown algorithm {self.algorithm!r}: use basic, enhanced, t1..t4 (t2+4), "
                    + ", ".join(BASELINES + LIGHTS + REACTIVE)
                ) from None
        if self.volume_end_per_10min is not None and not 1.0 <= self.volume_end_per_10min <= 2000:
            raise RunError("--volume-end is out of range: 1 to 2000 vehicles per 10 min")
        if not 0.1 <= self.tile_m <= 10.0:
            raise RunError("--tile-size must be between 0.1 and 10 m")
        if not 0.0 <= self.margin_m <= 5.0:
            raise RunError(f"--margin must be between 0 and 5 m, got {self.margin_m:g}")
        if not 0.0 <= self.lead_s <= 10.0:
            raise RunError(f"--lead must be between 0 and 10 s, got {self.lead_s:g}")
        if not 0.0 <= self.window_s <= 5.0:
            raise RunError(f"--window must be between 0 and 5 s, got {self.window_s:g}")
        if self.window_s and self.algorithm in BASELINES + LIGHTS + REACTIVE:
            raise RunError(f"--window orders DICA's requests; {self.algorithm} does not take it")
        if not 0.0 <= self.headway_s <= 5.0:
            raise RunError(f"--headway must be between 0 and 5 s, got {self.headway_s:g}")
        if not 0.0 <= self.time_pad_s <= 5.0:
            raise RunError(f"--time-pad must be between 0 and 5 s, got {self.time_pad_s:g}")
        if not 0.05 <= self.retry_s <= 60.0:
            raise RunError(f"retry must be between 0.05 and 60 s, got {self.retry_s:g}")
        if not 0.0 <= self.ev_prob <= 1.0:
            raise RunError(f"--ev-prob {self.ev_prob:g} is not a probability (0 to 1)")
        if self.revocation not in REVOCATIONS:
            raise RunError(
                f"unknown revocation {self.revocation!r}: use {' or '.join(REVOCATIONS)}"
            )
        if self.solver not in SOLVERS:
            raise RunError(f"unknown solver {self.solver!r}: use {', '.join(SOLVERS)}")


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
    extra: dict = field(default_factory=dict)  # mode-specific facts (clock, agents, ...)


def reactive_config(cfg: RunConfig) -> ReactiveConfig:
    """Reactive DICA's settings for a run (the cluster's ICA builds the same)."""
    return ReactiveConfig(
        solver=cfg.solver, seed=cfg.seed, replan_revoked=cfg.revocation == "replan"
    )


def ica_config(cfg: RunConfig) -> IcaConfig:
    return controller_config(
        cfg.algorithm,
        cfg.margin_m,
        cfg.time_pad_s,
        cfg.platoon,
        cfg.headway_s,
        cfg.run_up,
        cfg.exit_spacing,
    )
