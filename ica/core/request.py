"""What a head vehicle asks for, and the two answers it can get.

A REQUEST carries the vehicle's identity, size, the lanes it enters and
leaves by, the state it planned from, and its timed state sequence (TSS):
front-bumper position and heading every step from the plan's start until the
vehicle is fully out of the junction. Over a link with delay, a vehicle plans
from a start a little ahead of the state it observed (``t_obs_s``), from
the state its stopping manoeuvre will have reached by then, so the answer can
arrive before the plan begins. Everything in it is untrusted until
:func:`ica.core.validate.check_request` has accepted it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np


@dataclass(frozen=True, slots=True, eq=False)
class Tss:
    """Timed states: time [s], front-bumper x, y [m], heading [rad, CCW from +x]."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass(frozen=True, slots=True, eq=False)
class Request:
    vin: str
    seq: int
    in_lane: str
    out_lane: str
    length_m: float
    width_m: float
    t0_s: float  # time of the state below; the TSS starts here
    dist_to_entry_m: float  # front bumper to entry line, along the lane
    speed_mps: float
    tss: Tss
    t_obs_s: float = math.nan  # when the vehicle observed what it planned from; NaN: t0_s
    # [m] room on its exit lane beyond the junction at t_obs_s (inf: not known): the space
    # the vehicles there would take were they to queue (docs/architecture.md, "Room")
    exit_room_m: float = math.inf
    # [m] room left in the network of junctions at t_obs_s for a vehicle entering it from
    # outside (inf: not entering one): the network gate (ica.core.gridlock)
    network_room_m: float = math.inf


class Reason(StrEnum):
    """Why a request was not confirmed; stable codes for the wire and for logs."""

    BAD_TIME = "bad_time"  # non-increasing, non-finite or off-step times
    NOT_FINITE = "not_finite"
    BAD_SIZE = "bad_size"
    TOO_LARGE = "too_large"
    UNKNOWN_LANE = "unknown_lane"
    UNKNOWN_ROUTE = "unknown_route"
    OFF_ROUTE = "off_route"
    BAD_STATE = "bad_state"
    LIMITS = "limits"
    NOT_DETECTED = "not_detected"
    NOT_HEAD = "not_head"
    ALREADY_CONFIRMED = "already_confirmed"
    STALE = "stale"
    INFEASIBLE = "infeasible"
    BAD_MESSAGE = "bad_message"  # the bytes were not a valid REQUEST (see schemas.codec)
    NO_ANSWER = "no_answer"  # no reply within the timeout: the link or the ICA is down
    HELD = "held"  # an emergency vehicle goes first: ask again later (reactive DICA)
    # platoons: from this state the vehicle cannot follow its leader's plan yet (too close
    # for the headway, or every stop at the line would run into the leader): ask again
    FOLLOW = "follow"
    # its exit lane beyond the junction has no room for it yet: ask again later
    NO_ROOM = "no_room"
    # its plan would hold a pedestrian crossing too far ahead, where walkers at the kerb
    # may be given it first: ask again later
    WALKERS = "walkers"


class RequestError(Exception):
    """A request the ICA cannot accept; the peer's fault, answered with a REJECT."""

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True, slots=True, eq=False)
class Confirmation:
    """A confirmed, conflict-free trajectory the vehicle can fly from its state."""

    vin: str
    seq: int
    route_id: str
    tss: Tss
    entry_time_s: float
    exit_time_s: float
    delay_s: float  # entry time minus the earliest entry the vehicle could have had
    iterations: int  # getCV / updateDTOT rounds it took


@dataclass(frozen=True, slots=True)
class Rejection:
    vin: str
    seq: int
    reason: Reason
    detail: str
