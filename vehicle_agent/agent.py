"""A vehicle-agent process: hosts one or many vehicles, each its own state machine.

The gateway hands a vehicle to an agent by naming it in the STATE it sends on
``sim/<j>/state/<agent>``; from then on the agent steps that vehicle's
machine on every STATE that names it, reaches the ICA with Zenoh queries on
its own keys (``dica/<j>/detect|request|cancel/<agent>``), acknowledges each
RESPONSE on ``dica/<j>/ack/<agent>`` and sends its actuators' plans on
``sim/<j>/command/<agent>``. A liveliness token ``sim/<j>/alive/<agent>``
tells the gateway the agent is up, and that it died (its vehicles are then
handed to another agent, which takes each one over in the phase its actuator
reports).

Two clocks (the gateway's CLOCK says which):

* **lockstep**: every STATE is answered with one COMMAND, after the queries
  it caused have been answered; runs are deterministic.
* **realtime**: nothing blocks. Queries are asynchronous, their answers
  arrive in the inbox; a plan goes out the moment its confirmation does, and
  again with every STATE that shows the actuator does not hold it yet (a lost
  COMMAND costs a step, not the reservation). When STATEs pile up, only the
  newest is acted on, and how far behind the agent runs is logged. Each
  REQUEST's plan starts ``lead`` ahead of its observation, the round trip
  the agent has measured lately plus a margin, so the plan can arrive in time.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from dica.deploy.transport import (
    Inbox,
    Item,
    every_answer,
    note_refused,
    publisher,
    put,
    query_payload,
    refused,
    reply,
    reply_body,
)
from dica.ica.convert import reject_to_core, request_from_core, response_to_core
from dica.ica.core.config import IcaConfig
from dica.ica.core.intersection import Intersection
from dica.ica.core.request import Reason, Rejection, Request
from dica.schemas import keys
from dica.schemas.codec import DecodeError, decode, encode, now_ns
from dica.schemas.messages import (
    BIG,
    KEPT,
    Ack,
    Cancel,
    Clock,
    Command,
    Detect,
    Reject,
    Response,
    Revoke,
    Setpoint,
    State,
    Stats,
)
from dica.vehicle_agent.machine import PENDING, Observation, Phase, Vehicle

LAG_WARN_S = 0.5  # [s wall] a STATE older than this when acted on is worth a warning
FORGET_S = 60.0  # [s wall] a vehicle no STATE has named for this long is forgotten
LEAD_MIN_S = 0.25  # [s sim] shortest automatic lead in real time
MIN_TIMEOUT_S, MAX_TIMEOUT_S = 0.2, 3.0  # [s wall] bounds of the adaptive query timeout
# [s wall] what a lockstep query waits: the gateway waits for the answer anyway, and one
# given up early makes other decisions than the embedded run. 2 s was seen running out
# on a loaded host (an ICA answering a stolen log-in's flood, two cores shared by a
# dozen processes); only a dead ICA should time out
LOCKSTEP_TIMEOUT_S = 5.0
BACKOFF_MAX = 4.0  # the most the timeout is stretched while queries go unanswered


@dataclass(slots=True)
class Timing:
    """What the agent measures about its links, for the lead, the timeouts and the record."""

    rtt_s: deque[float] = field(default_factory=lambda: deque(maxlen=200))  # wall
    state_age_s: deque[float] = field(default_factory=lambda: deque(maxlen=200))  # wall
    all_rtt_s: list[float] = field(default_factory=list)
    queries: int = 0
    no_answer: int = 0
    states: int = 0
    stale_states: int = 0  # skipped: a newer one was already waiting
    max_lag_s: float = 0.0
    lag_warnings: int = 0
    resent_plans: int = 0
    bad_replies: int = 0
    via_publication: int = 0  # answers taken from the ICA's publication, the reply lost

    def q(self, xs: deque[float], p: float, default: float) -> float:
        return float(np.percentile(np.asarray(xs), p)) if len(xs) >= 5 else default


class ZenohLink:
    """A vehicle's link to the ICA: Zenoh queries on this agent's own keys.

    Blocking (lockstep) or asynchronous (realtime): an asynchronous query
    returns PENDING and its answer arrives in the agent's inbox as a
    ``reply`` item. Only a reply on the exact key asked is taken. No answer in
    time becomes a NO_ANSWER rejection; the vehicle then asks again.
    """

    def __init__(
        self, session, junction: str, agent_id: str, inbox: Inbox, log: logging.Logger
    ) -> None:
        self.session = session
        self.inbox = inbox
        self.log = log
        self.blocking = True
        self.timeout_s = LOCKSTEP_TIMEOUT_S  # until round trips are measured
        self.loss = 0.0  # running share of queries that went unanswered
        # grows while queries go unanswered: a timeout shorter than the round trip would
        # drop every answer, and no answer would ever teach it the round trip
        self.backoff = 1.0
        self.timing = Timing()
        self.revoke_answers = 0
        self._keys = {
            "detect": keys.detect(junction, agent_id),
            "request": keys.request(junction, agent_id),
            "cancel": keys.cancel(junction, agent_id),
        }
        self._ack_key = keys.ack(junction, agent_id)
        # what the region's detector reads as a vehicle passes it: EV or not, and its speed
        self.detector: dict[str, tuple[bool, float]] = {}

    # -- the IcaLink protocol -------------------------------------------------
    def detect(self, vin: str, lane: str, t_s: float):
        ev, speed = self.detector.get(vin, (False, 0.0))
        msg = Detect(vin, lane, t_s, ev, min(max(speed, 0.0), 200.0), now_ns())
        return self._ask("detect", vin, -1, encode(msg))

    def request(self, req: Request, now_s: float):
        return self._ask("request", req.vin, req.seq, encode(request_from_core(req)))

    def cancel(self, vin: str, seq: int) -> None:
        import zenoh

        self.session.get(
            self._keys["cancel"],
            zenoh.handlers.Callback(lambda _r: None),
            payload=query_payload(encode(Cancel(vin, seq, now_ns()))),
            timeout=self.timeout_s,
            **every_answer(),
        )

    def answer_revoke(self, vin: str, seq: int, dropped: bool) -> None:
        """ACK a REVOKE: ``revoke`` once the actuator dropped the plan, ``kept`` if it could
        not (a publication: a lost one is answered again when the REVOKE comes again)."""
        of = Revoke.KIND if dropped else KEPT
        put(self.session, self._ack_key, encode(Ack(vin, seq, of, now_ns())))
        self.revoke_answers += 1

    # -- answers ----------------------------------------------------------------
    def _ask(self, what: str, vin: str, seq: int, payload: bytes):
        key = self._keys[what]
        payload = query_payload(payload)
        self.timing.queries += 1
        t = time.perf_counter()
        if self.blocking:
            found = None
            for r in self.session.get(
                key, payload=payload, timeout=self.timeout_s, **every_answer()
            ):
                found = found or self._take(what, key, r, t)
            self._outcome(found is not None)
            return self._answer(what, vin, seq, found)
        import zenoh

        # over a lossy link the same query goes out more than once (the ICA answers a
        # repeat with the same answer): the first answer counts, silence from all is NO_ANSWER
        copies = self.copies()
        lock = threading.Lock()
        state = {"answered": False, "open": copies}

        def on_reply(r) -> None:
            msg = self._take(what, key, r, t)
            with lock:
                if msg is None or state["answered"]:
                    return
                state["answered"] = True
            self.inbox.put(Item("reply", b"", key, (what, vin, seq, msg)))

        def on_done() -> None:
            with lock:
                state["open"] -= 1
                if state["open"] or state["answered"]:
                    if not state["open"]:
                        self._outcome(True)
                    return
            self._outcome(False)
            self.inbox.put(Item("reply", b"", key, (what, vin, seq, None)))

        for _ in range(copies):
            self.session.get(
                key,
                zenoh.handlers.Callback(on_reply, on_done),
                payload=payload,
                timeout=self.timeout_s,
                express=True,
                **every_answer(),
            )
        return PENDING

    def _outcome(self, answered: bool) -> None:
        """Keep a running estimate of how often a query goes unanswered."""
        self.loss = 0.9 * self.loss + 0.1 * (0.0 if answered else 1.0)
        self.backoff = 1.0 if answered else min(self.backoff * 1.5, BACKOFF_MAX)

    def copies(self) -> int:
        """How many copies of each query: more the more of them go unanswered."""
        return 1 if self.loss < 0.05 else 2 if self.loss < 0.2 else 3

    def _take(self, what: str, key: str, r, t: float):
        """One reply, if it is one to act on: on the exact key asked, from the ICA."""
        if r.ok is None:
            return None
        body = reply_body(r, key)
        if body is None:
            self.timing.bad_replies += 1
            self.log.warning("ignored a reply on %s to a query on %s", r.ok.key_expr, key)
            return None
        kinds = (Ack, Reject) if what != "request" else (Response, Reject)
        try:
            msg = decode(body, *kinds)
        except DecodeError as e:
            self.timing.bad_replies += 1
            self.log.warning("bad reply on %s: %s", key, e)
            return None
        rtt = time.perf_counter() - t
        self.timing.rtt_s.append(rtt)
        self.timing.all_rtt_s.append(rtt)
        return msg

    def _answer(self, what: str, vin: str, seq: int, msg):
        """The machine's view of a (possibly missing) answer."""
        if msg is None:
            self.timing.no_answer += 1
            rej = Rejection(vin, seq, Reason.NO_ANSWER, f"no answer to {what.upper()}")
            return rej
        if isinstance(msg, Reject):
            return reject_to_core(msg)
        if what != "request":
            return None  # a DETECT's ACK
        if msg.vin != vin or msg.seq != seq:
            return Rejection(vin, seq, Reason.BAD_MESSAGE, "a RESPONSE for someone else")
        put(self.session, self._ack_key, encode(Ack(msg.vin, msg.seq, Response.KIND, now_ns())))
        return response_to_core(msg)

    def adapt(self) -> None:
        """Query timeouts: in lockstep :data:`LOCKSTEP_TIMEOUT_S`; in real time from the
        round trips measured lately, never shorter than two of the STATEs' one-way ages
        (a round trip crosses at least two such links), and longer while queries go
        unanswered."""
        if self.blocking:
            self.timeout_s = LOCKSTEP_TIMEOUT_S
            return
        t = self.timing
        base = max(1.5 * t.q(t.rtt_s, 90, 0.4), 2.5 * t.q(t.state_age_s, 90, 0.0)) + 0.05
        self.timeout_s = min(max(base * self.backoff, MIN_TIMEOUT_S), MAX_TIMEOUT_S)


