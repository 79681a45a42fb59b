"""The ICA's configuration: which algorithm variant, limits and tolerances."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from dica.ica.core.limits import Kinematics, SpeedCaps

BASELINES = ("fifo", "concurrent", "tiles")  # reservation baselines (ica/core/baselines.py)
REACTIVE = ("rdica",)  # reactive DICA: emergency vehicles first (ica/core/reactive.py)
SOLVERS = ("exact", "ga", "exhaustive")  # its ordering solvers (ica/core/ordering/)
# [s] the most reorderings may add to any one normal vehicle by default: on held-out seeds
# 1 to 6 (volumes 100 to 500, 1 h) 2 s kept every seed's longest normal trip within 1.03x
# plain DICA's (unbounded: up to 1.63x) and the EVs' mean trip within 0.49x the reactive
# light's; 3 s let one seed's reach 1.12x, 1 s the EVs' 0.51x (docs/results.md)
MAX_ADDED_DELAY_S = 2.0


@dataclass(frozen=True, slots=True)
class Techniques:
    """The four enhancements of chapter 4, each switchable on its own.

    1. ``reduced_set``: skip confirmed vehicles on compatible routes or whose
       crossing interval does not overlap the requester's.
    2. ``conflict_zones``: test only occupancies inside the offline conflict
       zone of the two routes.
    3. ``estimated_oti``: occupancy time intervals from the route's offline
       skip distances in one compiled pass instead of the exhaustive search.
       With ``exact_oti`` (enhanced DICA) the distances are those within which
       footprints surely overlap, and the exact test finds the nearest clear
       sample beyond: the exhaustive intervals, bit for bit. Without it, the
       dissertation's technique: the distances beyond which footprints surely
       do not overlap, an estimate never narrower than the exhaustive interval
       and often wider, which delays vehicles more.
    4. ``bisection``: for each occupancy of a confirmed vehicle, find the
       requester's occupancies whose intervals can overlap by binary search.

    All off is basic DICA (Algorithms 1-2); all on with exact intervals is
    enhanced DICA, which decides exactly as basic DICA does. ``t1+2+3+4`` is
    the dissertation's enhanced DICA, ``t3`` its technique 3 alone. The kind of
    interval travels with the ICA's offline tables
    (:func:`ica.core.zones.ConflictTables` ``exact_oti``), so an ICA built
    with another kind must be given matching tables
    (:func:`dica.ica.core.controller.build_controller` does).
    """

    reduced_set: bool = True
    conflict_zones: bool = True
    estimated_oti: bool = True
    bisection: bool = True
    exact_oti: bool = True

    @staticmethod
    def parse(name: str) -> Techniques:
        """'basic', 'enhanced', or 't' plus technique numbers joined by '+' ('t2+4').

        A name with technique 3 is the dissertation's technique 3 (estimated
        intervals); 'enhanced' has all four with exact intervals.
        """
        if name == "basic":
            return BASIC
        if name == "enhanced":
            return ENHANCED
        if not name.startswith("t"):
            raise ValueError(f"unknown DICA variant {name!r}: use basic, enhanced or t1..t4 (t2+4)")
        try:
            nums = {int(x) for x in name[1:].split("+")}
        except ValueError:
            raise ValueError(f"unknown DICA variant {name!r}") from None
        if not nums or not nums <= {1, 2, 3, 4}:
            raise ValueError(f"unknown DICA variant {name!r}: techniques are 1 to 4")
        names = [f.name for f in fields(Techniques)][:4]
        on = {n: (i + 1) in nums for i, n in enumerate(names)}
        return Techniques(**on, exact_oti=3 not in nums)


BASIC = Techniques(False, False, False, False)
ENHANCED = Techniques()
DISSERTATION_ENHANCED = Techniques(exact_oti=False)


@dataclass(frozen=True, slots=True)
class IcaConfig:
    """One ICA's settings; the defaults are the dissertation's set-up.

    ``margin_m`` grows every occupancy on each side: the gap the ICA keeps
    between footprints, and where tracking error or delay bounds go.
    A vehicle is head of its lane when every vehicle ahead of it has begun
    to enter the junction (the dissertation's rule); with ``platoon`` it is
    enough that every vehicle ahead of it is confirmed, so a queue can cross
    behind its leader at speed (see docs/architecture.md, "Platoons").
    """

    techniques: Techniques = ENHANCED
    step_s: float = 0.05
    margin_m: float = 0.25
    kinematics: Kinematics = field(default_factory=Kinematics)
    caps: SpeedCaps = field(default_factory=SpeedCaps)
    max_length_m: float = 12.0
    max_width_m: float = 3.0
    max_tss_samples: int = 4000
    on_route_tol_m: float = 0.2  # never more than margin_m is used: see validate.py
    heading_tol_rad: float = 0.2
    speed_tol_mps: float = 0.05
    accel_tol_mps2: float = 0.1
    max_request_age_s: float = 1.0  # [s] oldest observation a REQUEST may be planned from
    max_lead_s: float = 10.0  # [s] furthest ahead of its observation a plan may start
    # [s] how far off its plan in time a vehicle may be (tracking error, late
    # actuation): every confirmed occupancy interval is grown by it on each side
    time_pad_s: float = 0.0
    # [s] how late after a human driver's green time its roadside may still turn the head
    # green (the LIT's way there): the envelope's slow bound allows for it, and the
    # roadside drops a later LIT (sim_gateway/humans.py)
    green_late_s: float = 0.0
    platoon: bool = False
    # [s] a follower keeps its lane leader's plan this much later in time as well as
    # ``2 * margin_m`` behind in space (the time-headway of a platoon)
    headway_s: float = 0.0
    # a plan may leave faster than a slower vehicle ahead on its exit lane, late enough
    # that the driver it is handed to never brakes (ica/core/handover.py), where
    # checkFV's cap alone would slow it to that vehicle's speed
    exit_spacing: bool = False
    max_iterations: int = 2000
    max_wait_s: float = 300.0

    def __post_init__(self) -> None:
        if not (0 < self.step_s <= 1.0):
            raise ValueError("step_s must be in (0, 1] seconds")
        if not 0.0 <= self.margin_m <= 5.0:
            raise ValueError("margin_m must be between 0 and 5 m")
        if not 0.0 <= self.time_pad_s <= 5.0:
            raise ValueError("time_pad_s must be between 0 and 5 s")
        if not 0.0 <= self.green_late_s <= 5.0:
            raise ValueError("green_late_s must be between 0 and 5 s")
        if not 0.0 <= self.headway_s <= 5.0:
            raise ValueError("headway_s must be between 0 and 5 s")
        if not 0.0 < self.max_request_age_s <= 60.0:
            raise ValueError("max_request_age_s must be in (0, 60] s")
        if not 0.0 <= self.max_lead_s <= 60.0:
            raise ValueError("max_lead_s must be between 0 and 60 s")
