"""Every message the processes exchange, as typed, versioned definitions.

One dataclass per message kind. Fields carry their wire limits in their
metadata (``lim``): numbers their closed range, strings, lists and arrays their
maximum length. :mod:`schemas.codec` enforces them when bytes become objects,
so code that receives a message can rely on its types and ranges.

Every message that crosses a link carries ``sent_ns`` (the sender's wall
clock, ns since the epoch) and, where it matters, the sim time it refers to,
so delay and loss can be measured and injected on exactly these links.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

# 12: an ASKGREEN and a LIT carry ``speed_mps`` (a driver given its green rolling towards
# its line); 11: EVCOMING exists (notices of emergency vehicles on their way);
# 10: SPOTTED, ASKGREEN, LIT, SIGHTING and SHRUNK exist (human drivers), and a vehicle
# state carries a human driver's ``signal``;
# 9: a WALK carries ``near_lo_m`` (the shortest way the walker may take to the crossing),
# a GO the whole slot (the ICA also publishes it for observers), and PEOPLE exists;
# 8: a WALK carries the walker's ``walk_m``, ``speed_mps``, ``side`` and ``near_m``, and
# ACROSS exists;
# 7: a REQUEST and a vehicle state carry ``network_room_m`` (the network gate); 6: they
# carry ``exit_room_m``; 5: a vehicle state carries ``intent_m``; 4: ``follows`` and
# REORDER; 3: DETECT carries the EV flag and the detection speed, a vehicle state ``ev``
# and ``kept_seq``, a setpoint ``drop``, and REVOKE exists (2 had no revocations; 1 had
# open-loop speed commands)
VERSION = 13
MAX_SAMPLES = 8192  # TSS samples: 400 s at 0.05 s, beyond any request the ICA accepts
MAX_VEHICLES = 2048  # vehicles in one STATE or COMMAND batch
MAX_TEXT = 128  # VINs, lane and route ids, agent names
MAX_DETAIL = 512  # human-readable reasons
MAX_STATS = 64 * 1024  # [bytes] a role's statistics as JSON text
BIG = 1e9 + 1  # [s] or [m]: the outer bound of every time and distance on the wire


def lim(lo: float | None = None, hi: float | None = None, *, n: int | None = None, **default):
    """A field with wire limits: ``lo..hi`` for numbers, ``n`` items for text and arrays
    (and a ``default=`` for the Python constructor; the wire always carries the field)."""
    return field(metadata={"lim": (lo, hi, n)}, **default)


TIME = (-BIG, BIG)


@dataclass(frozen=True, slots=True, eq=False)
class Request:
    """A head vehicle asks to cross: its size, the state it planned from, its TSS."""

    KIND: ClassVar[str] = "request"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(0, 2**31 - 1)
    in_lane: str = lim(n=MAX_TEXT)
    out_lane: str = lim(n=MAX_TEXT)
    length_m: float = lim(0.0, 100.0)
    width_m: float = lim(0.0, 20.0)
    t0_s: float = lim(*TIME)  # sim time of the state below; the TSS starts here
    dist_to_entry_m: float = lim(-BIG, BIG)
    speed_mps: float = lim(0.0, 200.0)
    t_s: np.ndarray = lim(n=MAX_SAMPLES)
    x_m: np.ndarray = lim(n=MAX_SAMPLES)
    y_m: np.ndarray = lim(n=MAX_SAMPLES)
    heading_rad: np.ndarray = lim(n=MAX_SAMPLES)
    t_obs_s: float = lim(*TIME)  # when the vehicle observed what it planned from (<= t0_s)
    sent_ns: int = lim(0, 2**63 - 1)
    # room on its exit lane beyond the junction when it observed [m] (BIG: not known)
    exit_room_m: float = lim(0.0, BIG, default=BIG)
    # room left in the network of junctions for it when it observed [m] (BIG: it is not
    # entering one)
    network_room_m: float = lim(0.0, BIG, default=BIG)


@dataclass(frozen=True, slots=True, eq=False)
class Response:
    """The ICA's confirmation: a conflict-free TSS the vehicle can fly from its state."""

    KIND: ClassVar[str] = "response"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(0, 2**31 - 1)
    route_id: str = lim(n=MAX_TEXT)
    t_s: np.ndarray = lim(n=MAX_SAMPLES)
    x_m: np.ndarray = lim(n=MAX_SAMPLES)
    y_m: np.ndarray = lim(n=MAX_SAMPLES)
    heading_rad: np.ndarray = lim(n=MAX_SAMPLES)
    entry_time_s: float = lim(*TIME)
    exit_time_s: float = lim(*TIME)
    delay_s: float = lim(0.0, BIG)
    iterations: int = lim(0, 2**31 - 1)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Reject:
    """The ICA will not confirm this request; ``reason`` is a stable code."""

    KIND: ClassVar[str] = "reject"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(-1, 2**31 - 1)  # -1 when the request was too broken to read one
    reason: str = lim(n=64)
    detail: str = lim(n=MAX_DETAIL)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Walk:
    """A walker at the kerb of ``crossing`` (SUMO's crossing edge id) since sim time
    ``ready_s`` asks to cross; the roadside asks for it (its detector or push button).
    As the roadside sees it: the walker stands ``near_m`` short of the crossing's end
    ``side`` (0: the first point of its centre line in the net, 1: the last) by the way
    round the corner, and ``near_lo_m`` as the crow flies to the crossing's end (the
    ICA takes it as soon on the crossing as that allows), has
    ``walk_m`` to go until it is off the corner beyond, and walks at ``speed_mps`` (0:
    not known; the ICA plans a slow walk anyway)."""

    KIND: ClassVar[str] = "walk"
    person: str = lim(n=MAX_TEXT)
    crossing: str = lim(n=MAX_TEXT)
    ready_s: float = lim(*TIME)
    walk_m: float = lim(0.0, 1000.0)
    speed_mps: float = lim(0.0, 10.0)
    side: int = lim(0, 1)
    near_m: float = lim(0.0, 1000.0)
    near_lo_m: float = lim(0.0, 1000.0)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Across:
    """The roadside saw walker ``person`` off ``crossing`` and its corners at sim time
    ``t_s``: its slot ends there (the ICA answers with an ACK)."""

    KIND: ClassVar[str] = "across"
    person: str = lim(n=MAX_TEXT)
    crossing: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Go:
    """The ICA's answer to a WALK: ``crossing`` is the walker's from ``start_s`` to
    ``end_s`` (sim time); no vehicle is confirmed through it meanwhile. The rest is the
    slot whole (``ica.core.walk.WalkSlot``: where the walker starts, how fast it may go),
    given at the ICA's ``given_s``, for an observer to draw what the walker holds."""

    KIND: ClassVar[str] = "go"
    person: str = lim(n=MAX_TEXT)
    crossing: str = lim(n=MAX_TEXT)
    start_s: float = lim(*TIME)
    end_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)
    given_s: float = lim(*TIME, default=0.0)
    side: int = lim(0, 1, default=0)
    near_m: float = lim(0.0, 1000.0, default=0.0)
    near_lo_m: float = lim(0.0, 1000.0, default=0.0)
    v_lo: float = lim(0.0, 20.0, default=1.0)
    v_hi: float = lim(0.0, 20.0, default=2.5)
    eta_s: float = lim(*TIME, default=0.0)
    late_s: float = lim(0.0, 10.0, default=0.0)  # the roadside may let it go this late


