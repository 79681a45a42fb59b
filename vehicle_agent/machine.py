"""One connected vehicle's side of DICA, as a small state machine.

    approaching -> requesting -> confirmed -> crossing -> exited

*approaching*: not yet announced; once it has crossed the communication
region's entry line it sends a DETECT (over an asynchronous link it does
not wait for the answer before it may ask). *requesting*: without a plan it may
fly, the vehicle's own control stops it short of the junction's entry line
(:mod:`vehicle_agent.control`, run at the actuator every step, no message
needed); when it is head of its lane it sends a REQUEST (again ``retry_s``
after a rejection, half a step after NOT_HEAD). The REQUEST plans from a start
``lead_s`` ahead of the observed state, from where the stop law will have
taken the vehicle by then, so that an answer that takes a while still arrives
before its plan begins. A confirmation goes to the actuator, which flies it by
position only if it arrives before its start; the next observation says
whether it did (*confirmed*) or refused it as late, in which case the vehicle
cancels it and asks again under a new sequence number. *crossing*: its front
has passed the entry line. *exited*: its rear has left the junction (the
actuator hands it back to SUMO's driver by itself).

The machine does no I/O: it reads one observation per step, talks to the ICA
through an :class:`IcaLink` (in-process in the embedded runner, Zenoh queries
in a vehicle-agent process) and returns what its actuator must be told. A
link may answer at once or later (``PENDING``; the answer then comes through
:meth:`Vehicle.answered`). The same code runs in both modes, so they make the
same decisions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Final, Protocol

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Reason, Rejection, Request, RequestError
from dica.ica.core.route import Route
from dica.vehicle_agent.actuation import BIG, NO_PLAN, Actuation
from dica.vehicle_agent.control import predict_stop


class _Pending:
    """The answer is on its way (an asynchronous link); see :meth:`Vehicle.answered`."""

    def __repr__(self) -> str:
        return "PENDING"


PENDING: Final = _Pending()


class Phase(StrEnum):
    APPROACHING = "approaching"
    REQUESTING = "requesting"
    CONFIRMED = "confirmed"
    CROSSING = "crossing"
    EXITED = "exited"


class IcaLink(Protocol):
    """How a vehicle reaches its ICA."""

    def detect(self, vin: str, lane: str, t_s: float) -> Rejection | _Pending | None: ...

    def request(self, req: Request, now_s: float) -> Confirmation | Rejection | _Pending: ...

    def cancel(self, vin: str, seq: int) -> None: ...

    def answer_revoke(self, vin: str, seq: int, dropped: bool) -> None:
        """Tell the ICA whether the actuator dropped revoked plan ``seq`` (ACK) or
        kept it, being unable to stop short of the line."""
        ...


@dataclass(frozen=True, slots=True)
class Observation:
    """What the vehicle knows about itself this step (from its sensors, or the gateway)."""

    t_s: float
    lane: str
    dist_to_entry_m: float  # along the incoming lane, front bumper to entry line
    speed_mps: float
    head: bool  # no vehicle ahead on the incoming lane
    detected_s: float  # when it crossed the region's entry line; NaN before
    exited: bool  # rear out of the junction
    plan_seq: int = NO_PLAN  # the plan the actuator holds (waiting for its start, or flying)
    refused_seq: int = NO_PLAN  # the last plan the actuator refused (too late) or dropped
    kept_seq: int = NO_PLAN  # the last plan it was told to drop and kept: it could not stop
    # platoons: the vehicle ahead on the incoming lane holds a plan, so this one may ask
    # to follow it (the ICA plans it behind that plan)
    follows: bool = False
    # where its own control law takes it over the next steps if no plan comes [route
    # position, m, after each step]: a plan asked for ahead of time starts there
    intent_m: tuple[float, ...] = ()
    # the room on its exit lane beyond the junction [m] (its own sensing or the roadside's:
    # the space the vehicles there take were they to queue; inf: not measured)
    exit_room_m: float = math.inf
    # the room left in the network of junctions for it, were it let in from outside [m]
    # (the roadside's count; inf: it is not entering a network: ica.core.gridlock)
    network_room_m: float = math.inf

    @property
    def may_ask(self) -> bool:
        return self.head or self.follows


@dataclass(slots=True)
class Vehicle:
    vin: str
    route: Route
    length_m: float
    width_m: float
    max_speed_mps: float  # the speed it entered with and would keep when free
    config: IcaConfig
    retry_s: float = 0.5
    lead_s: float = 0.0  # [s] how far ahead of its observation a REQUEST's plan starts
    phase: Phase = Phase.APPROACHING
    next_request_s: float = 0.0
    last_seq: int = NO_PLAN  # the newest REQUEST sent; only its answer counts
    pending: bool = False  # a REQUEST awaits its answer
    announcing: bool = False  # a DETECT awaits its answer
    held: Actuation | None = None  # a plan sent to the actuator, its verdict not yet seen
    confirmation: Confirmation | None = None  # the plan the actuator flies
    rejections: dict[str, int] = field(default_factory=dict)
    _answer: Confirmation | None = None  # the confirmation behind ``held``
    revoking: int = NO_PLAN  # a revoked plan whose drop awaits the actuator's verdict
    revoked_seq: int = NO_PLAN  # the newest revoked plan whose verdict the ICA was told
    revoke_dropped: bool = True  # that verdict

    def step(self, obs: Observation, link: IcaLink) -> Actuation | None:
        """Advance one step; what the actuator must be told, or None for nothing new."""
        if self.revoking != NO_PLAN:
            done = self._revoke_verdict(obs, link)
            if done is not None:
                return done
        if obs.exited:
            self.phase = Phase.EXITED
            return None
        if self.held is not None and (verdict := self._verdict(obs, link)) is not None:
            return verdict
        cmd = None
        if self.phase is Phase.APPROACHING:
            if math.isnan(obs.detected_s) or self.announcing:
                return None
            rej = link.detect(self.vin, self.route.in_lane, obs.detected_s)
            if rej is PENDING:
                # its REQUEST need not wait for the DETECT's answer: the ICA orders a lane
                # by detection time, and answers NOT_DETECTED a REQUEST it cannot place
                self.announcing = True
                self.phase = Phase.REQUESTING
            else:
                cmd = self.detected(rej, obs.t_s)
                if self.phase is not Phase.REQUESTING:
                    return cmd
        if self.phase is Phase.REQUESTING:
            if (
                self.held is None
                and not self.pending
                and obs.t_s >= self.next_request_s
                and obs.may_ask
            ):
                return self._request(obs, link)
            return cmd
        if self.phase is Phase.CONFIRMED:
            if obs.lane != self.route.in_lane:
                self.phase = Phase.CROSSING
            elif obs.plan_seq == NO_PLAN:  # the actuator dropped it (taken over from another agent)
                return self._unflown(self.last_seq, obs, link)
        return None

    def detected(self, rej: Rejection | None, now_s: float) -> Actuation | None:
        """The ICA's answer to this vehicle's DETECT (None: accepted)."""
        self.announcing = False
        if self.phase is Phase.REQUESTING and rej is not None:
            # asked already (an asynchronous link): announce again unless a REQUEST is out,
            # whose answer says whether the ICA knows the vehicle after all
            self._count(rej.reason.value)
            if self.pending or self.held is not None:
                return None
            self.phase = Phase.APPROACHING
            return Actuation(self.vin, wake_s=-BIG)
        if self.phase is not Phase.APPROACHING:
            return None
        if rej is not None:
            self._count(rej.reason.value)
            return Actuation(self.vin, wake_s=-BIG)  # announce again next step; never enter
        self.phase = Phase.REQUESTING
        return Actuation(self.vin, wake_s=self.next_request_s)  # it may ask once head

    def answered(self, answer: Confirmation | Rejection, now_s: float) -> Actuation | None:
        """The ICA's answer to a REQUEST; answers to any but the newest are stale, and
        so is one whose plan has been revoked meanwhile."""
        if answer.seq != self.last_seq or self.phase is not Phase.REQUESTING:
            return None
        if answer.seq <= max(self.revoking, self.revoked_seq):
            return None
        if self.held is not None:  # a repeat of the answer already taken
            return None
        self.pending = False
        if isinstance(answer, Confirmation):
            self._answer = answer
            t0 = float(answer.tss.t_s[0])
            self.held = Actuation(self.vin, answer.seq, t0, _positions(self.route, answer), BIG)
            return self.held
        self._count(answer.reason.value)
        if answer.reason is Reason.NOT_DETECTED:  # the ICA lost track of it: announce again
            self.phase = Phase.APPROACHING
            return Actuation(self.vin, wake_s=-BIG)
        if answer.reason is Reason.NO_ANSWER:
            wait = self.config.step_s  # the query has waited its timeout already
        elif answer.reason is Reason.NOT_HEAD:
            wait = self.config.step_s / 2  # the lane's order is about to change
        elif answer.reason is Reason.HELD:
            # held for an emergency vehicle's reordering: what it waits for (an answer to a
            # revocation, the EV's plan, those ordered before it) comes within a step or
            # two, and every step it waits longer it brakes further from what was planned:
            # it asks at the next step (half a step on, so no rounding skips one)
            wait = self.config.step_s / 2
        else:
            wait = self.retry_s
        self.next_request_s = now_s + wait
        return Actuation(self.vin, wake_s=self.next_request_s)

    def _verdict(self, obs: Observation, link: IcaLink) -> Actuation | None:
        """Whether the actuator flies the held plan, or it never will.

        Taken is not flown: an actuator that took a plan still refuses it at
        its start if the vehicle is not where the plan begins. Once the start
        has passed, the actuator either flies it or never will.
        """
        held = self.held
        assert held is not None
        started = obs.t_s > held.t0_s + 1e-6
        if obs.refused_seq == held.seq or (started and obs.plan_seq != held.seq):
            return self._unflown(held.seq, obs, link)
        if started:
            self.confirmation = self._answer
            self.held = None
            self.phase = Phase.CONFIRMED if obs.lane == self.route.in_lane else Phase.CROSSING
        return None

    def _unflown(self, seq: int, obs: Observation, link: IcaLink) -> Actuation:
        """Never flown, and it never will be: free the reservation and ask again."""
        self._count("unflown")
        self.held = None
        self._answer = None
        self.confirmation = None
        self.phase = Phase.REQUESTING
        link.cancel(self.vin, seq)
        self.next_request_s = obs.t_s
        return Actuation(self.vin, wake_s=obs.t_s)

    def revoked(self, confirmation: Confirmation | None, now_s: float) -> Actuation:
        """The ICA revoked this vehicle's confirmation (reactive DICA) and, unless
        ``confirmation`` is None, confirmed it again under the next seq, from where
        its old plan has it at the new plan's start. The actuator flies the old
        plan up to that start and the new one from there, as one plan; if it
        cannot (the vehicle is off its plan), it refuses it like a late one, and
        the vehicle cancels it and asks again. Without a new plan the actuator
        drops the old one, stops the vehicle short of the line, and the vehicle
        asks again. In-process runners call this; the revocation comes with the call.
        """
        old = self.confirmation if self.confirmation is not None else self._answer
        self.confirmation = self._answer = self.held = None
        self.phase = Phase.REQUESTING
        if confirmation is None:
            self.next_request_s = now_s
            return Actuation(self.vin, self.last_seq, wake_s=now_s, drop=True)
        h = self.config.step_s
        s_new = _positions(self.route, confirmation)
        t0 = float(confirmation.tss.t_s[0])
        if old is not None and t0 > now_s + 1e-9:
            s_old = _positions(self.route, old)
            k0 = round((now_s - float(old.tss.t_s[0])) / h)
            k1 = round((t0 - float(old.tss.t_s[0])) / h)
            s_new = np.concatenate([s_old[max(k0, 0) : max(k1, 0)], s_new])
            t0 = now_s
        elif t0 < now_s - 1e-9:
            s_new = s_new[round((now_s - t0) / h) :]
            t0 = now_s
        self.last_seq = max(self.last_seq, confirmation.seq)
        self._answer = confirmation
        self.held = Actuation(self.vin, confirmation.seq, t0, s_new, BIG)
        return self.held

    def revoke(self, seq: int, link: IcaLink) -> Actuation | None:
        """The ICA revoked plan ``seq`` and will not plan this vehicle again (the
        cluster's way): the actuator is told to drop every plan up to ``seq``. The
        next observation says whether it did (the vehicle then asks again like any
        head of its lane) or kept it, unable to stop short of the line; the ICA
        hears which (:meth:`IcaLink.answer_revoke`) and only then frees or restores
        the reservation. A repeated REVOKE is answered again and changes nothing.
        """
        if seq <= self.revoked_seq:
            link.answer_revoke(self.vin, self.revoked_seq, self.revoke_dropped)
            return None
        self.revoking = max(self.revoking, seq)
        if self.pending and self.last_seq <= seq and self.phase is Phase.REQUESTING:
            self.pending = False  # its answer, whatever it is, would be revoked too
        return Actuation(self.vin, self.revoking, drop=True)

    def _revoke_verdict(self, obs: Observation, link: IcaLink) -> Actuation | None:
        """The actuator's verdict on the drop of ``revoking``, once it shows."""
        r = self.revoking
        if obs.kept_seq >= r or (obs.plan_seq != NO_PLAN and obs.plan_seq <= r and obs.exited):
            self.revoking, self.revoked_seq, self.revoke_dropped = NO_PLAN, r, False
            link.answer_revoke(self.vin, r, False)
            return None  # it flies on, as before
        if obs.refused_seq < r:
            return Actuation(self.vin, r, drop=True)  # not heard yet (a lost COMMAND): again
        self.revoking, self.revoked_seq, self.revoke_dropped = NO_PLAN, r, True
        link.answer_revoke(self.vin, r, True)
        lost = self.phase is Phase.REQUESTING and self.held is None and self.last_seq <= r
        if self.held is not None and self.held.seq <= r:
            self.held = self._answer = None
            lost = True
        if self.confirmation is not None and self.confirmation.seq <= r:
            self.confirmation = None
            lost = True
        if lost and self.phase in (Phase.CONFIRMED, Phase.REQUESTING):
            self.phase = Phase.REQUESTING
            self.pending = False
            self.next_request_s = obs.t_s
        if obs.exited:
            return None
        cmd = self.step(obs, link)  # it may ask at once, being head of its lane
        return cmd if cmd is not None else Actuation(self.vin, wake_s=self.next_request_s)

    def _request(self, obs: Observation, link: IcaLink) -> Actuation | None:
        cfg = self.config
        h = cfg.step_s
        lead = max(round(self.lead_s / h), 0)
        d, v = max(obs.dist_to_entry_m, 0.0), obs.speed_mps
        if 0 < lead <= len(obs.intent_m):
            # the actuator's own prediction: it knows what the vehicle ahead will do
            before = obs.intent_m[lead - 2] if lead > 1 else -d
            d, v = -obs.intent_m[lead - 1], (obs.intent_m[lead - 1] - before) / h
        elif lead:
            kin = cfg.kinematics
            d, v = predict_stop(
                d,
                v,
                lead,
                gap_m=kin.stop_gap_m,
                cap_mps=min(self.max_speed_mps, v),  # a head vehicle does not speed up
                h=h,
                accel_mps2=kin.accel_mps2,
                decel_mps2=kin.decel_mps2,
            )
        # sequence numbers grow with the step observed, so a vehicle handed to another
        # agent still asks under numbers higher than any it asked under before
        seq = max(self.last_seq + 1, round(obs.t_s / h))
        self.last_seq = seq
        try:
            req = propose(
                self.route,
                vin=self.vin,
                seq=seq,
                t0_s=obs.t_s + lead * h,
                dist_to_entry_m=max(d, 0.0),
                speed_mps=v,
                length_m=self.length_m,
                width_m=self.width_m,
                config=cfg,
            )
            answer = link.request(
                replace(
                    req,
                    t_obs_s=obs.t_s,
                    exit_room_m=obs.exit_room_m,
                    network_room_m=obs.network_room_m,
                ),
                obs.t_s,
            )
        except RequestError as e:  # cannot even make a plan: stop and ask later
            answer = Rejection(self.vin, seq, e.reason, e.detail)
        if answer is PENDING:
            self.pending = True
            return None
        return self.answered(answer, obs.t_s)

    def adopt(self, obs: Observation) -> None:
        """Take over a vehicle from another agent, in the phase its actuator says it is."""
        if obs.plan_seq != NO_PLAN:
            self.phase = Phase.CONFIRMED if obs.lane == self.route.in_lane else Phase.CROSSING
            self.last_seq = obs.plan_seq

    def resend(self) -> Actuation | None:
        """The held plan again (for a link that may have lost it), while it can be flown."""
        return self.held

    def _count(self, reason: str) -> None:
        self.rejections[reason] = self.rejections.get(reason, 0) + 1


def _positions(route: Route, conf: Confirmation) -> np.ndarray:
    """Route positions [m] per step of a confirmed TSS, as the actuator flies it."""
    tss = conf.tss
    s, _ = route.project(np.stack([tss.x_m, tss.y_m], -1))
    return np.maximum.accumulate(s)
