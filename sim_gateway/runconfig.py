"""What one run is: the scenario inputs, checked, and what a run returns."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from dica.ica.core.config import BASELINES, MAX_ADDED_DELAY_S, REACTIVE, SOLVERS, Techniques
from dica.sim_gateway.metrics import TripLog

if TYPE_CHECKING:
    from dica.ica.core.controller import ControllerSpec

# SUMO drives; the junction is signalised (or, the all-way stop, signed)
LIGHTS = ("fixed", "actuated", "reactive-light", "allway-stop")
REVOCATIONS = ("replan", "drop")  # how rdica's revoked vehicles get their next plan
GATE_RULES = ("route", "cycle")  # the network gate's (sim_gateway.network_gate)


class RunError(Exception):
    """A run that cannot start or cannot go on (bad input, SUMO refused, a peer died)."""


@dataclass(frozen=True, slots=True)
class Limit:
    """The range a setting may take, and the one sentence that refuses a value outside
    it (the command line's option names it: ``flag``)."""

    flag: str
    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False  # the least value itself is out

    def holds(self, x: float) -> bool:
        return (self.lo < x if self.lo_open else self.lo <= x) and x <= self.hi

    def text(self, x: float) -> str:
        unit = f" {self.unit}" if self.unit else ""
        low = "above" if self.lo_open else "between"
        high = "and at most" if self.lo_open else "and"
        lo, hi, got = _plain(self.lo), _plain(self.hi), _plain(x)
        return f"{self.flag} must be {low} {lo} {high} {hi}{unit}, got {got}"

    def check(self, x: float) -> None:
        if not self.holds(x):
            raise RunError(self.text(x))


def _plain(x: float) -> str:
    """A number as a person writes it: 1000000, not 1e+06."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


# what a run's settings may be (the command line refuses the same values with the same words)
LIMITS = {
    "volume_per_10min": Limit("--volume", 1.0, 2000.0, "vehicles per 10 min"),
    "volume_end_per_10min": Limit("--volume-end", 1.0, 2000.0, "vehicles per 10 min"),
    "duration_s": Limit("--duration", 0.0, 1e7, "s", lo_open=True),
    "until_left": Limit("--until-left", 1, 1_000_000),
    "seed": Limit("--seed", 0, 2**32 - 1),
    "tile_m": Limit("--tile-size", 0.1, 10.0, "m"),
    "margin_m": Limit("--margin", 0.0, 5.0, "m"),
    "lead_s": Limit("--lead", 0.0, 9.0, "s"),
    "window_s": Limit("--window", 0.0, 5.0, "s"),
    "headway_s": Limit("--headway", 0.0, 5.0, "s"),
    "time_pad_s": Limit("--time-pad", 0.0, 5.0, "s"),
    "green_late_s": Limit("--green-late", 0.0, 5.0, "s"),
    "retry_s": Limit("--retry", 0.05, 60.0, "s"),
    "ev_prob": Limit("--ev-prob", 0.0, 1.0),
    "begin_s": Limit("--begin", 0.0, 1e7, "s"),
    "peds_per_h": Limit("--peds", 0.0, 3600.0, "persons per hour per crossing"),
    "cav_share": Limit("--cav-share", 0.0, 1.0),
    "max_added_delay_s": Limit("--max-added-delay", 0.0, math.inf, "s"),
}


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
    green_late_s: float = 0.0  # [s] how late a human's head may turn green (IcaConfig's)
    ev_prob: float = 0.0  # each arrival an emergency-vehicle candidate with this probability
    solver: str = "exact"  # reactive DICA's ordering solver
    # [s] reactive DICA: the most reorderings may add to any one normal vehicle (inf: none)
    max_added_delay_s: float = MAX_ADDED_DELAY_S
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
    # a SUMO demand file instead of the random demand: SUMO drives its vehicles through
    # the net, and the junction takes each over in its region (sim_gateway/route_file.py)
    routes_path: str | None = None
    begin_s: float = 0.0  # [s] the simulation starts here (SUMO's --begin)
    # several junctions, each under its own ICA (sim_gateway/network.py); junction_id is
    # the first of them. Empty: one junction
    junction_ids: tuple[str, ...] = ()
    # several junctions: the network gate bounds what the links between them hold, by the
    # route or the cycle rule, so the network cannot lock (sim_gateway.network_gate); off,
    # nothing bounds it (and a cycle of full links may stand still for ever)
    network_gate: bool = True
    network_gate_rule: str = "route"  # one of GATE_RULES
    # several junctions under reactive DICA: each EV tells the junctions ahead on its route
    # that it is coming (sim_gateway/ev_corridor.py, ica/core/ev_notice.py); off by default,
    # since near saturation on the grid it cost more than it gained (docs/results.md)
    ev_notices: bool = False
    # [persons/h] people crossing at every crossing of the junctions (sim_gateway/walkers.py)
    peds_per_h: float = 0.0
    # the share of connected automated vehicles in the random demand; the others are driven
    # by SUMO's own driver, each held at a signal head of its own (sim_gateway/humans.py)
    cav_share: float = 1.0

    def controller_spec(self) -> ControllerSpec:
        """The controller this run drives (a light runs FIFO underneath, never asked)."""
        from dica.ica.core.controller import ControllerSpec  # the compiled core, when needed
        from dica.ica.core.ev_event import ReactiveConfig

        reactive = ReactiveConfig(
            solver=self.solver,
            seed=self.seed,
            replan_revoked=self.revocation == "replan",
            max_added_delay_s=self.max_added_delay_s,
        )
        spec = ControllerSpec.of(
            "fifo" if self.algorithm in LIGHTS else self.algorithm,
            self.margin_m, self.time_pad_s, self.platoon, self.headway_s, self.run_up,
            self.exit_spacing, self.tile_m, reactive,
        )  # fmt: skip
        return spec.with_green_late(self.green_late_s)

    def _check_mixed(self) -> None:
        why = _mixed_refusal(self)
        if why is not None:
            raise RunError(why)

    @property
    def plan_lead_s(self) -> float:
        """How far ahead vehicles plan: a windowed request is decided up to a window late."""
        return max(self.lead_s, self.window_s)

    def __post_init__(self) -> None:
        for name, limit in LIMITS.items():
            value = getattr(self, name)
            if value is not None:
                limit.check(value)
        if self.algorithm not in BASELINES + LIGHTS + REACTIVE:
            try:
                Techniques.parse(self.algorithm)
            except ValueError:
                raise RunError(
                    f"unknown algorithm {self.algorithm!r}: use basic, enhanced, t1..t4 (t2+4), "
                    + ", ".join(BASELINES + LIGHTS + REACTIVE)
                ) from None
        if self.window_s and self.algorithm in BASELINES + LIGHTS + REACTIVE:
            raise RunError(f"--window orders DICA's requests; {self.algorithm} does not take it")
        if self.revocation not in REVOCATIONS:
            raise RunError(
                f"unknown revocation {self.revocation!r}: use {' or '.join(REVOCATIONS)}"
            )
        if self.routes_path and self.until_left:
            raise RunError("--until-left counts the random demand's vehicles; with --routes "
                           "give --duration")  # fmt: skip
        if self.routes_path and self.ev_prob:
            raise RunError("--ev-prob draws the random demand's emergency vehicles; a route "
                           "file's vehicles are as the file has them")  # fmt: skip
        if self.begin_s and not self.routes_path:
            raise RunError("--begin starts a route file's demand (--routes)")
        if len(self.junction_ids) > 1:
            if not self.routes_path:
                raise RunError("several junctions take their vehicles from a route file: "
                               "give --routes")  # fmt: skip
            if self.algorithm in LIGHTS:
                raise RunError(f"--junctions runs the signal-free algorithms; {self.algorithm} "
                               "is a light's baseline for one --junction")  # fmt: skip
            if len(set(self.junction_ids)) < len(self.junction_ids):
                raise RunError(f"--junctions names a junction twice: {','.join(self.junction_ids)}")
        if self.cav_share < 1.0:
            self._check_mixed()
        if self.solver not in SOLVERS:
            raise RunError(f"unknown solver {self.solver!r}: use {', '.join(SOLVERS)}")


MIXED_ALGORITHMS = ("basic", "enhanced")  # those that serve human drivers, with the lights


def _mixed_refusal(cfg: RunConfig) -> str | None:
    """Why human drivers cannot be served in ``cfg``'s run (None: they can)."""
    alg = cfg.algorithm
    if alg not in MIXED_ALGORITHMS + LIGHTS and not alg.startswith("t"):
        return (f"--cav-share below 1 runs DICA ({', '.join(MIXED_ALGORITHMS)}, t1..t4) or a "
                f"light; {alg} does not serve human drivers yet")  # fmt: skip
    if cfg.junction_ids:
        return ("--cav-share serves human drivers at one --junction; several junctions do "
                "not serve them yet")  # fmt: skip
    if cfg.window_s:
        return "--cav-share with --window is not served yet"
    return None


@dataclass(slots=True)
class RunResult:
    metrics: dict
    trips: TripLog
    safety: dict
    requests: dict
    sumo_collisions: int
    sim_time_s: float  # SUMO's clock at the end (a route file's --begin plus the run)
    wall_s: float
    sumo_command: list[str] = field(default_factory=list)
    signal: dict | None = None
    extra: dict = field(default_factory=dict)  # mode-specific facts (clock, agents, ...)
    # a network's trips from SUMO's records (sim_gateway/network_trips.py), if kept
    net_trips: list | None = None
    persons: list[dict] | None = None  # one row per walker (sim_gateway/walkers.py)
    begin_s: float = 0.0  # SUMO's clock at the start (--begin)

    @property
    def simulated_s(self) -> float:
        """The span the run simulated: the clock at the end less the clock at its start."""
        return self.sim_time_s - self.begin_s