@dataclass(frozen=True, slots=True)
class Spotted:
    """The roadside's detector saw human driver ``vin`` enter the communication region
    on ``lane`` at sim time ``t_s``: a car the ICA cannot command, with no intent."""

    KIND: ClassVar[str] = "spotted"
    vin: str = lim(n=MAX_TEXT)
    lane: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class AskGreen:
    """Human driver ``vin`` stands ``near_m`` short of its line at the head of its lane at
    sim time ``t_s``, its signal head red: the roadside asks for its green. ``again``: it
    holds one still to come and asks for a sooner one (an ACK: none sooner)."""

    KIND: ClassVar[str] = "askgreen"
    vin: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    length_m: float = lim(0.0, 100.0)
    width_m: float = lim(0.0, 20.0)
    near_m: float = lim(0.0, 100.0)
    again: bool = lim()
    sent_ns: int = lim(0, 2**63 - 1)
    # above 0: rolling towards its line at this speed, not standing; a green now or none
    speed_mps: float = lim(0.0, 100.0, default=0.0)


@dataclass(frozen=True, slots=True)
class Lit:
    """The ICA's answer to an ASKGREEN, also published for observers: ``vin``'s head
    turns green at ``green_s``, asked at ``asked_s`` standing ``near_m`` short of its
    line; it may then take any of ``routes``, every crossing between its fastest and
    slowest reserved (``ica.core.envelope``, from the limits both sides derive from the
    site's configuration)."""

    KIND: ClassVar[str] = "lit"
    vin: str = lim(n=MAX_TEXT)
    green_s: float = lim(*TIME)
    asked_s: float = lim(*TIME)
    near_m: float = lim(0.0, 100.0)
    length_m: float = lim(0.0, 100.0)
    width_m: float = lim(0.0, 20.0)
    routes: tuple[str, ...] = lim(n=64)
    sent_ns: int = lim(0, 2**63 - 1)
    # what the ICA assumed, for an observer to draw the same envelope: the drivers' top
    # speed and the ICA's time step
    top_mps: float = lim(0.0, 200.0, default=0.0)
    step_s: float = lim(0.0, 10.0, default=0.0)
    speed_mps: float = lim(0.0, 100.0, default=0.0)  # given rolling at this speed (0: standing)
    late_s: float = lim(0.0, 10.0, default=0.0)  # the head may turn green this late


