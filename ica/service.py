"""The ICA process: the DICA core behind Zenoh queryables.

Keys (``schemas.keys``): each agent asks on its own chunk, REQUESTs on
``dica/<j>/request/<agent>`` (a RESPONSE or a REJECT), DETECTs on
``dica/<j>/detect/<agent>`` (an ACK or a REJECT), CANCELs on
``dica/<j>/cancel/<agent>``. The roadside (the gateway) alone tells of walkers on
``dica/<j>/walk/gateway`` and of human drivers on ``dica/<j>/human/gateway``
(SPOTTED, ASKGREEN, SIGHTING); a human driver's VIN is the roadside's, and no
agent may ask, detect or cancel for it. Every new confirmation is also published on
``dica/<j>/confirmed/<vin>`` for observers, reactive DICA's reorderings (and
what became of each revoked plan) on ``dica/<j>/reorder``, and the statistics
answer on ``dica/<j>/stats``.

Time: the ICA's clock is the sim CLOCK, taken only from the gateway's exact
key and only forward (an old or repeated CLOCK changes nothing). It never
takes a vehicle's word for the time: a request observed at a time the clock
has not reached waits (briefly) for the clock; one observed longer ago than
the declared bound, or whose plan would already have begun, is refused as
stale.

Repeats and loss: a repeated request (same VIN and sequence number) gets the
same confirmation, never a second reservation; an older one is refused; a
newer one means the vehicle did not fly the one it holds, which is then freed.

Whose vehicle: the first agent to announce a vehicle (its DETECT, on the
agent's own key) speaks for it from then on; another agent's DETECT, REQUEST
or CANCEL for it is refused, unless the gateway's vehicle feed says the
vehicle was handed to that agent (its first agent died). So one agent's
credentials cannot take back, or ask over, another agent's reservations.

Crashes: with a journal, every DETECT taken, confirmation given and
reservation freed is written to disk before it is answered, and a restarted
ICA replays it before it serves, so no confirmation after a restart conflicts
with one before. Only one ICA serves a junction: a second one waits until the
first one's liveliness token is gone. Bytes that are not a valid message get a
REJECT with the reason when a reply is possible, and are logged; the ICA keeps
serving.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dica.deploy.transport import Inbox, Item, note_refused, put, refused, reply
from dica.ica.convert import (
    go_from_slot,
    reject_from_core,
    request_to_core,
    response_from_core,
)
from dica.ica.core import reactive
from dica.ica.core.controller import Controller
from dica.ica.core.envelope import human_limits
from dica.ica.core.ev_notice import EvNotice
from dica.ica.core.request import Confirmation, Reason, Rejection, RequestError
from dica.ica.journal import Journal, Replayed, replay
from dica.schemas import keys
from dica.schemas.codec import DecodeError, decode, encode, now_ns
from dica.schemas.messages import (
    DROPPED,
    EXPIRED,
    KEPT,
    NOT_REVOKED,
    REVOKED,
    TIME,
    Ack,
    Across,
    AskGreen,
    Cancel,
    Clock,
    Detect,
    EvComing,
    Lit,
    Place,
    Reject,
    Reorder,
    Request,
    Revoke,
    Shrunk,
    Sighting,
    Spotted,
    State,
    Stats,
    Unlit,
    Walk,
)

HOLD_S = 2.0  # [s wall] longest a request may wait for the clock to reach its time
# [s sim] how far ahead of its last CLOCK the roadside may ask (a human driver's green, a
# sighting, an EV's notice): it asks at the start of its step, before that step's CLOCK
ROADSIDE_AHEAD_S = 1.0
HUMAN_OWNER = "gateway"  # who speaks for a human driver: the roadside, no agent
REVOKE_EVERY_S = 0.5  # [s wall] an unanswered REVOKE goes out again this often
STATS_EVERY_S = 5.0  # [s wall] how often the statistics file is rewritten
SHOWN_REORDERS = 16  # reorderings kept to tell observers what became of their revoked plans
# what became of a revoked plan, from the core's words to the wire's
_PLAN = {reactive.DROPPED: DROPPED, reactive.KEPT: KEPT, reactive.EXPIRED: EXPIRED}


@dataclass(slots=True)
class ServiceStats:
    requests: int = 0
    confirmed: int = 0
    repeated: int = 0
    superseded: int = 0
    detects: int = 0
    cancels: int = 0
    walks: int = 0  # walkers given a slot on a crossing
    humans: int = 0  # human drivers the roadside told of
    notices: int = 0  # emergency vehicles' notices the roadside gave
    greens: int = 0  # greens given them (sooner ones included)
    shrunk: int = 0  # their reservations shrunk to where they were seen
    unlit: int = 0  # greens the roadside dropped (late), their reservations freed
    bad_messages: int = 0
    acks: int = 0
    ignored_clocks: int = 0
    not_theirs: int = 0  # asked about another agent's vehicle
    handovers: int = 0  # vehicles the gateway handed to another agent
    rejections: dict[str, int] = field(default_factory=dict)
    compute_s: list[float] = field(default_factory=list)
    journal_replayed: dict | None = None
    revokes_sent: int = 0  # REVOKE messages, repeats included
    revoke_acks: int = 0  # answered: plan dropped (an ACK, or the vehicle asked again)
    revoke_kept: int = 0  # answered: the vehicle could not stop, its reservation restored
    reactive: dict | None = None  # reactive DICA's own figures

    def as_dict(self) -> dict:
        rt = np.array(self.compute_s) if self.compute_s else np.zeros(1)
        return {
            "requests": self.requests,
            "confirmed": self.confirmed,
            "repeated": self.repeated,
            "superseded": self.superseded,
            "detects": self.detects,
            "cancels": self.cancels,
            "walks": self.walks,
            "humans": self.humans,
            "notices": self.notices,
            "greens": self.greens,
            "shrunk": self.shrunk,
            "unlit": self.unlit,
            "bad_messages": self.bad_messages,
            "acks": self.acks,
            "ignored_clocks": self.ignored_clocks,
            "not_theirs": self.not_theirs,
            "handovers": self.handovers,
            "rejections": dict(self.rejections),
            "compute_median_ms": float(np.median(rt) * 1e3),
            "compute_p99_ms": float(np.percentile(rt, 99) * 1e3),
            "journal_replayed": self.journal_replayed,
            "revokes_sent": self.revokes_sent,
            "revoke_acks": self.revoke_acks,
            "revoke_kept": self.revoke_kept,
            "reactive": self.reactive,
            "refused_unsealed": refused(),
        }


class IcaService:
    """One junction's ICA: owns the core, answers the wire, publishes confirmations."""

    def __init__(
        self,
        session,
        ica: Controller,
        junction: str,
        log: logging.Logger,
        journal: Journal | None = None,
    ) -> None:
        self.session = session
        self.ica = ica
        self.junction = junction
        self.log = log
        self.journal = journal
        self.inbox = Inbox()
        self.now_s = -1.0
        self.clock_step = -1
        self.ended = False
        self.stats = ServiceStats()
        self._held: list[tuple[float, Item]] = []
        self._published: set[tuple[str, int]] = set()
        self._clock_key = keys.clock(junction)
        self._vehicles_key = keys.vehicles(junction)
        self._owner: dict[str, str] = {}  # VIN -> the agent that speaks for it
        self._decls: list = []
        self._token = None
        self._revoke_sent: dict[tuple[str, int], float] = {}  # (vin, seq) -> wall time sent
        self._shown: list[Reorder] = []  # the latest reorderings, as observers were told
        self._event_journalled: dict | None = None  # reactive DICA's event as last journalled
        cfg = ica.config  # the roadside derives the same
        self._driver_limits = human_limits(cfg.caps.road_mps, cfg.green_late_s)

    def restore(self, path: Path) -> Replayed:
        """Replay a journal into the core before serving (a restarted ICA)."""
        done = replay(path, self.ica)
        snap = getattr(self.ica, "snapshot", None)
        if snap is not None:
            self._event_journalled = snap()
        for vin, c in self.ica.confirmed.items():
            self._published.add((vin, c.confirmation.seq))
        for vin in done.humans:
            self._owner[vin] = HUMAN_OWNER
        self.stats.journal_replayed = {
            "detects": done.detects,
            "confirmations": done.confirmations,
            "cancels": done.cancels,
            "walks": done.walks,
            "greens": done.greens,
            "revocations": done.revocations,
            "skipped": done.skipped,
            "truncated": done.truncated,
            "confirmed_set_after": len(self.ica.confirmed),
        }
        return done

    def wait_alone(self, timeout_s: float = 30.0) -> None:
        """Wait while another ICA holds this junction's token: never two answering at once."""
        key = keys.ica_alive(self.junction)
        deadline = time.monotonic() + timeout_s
        noted = False
        while time.monotonic() < deadline and not self.inbox.stopping.is_set():
            if not list(self.session.liveliness().get(key, timeout=1.0)):
                return
            if not noted:
                self.log.warning(
                    "another ICA serves junction %s; waiting for it to go", self.junction
                )
                noted = True
            time.sleep(0.5)
        raise RuntimeError(f"another ICA still serves junction {self.junction}")

    def serve(self) -> None:
        """Declare the queryables and the token: from now on the ICA answers."""
        j = self.junction
        self._decls = [
            self.session.declare_queryable(keys.request(j), self.inbox.query_cb("request")),
            self.session.declare_queryable(keys.detect(j), self.inbox.query_cb("detect")),
            self.session.declare_queryable(keys.cancel(j), self.inbox.query_cb("cancel")),
            self.session.declare_queryable(keys.walk(j), self.inbox.query_cb("walk")),
            self.session.declare_queryable(keys.human(j), self.inbox.query_cb("human")),
            self.session.declare_queryable(keys.ev(j), self.inbox.query_cb("ev")),
            self.session.declare_queryable(keys.ica_stats(j), self.inbox.query_cb("stats")),
            self.session.declare_subscriber(self._clock_key, self.inbox.sample_cb("clock")),
            self.session.declare_subscriber(keys.ack(j), self.inbox.sample_cb("ack")),
            self.session.declare_subscriber(self._vehicles_key, self.inbox.sample_cb("vehicles")),
        ]
        self._token = self.session.liveliness().declare_token(keys.ica_alive(j))

    def run(self, idle_exit_s: float | None = None, stats_path: Path | None = None) -> None:
        """Serve until SIGTERM, the run's end on the clock, or ``idle_exit_s`` of silence."""
        last = time.monotonic()
        written = time.monotonic()
        if stats_path is not None:  # at once: one killed within STATS_EVERY_S is on record too
            write_stats(stats_path, self.stats)
        while not self.inbox.stopping.is_set() and not self.ended:
            item = self.inbox.get(timeout=0.1)
            self._expire_held()
            if item is None:
                self._revoke()  # resend what is still unanswered
            if time.monotonic() - written > STATS_EVERY_S:
                note_refused(self.log)
                if stats_path is not None:
                    self.note_reactive()
                    write_stats(stats_path, self.stats)
                written = time.monotonic()
            if item is None:
                if idle_exit_s is not None and time.monotonic() - last > idle_exit_s:
                    break
                continue
            last = time.monotonic()
            try:
                self._dispatch(item)
            except Exception:  # a bug must not take the junction's controller down
                self.log.exception("could not handle %s on %s", item.what, item.key)
            self._revoke()

    def close(self) -> None:
        for _, item in self._held:
            self._reject(item.query, "?", -1, Reason.BAD_TIME, "the ICA is stopping")
        self._held.clear()
        if self._token is not None:
            self._token.undeclare()
        for d in self._decls:
            d.undeclare()
        if self.journal is not None:
            self.journal.close()

    # -- messages ------------------------------------------------------------
    def _dispatch(self, item: Item) -> None:
        if item.what == "clock":
            self._on_clock(item)
        elif item.what == "request":
            self._on_request(item)
        elif item.what == "detect":
            self._on_detect(item)
        elif item.what == "cancel":
            self._on_cancel(item)
        elif item.what == "vehicles":
            self._on_vehicles(item)
        elif item.what == "walk":
            self._on_walk(item)
        elif item.what == "human":
            self._on_human(item)
        elif item.what == "ev":
            self._on_ev(item)
        elif item.what == "stats":
            self.note_reactive()
            body = json.dumps(self.stats.as_dict())
            reply(item.query, item.key, encode(Stats("ica", self.junction, body, now_ns())))
        elif item.what == "ack":
            try:
                ack = decode(item.payload, Ack)
            except DecodeError as e:
                self._bad(item, e)
                return
            self.stats.acks += 1
            if ack.of in (Revoke.KIND, KEPT):
                self._on_revoke_answer(item, ack)

    # -- revocations (reactive DICA) -----------------------------------------------
    def _revoke(self) -> None:
        """Send each revocation now due (again, if unanswered for REVOKE_EVERY_S).

        Published before the answer to the query that caused it: a lockstep agent
        then has it before it answers its STATE.
        """
        ica = self.ica
        self._journal_event()  # before any vehicle hears of it
        for r in ica.take_reorders():
            if r.revoked:
                self.log.info(
                    "EV %s: %d confirmations revoked (%s)", r.ev, len(r.revoked), r.solver
                )
            self._shown = [*self._shown[1 - SHOWN_REORDERS :], _reorder_message(r)]
            self._show(self._shown[-1])
        for a in ica.take_answers():
            self._show_answer(a)
        now = time.monotonic()
        due = ica.due_revocations()
        for vin, seq in due:
            sent = self._revoke_sent.get((vin, seq))
            if sent is not None and now - sent < REVOKE_EVERY_S:
                continue
            owner = self._owner.get(vin)
            if owner is None:
                continue  # nobody speaks for it yet: asked again later
            self._revoke_sent[(vin, seq)] = now
            self.stats.revokes_sent += 1
            msg = Revoke(vin, seq, self.now_s, now_ns())
            put(self.session, keys.revoke(self.junction, keys.chunk(owner)), encode(msg))
        if len(self._revoke_sent) > len(due):
            keep = set(due)
            self._revoke_sent = {k: t for k, t in self._revoke_sent.items() if k in keep}

    def _journal_event(self) -> None:
        """Journal reactive DICA's event whenever it has changed (a reordering, an answer
        to a revocation), so that a restarted ICA carries it on."""
        snap = getattr(self.ica, "snapshot", None)
        if self.journal is None or snap is None:
            return
        now = snap()
        if now != self._event_journalled:
            self.journal.reactive(now)
            self._event_journalled = now

    def _show(self, msg: Reorder) -> None:
        """Tell observers of a reordering, or of a change in what became of its plans."""
        put(self.session, keys.reorder(self.junction), encode(msg))

    def _show_answer(self, a: reactive.Answer) -> None:
        """A revoked plan was dropped, kept or ended unanswered: the reordering that
        revoked it goes out again, whole, with that vehicle's place updated."""
        for i in range(len(self._shown) - 1, -1, -1):
            msg = self._shown[i]
            places = list(msg.order)
            for j, p in enumerate(places):
                if p.vin == a.vin and p.seq == a.seq and p.plan == REVOKED:
                    places[j] = Place(p.vin, p.seq, _PLAN.get(a.outcome, EXPIRED), _time(a.t_s))
                    self._shown[i] = replace(msg, order=tuple(places), sent_ns=now_ns())
                    self._show(self._shown[i])
                    return

    def note_reactive(self) -> None:
        """Reactive DICA's figures into the statistics."""
        summary = self.ica.summary()
        if summary is not None:
            self.stats.reactive = summary

    def _on_revoke_answer(self, item: Item, ack: Ack) -> None:
        """A vehicle's answer to a REVOKE: its old reservation goes (plan dropped, and
        journalled as a cancel first, so a restart does not bring it back) or is its own
        again (it could not stop)."""
        ica = self.ica
        if not self._speaks_for(item, ack.vin):
            return
        if ack.vin not in ica.pending() or ack.seq < 0:
            return  # answered already (a repeat), or about nothing pending
        if ack.of == KEPT:
            ica.restore(ack.vin, ack.seq)
            self.stats.revoke_kept += 1
            self._journal_event()
            return
        if self.journal is not None:
            self.journal.cancel(ack.vin, ack.seq)
        counts = ica.revoked_seq(ack.vin) == ack.seq  # else an answer about another plan
        ica.acknowledge(ack.vin, ack.seq)
        self.stats.revoke_acks += counts
        self._journal_event()

    def _revoked_seq(self, vin: str) -> int | None:
        return self.ica.revoked_seq(vin)

    def _on_clock(self, item: Item) -> None:
        if item.key != self._clock_key:
            self.stats.ignored_clocks += 1
            return
        try:
            clock = decode(item.payload, Clock)
        except DecodeError as e:
            self._bad(item, e)
            return
        if clock.step <= self.clock_step:
            if not clock.end:
                self.stats.ignored_clocks += 1  # an old or repeated CLOCK
                return
        else:
            self.clock_step = clock.step
        if clock.t_s > self.now_s:
            self.now_s = clock.t_s
            self.ica.advance(self.now_s)
        held, self._held = self._held, []
        for since, h in held:  # each by its kind: a roadside's word, or a REQUEST
            {"human": self._on_human, "ev": self._on_ev}.get(h.what, self._on_request)(h, since)
        self.ended = clock.end

    def _on_vehicles(self, item: Item) -> None:
        """The gateway's word on who hosts each vehicle (it changes when an agent dies)."""
        if item.key != self._vehicles_key:
            return
        try:
            state = decode(item.payload, State)
        except DecodeError as e:
            self._bad(item, e)
            return
        for v in state.vehicles:
            before = self._owner.get(v.vin)
            if before == HUMAN_OWNER:  # a human driver is no agent's to be handed
                continue
            if v.owner and before != v.owner:
                self._owner[v.vin] = v.owner
                self.stats.handovers += before is not None
            if v.exited:
                self._owner.pop(v.vin, None)

    def _speaks_for(self, item: Item, vin: str) -> bool:
        """Whether the agent that asked (its key's last chunk) may speak for ``vin``."""
        owner = self._owner.get(vin)
        if owner == HUMAN_OWNER:  # a human driver's: the roadside's, on its own key
            return False
        return owner is None or owner == keys.last(item.key)

    def _on_request(self, item: Item, since: float | None = None) -> None:
        msg = self._asked(item, Request)
        if msg is None:
            return
        if not _is_chunk(msg.vin):
            self._reject(item.query, "?", msg.seq, Reason.BAD_STATE, "VIN has key characters")
            return
        if not self._speaks_for(item, msg.vin):
            self.stats.not_theirs += 1
            self._reject(item.query, msg.vin, msg.seq, Reason.BAD_STATE, "another agent's vehicle")
            return
        if msg.t_obs_s > self.now_s + 1e-9:
            # observed at a time the ICA's clock has not reached: the CLOCK for it
            # may still be on its way (another path through the router); wait for it
            self._held.append((since if since is not None else time.monotonic(), item))
            return
        self.stats.requests += 1
        req = request_to_core(msg)
        held = self.ica.confirmed.get(msg.vin)
        revoked = self._revoked_seq(msg.vin)
        t_c = time.perf_counter()
        answer = self.ica.handle(req, self.now_s)
        self.stats.compute_s.append(time.perf_counter() - t_c)
        if revoked is not None and self._revoked_seq(msg.vin) is None:
            # asking again under a higher seq answered the REVOKE (its ACK may still be on
            # its way): journalled as a cancel before anything this request decided
            if self.journal is not None:
                self.journal.cancel(msg.vin, revoked)
            self.stats.revoke_acks += 1
        if isinstance(answer, Confirmation):
            payload = encode(response_from_core(answer))
            if (answer.vin, answer.seq) in self._published:
                self.stats.repeated += 1
            else:
                if held is not None and held.confirmation.seq != answer.seq:
                    self.stats.superseded += 1
                if self.journal is not None:
                    self.journal.confirm(answer, msg.length_m, msg.width_m, msg.in_lane)
                # published before the reply: observers have it before the vehicle acts on it
                self._published.add((answer.vin, answer.seq))
                self.stats.confirmed += 1
                put(self.session, keys.confirmed(self.junction, keys.chunk(answer.vin)), payload)
            self._revoke()
            reply(item.query, item.key, payload)
            return
        self._count(answer)
        self._revoke()  # revocations this request caused go out before its answer
        reply(item.query, item.key, encode(reject_from_core(answer)))

    def _on_detect(self, item: Item) -> None:
        msg = self._asked(item, Detect)
        if msg is None:
            return
        self.stats.detects += 1
        if not _is_chunk(msg.vin):
            self._reject(item.query, "?", -1, Reason.BAD_STATE, "VIN has key characters")
            return
        if not self._speaks_for(item, msg.vin):
            self.stats.not_theirs += 1
            self._reject(item.query, msg.vin, -1, Reason.BAD_STATE, "another agent's vehicle")
            return
        known = self.ica.knows(msg.vin)
        try:
            self.ica.detect(msg.vin, msg.lane, msg.t_s, emergency=msg.ev, speed_mps=msg.speed_mps)
        except RequestError as e:
            self._count(Rejection(msg.vin, -1, e.reason, e.detail))
            self._reject(item.query, msg.vin, -1, e.reason, e.detail)
            return
        self._owner.setdefault(msg.vin, keys.last(item.key))
        if self.journal is not None and not known:
            self.journal.detect(msg.vin, msg.lane, msg.t_s, msg.ev, msg.speed_mps)
        reply(item.query, item.key, encode(Ack(msg.vin, -1, Detect.KIND, now_ns())))

    def _on_cancel(self, item: Item) -> None:
        msg = self._asked(item, Cancel)
        if msg is None:
            return
        if not self._speaks_for(item, msg.vin):
            self.stats.not_theirs += 1
            self._reject(item.query, msg.vin, msg.seq, Reason.BAD_STATE, "another agent's vehicle")
            return
        if self.ica.cancel(msg.vin, msg.seq):
            self.stats.cancels += 1
            if self.journal is not None:
                self.journal.cancel(msg.vin, msg.seq)
        reply(item.query, item.key, encode(Ack(msg.vin, msg.seq, Cancel.KIND, now_ns())))

    def _on_walk(self, item: Item) -> None:
        """A walker at the kerb (WALK), or across (ACROSS), told by the roadside: the slot
        journalled before it is answered (a restarted ICA never confirms a vehicle through
        it), or its end brought forward."""
        msg = self._from_roadside(item, (Walk, Across), "walks", "crossings")
        if msg is None:
            return
        walks = self.ica.walks
        if isinstance(msg, Across):
            try:
                if self.ica.walked(msg.person, msg.crossing, msg.t_s) and self.journal:
                    self.journal.across(msg.person, msg.crossing, msg.t_s)
            except RequestError as e:
                self._reject(item.query, msg.person, -1, e.reason, e.detail)
                return
            reply(item.query, item.key, encode(Ack(msg.person, -1, Across.KIND, now_ns())))
            return
        again = walks.slot_of(msg.person, msg.crossing) is not None
        try:
            slot = self.ica.walk(
                msg.person, msg.crossing, msg.ready_s, self.now_s, msg.walk_m, msg.speed_mps,
                msg.side, msg.near_m, msg.near_lo_m,
            )  # fmt: skip
        except RequestError as e:
            self._reject(item.query, msg.person, -1, e.reason, e.detail)
            return
        payload = encode(go_from_slot(slot, self.now_s))
        if again:
            self.stats.repeated += 1  # the same slot again, journalled already
        else:
            if self.journal is not None:
                self.journal.walk(slot)
            self.stats.walks += 1
            put(self.session, keys.walks(self.junction, keys.chunk(slot.person)), payload)
        reply(item.query, item.key, payload)

    def _on_human(self, item: Item, since: float | None = None) -> None:
        """A human driver, told by the roadside: in the region (SPOTTED), at its line
        (ASKGREEN: the green, journalled before it is answered, so a restarted ICA never
        confirms a vehicle through its envelope), or seen on its green (SIGHTING: its
        reservations shrunk to where it is). Each is decided at the roadside's step time,
        which may be one step ahead of the last CLOCK (the roadside asks first), never
        behind it."""
        msg = self._from_roadside(
            item, (Spotted, AskGreen, Sighting, Unlit), "greens", "human drivers"
        )
        if msg is None:
            return
        if not _is_chunk(msg.vin):
            self._reject(item.query, "?", -1, Reason.BAD_STATE, "VIN has key characters")
            return
        if msg.t_s > self.now_s + ROADSIDE_AHEAD_S:
            # the CLOCKs sent before it may not have been taken yet (the session hands
            # samples and queries over on threads of its own): wait for them, as a REQUEST
            # observed ahead of the clock does; refused if they never come (HOLD_S)
            self._held.append((since if since is not None else time.monotonic(), item))
            return
        # seen before; a dropped green is told whenever it comes (its driver stands on red)
        late = msg.t_s < self.now_s - 1e-9 and not isinstance(msg, (Spotted, Unlit))
        if late:
            why = f"t={msg.t_s:g} s is not this step's (clock {self.now_s:g} s)"
            self._reject(item.query, msg.vin, -1, Reason.BAD_TIME, why)
            return
        ica, limits = self.ica, self._driver_limits
        try:
            if isinstance(msg, Spotted):
                known = ica.knows(msg.vin)
                ica.detect(msg.vin, msg.lane, msg.t_s)
                self._owner[msg.vin] = HUMAN_OWNER  # no agent speaks for it
                if self.journal is not None and not known:
                    self.journal.detect(msg.vin, msg.lane, msg.t_s)
                    self.journal.human(msg.vin)
                self.stats.humans += not known
                reply(item.query, item.key, encode(Ack(msg.vin, -1, Spotted.KIND, now_ns())))
                return
            if isinstance(msg, Unlit):  # a head kept red, or (a crossing) a walker at its kerb
                if msg.crossing:
                    freed = ica.unwalk(msg.vin, msg.crossing, msg.green_s)
                else:
                    freed = ica.unlight(msg.vin, msg.green_s)
                if freed:
                    self.stats.unlit += 1
                    if self.journal is not None:
                        self.journal.unlit(msg.vin, msg.green_s, msg.crossing)
                reply(item.query, item.key, encode(Ack(msg.vin, -1, Unlit.KIND, now_ns())))
                return
            ica.advance(msg.t_s)  # as the embedded roadside does before it asks
            if isinstance(msg, AskGreen):
                had = ica.greens.get(msg.vin)
                t_c = time.perf_counter()
                if msg.again:
                    g = ica.regreen(msg.vin, msg.t_s, msg.length_m, msg.width_m, limits,
                                    msg.near_m)  # fmt: skip
                else:
                    g = ica.green(msg.vin, msg.t_s, msg.length_m, msg.width_m, limits,
                                  msg.near_m, msg.speed_mps)  # fmt: skip
                self.stats.compute_s.append(time.perf_counter() - t_c)
                if g is None:  # none sooner: the one held stands
                    reply(item.query, item.key, encode(Ack(msg.vin, -1, AskGreen.KIND, now_ns())))
                    return
                lit = Lit(g.vin, g.green_s, g.asked_s, g.near_m, msg.length_m, msg.width_m,
                          g.routes, now_ns(), limits.top_mps, ica.config.step_s,
                          g.speed_mps, limits.late_s)  # fmt: skip
                if g is not had:  # a new green (a repeated ask gets the one it holds)
                    if self.journal is not None:
                        self.journal.green(lit)
                    self.stats.greens += 1
                    put(self.session, keys.greens(self.junction, msg.vin), encode(lit))
                reply(item.query, item.key, encode(lit))
                return
            routes = ica.tighten(msg.vin, msg.t_s, msg.s_m, msg.speed_mps, msg.lane, limits)
            if routes is None:
                reply(item.query, item.key, encode(Ack(msg.vin, -1, Sighting.KIND, now_ns())))
                return
            if self.journal is not None:
                self.journal.sighting(msg)
            self.stats.shrunk += 1
            shrunk = Shrunk(msg.vin, msg.t_s, routes, now_ns())
            reply(item.query, item.key, encode(shrunk))
        except RequestError as e:
            self._count(Rejection(msg.vin, -1, e.reason, e.detail))
            self._reject(item.query, msg.vin, -1, e.reason, e.detail)

    def _on_ev(self, item: Item, since: float | None = None) -> None:
        """An emergency vehicle on its way, told by the roadside (EVCOMING): kept at the
        roadside's step time, as the embedded run gives it before the step's requests."""
        msg = self._from_roadside(item, (EvComing,), "notices", "emergency vehicles' notices")
        if msg is None:
            return
        if msg.t_s > self.now_s + ROADSIDE_AHEAD_S:  # the CLOCKs before it first (_on_human)
            self._held.append((since if since is not None else time.monotonic(), item))
            return
        notice = EvNotice(msg.ev, msg.in_edge, msg.out_edge, msg.eta_s, msg.t_s)
        try:
            self.ica.ev_coming(notice, max(msg.t_s, self.now_s))
        except RequestError as e:
            self._reject(item.query, msg.ev, -1, e.reason, e.detail)
            return
        self.stats.notices += 1
        reply(item.query, item.key, encode(Ack(msg.ev, -1, EvComing.KIND, now_ns())))

    # -- helpers -------------------------------------------------------------
    def _from_roadside(self, item: Item, kinds: tuple[type, ...], served: str, what: str):
        """The roadside's message of one of ``kinds`` on its own key (``gateway``), or
        None, answered with a REJECT: bytes that are none, another asker, or a core
        without ``served`` (it serves no ``what``)."""
        msg = self._asked(item, *kinds)
        if msg is None:
            return None
        who = getattr(msg, "person", None) or getattr(msg, "ev", None) or msg.vin
        if keys.last(item.key) != "gateway":
            self.stats.not_theirs += 1
            self._reject(item.query, who, -1, Reason.BAD_STATE, "only the roadside asks")
            return None
        if getattr(self.ica, served, None) is None:
            self._reject(item.query, who, -1, Reason.BAD_STATE, f"no {what} served here")
            return None
        return msg

    def _asked(self, item: Item, *kinds: type):
        """The query's message of one of ``kinds``, or None: bytes that are not one are
        counted, logged and answered with a REJECT ``bad_message``."""
        try:
            return decode(item.payload, *kinds)
        except DecodeError as e:
            self._bad(item, e)
            self._reject(item.query, "?", -1, Reason.BAD_MESSAGE, f"{e.why.value}: {e.detail}")
            return None

    def _expire_held(self) -> None:
        if not self._held:
            return
        now = time.monotonic()
        keep = []
        for since, item in self._held:
            if now - since > HOLD_S:
                self._reject(item.query, "?", -1, Reason.BAD_TIME, "observed ahead of the clock")
            else:
                keep.append((since, item))
        self._held = keep

    def _reject(self, query, vin: str, seq: int, reason: Reason, detail: str) -> None:
        if query is None:
            return
        self.stats.rejections[reason.value] = self.stats.rejections.get(reason.value, 0) + 1
        msg = Reject(vin[:128], seq, reason.value, detail[:512], now_ns())
        reply(query, str(query.key_expr), encode(msg))

    def _count(self, rej: Rejection) -> None:
        self.stats.rejections[rej.reason.value] = self.stats.rejections.get(rej.reason.value, 0) + 1

    def _bad(self, item: Item, e: DecodeError) -> None:
        self.stats.bad_messages += 1
        self.log.warning("dropped a bad %s message on %s: %s", item.what, item.key, e)


