"""What a controller that takes confirmations back tells its callers.

Reactive DICA (:mod:`dica.ica.core.reactive`) revokes confirmations to let an
emergency vehicle cross first; every controller hands out the same plain data
(:class:`dica.ica.core.controller.Controller`), plain DICA none of it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Reorder:
    """One EV event's decision, for the protocol layer to carry out."""

    t_s: float  # when it was decided
    effective_s: float  # when the revocations take effect
    ev: str
    solver: str
    order: tuple[str, ...]  # the modifiable vehicles, the EV among them, in crossing order
    revoked: tuple[str, ...]  # withdrawn confirmations, pending until acknowledged
    ev_entry_before_s: float  # the EV's entry by the ordering model, present order kept
    ev_entry_after_s: float  # the same in the new order
    solve_s: float  # the solver's wall time
    prepare_s: float  # the wall time of finding the candidates and measuring separations
    refused: str = ""  # why the solver gave no order (the present order is kept)
    lane: str = ""  # the EV's incoming lane
    seqs: tuple[int, ...] = ()  # the seq of each revoked confirmation, as in ``revoked``
    # [s] what the new order adds to each vehicle of ``order`` by the ordering model (its
    # entry less that in the present order, 0 if earlier; 0 for the EV)
    added_s: tuple[float, ...] = ()


DROPPED = "dropped"  # the vehicle gave up the revoked plan: its reservation is gone
KEPT = "kept"  # it could not stop short of the line: its reservation is its own again
EXPIRED = "expired"  # no answer came before the revoked plan ended


@dataclass(frozen=True, slots=True)
class Answer:
    """What became of one revoked confirmation, and when the ICA learnt it [sim s]:
    only a DROPPED plan is withdrawn; a KEPT one is still flown."""

    vin: str
    seq: int
    outcome: str  # DROPPED, KEPT or EXPIRED
    t_s: float