@dataclass(frozen=True, slots=True)
class Unlit:
    """The roadside kept human driver ``vin``'s head red at sim time ``t_s``: the LIT for
    its green of ``green_s`` came later than the head may still turn green
    (``--green-late``). The ICA frees that green's reservations (an ACK); the driver
    asks again. With a ``crossing``, ``vin`` is a walker kept at its kerb: the GO for its
    slot from ``green_s`` came too late, and the slot goes."""

    KIND: ClassVar[str] = "unlit"
    vin: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    green_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)
    crossing: str = lim(n=MAX_TEXT, default="")


@dataclass(frozen=True, slots=True)
class Sighting:
    """Human driver ``vin``, on its green, seen at sim time ``t_s`` on ``lane`` with its
    front ``s_m`` along its lane's routes at ``speed_mps``: the roadside asks the ICA to
    shrink its reservations to where it is (a SHRUNK, or an ACK: they stay)."""

    KIND: ClassVar[str] = "sighting"
    vin: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    lane: str = lim(n=MAX_TEXT)
    s_m: float = lim(-BIG, BIG)
    speed_mps: float = lim(0.0, 200.0)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class EvComing:
    """Emergency vehicle ``ev`` is on its way to the junction: in by edge ``in_edge``,
    out by ``out_edge``, its front at the entry line at sim time ``eta_s`` at the
    earliest (free flow from where it was at ``t_s``). Sent by the roadside every few
    seconds while the EV drives on (ica.core.ev_notice); answered with an ACK."""

    KIND: ClassVar[str] = "evcoming"
    ev: str = lim(n=MAX_TEXT)
    in_edge: str = lim(n=MAX_TEXT)
    out_edge: str = lim(n=MAX_TEXT)
    eta_s: float = lim(*TIME)
    t_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Shrunk:
    """The ICA's answer to a SIGHTING: ``vin``'s reservations now run from where it was
    seen at ``t_s``, on ``routes`` only (the ones it may still take)."""

    KIND: ClassVar[str] = "shrunk"
    vin: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    routes: tuple[str, ...] = lim(n=64)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Ack:
    """Delivery receipt: the ICA for a DETECT or CANCEL, a vehicle for a RESPONSE or a
    REVOKE. ``of`` is the kind acknowledged; for a REVOKE, ``revoke`` says the actuator
    dropped plan ``seq`` and ``kept`` that it could not (it flies on)."""

    KIND: ClassVar[str] = "ack"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(-1, 2**31 - 1)
    of: str = lim(n=32)  # the kind acknowledged
    sent_ns: int = lim(0, 2**63 - 1)


KEPT = "kept"  # Ack.of: a REVOKE received, but the actuator could not drop the plan


@dataclass(frozen=True, slots=True)
class Revoke:
    """The ICA takes back confirmation ``seq`` (reactive DICA): drop it and stop short
    of the line, then ACK (``revoke``, or ``kept`` if it cannot stop); sent again until
    answered. ``t_s`` is the sim time it was decided."""

    KIND: ClassVar[str] = "revoke"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(0, 2**31 - 1)
    t_s: float = lim(*TIME)
    sent_ns: int = lim(0, 2**63 - 1)


# Place.plan: what became of a vehicle's confirmation in a reordering
NOT_REVOKED = ""  # it had none to revoke (the EV, or not confirmed yet) or kept its place
REVOKED = "revoked"  # REVOKE sent, no answer yet: the plan may still be flown
DROPPED = "dropped"  # the vehicle dropped the plan (ACK revoke, or a CANCEL): withdrawn
# KEPT (above): it could not stop short of the line, the plan stands
EXPIRED = "expired"  # no answer came before the plan ended
PLANS = (NOT_REVOKED, REVOKED, DROPPED, KEPT, EXPIRED)


