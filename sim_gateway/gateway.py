"""The gateway process: SUMO's side of the cluster, keyed to Zenoh.

The only process that imports libsumo. It steps the same world as the
embedded runner (:mod:`sim_gateway.world`), which is also every vehicle's
actuator; publishes the sim CLOCK on ``sim/<j>/clock`` and each agent's
vehicles' states on ``sim/<j>/state/<agent>`` (the first STATE naming a
vehicle hands it to that agent), and takes the plans agents send on
``sim/<j>/command/<agent>``, each only from the agent that hosts the vehicle.

Two clocks:

* ``lockstep``: a step waits for the agents only when one of their vehicles
  must talk to the ICA (announce itself, or ask, being head of its lane),
  in waves that keep the ICA's order of contacts (see
  :meth:`ZenohDrivers._waves`); a STATE whose COMMAND does not come back in
  time is sent again. Deterministic, the same decisions as the embedded
  runner, and as fast as the slowest participant.
* ``realtime``: steps are paced to the wall clock times ``--speed``; each
  agent gets its vehicles' states every step, and whatever plans have arrived
  are handed to the actuators, which take a plan only before its start.

Peers come and go. Agents announce themselves with liveliness tokens; when one
disappears (a killed process, a lost link) its vehicles are handed to the
least loaded live agent, which takes each over in the phase its actuator
reports, and until then each actuator keeps its vehicle short of the line (or
flying the plan it holds). Without the ICA no vehicle gets a new plan and the
run goes on. What the run knows so far is written every so often (marked
incomplete), so a crash of the gateway itself loses at most that interval.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import zenoh

from dica.deploy.transport import (
    Inbox,
    Item,
    every_answer,
    known_writer,
    note_refused,
    publisher,
    query_payload,
    refused,
    reply_body,
)
from dica.ica.core.ev_notice import EvNotice
from dica.schemas import keys
from dica.schemas.codec import DecodeError, decode, encode, now_ns
from dica.schemas.messages import BIG as WIRE_BIG
from dica.schemas.messages import (
    MAX_VEHICLES,
    Ack,
    Across,
    AskGreen,
    Clock,
    Command,
    EvComing,
    Go,
    Lit,
    People,
    PersonPlace,
    Reject,
    Revoke,
    Shrunk,
    Sighting,
    Spotted,
    State,
    Stats,
    Unlit,
    VehicleState,
    Walk,
)
from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.humans import SignalHeads
from dica.sim_gateway.junction import Car, Seen
from dica.sim_gateway.runconfig import RunConfig, RunError, RunResult
from dica.sim_gateway.walkers import Walkers
from dica.sim_gateway.world import World
from dica.vehicle_agent.actuation import BIG, NO_PLAN, Actuation

CLOCKS = ("lockstep", "realtime")
PREDICT_S = 2.0  # [s sim] how far ahead a realtime STATE says where each asker will be
WALK_TIMEOUT_S = 2.0  # [s wall] how long the roadside waits for the ICA's GO to a WALK
# [s wall] the same in lockstep, where the step waits anyway and an answer given up on a
# loaded host would make other decisions than the embedded run (the agents' lockstep wait)
LOCKSTEP_ASK_S = 5.0
NOTICE_S = 1.0  # [s sim] how long a realtime STATE keeps naming a vehicle after news about it
VEHICLES_EVERY = 20  # steps: how often VEHICLES goes out with no news and no observer
AGE_BINS_MS = (0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000)  # command age histogram


@dataclass(slots=True)
class _Out:
    """A human driver's question to the ICA still out (realtime): its answers' channel,
    when it was asked and from where, and the answer taken."""

    answers: object
    t_s: float
    near_m: float
    v_mps: float
    s_m: float = 0.0
    got: object = None


@dataclass
class Fleet:
    """Which agent hosts each vehicle. A network's junctions share one, so a vehicle
    keeps its agent from one junction to the next (the agent serves them all)."""

    owner: dict[str, str] = field(default_factory=dict)
    load: Counter[str] = field(default_factory=Counter)  # vehicles in some region, per agent
    hosted: Counter[str] = field(default_factory=Counter)  # vehicles ever handed, per agent
    adoptions: int = 0  # vehicles handed on from an agent that died


class ZenohDrivers:
    """The vehicles' decisions, made by agent processes reached over Zenoh."""

    def __init__(
        self,
        session,
        junction: str,
        cfg: RunConfig,
        *,
        agents: int,
        observers: int = 0,
        per_agent: int = 0,
        clock: str = "lockstep",
        speed: float = 1.0,
        step_timeout_s: float = 30.0,
        resend_s: float = 0.5,
        fleet: Fleet | None = None,
        log: logging.Logger,
    ) -> None:
        if clock not in CLOCKS:
            raise RunError(f"unknown clock {clock!r}: use lockstep or realtime")
        if agents < 1:
            raise RunError("at least one vehicle agent is needed")
        self.session = session
        self.junction = junction
        self.cfg = cfg
        self.n_agents = agents
        self.n_observers = observers
        self.observers: set[str] = set()
        self.per_agent = per_agent
        self.clock = clock
        self.speed = speed
        self.step_timeout_s = step_timeout_s
        self.resend_s = resend_s
        self.log = log
        self.inbox = Inbox()
        self.ended = False
        self.alive: set[str] = set()
        self.ica_alive = False
        self.ica_outages = 0
        self.fleet = fleet if fleet is not None else Fleet()
        self.owner = self.fleet.owner
        self.load = self.fleet.load
        self.here: set[str] = set()  # vehicles in this region counted in their agent's load
        self.owner_news = False  # a vehicle changed hands since the last VEHICLES
        self.agent_deaths = 0
        self.multi_wave_steps = 0
        self.resent_states = 0
        self.stale_commands = 0  # lockstep: answers to an earlier step or wave
        self.known: set[str] = set()  # vehicles their agent has seen (it has DETECTed them)
        self.wake: dict[str, float] = {}  # per vehicle: when it may next talk to the ICA
        self.news: dict[str, float] = {}  # realtime: vehicles to keep naming until this time
        self.exits: list[Seen] = []  # lockstep: exit notices not yet delivered
        # lockstep: vehicles told to drop a plan, whose agent must see the actuator's verdict
        self.dropping: set[str] = set()
        # lockstep: vehicles whose REVOKE went out this step; their agents hear it at once
        self.revoked_news: set[str] = set()
        self.revoke_waves = 0  # lockstep waves added for a REVOKE to another agent's vehicle
        self._seen_now: list[Seen] = []
        self.dropped_setpoints = 0
        self.walks_unanswered = 0  # WALKs the ICA did not answer with a GO (asked again)
        self.humans_unanswered = 0  # human drivers' questions the ICA did not answer
        self.notices_unanswered = 0  # EVs' notices the ICA did not answer
        self.green_refused: dict[str, int] = {}  # greens asked too soon, by reason
        self.green_late_s = cfg.green_late_s  # how late a head may turn green
        self.greens_dropped = 0  # LITs come too late to light their head (the ICA told)
        self.walks_dropped = 0  # GOs come too late to let their walker go (the ICA told)
        # realtime: the human drivers' questions still out, by VIN and kind ("green",
        # "sighting"); the world does not wait for them (see _asked)
        self._out: dict[tuple[str, str], _Out] = {}
        self._human_states: tuple[VehicleState, ...] = ()  # this step's, for observers
        self.fake_tokens = 0  # liveliness tokens of names that are not the site's agents
        self.age_ms: list[float] = []
        self.wait_s: list[float] = []
        self.step_s = cfg.controller_spec().config.step_s
        self._pending: tuple[int, int, dict[str, list[VehicleState]], list[Actuation]] = (
            0, 0, {}, []
        )  # fmt: skip
        self._k = 0
        self._t0_wall = 0.0
        self._seen_plan: dict[str, tuple[int, int]] = {}
        j = junction
        self._clock_pub = publisher(session, keys.clock(j))
        self._vehicles_pub = publisher(session, keys.vehicles(j))
        self._people_pub = publisher(session, keys.people(j))
        self._state_pubs: dict[str, object] = {}
        lv = session.liveliness()
        self._decls = [
            session.declare_subscriber(keys.command(j), self.inbox.sample_cb("command")),
            lv.declare_subscriber(
                keys.agent_alive(j), self.inbox.liveliness_cb("agent"), history=True
            ),
            lv.declare_subscriber(keys.ica_alive(j), self.inbox.liveliness_cb("ica"), history=True),
            lv.declare_subscriber(
                keys.observer_alive(j), self.inbox.liveliness_cb("observer"), history=True
            ),
        ]
        if clock == "lockstep":  # a REVOKE may be for a vehicle whose agent gets no STATE
            self._decls.append(
                session.declare_subscriber(keys.revoke(j), self.inbox.sample_cb("revoke"))
            )
        self._agent_key = keys.agent_alive(j, "x").rsplit("/", 1)[0] + "/"
        self._ica_key = keys.ica_alive(j)
        self._observer_key = keys.observer_alive(j, "x").rsplit("/", 1)[0] + "/"
        self._command_key = keys.command(j, "x").rsplit("/", 1)[0] + "/"

    # -- start and end ---------------------------------------------------------
    def wait_for_peers(self, timeout_s: float) -> None:
        """Block until the ICA, every agent and every observer are up (liveliness), or fail."""
        deadline = time.monotonic() + timeout_s
        while (
            len(self.alive) < self.n_agents
            or not self.ica_alive
            or len(self.observers) < self.n_observers
        ):
            if self.inbox.stopping.is_set():
                raise RunError("stopped while waiting for the ICA and the agents")
            if time.monotonic() > deadline:
                raise RunError(
                    f"after {timeout_s:.0f} s: ICA {'up' if self.ica_alive else 'not up'}, "
                    f"{len(self.alive)} of {self.n_agents} vehicle agents and "
                    f"{len(self.observers)} of {self.n_observers} observers up"
                )
            item = self.inbox.get(timeout=0.1)
            if item is not None:
                self._note(item)
        self.log.info(
            "ICA and %d agents up at %s: %s",
            len(self.alive), self.junction, ", ".join(sorted(self.alive)),
        )  # fmt: skip
        self._t0_wall = time.monotonic()

    def end(self, t: float, copies: int = 5) -> None:
        """Tell the roles the run is over; a few times, as a lossy link may eat one."""
        self.ended = True  # from now on the roles stop: their tokens going is no news
        msg = encode(Clock(self._k + 1, t, self.clock, self.speed, True, now_ns()))
        for i in range(copies):
            if i:
                time.sleep(0.2)
            self._clock_pub.put(msg)

    def close(self) -> None:
        self._clock_pub.undeclare()
        self._vehicles_pub.undeclare()
        self._people_pub.undeclare()
        for p in self._state_pubs.values():
            p.undeclare()
        for d in self._decls:
            d.undeclare()

    def role_stats(self, timeout_s: float = 2.0) -> dict:
        """The ICA's and every live agent's own figures, asked for at the end of the run."""
        out: dict = {"ica": None, "agents": {}}
        j = self.junction
        targets = [("ica", keys.ica_stats(j))] + [
            (a, keys.agent_stats(j, a)) for a in sorted(self.alive)
        ]
        for name, key in targets:
            for _ in range(5):  # a lossy link may eat the query or the answer
                got = None
                for r in self.session.get(
                    key, payload=query_payload(b""), timeout=timeout_s, **every_answer()
                ):
                    body = reply_body(r, key)
                    if body is None:
                        continue
                    try:
                        got = json.loads(decode(body, Stats).json)
                    except (DecodeError, ValueError):
                        continue
                if got is not None:
                    if name == "ica":
                        out["ica"] = got
                    else:
                        out["agents"][name] = got
                    break
        return out

    # -- one step ----------------------------------------------------------------
    def walk(self, walkers: Walkers, t: float) -> None:
        """The walkers seen across this step (ACROSS: their slots end now), and the
        roadside's WALK requests of this step (and those left unanswered a second ago),
        each asked of the ICA and answered before the step's CLOCK: the ICA decides them
        on what it held after the last step, as the embedded runner does, before any
        vehicle's request of this step. Then the walkers whose start has come go. While
        the ICA is gone nothing is asked (the walkers wait; a query would stall the step)."""
        if not self.ica_alive:  # no one to ask: the walkers wait, and are asked for again
            self.walks_unanswered += len(walkers.asks)
            walkers.release(t)
            return
        key = keys.walk(self.junction, "gateway")
        for person, crossing, _junction in walkers.cleared:
            msg = Across(person, crossing, t, now_ns())
            if self._ask_ica(key, msg, (Ack,)) is None:
                self.walks_unanswered += 1
        for ask in [*walkers.asks, *walkers.again(t)]:
            msg = Walk(ask.person, ask.crossing, ask.ready_s, ask.walk_m, ask.speed_mps,
                       ask.side, ask.near_m, ask.near_lo_m, now_ns())  # fmt: skip
            asked = time.monotonic()
            got = self._ask_ica(key, msg, (Go,))
            if isinstance(got, Go):
                go_s = self._lit_s(t, got.start_s, time.monotonic() - asked)
                if go_s is None:  # it stays at the kerb, its slot freed; it asks again
                    self._unwalk(got, t)
                    continue
                walkers.answer(got.person, got.start_s, got.end_s, t, go_s)
            else:
                self.walks_unanswered += 1
                why = "no answer" if got is None else f"refused: {got.detail}"
                self.log.warning("WALK for %s at %s: %s", ask.person, ask.crossing, why)
        walkers.release(t)

    def people(self, walkers: Walkers, t: float) -> None:
        """This step's people, for the observers' recording (PEOPLE; nothing when no
        observer listens)."""
        if not self.observers or not self._people_pub.matching_status.matching:
            return
        waiting = walkers.waiting_mask()
        places = tuple(
            PersonPlace(float(x), float(y), bool(w))
            for (x, y), w in zip(walkers.xy[:MAX_VEHICLES], waiting, strict=False)
        )
        self._people_pub.put(encode(People(self._k, t, places, now_ns())))

    def humans(self, heads: SignalHeads, seen: list[Seen], t: float) -> None:
        """The human drivers of this step, the ICA asked over Zenoh before the step's
        CLOCK, as the embedded roadside asks it in process
        (:meth:`sim_gateway.humans.SignalHeads.serve`). While the ICA is gone none is
        asked: those at their line wait on red, those on their green go on in the
        envelopes reserved for them."""
        if self.clock == "realtime":
            self._answered(heads, t)
        if self.ica_alive:
            heads.serve(seen, t, self)
        else:
            heads.release(t)
        if self.observers:
            self._human_states = tuple(
                self._vehicle_state(s, "green" if heads.drivers[s.car.vin].resumed else "red")
                for s in seen
                if s.car.vin in heads.drivers
            )

    # -- the roadside's desk at the ICA for human drivers (sim_gateway.humans.Desk) --------
    def spotted(self, car: Car, t: float) -> bool:
        got = self._ask_ica(keys.human(self.junction, "gateway"),
                            Spotted(car.vin, car.route.in_lane, t, now_ns()), (Ack,))  # fmt: skip
        if isinstance(got, Ack):
            return True
        self.humans_unanswered += got is None
        self.log.warning("SPOTTED %s: %s", car.vin, "no answer" if got is None else got.detail)
        return got is not None  # refused: telling it again changes nothing

    def green(
        self, car: Car, t: float, near_m: float, again: bool, v_mps: float = 0.0
    ) -> tuple[float, tuple, float] | None:
        msg = AskGreen(car.vin, t, car.length_m, car.width_m, near_m, again, now_ns(), v_mps)
        if self.clock == "realtime":
            # asked, not waited for: its LIT lights the head when it comes (_answered). No
            # sooner green is asked for: the one held might come while it was out, and
            # the driver be on its way under the reservations the sooner one replaced
            if not again:
                self._ask_later(("green", car.vin), msg, t, near_m, v_mps)
            return None
        got = self._ask_ica(keys.human(self.junction, "gateway"), msg, (Lit, Ack))
        if isinstance(got, Lit):  # lockstep: the world waits for it, never late
            return got.green_s, got.routes, got.green_s
        if isinstance(got, Reject):  # not yet (one ahead has not begun to enter): again
            if not again:
                self.green_refused[got.reason] = self.green_refused.get(got.reason, 0) + 1
        elif got is None:
            self.humans_unanswered += 1
        return None

    def _lit_s(self, t: float, start_s: float, took_s: float) -> float | None:
        """When a walker is let go whose GO took ``took_s`` of wall time to come back to an
        ask at step time ``t``: at its start, or at the first step after the answer came
        (in real time the stepping paused for the answer here, but the world would not
        have: the walker goes as late as a roadside would let it); None if that is more
        than ``green_late_s`` after the start. Lockstep is never late."""
        if self.clock == "lockstep":
            return start_s
        came = t + math.ceil(took_s * self.speed / self.step_s - 1e-9) * self.step_s
        lit = max(start_s, came)
        return lit if lit <= start_s + self.green_late_s + 1e-9 else None

    def _unlight(self, car: Car, t: float, green_s: float) -> None:
        """A LIT come too late: the head stays red, and the ICA frees that green's
        reservations (if this is lost, the next ask gets the same stale green back and
        it is dropped again)."""
        self.greens_dropped += 1
        msg = Unlit(car.vin, t, green_s, now_ns())
        if self.clock == "realtime":  # not waited for either
            self._ask_later(("unlit", car.vin), msg, t, 0.0, 0.0)
        else:
            got = self._ask_ica(keys.human(self.junction, "gateway"), msg, (Ack,))
            self.humans_unanswered += got is None
        self.log.info("green of %s for %g s came too late: its head stays red", car.vin, green_s)

    def _unwalk(self, go: Go, t: float) -> None:
        """A GO come too late: the walker stays at its kerb, and the ICA frees its slot (a
        lost word is made good as a lost UNLIT is)."""
        self.walks_dropped += 1
        msg = Unlit(go.person, t, go.start_s, now_ns(), go.crossing)
        got = self._ask_ica(keys.human(self.junction, "gateway"), msg, (Ack,))
        self.walks_unanswered += got is None
        self.log.info("GO of %s for %g s came too late: it stays at the kerb", go.person,
                      go.start_s)  # fmt: skip

    def _ask_later(
        self, what: tuple[str, str], msg, t: float, near_m: float, v_mps: float, s_m: float = 0.0
    ) -> None:
        """Realtime: send ``msg`` to the ICA's human desk without waiting; one question of
        each kind per driver out at a time (the driver seen ``near_m`` short of its line,
        or at ``s_m`` along its route, at ``v_mps``, at ``t``)."""
        if what in self._out:
            return
        key = keys.human(self.junction, "gateway")
        got = self.session.get(key, payload=query_payload(encode(msg)), timeout=WALK_TIMEOUT_S,
                               **every_answer())  # fmt: skip
        self._out[what] = _Out(got, t, near_m, v_mps, s_m)

    def _answered(self, heads: SignalHeads, t: float) -> None:
        """Realtime: the answers come since the last step, taken now. A LIT lights its head
        now (at its green, if that is still to come), or is dropped if now is later than
        ``green_late_s`` after its green, as is one whose driver was given another
        meanwhile (the ICA told either way); a SHRUNK holds its driver to the bounds from
        where it was seen, if its green is the one it was seen on."""
        key = keys.human(self.junction, "gateway")
        for what, out in list(self._out.items()):
            kind, vin = what
            try:
                reply_ = out.answers.try_recv()
            except zenoh.ZError:  # the query is over (answered, or none came in time)
                del self._out[what]
                if out.got is None:
                    self.humans_unanswered += 1
                continue
            if reply_ is None:
                continue  # still out
            body = reply_body(reply_, key) if reply_.ok is not None else None
            if body is None or out.got is not None:
                continue
            with contextlib.suppress(DecodeError):
                out.got = decode(body, Lit, Shrunk, Ack, Reject)
            d = heads.drivers.get(vin)
            if d is None:
                continue
            if isinstance(out.got, Lit) and kind == "green":
                g = out.got
                head_s = max(g.green_s, t)
                if not math.isnan(d.green_s):  # lit already (never while this was out)
                    if abs(d.green_s - g.green_s) > 1e-9:
                        self._unlight(d.car, t, g.green_s)
                elif head_s > g.green_s + self.green_late_s + 1e-9:
                    self._unlight(d.car, t, g.green_s)
                else:
                    heads.lit(vin, g.green_s, g.routes, head_s, out.near_m, out.v_mps)
            elif isinstance(out.got, Shrunk) and d.green_s <= out.t_s:
                heads.shrunk += 1
                heads.tightened(vin, out.got.t_s, out.got.routes, out.s_m, out.v_mps)
            elif isinstance(out.got, Reject) and kind == "green":
                r = out.got.reason
                self.green_refused[r] = self.green_refused.get(r, 0) + 1

    def tighten(self, car: Car, t: float, s_m: float, v_mps: float, lane: str) -> tuple | None:
        msg = Sighting(car.vin, t, lane, s_m, v_mps, now_ns())
        if self.clock == "realtime":  # its SHRUNK taken when it comes (_answered)
            self._ask_later(("sighting", car.vin), msg, t, 0.0, v_mps, s_m)
            return None
        got = self._ask_ica(keys.human(self.junction, "gateway"), msg, (Shrunk, Ack))
        self.humans_unanswered += got is None
        return got.routes if isinstance(got, Shrunk) else None

    # -- the roadside's word of an emergency vehicle on its way (ica.core.ev_notice) -------
    def ev_coming(self, notice: EvNotice, t_s: float) -> bool:
        """Tell the ICA that an EV is on its way at step time ``t_s`` (the notice's own);
        False if it did not take the notice (as the core's ``ev_coming``)."""
        msg = EvComing(notice.ev, notice.in_edge, notice.out_edge, notice.eta_s,
                       notice.sent_s, now_ns())  # fmt: skip
        got = self._ask_ica(keys.ev(self.junction, "gateway"), msg, (Ack,))
        if isinstance(got, Ack):
            return True
        self.notices_unanswered += got is None
        self.log.warning("EVCOMING %s: %s", notice.ev, "no answer" if got is None else got.detail)
        return False

    def _ask_ica(self, key: str, msg, kinds: tuple[type, ...]):
        """One query to the ICA, waited for: its answer of one of ``kinds`` or a REJECT,
        or None."""
        got = None
        for r in self.session.get(
            key,
            payload=query_payload(encode(msg)),
            timeout=LOCKSTEP_ASK_S if self.clock == "lockstep" else WALK_TIMEOUT_S,
            **every_answer(),
        ):
            body = reply_body(r, key) if r.ok is not None else None
            if got is None and body is not None:
                with contextlib.suppress(DecodeError):
                    got = decode(body, *kinds, Reject)
        return got

    def send(self, t: float, seen: list[Seen]) -> None:
        """Publish this step's CLOCK and STATEs; in lockstep, every wave but the
        last is also answered here. :meth:`collect` gets the last answers."""
        out: list[Actuation] = []
        for item in self.inbox.drain():
            self._take(item, None, out)  # liveliness news, and realtime's commands
        self._k += 1
        if self._k % 200 == 0:
            note_refused(self.log)
        k = self._k
        self._clock_pub.put(encode(Clock(k, t, self.clock, self.speed, False, now_ns())))
        stamp = now_ns()
        if self._vehicles_due(k, seen):
            everyone = (*(self._vehicle_state(s) for s in seen), *self._human_states)
            self._vehicles_pub.put(encode(State("", k, 0, t, everyone, stamp)))
        if self.clock == "lockstep":
            self._seen_now = seen
            waves = self._waves(t, seen)
        else:  # a verdict is news there anyway (see _realtime_feed)
            self.dropping.clear()
            waves = [self._batches(self._realtime_feed(t, seen))]
        for part, batches in enumerate(waves):
            if part > 0:
                self._wait_commands(k, part - 1, waves[part - 1], out, t)
            for agent, vehicles in batches.items():
                self._publish_state(agent, State(agent, k, part, t, tuple(vehicles), stamp))
        if len(waves) > 1:
            self.multi_wave_steps += 1
        for s in seen:
            if s.obs.exited:
                agent = self.owner.get(s.car.vin)
                if agent is not None and s.car.vin in self.here:
                    self.load[agent] -= 1
                self.here.discard(s.car.vin)
                self.known.discard(s.car.vin)
                self.wake.pop(s.car.vin, None)
        self._pending = (k, len(waves) - 1, waves[-1] if waves else {}, out)

    def collect(self, t: float) -> list[Actuation]:
        """The plans to hand to the actuators before the next step (lockstep: waits)."""
        k, part, expected, out = self._pending
        if self.clock == "lockstep":
            if expected:
                self._wait_commands(k, part, expected, out, t)
            while news := self._revoke_wave():
                part += 1
                self.revoke_waves += 1
                for agent, vehicles in news.items():
                    self._publish_state(agent, State(agent, k, part, t, tuple(vehicles), now_ns()))
                self._wait_commands(k, part, news, out, t)
        else:
            if self.inbox.stopping.is_set():  # as in lockstep: the run ends here, its outputs
                raise RunError(f"stopped by a signal at t={t:.2f} s")  # written as far as it got
            for item in self.inbox.drain():
                self._take(item, None, out)
            pace = self._t0_wall + k * self.step_s / self.speed - time.monotonic()
            if pace > 0:
                time.sleep(pace)
        return out

    def _vehicles_due(self, k: int, seen: list[Seen]) -> bool:
        """Whether this step's VEHICLES goes out: every step while an observer draws them;
        else, for the ICA (which keeps only who hosts each vehicle), the step after a
        vehicle changed hands or left, and every VEHICLES_EVERY steps lest one be lost."""
        news, self.owner_news = self.owner_news or any(s.obs.exited for s in seen), False
        if not (self.observers or news or k % VEHICLES_EVERY == 0):
            return False
        return self._vehicles_pub.matching_status.matching  # the ICA or an observer listens

    def _publish_state(self, agent: str, state: State) -> None:
        pub = self._state_pubs.get(agent)
        if pub is None:
            pub = self._state_pubs[agent] = publisher(
                self.session, keys.state(self.junction, agent)
            )
        pub.put(encode(state))

    def _realtime_feed(self, t: float, seen: list[Seen]) -> list[Seen]:
        """Who the agents hear about this step: every vehicle without a plan, and any
        vehicle with news (a plan taken or refused, an exit) for NOTICE_S after it."""
        feed = []
        for s in seen:
            c = s.car
            if s.obs.exited:  # named once, the step it leaves
                self.news.pop(c.vin, None)
                self._seen_plan.pop(c.vin, None)
                feed.append(s)
                continue
            mark = (c.plan_seq, c.refused_seq, c.kept_seq)
            if self._seen_plan.get(c.vin) != mark:
                self._seen_plan[c.vin] = mark
                self.news[c.vin] = t + NOTICE_S
            if c.plan_seq == NO_PLAN or t <= self.news.get(c.vin, -math.inf):
                feed.append(s)
        return feed

    def _batches(self, seen: list[Seen]) -> dict[str, list[VehicleState]]:
        batches: dict[str, list[VehicleState]] = {}
        for s in seen:
            if s.obs.exited:  # only its own agent needs to hear it left
                agent = self.owner.get(s.car.vin)
                if agent not in self.alive:
                    continue
            else:
                agent = self._owner(s.car.vin)
            if agent is None:
                continue
            batches.setdefault(agent, []).append(self._vehicle_state(s))
            self.known.add(s.car.vin)
        return batches

    def _waves(self, t: float, seen: list[Seen]) -> list[dict[str, list[VehicleState]]]:
        """This step's STATEs, in waves that keep the order of ICA contacts across agents.

        A vehicle talks to the ICA this step if it is new to its agent (it
        will DETECT) or its agent said it may (``wake_s``) and it is head of
        its lane. Only such vehicles are sent, with any exit notices waiting;
        a step without one costs no round trip. When contacts belong to more
        than one agent, the step is split: each run of consecutive contacts
        (in the world's order, the embedded runner's order) of one agent is a
        wave, and a wave is sent only after the previous one is answered. The
        ICA then sees DETECTs and REQUESTs in exactly the embedded runner's
        order, whatever the number of agents: lockstep runs are deterministic
        and equal to it.
        """
        runs: list[tuple[str, list[Seen]]] = []
        for s in seen:
            vin = s.car.vin
            if s.obs.exited:
                if vin in self.known:
                    self.exits.append(s)
                continue
            verdict = vin in self.dropping  # the actuator dropped or kept a revoked plan
            self.dropping.discard(vin)
            if s.car.plan_seq != NO_PLAN and not verdict:
                continue  # flying its plan: nothing to ask
            wake = self.wake.get(vin, -BIG)
            if (
                vin in self.known
                and not verdict
                and not (t >= wake and (s.obs.may_ask or wake <= -BIG))
            ):
                continue
            agent = self._owner(vin)
            if agent is None:
                continue
            if runs and runs[-1][0] == agent:
                runs[-1][1].append(s)
            else:
                runs.append((agent, [s]))
        if not runs:
            return []
        waves: list[dict[str, list[VehicleState]]] = []
        for agent, run in runs:
            waves.append({agent: [self._vehicle_state(s) for s in run]})
            self.known.update(s.car.vin for s in run)
        for s in self.exits:  # no ICA contact: order does not matter, send them first
            agent = self.owner.get(s.car.vin)
            if agent in self.alive:
                waves[0].setdefault(agent, []).append(self._vehicle_state(s))
        self.exits = []
        return waves

    def _revoke_wave(self) -> dict[str, list[VehicleState]]:
        """Lockstep: the vehicles revoked this step whose drop has not come back with a
        COMMAND, by agent. A reordering asked for by one agent's vehicle may revoke
        another agent's, and that agent gets no STATE while its vehicles fly their
        plans: it would hear its REVOKE only when idle, a wall-clock moment. Sent now,
        in one more wave of this step, it answers the REVOKE in this step's COMMAND,
        as an agent that caused the reordering does: the ICA hears every drop in the
        same step whoever hosts the vehicle, and lockstep runs stay deterministic.
        (The ICA publishes a REVOKE before it answers the query that caused it, and
        the router forwards both in order, so the REVOKE is here, and at the revoked
        vehicle's agent, before that query's COMMAND.)"""
        news, self.revoked_news = self.revoked_news - self.dropping, set()
        batches: dict[str, list[VehicleState]] = {}
        if not news:
            return batches
        seen = {s.car.vin: s for s in self._seen_now}
        for vin in sorted(news):
            s = seen.get(vin)
            agent = self.owner.get(vin)
            if s is None or s.obs.exited or agent not in self.alive or vin not in self.known:
                continue
            batches.setdefault(agent, []).append(self._vehicle_state(s))
        return batches

    def _owner(self, vin: str) -> str | None:
        agent = self.owner.get(vin)
        if agent is not None and agent in self.alive:
            if vin not in self.here:  # hosted at an earlier junction: its agent keeps it
                self.here.add(vin)
                self.load[agent] += 1
                self.owner_news = True  # news to this junction's ICA
            return agent
        return self._assign(vin)

    def _assign(self, vin: str) -> str | None:
        free = [
            a for a in sorted(self.alive) if not self.per_agent or self.load[a] < self.per_agent
        ]
        if not free:
            if not self.alive:
                return None  # no agent at all for now: the actuator keeps it short of the line
            raise RunError(
                f"no vehicle agent has room for {vin}: {len(self.alive)} agents x "
                f"{self.per_agent} vehicles are all in use; start more agents or raise --per-agent"
            )
        agent = min(free, key=lambda a: (self.load[a], a))
        old = self.owner.get(vin)
        if old is not None:
            self.fleet.adoptions += 1
            self.known.discard(vin)
        self.owner[vin] = agent
        self.owner_news = True
        self.here.add(vin)
        self.load[agent] += 1
        self.fleet.hosted[agent] += 1
        return agent

    def _wait_commands(
        self,
        k: int,
        part: int,
        batches: dict[str, list[VehicleState]],
        out: list[Actuation],
        t: float,
    ) -> None:
        start = time.perf_counter()
        expected = set(batches)
        deadline = time.monotonic() + self.step_timeout_s
        resend_at = time.monotonic() + self.resend_s
        while expected:
            dead = expected - self.alive
            for agent in dead:  # its vehicles go to another agent at the next step
                expected.discard(agent)
                for vs in batches[agent]:
                    self.known.discard(vs.vin)
            if not expected:
                break
            if self.inbox.stopping.is_set():
                raise RunError(f"stopped by a signal at t={t:.2f} s")
            now = time.monotonic()
            if now > deadline:
                raise RunError(
                    f"no command for step {k} (t={t:.2f} s) from "
                    f"{', '.join(sorted(expected))} within {self.step_timeout_s:.0f} s"
                )
            if now > resend_at:  # lost on the way there or back: the same STATE again
                for agent in expected:
                    self.resent_states += 1
                    self._publish_state(
                        agent, State(agent, k, part, t, tuple(batches[agent]), now_ns())
                    )
                resend_at = now + self.resend_s
            item = self.inbox.get(timeout=min(0.05, max(deadline - now, 0.01)))
            if item is None:
                continue
            answered = self._take(item, (k, part), out)
            if answered is not None:
                expected.discard(answered)
        self.wait_s.append(time.perf_counter() - start)

    def _take(self, item: Item, wanted: tuple[int, int] | None, out: list[Actuation]) -> str | None:
        """Handle one inbox item; the agent, if it was its command for (step, part) ``wanted``."""
        if item.what != "command":
            self._note(item)
            return None
        if not item.key.startswith(self._command_key):
            return None
        try:
            cmd = decode(item.payload, Command)
        except DecodeError as e:
            self.log.warning("dropped a bad command on %s: %s", item.key, e)
            return None
        if keys.last(item.key) != cmd.agent:
            self.dropped_setpoints += len(cmd.setpoints)  # someone else's name on its key
            return None
        self.age_ms.append(max((item.arrived_ns - cmd.sent_ns) / 1e6, 0.0))  # in transit
        stale = wanted is not None and (cmd.step, cmd.part) != wanted
        if stale:
            self.stale_commands += 1  # lockstep: an answer to an earlier STATE (resent, or late)
        for sp in cmd.setpoints:
            if self.owner.get(sp.vin) != cmd.agent:
                self.dropped_setpoints += 1  # not this agent's vehicle (any more)
                continue
            if sp.drop:  # a revoked plan: safe to hand over whenever it comes, even twice
                self.dropping.add(sp.vin)
                out.append(Actuation(sp.vin, sp.seq, drop=True))
                continue
            if stale:
                continue
            if sp.wake_s != BIG or sp.seq != NO_PLAN:
                self.wake[sp.vin] = sp.wake_s
            out.append(Actuation(sp.vin, sp.seq, sp.t0_s, sp.s_m, sp.wake_s))
        if stale:
            return None
        return cmd.agent if wanted is not None else None

    def _note(self, item: Item) -> None:
        if item.what == "revoke":
            try:
                self.revoked_news.add(decode(item.payload, Revoke).vin)
            except DecodeError as e:
                self.log.warning("dropped a bad revoke message: %s", e)
            return
        up = item.payload == b"+"
        name = keys.last(item.key)
        if item.what == "agent" and item.key.startswith(self._agent_key):
            if not _is_name(name) or not known_writer(name):
                if up:
                    self.fake_tokens += 1
                    self.log.warning("ignored a token for %r: not an agent of this site", name)
                return
            if up:
                self.alive.add(name)
            elif name in self.alive and not self.ended:
                self.alive.discard(name)
                self.agent_deaths += 1
                gone = sorted(v for v, a in self.owner.items() if a == name and v in self.known)
                self.load.pop(name, None)
                self.log.error(
                    "vehicle agent %s is gone; %d of its vehicles at %s go to the other agents",
                    name, len(gone), self.junction,
                )  # fmt: skip
                for vin in gone:
                    self.known.discard(vin)
                    # handed over now, not at the next step: a restarted agent of the same
                    # name may be back by then and would find them still its own
                    if any(a != name for a in self.alive):
                        with contextlib.suppress(RunError):  # no room: the next step says so
                            self._assign(vin)
        elif item.what == "observer" and item.key.startswith(self._observer_key):
            if not _is_name(name):
                return
            (self.observers.add if up else self.observers.discard)(name)
        elif item.what == "ica" and item.key == self._ica_key:
            if self.ica_alive and not up and not self.ended:
                self.ica_outages += 1
                self.log.error(
                    "the ICA of %s is gone: no new plans until it is back", self.junction
                )
            elif up and not self.ica_alive and self.ica_outages:
                self.log.info("the ICA of %s is back", self.junction)
            self.ica_alive = up

    def _vehicle_state(self, s: Seen, signal: str = "") -> VehicleState:
        c, o = s.car, s.obs
        return VehicleState(
            vin=c.vin,
            route_id=c.route.id,
            lane=o.lane,
            dist_to_entry_m=float(o.dist_to_entry_m),
            speed_mps=float(o.speed_mps),
            x_m=float(s.xy[0]),
            y_m=float(s.xy[1]),
            angle_deg=float(s.angle_deg),
            length_m=c.length_m,
            width_m=c.width_m,
            max_speed_mps=float(c.entry_speed_mps),
            head=o.head,
            detected_s=float(o.detected_s),
            exited=o.exited,
            plan_seq=c.plan_seq,
            refused_seq=c.refused_seq,
            kept_seq=c.kept_seq,
            ev=c.ev,
            follows=o.follows,
            owner=self.owner.get(c.vin, ""),
            intent_m=np.asarray(o.intent_m, dtype=float),
            exit_room_m=min(o.exit_room_m, WIRE_BIG),
            network_room_m=min(max(o.network_room_m, 0.0), WIRE_BIG),
            signal=signal,
        )

    def facts(self) -> dict:
        w = np.array(self.wait_s) if self.wait_s else np.full(1, math.nan)
        age = np.array(self.age_ms) if self.age_ms else np.full(1, math.nan)
        hist = np.histogram(np.clip(age, 0, None), bins=[*AGE_BINS_MS, math.inf])[0]
        return {
            "clock": self.clock,
            "walks_unanswered": self.walks_unanswered,
            "humans_unanswered": self.humans_unanswered,
            "notices_unanswered": self.notices_unanswered,
            "green_refused": dict(sorted(self.green_refused.items())),
            "greens_dropped_late": self.greens_dropped,
            "walks_dropped_late": self.walks_dropped,
            "speed": self.speed if self.clock == "realtime" else None,
            "agents": dict(sorted(self.fleet.hosted.items())),
            "agent_deaths": self.agent_deaths,
            "adoptions": self.fleet.adoptions,
            "ica_outages": self.ica_outages,
            "multi_wave_steps": self.multi_wave_steps,
            "revoke_waves": self.revoke_waves,
            "lockstep_waits": len(self.wait_s),
            "resent_states": self.resent_states,
            "stale_commands": self.stale_commands,
            "dropped_setpoints": self.dropped_setpoints,
            "refused_unsealed": refused(),
            "fake_tokens": self.fake_tokens,
            "step_wait_median_ms": float(np.median(w) * 1e3),
            "step_wait_p99_ms": float(np.percentile(w, 99) * 1e3),
            "command_age_ms": {
                "median": float(np.median(age)),
                "p99": float(np.percentile(age, 99)),
                "max": float(np.max(age)),
                "histogram": {
                    f"{lo}-{hi}": int(n)
                    for lo, hi, n in zip(AGE_BINS_MS, [*AGE_BINS_MS[1:], "inf"], hist, strict=True)
                },
            },
        }


