"""Every intersection controller behind one interface, built in one place.

The embedded runner, the ICA process, the request stream and the benchmarks
drive a controller through :class:`Controller` alone and get it from
:func:`build_controller`; nothing else knows which class it is. Plain DICA,
its variants and the reservation baselines never take a confirmation back:
their revocation hooks are no-ops (:class:`dica.ica.core.dica.Dica`); reactive
DICA (:mod:`dica.ica.core.reactive`) fills them in.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Protocol

from dica.ica.core.baselines import Concurrent, Fifo, Tiles
from dica.ica.core.config import BASELINES, ENHANCED, REACTIVE, IcaConfig, Techniques
from dica.ica.core.dica import Confirmed, Dica
from dica.ica.core.ev_event import ReactiveConfig
from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Kinematics
from dica.ica.core.reactive import ReactiveDica
from dica.ica.core.request import Confirmation, Rejection, Request
from dica.ica.core.revocation import Answer, Reorder
from dica.ica.core.zones import ConflictTables


class Controller(Protocol):
    """What a caller may ask of a junction's controller.

    Requests: ``detect`` (a vehicle entered the communication region),
    ``handle`` (a REQUEST, answered), ``cancel`` (a plan that will not be
    flown), ``advance`` (the clock), ``adopt`` (a confirmation replayed from
    the journal). Revocations (reactive DICA; empty elsewhere): the
    reorderings and revocations to carry out, and the vehicles' answers to
    them (``acknowledge``: dropped, ``restore``: kept).
    """

    intersection: Intersection
    config: IcaConfig
    replans_revoked: bool  # the ICA re-plans revoked vehicles itself (in process)

    @property
    def confirmed(self) -> dict[str, Confirmed]: ...

    def prepare(self) -> None: ...

    def knows(self, vin: str) -> bool: ...

    def detect(
        self,
        vin: str,
        lane: str,
        t_s: float,
        emergency: bool = False,
        speed_mps: float | None = None,
    ) -> None: ...

    def handle(self, req: Request, now_s: float) -> Confirmation | Rejection: ...

    def cancel(self, vin: str, seq: int) -> bool: ...

    def advance(self, now_s: float) -> list[str]: ...

    def adopt(
        self, confirmation: Confirmation, length_m: float, width_m: float, in_lane: str
    ) -> None: ...

    def take_reorders(self) -> list[Reorder]: ...

    def take_answers(self) -> list[Answer]: ...

    def take_confirmations(self) -> list[Confirmation]: ...

    def due_revocations(self) -> list[tuple[str, int]]: ...

    def pending(self) -> tuple[str, ...]: ...

    def revoked_seq(self, vin: str) -> int | None: ...

    def acknowledge(self, vin: str, seq: int | None = None) -> list[Confirmation]: ...

    def restore(self, vin: str, seq: int | None = None) -> tuple[str, ...]: ...

    def settle(self) -> None: ...

    def summary(self, events: bool = False) -> dict | None: ...


@dataclass(frozen=True, slots=True)
class ControllerSpec:
    """Which controller, with which settings.

    ``algorithm``: a DICA variant (``basic``, ``enhanced``, ``t1``..``t4`` and
    their sums such as ``t2+4``), a baseline (``fifo``, ``concurrent``,
    ``tiles``) or ``rdica`` (reactive DICA). ``config`` holds every limit and
    tolerance, ``tile_m`` the tiles baseline's tile edge, ``reactive`` reactive
    DICA's ordering.
    """

    algorithm: str = "enhanced"
    config: IcaConfig = field(default_factory=IcaConfig)
    tile_m: float = 1.0
    reactive: ReactiveConfig = field(default_factory=ReactiveConfig)

    @classmethod
    def of(
        cls,
        algorithm: str,
        margin_m: float = 0.25,
        time_pad_s: float = 0.0,
        platoon: bool = False,
        headway_s: float = 0.0,
        run_up: bool = True,
        exit_spacing: bool = True,
        tile_m: float = 1.0,
        reactive: ReactiveConfig | None = None,
    ) -> ControllerSpec:
        """A spec from the options of a run or of the ICA process.

        A DICA variant's name gives its techniques; every other controller keeps
        enhanced DICA's machinery underneath. Raises ValueError for settings out
        of range (see :class:`IcaConfig`, :class:`ReactiveConfig`)."""
        try:
            techniques = Techniques.parse(algorithm)
        except ValueError:
            if algorithm not in BASELINES + REACTIVE:
                raise ValueError(
                    f"unknown controller {algorithm!r}: use basic, enhanced, t1..t4 (t2+4), "
                    + ", ".join(BASELINES + REACTIVE)
                ) from None
            techniques = ENHANCED
        config = IcaConfig(
            techniques=techniques,
            margin_m=margin_m,
            time_pad_s=time_pad_s,
            platoon=platoon,
            headway_s=headway_s,
            kinematics=Kinematics() if run_up else Kinematics.at_the_line(),
            exit_spacing=exit_spacing,
        )
        return cls(algorithm, config, tile_m, reactive or ReactiveConfig())

    def with_green_late(self, late_s: float) -> ControllerSpec:
        """This spec, human drivers' heads allowed to turn green up to ``late_s`` late
        (:attr:`IcaConfig.green_late_s`)."""
        return dataclasses.replace(
            self, config=dataclasses.replace(self.config, green_late_s=late_s)
        )


def build_controller(
    spec: ControllerSpec, intersection: Intersection, tables: ConflictTables | None = None
) -> Controller:
    """The controller ``spec`` names, for ``intersection``.

    ``tables`` shares DICA's offline conflict tables between controllers of
    the same junction and margin (a benchmark's variants); they must be of the
    spec's kind of intervals. Not prepared: call ``prepare()`` before serving.
    """
    name, config = spec.algorithm, spec.config
    if name == "fifo":
        return Fifo(intersection, config)
    if name == "concurrent":
        return Concurrent(intersection, config)
    if name == "tiles":
        return Tiles(intersection, config, spec.tile_m)
    # the kind of technique 3's intervals lives in the offline tables
    if tables is None:
        tables = ConflictTables(
            intersection, config.margin_m, exact_oti=config.techniques.exact_oti
        )
    elif tables.exact_oti != config.techniques.exact_oti:
        raise ValueError("shared conflict tables hold another kind of occupancy intervals")
    if name in REACTIVE:
        return ReactiveDica(intersection, config, tables, reactive=spec.reactive)
    return Dica(intersection, config, tables)


__all__ = ["BASELINES", "REACTIVE", "Controller", "ControllerSpec", "build_controller"]