@dataclass(frozen=True, slots=True)
class Place:
    """One vehicle of a reordering, in the new crossing order, and what became of its
    confirmation ``seq`` (-1: none was revoked) as of sim time ``t_s``."""

    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(-1, 2**31 - 1)
    plan: str = lim(n=16)  # one of PLANS
    t_s: float = lim(*TIME)


@dataclass(frozen=True, slots=True)
class Reorder:
    """Reactive DICA reordered the vehicles for emergency vehicle ``ev`` at sim time
    ``t_s`` (ICA -> observers). Sent when decided and again whenever a revoked
    plan's fate changes, whole each time, so an observer that missed one is put
    right by the next. ``ev_entry_*_s``: the EV's entry by the ordering model in
    the present order and in the new one (NaN: not known); ``refused``: why the
    solver gave no order (the present one was kept)."""

    KIND: ClassVar[str] = "reorder"
    ev: str = lim(n=MAX_TEXT)
    lane: str = lim(n=MAX_TEXT)  # the EV's incoming lane
    t_s: float = lim(*TIME)
    solver: str = lim(n=32)
    order: tuple[Place, ...] = lim(n=MAX_VEHICLES)
    ev_entry_before_s: float = lim(*TIME, n=-1)
    ev_entry_after_s: float = lim(*TIME, n=-1)
    refused: str = lim(n=MAX_DETAIL)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Cancel:
    """The vehicle will not fly confirmation ``seq`` (it came too late): free it."""

    KIND: ClassVar[str] = "cancel"
    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(0, 2**31 - 1)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Detect:
    """A vehicle entered the communication region on ``lane`` at sim time ``t_s``;
    ``ev``: it is an emergency vehicle; ``speed_mps``: how fast it came in."""

    KIND: ClassVar[str] = "detect"
    vin: str = lim(n=MAX_TEXT)
    lane: str = lim(n=MAX_TEXT)
    t_s: float = lim(*TIME)
    ev: bool = lim()
    speed_mps: float = lim(0.0, 200.0)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """One vehicle as SUMO holds it this step, and the facts its agent needs.

    ``x_m, y_m`` is the front-bumper centre, ``angle_deg`` SUMO's heading
    (0 = north, clockwise). ``dist_to_entry_m`` is measured along the incoming
    lane (meaningful while ``lane`` is that lane). ``head``: no vehicle is ahead
    on the incoming lane. ``detected_s`` is when it crossed the communication
    region's entry line (NaN before). ``exited``: its rear has left the junction.
    ``plan_seq`` is the plan its actuator holds (-1: none), ``refused_seq`` the
    last plan it refused because it arrived after its start or dropped on a
    REVOKE (-1: none), ``kept_seq`` the last plan it was told to drop and kept,
    unable to stop short of the line. ``ev``: an emergency vehicle. ``follows``:
    platoons are on and the vehicle ahead on the incoming lane holds a plan, so
    this one may ask to follow it. ``owner``
    is the agent that hosts it. ``intent_m``: where its actuator will take it
    over the next steps without a new plan (route positions, m; empty if not
    predicted), for the plan its agent asks ahead of time. The first STATE that
    names a vehicle to an agent hands it to that agent.
    """

    vin: str = lim(n=MAX_TEXT)
    route_id: str = lim(n=MAX_TEXT)
    lane: str = lim(n=MAX_TEXT)
    dist_to_entry_m: float = lim(-BIG, BIG)
    speed_mps: float = lim(-1.0, 200.0)
    x_m: float = lim(-BIG, BIG)
    y_m: float = lim(-BIG, BIG)
    angle_deg: float = lim(-720.0, 720.0)
    length_m: float = lim(0.0, 100.0)
    width_m: float = lim(0.0, 20.0)
    max_speed_mps: float = lim(0.0, 200.0)  # the speed it wants when free
    head: bool = lim()
    detected_s: float = lim(*TIME, n=-1)  # n=-1: NaN allowed (not yet detected)
    exited: bool = lim()
    plan_seq: int = lim(-1, 2**31 - 1)
    refused_seq: int = lim(-1, 2**31 - 1)
    kept_seq: int = lim(-1, 2**31 - 1)
    ev: bool = lim()
    follows: bool = lim()
    owner: str = lim(n=MAX_TEXT)
    # its actuator's prediction of its route position [m] after each of the next steps,
    # should no plan reach it (empty: not predicted; see Observation.intent_m)
    intent_m: np.ndarray = lim(n=MAX_SAMPLES)
    # room on its exit lane beyond the junction [m] (BIG: not measured; see
    # Observation.exit_room_m)
    exit_room_m: float = lim(0.0, BIG, default=BIG)
    # room left in the network of junctions for it [m] (BIG: not entering one; see
    # Observation.network_room_m)
    network_room_m: float = lim(0.0, BIG, default=BIG)
    # a human driver's signal head, "red" or "green" (observers only; "": a connected
    # vehicle)
    signal: str = lim(n=8, default="")