def _is_name(name: str) -> bool:
    try:
        keys.chunk(name)
    except keys.KeyChunkError:
        return False
    return True


def run_gateway(
    session,
    cfg: RunConfig,
    inter,
    drivers: ZenohDrivers,
    *,
    peers_timeout_s: float = 60.0,
    progress=None,
    checkpoint: Callable[[RunResult, str | None], None] | None = None,
    checkpoint_every_s: float = 30.0,
) -> RunResult:
    """Run the world with the agents' decisions; the same result as an embedded run.

    ``checkpoint(result, why)`` is handed what the run knows every
    ``checkpoint_every_s`` of sim time (``why`` says it is incomplete) and,
    should the run stop early, once more with the reason.
    """
    from dica.sim_gateway.sumo_io import import_libsumo, start_sumo

    ls = import_libsumo()
    ica_cfg = cfg.controller_spec().config
    schedule, _spec, horizon = schedule_for(cfg, inter, ica_cfg.step_s)
    drivers.wait_for_peers(peers_timeout_s)
    cmd = start_sumo(ls, cfg, ica_cfg.step_s)
    world = None

    def result() -> RunResult:
        res = world.result({}, cmd)
        res.extra.update(drivers.facts())
        return res

    try:
        # in real time the agents plan ahead by their measured lead: each vehicle that may
        # ask is told where its actuator takes it over the next PREDICT_S (lockstep: now)
        predict = PREDICT_S if drivers.clock == "realtime" else cfg.lead_s
        world = World(ls, cfg, inter, ica_cfg, schedule, horizon, want_xy=True, predict_s=predict)
        next_checkpoint = checkpoint_every_s
        ended = False
        try:
            while True:
                seen = world.step()
                if world.walkers is not None:
                    drivers.walk(world.walkers, world.t)  # the roadside asks first
                    drivers.people(world.walkers, world.t)
                if world.heads is not None:
                    drivers.humans(world.heads, world.human_seen, world.t)
                drivers.send(world.t, seen)
                world.end_step(progress)  # while the agents decide
                world.apply(drivers.collect(world.t))
                if world.done():
                    break
                if checkpoint is not None and world.t >= next_checkpoint:
                    checkpoint(result(), f"running: checkpoint at t={world.t:.0f} s")
                    next_checkpoint += checkpoint_every_s
            res = result()
            res.extra["roles"] = drivers.role_stats()  # before the end: they stop on it
            drivers.end(world.t)
            ended = True
            return res
        except (RunError, KeyboardInterrupt) as e:
            if checkpoint is not None:
                checkpoint(result(), f"stopped at t={world.t:.2f} s: {e or 'interrupted'}")
            raise
        finally:
            if not ended:
                drivers.end(world.t)
    finally:
        ls.close()