def _reorder_message(r: reactive.Reorder) -> Reorder:
    """A reordering as observers see it: every vehicle in the new order, the revoked
    ones with the seq of the plan taken back."""
    seqs = dict(zip(r.revoked, r.seqs, strict=True))
    places = tuple(
        Place(v, seqs.get(v, -1), REVOKED if v in seqs else NOT_REVOKED, _time(r.t_s))
        for v in r.order
    )
    return Reorder(
        r.ev, r.lane, _time(r.t_s), r.solver[:32], places, _time(r.ev_entry_before_s, math.nan),
        _time(r.ev_entry_after_s, math.nan), r.refused[:512], now_ns(),
    )  # fmt: skip


def _time(t_s: float, otherwise: float = 0.0) -> float:
    """A time as the wire takes it (``otherwise`` where it is not finite)."""
    return float(t_s) if math.isfinite(t_s) and TIME[0] <= t_s <= TIME[1] else otherwise


def _is_chunk(name: str) -> bool:
    try:
        keys.chunk(name)
    except keys.KeyChunkError:
        return False
    return True


def write_stats(path: Path, stats: ServiceStats) -> None:
    """This ICA's statistics, beside those of earlier ICAs of the same run.

    A restarted ICA must not replace its predecessor's figures with its own
    (nearly empty) ones: the file keeps one entry per ICA process, each
    rewritten atomically as it goes, and their sum.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    mine = {"pid": os.getpid(), **stats.as_dict()}
    try:
        old = json.loads(path.read_text())
        runs = [r for r in old.get("incarnations", []) if r.get("pid") != mine["pid"]]
    except (OSError, ValueError, AttributeError):
        runs = []
    runs.append(mine)
    total: dict = {"incarnations": runs}
    for k in ("requests", "confirmed", "repeated", "superseded", "detects", "cancels",
              "walks", "humans", "notices", "greens", "shrunk", "unlit", "bad_messages", "acks",
              "ignored_clocks", "not_theirs", "handovers"):  # fmt: skip
        total[k] = sum(int(r.get(k, 0)) for r in runs)
    rej: dict[str, int] = {}
    for r in runs:
        for k, v in (r.get("rejections") or {}).items():
            rej[k] = rej.get(k, 0) + int(v)
    total["rejections"] = rej
    total["journal_replays"] = sum(1 for r in runs if r.get("journal_replayed"))
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(total, indent=2))
    os.replace(tmp, path)