class Agent:
    """Vehicles hosted by this process, stepped on the STATEs from the gateway."""

    def __init__(
        self,
        session,
        agent_id: str,
        inter: Intersection,
        config: IcaConfig,
        *,
        retry_s: float = 0.5,
        lead_s: float | None = None,
        log: logging.Logger,
    ) -> None:
        self.session = session
        self.agent_id = keys.chunk(agent_id)
        self.inter = inter
        self.config = config
        self.retry_s = retry_s
        self.fixed_lead_s = lead_s  # None: measured (realtime); lockstep always plans from now
        self.log = log
        j = inter.junction_id
        self.inbox = Inbox()
        self.revokes = Inbox()  # REVOKEs, taken before each COMMAND goes out
        self.revoked = 0
        self.link = ZenohLink(session, j, self.agent_id, self.inbox, log)
        self.vehicles: dict[str, Vehicle] = {}
        self.rejections: dict[str, int] = {}  # one tally for every hosted vehicle
        self.seen_wall: dict[str, float] = {}
        self.hosted = 0
        self.adopted = 0
        self.ended = False
        self.clock: Clock | None = None
        self._last_warn = 0.0
        self._outbox: list[Setpoint] = []
        self._answered: tuple[int, int, bytes] | None = None  # lockstep: the last COMMAND
        self._clock_key = keys.clock(j)
        self._decls = [
            session.declare_subscriber(keys.state(j, self.agent_id), self.inbox.sample_cb("state")),
            session.declare_subscriber(self._clock_key, self.inbox.sample_cb("clock")),
            session.declare_subscriber(
                keys.revoke(j, self.agent_id), self.revokes.sample_cb("revoke")
            ),
            # the ICA publishes every confirmation too: a second way for a lost reply to arrive
            session.declare_subscriber(keys.confirmed(j), self.inbox.sample_cb("confirmed")),
            session.declare_queryable(
                keys.agent_stats(j, self.agent_id), self.inbox.query_cb("stats")
            ),
        ]
        self._pub = publisher(session, keys.command(j, self.agent_id))
        self._token = session.liveliness().declare_token(keys.agent_alive(j, self.agent_id))

    @property
    def realtime(self) -> bool:
        return self.clock is not None and self.clock.mode == "realtime"

    # -- the loop --------------------------------------------------------------
    def run(self) -> None:
        while not self.inbox.stopping.is_set() and not self.ended:
            item = self.inbox.get(timeout=0.1)
            if item is None:
                self._forget_silent()
                note_refused(self.log)
                self._take_revokes()  # none came with a STATE: sent on their own
                self._flush(step=self._answered[0] if self._answered else 0, part=0, always=False)
                continue
            if self.realtime:
                self._realtime(item)
            else:
                self._handle(item)

    def _realtime(self, first: Item) -> None:
        """Everything waiting, with only the newest STATE acted on."""
        items = [first, *self.inbox.drain()]
        states = [i for i in items if i.what == "state"]
        for it in items:
            if it.what != "state":
                self._handle(it)
        if states:
            self.link.timing.stale_states += len(states) - 1
            self._handle(states[-1])
        self._take_revokes()
        self._flush(step=0, part=0, always=False)

    def _handle(self, item: Item) -> None:
        try:
            if item.what == "state":
                if self.clock is None:
                    return  # the clock says how to answer; it is sent before any STATE
                self._on_state(decode(item.payload, State))
            elif item.what == "clock":
                self._on_clock(item)
            elif item.what == "reply":
                self._on_reply(*item.query)
            elif item.what == "confirmed":
                self._on_confirmed(item)
            elif item.what == "stats":
                body = json.dumps(self.summary())
                reply(item.query, item.key, encode(Stats("agent", self.agent_id, body, now_ns())))
        except DecodeError as e:
            self.log.warning("dropped a bad %s message: %s", item.what, e)

    def _on_clock(self, item: Item) -> None:
        if item.key != self._clock_key:
            return  # only the gateway's own key counts
        clock = decode(item.payload, Clock)
        if self.clock is not None and clock.step <= self.clock.step and not clock.end:
            return  # an old or repeated CLOCK
        self.clock = clock
        self.ended = clock.end
        self.link.blocking = clock.mode != "realtime"

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()
        for d in self._decls:
            d.undeclare()

    # -- STATE -------------------------------------------------------------------
    def _on_state(self, state: State) -> None:
        if not self.realtime:
            last = self._answered
            if last is not None and (state.step, state.part) <= last[:2]:
                if (state.step, state.part) == last[:2]:
                    self._pub.put(last[2])  # the gateway missed our COMMAND: the same again
                return
        timing = self.link.timing
        timing.states += 1
        age = max((now_ns() - state.sent_ns) / 1e9, 0.0)
        timing.state_age_s.append(age)
        timing.max_lag_s = max(timing.max_lag_s, age)
        if age > LAG_WARN_S and time.monotonic() - self._last_warn > 5.0:
            self._last_warn = time.monotonic()
            timing.lag_warnings += 1
            self.log.warning(
                "acting on a STATE %.2f s old (t=%.2f s); %d stale ones skipped so far",
                age, state.t_s, timing.stale_states,
            )  # fmt: skip
        realtime = self.realtime
        lead = self._lead() if realtime else 0.0
        self.link.adapt()
        wall = time.monotonic()
        for vs in state.vehicles:
            v = self.vehicles.get(vs.vin)
            obs = Observation(
                t_s=state.t_s,
                lane=vs.lane,
                dist_to_entry_m=vs.dist_to_entry_m,
                speed_mps=vs.speed_mps,
                head=vs.head,
                detected_s=vs.detected_s,
                exited=vs.exited,
                plan_seq=vs.plan_seq,
                refused_seq=vs.refused_seq,
                kept_seq=vs.kept_seq,
                follows=vs.follows,
                intent_m=tuple(vs.intent_m.tolist()),
                exit_room_m=math.inf if vs.exit_room_m >= BIG else vs.exit_room_m,
                network_room_m=math.inf if vs.network_room_m >= BIG else vs.network_room_m,
            )
            if v is None:
                if vs.exited:
                    continue
                v = self._host(vs, obs)
                if v is None:
                    continue
            if v.phase is Phase.APPROACHING:
                self.link.detector[vs.vin] = (vs.ev, vs.speed_mps)
            self.seen_wall[vs.vin] = wall
            v.lead_s = lead
            cmd = v.step(obs, self.link)
            if cmd is not None:
                self._send(cmd)
            elif (
                realtime
                and v.held is not None
                and obs.plan_seq != v.held.seq
                and state.t_s < v.held.t0_s
            ):
                self.link.timing.resent_plans += 1
                self._send(v.held)  # the actuator has not got it yet: again
            if vs.exited:
                self.vehicles.pop(vs.vin, None)
                self.seen_wall.pop(vs.vin, None)
                self.link.detector.pop(vs.vin, None)
        if not realtime:
            # the REVOKEs the queries of this STATE caused are here already (the ICA
            # sends them before it answers): their drops go out with this COMMAND
            self._take_revokes()
            self._flush(state.step, state.part, always=True)

    def _take_revokes(self) -> None:
        """Every REVOKE waiting: the vehicle's actuator is told to drop the plan."""
        for item in self.revokes.drain():
            try:
                msg = decode(item.payload, Revoke)
            except DecodeError as e:
                self.log.warning("dropped a bad revoke message: %s", e)
                continue
            v = self.vehicles.get(msg.vin)
            if v is None:
                continue  # not ours (any more): its new agent is told when it comes again
            self.revoked += 1
            cmd = v.revoke(msg.seq, self.link)
            if cmd is not None:
                self._send(cmd)

    def _on_reply(self, what: str, vin: str, seq: int, msg) -> None:
        v = self.vehicles.get(vin)
        if v is None:
            return
        answer = self.link._answer(what, vin, seq, msg)
        now = self.clock.t_s if self.clock is not None else 0.0
        if what == "detect":
            cmd = v.detected(answer, now)
        elif what == "request":
            cmd = v.answered(answer, now)
        else:
            return
        if cmd is not None:
            self._send(cmd)

    def _on_confirmed(self, item: Item) -> None:
        """A published confirmation of one of ours, taken as the answer if it is awaited."""
        vin = keys.last(item.key)
        v = self.vehicles.get(vin)
        if v is None or not v.pending or v.held is not None:
            return
        msg = decode(item.payload, Response)
        if msg.vin == vin and msg.seq == v.last_seq:
            self.link.timing.via_publication += 1
            self._on_reply("request", vin, msg.seq, msg)

    def _lead(self) -> float:
        """How far ahead a REQUEST's plan starts [sim s]: the measured latency, with margin.

        From the observation to the actuator a plan crosses the STATE's way to
        the agent, the query's round trip and the COMMAND's way back (about
        the STATE's); each taken at its 90th percentile of late, in sim time.
        """
        if self.fixed_lead_s is not None:
            return self.fixed_lead_s
        t = self.link.timing
        speed = self.clock.speed if self.clock is not None and self.clock.speed > 0 else 1.0
        wall = t.q(t.rtt_s, 90, 0.3) + 2.0 * t.q(t.state_age_s, 90, 0.1)
        lead = 1.25 * speed * wall + 2 * self.config.step_s
        return min(max(lead, LEAD_MIN_S), self.config.max_lead_s - 1.0)

    def _send(self, cmd) -> None:
        self._outbox.append(Setpoint(cmd.vin, cmd.seq, cmd.t0_s, cmd.s_m, cmd.wake_s, cmd.drop))

    def _flush(self, step: int, part: int, always: bool) -> None:
        if not self._outbox and not always:
            return
        out = encode(Command(self.agent_id, step, part, tuple(self._outbox), now_ns()))
        self._outbox = []
        self._pub.put(out)
        if always:
            self._answered = (step, part, out)

    def _host(self, vs, obs: Observation) -> Vehicle | None:
        route = self.inter.route_by_id(vs.route_id)
        if route is None:
            self.log.error("vehicle %s on unknown route %r: not hosted", vs.vin, vs.route_id)
            return None
        v = Vehicle(
            vs.vin,
            route,
            vs.length_m,
            vs.width_m,
            vs.max_speed_mps,
            self.config,
            self.retry_s,
        )
        v.rejections = self.rejections
        if obs.plan_seq >= 0:  # another agent's vehicle, already flying its plan
            v.adopt(obs)
            self.adopted += 1
        self.vehicles[vs.vin] = v
        self.hosted += 1
        return v

    def _forget_silent(self) -> None:
        """Vehicles no STATE has named for a long while went to another agent."""
        if not self.realtime or not self.seen_wall:
            return
        cut = time.monotonic() - FORGET_S
        for vin in [vin for vin, t in self.seen_wall.items() if t < cut]:
            self.vehicles.pop(vin, None)
            self.seen_wall.pop(vin, None)

    def summary(self) -> dict:
        t = self.link.timing
        rtt = np.array(t.all_rtt_s) if t.all_rtt_s else np.full(1, math.nan)
        return {
            "agent": self.agent_id,
            "hosted": self.hosted,
            "adopted_flying": self.adopted,
            "queries": t.queries,
            "no_answer": t.no_answer,
            "bad_replies": t.bad_replies,
            "rtt_median_ms": float(np.median(rtt) * 1e3),
            "rtt_p99_ms": float(np.percentile(rtt, 99) * 1e3),
            "states": t.states,
            "stale_states_skipped": t.stale_states,
            "max_lag_ms": t.max_lag_s * 1e3,
            "lag_warnings": t.lag_warnings,
            "plans_resent": t.resent_plans,
            "answers_via_publication": t.via_publication,
            "revokes_received": self.revoked,
            "revoke_answers": self.link.revoke_answers,
            "query_copies": self.link.copies(),
            "lead_s": self._lead() if self.realtime else 0.0,
            "rejections": dict(self.rejections),
            "refused_unsealed": refused(),
        }