@dataclass(frozen=True, slots=True)
class State:
    """This step's states of the vehicles one agent hosts (gateway -> agent, observers)."""

    KIND: ClassVar[str] = "state"
    agent: str = lim(n=MAX_TEXT)
    step: int = lim(0, 2**62)
    part: int = lim(0, MAX_VEHICLES)  # lockstep: which wave of this step (see gateway)
    t_s: float = lim(*TIME)
    vehicles: tuple[VehicleState, ...] = lim(n=MAX_VEHICLES)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class PersonPlace:
    """One person near the junction as SUMO places it (its centre), and whether it is
    held at the kerb waiting for the ICA's go."""

    x_m: float = lim(-BIG, BIG)
    y_m: float = lim(-BIG, BIG)
    waiting: bool = lim()


@dataclass(frozen=True, slots=True)
class People:
    """This step's people of the junction (gateway -> observers): what a roadside camera
    would see, for the recording's top view and crossing bands."""

    KIND: ClassVar[str] = "people"
    step: int = lim(0, 2**62)
    t_s: float = lim(*TIME)
    people: tuple[PersonPlace, ...] = lim(n=MAX_VEHICLES)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True, eq=False)
class Setpoint:
    """A plan for one vehicle's actuator: route positions, one per step from ``t0_s``.

    ``s_m`` is the front's position along the route [m], 0 at the entry line;
    the actuator flies it by position and takes it only if it arrives by
    ``t0_s``. ``seq`` is the confirmation it comes from (-1 and no positions:
    no new plan, only ``wake_s``). ``drop``: give up every plan up to ``seq``
    (revoked) and stop short of the line, if the vehicle still can.
    """

    vin: str = lim(n=MAX_TEXT)
    seq: int = lim(-1, 2**31 - 1)
    t0_s: float = lim(*TIME, n=-1)  # NaN without a plan
    s_m: np.ndarray = lim(n=MAX_SAMPLES)
    wake_s: float = lim(*TIME)  # next sim time it may DETECT or REQUEST (-1e9: now, 1e9: never)
    drop: bool = lim()


@dataclass(frozen=True, slots=True)
class Command:
    """An agent's answer to one STATE: setpoints for the vehicles that need new ones."""

    KIND: ClassVar[str] = "command"
    agent: str = lim(n=MAX_TEXT)
    step: int = lim(0, 2**62)
    part: int = lim(0, MAX_VEHICLES)  # echoes the STATE's part
    setpoints: tuple[Setpoint, ...] = lim(n=MAX_VEHICLES)
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Clock:
    """The sim clock (gateway -> everyone). ``end`` says the run is over."""

    KIND: ClassVar[str] = "clock"
    step: int = lim(0, 2**62)
    t_s: float = lim(*TIME)
    mode: str = lim(n=16)  # "lockstep" or "realtime"
    speed: float = lim(0.0, 1000.0)  # realtime: sim seconds per wall second
    end: bool = lim()
    sent_ns: int = lim(0, 2**63 - 1)


@dataclass(frozen=True, slots=True)
class Stats:
    """A role's statistics for the run's record (answer to a stats query)."""

    KIND: ClassVar[str] = "stats"
    role: str = lim(n=32)
    name: str = lim(n=MAX_TEXT)
    json: str = lim(n=MAX_STATS)
    sent_ns: int = lim(0, 2**63 - 1)


MESSAGES: tuple[type, ...] = (
    Request,
    Response,
    Reject,
    Walk,
    Across,
    Go,
    Spotted,
    AskGreen,
    Lit,
    Unlit,
    Sighting,
    Shrunk,
    EvComing,
    Ack,
    Revoke,
    Reorder,
    Cancel,
    Detect,
    State,
    Command,
    Clock,
    Stats,
    People,
)
