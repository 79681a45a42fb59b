"""The ICA's and the vehicle agent's message handlers, in this process, over a real
Zenoh router on loopback.

No SUMO and no other processes: the test plays the gateway and the vehicles'
agents itself, with real sessions through a real router, so a handler's answer to
each kind of message (and to the wrong writer, a repeat, bad bytes, a request
ahead of the clock) is checked on the wire, message by message.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import queue
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from dica.deploy import ZENOH_CONFIGS
from dica.deploy.transport import open_session, query_payload
from dica.ica.convert import request_from_core
from dica.ica.core.controller import ControllerSpec, build_controller
from dica.ica.core.proposal import propose
from dica.ica.service import IcaService
from dica.schemas import keys
from dica.schemas.codec import decode, encode, now_ns
from dica.schemas.messages import (
    Ack,
    Cancel,
    Clock,
    Command,
    Detect,
    Reject,
    Response,
    State,
    VehicleState,
)
from dica.tools.loopback import free_port
from dica.vehicle_agent.agent import Agent

J = "C"
LANE, OUT = "N_in_1", "S_out_1"  # through from the north
LOG = logging.getLogger("test-handlers")


@pytest.fixture
def endpoint() -> Iterator[str]:
    """A Zenoh router in this process, from the deployment's own router config."""
    import zenoh

    where = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config.from_file(str(ZENOH_CONFIGS / "router.json5"))
    conf.insert_json5("listen/endpoints", json.dumps([where]))
    router = zenoh.open(conf)
    yield where
    router.close()


@pytest.fixture
def ica(endpoint, ch45) -> Iterator[IcaService]:
    """Enhanced DICA behind the ICA's handlers, serving in a thread of its own."""
    session = open_session(connect=endpoint)
    controller = build_controller(ControllerSpec.of("enhanced", platoon=True), ch45)
    service = IcaService(session, controller, J, LOG)
    service.serve()
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    yield service
    service.inbox.stopping.set()
    thread.join(10)
    service.close()
    session.close()


class Peer:
    """A session that asks the ICA and publishes the clock, as agents and the gateway do."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(connect=endpoint)
        self.step = 0

    def ask(self, key: str, payload: bytes, kinds: tuple[type, ...]):
        replies = [r for r in self.session.get(key, payload=query_payload(payload), timeout=5.0)]
        answers = [r.ok.payload.to_bytes() for r in replies if r.ok is not None]
        assert len(answers) == 1, f"{len(answers)} answers on {key}"
        return decode(answers[0], *kinds), answers[0]

    def clock(self, t_s: float, mode: str = "lockstep", end: bool = False) -> None:
        self.step += 1
        msg = Clock(self.step, t_s, mode, 1.0, end, now_ns())
        self.session.put(keys.clock(J), encode(msg))

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def peer(endpoint) -> Iterator[Peer]:
    p = Peer(endpoint)
    yield p
    p.close()


def _until(condition, timeout_s: float = 5.0) -> None:
    """Wait for a condition (a message handled in another thread), not for a time."""
    done = threading.Event()
    deadline = threading.Timer(timeout_s, done.set)
    deadline.start()
    try:
        while not condition():
            assert not done.wait(0.01), "the condition never held"
    finally:
        deadline.cancel()


def _detect(peer: Peer, vin: str, agent: str = "agent-1", t_s: float = 0.0):
    msg = Detect(vin, LANE, t_s, False, 15.0, now_ns())
    return peer.ask(keys.detect(J, agent), encode(msg), (Ack, Reject))[0]


def _request(ch45, vin: str, seq: int = 0, t_s: float = 0.0) -> bytes:
    route = ch45.route(LANE, OUT)
    req = propose(route, vin=vin, seq=seq, t0_s=t_s, dist_to_entry_m=45.0, speed_mps=15.0)
    return encode(request_from_core(req))


def test_a_detected_vehicle_is_confirmed_and_the_confirmation_published_first(ica, peer, ch45):
    seen: queue.Queue = queue.Queue()
    sub = peer.session.declare_subscriber(keys.confirmed(J), lambda s: seen.put(s))
    peer.clock(0.0)
    _until(lambda: ica.now_s == 0.0)
    assert isinstance(_detect(peer, "v1"), Ack)
    answer, raw = peer.ask(keys.request(J, "agent-1"), _request(ch45, "v1"), (Response, Reject))
    assert isinstance(answer, Response) and answer.vin == "v1" and answer.seq == 0
    published = seen.get(timeout=5.0)  # on the confirmed key, before the reply left
    assert str(published.key_expr) == keys.confirmed(J, "v1")
    assert published.payload.to_bytes() == raw
    assert set(ica.ica.confirmed) == {"v1"} and ica.stats.confirmed == 1
    sub.undeclare()


def test_a_repeated_request_gets_the_same_answer_and_no_second_reservation(ica, peer, ch45):
    peer.clock(0.0)
    _until(lambda: ica.now_s == 0.0)
    _detect(peer, "v1")
    payload = _request(ch45, "v1")
    first, _ = peer.ask(keys.request(J, "agent-1"), payload, (Response, Reject))
    again, _ = peer.ask(keys.request(J, "agent-1"), payload, (Response, Reject))
    assert isinstance(first, Response)
    same = dataclasses.replace(again, sent_ns=first.sent_ns)  # only when it left differs
    assert encode(same) == encode(first)
    assert ica.stats.repeated == 1 and ica.stats.confirmed == 1 and len(ica.ica.confirmed) == 1


def test_another_agents_vehicle_is_refused_and_keeps_its_reservation(ica, peer, ch45):
    peer.clock(0.0)
    _until(lambda: ica.now_s == 0.0)
    _detect(peer, "v1", agent="agent-1")
    peer.ask(keys.request(J, "agent-1"), _request(ch45, "v1"), (Response, Reject))
    other, _ = peer.ask(keys.request(J, "agent-2"), _request(ch45, "v1", seq=1), (Response, Reject))
    assert isinstance(other, Reject) and other.reason == "bad_state"
    assert "another agent" in other.detail
    seq = ica.ica.confirmed["v1"].confirmation.seq
    cancel = encode(Cancel("v1", seq, now_ns()))
    refused, _ = peer.ask(keys.cancel(J, "agent-2"), cancel, (Ack, Reject))
    assert isinstance(refused, Reject) and "v1" in ica.ica.confirmed
    assert ica.stats.not_theirs == 2
    done, _ = peer.ask(keys.cancel(J, "agent-1"), cancel, (Ack, Reject))
    assert isinstance(done, Ack) and "v1" not in ica.ica.confirmed


def test_bad_bytes_get_a_reject_and_the_ica_serves_on(ica, peer, ch45):
    peer.clock(0.0)
    _until(lambda: ica.now_s == 0.0)
    for junk in (b"", b"\x00\x01not msgpack", encode(Detect("v9", LANE, 0.0, False, 1.0, 1))):
        rej, _ = peer.ask(keys.request(J, "agent-1"), junk, (Response, Reject))
        assert isinstance(rej, Reject) and rej.reason == "bad_message"
    assert ica.stats.bad_messages == 3
    _detect(peer, "v1")
    ok, _ = peer.ask(keys.request(J, "agent-1"), _request(ch45, "v1"), (Response, Reject))
    assert isinstance(ok, Response)


def test_a_request_ahead_of_the_clock_waits_for_it(ica, peer, ch45):
    """Observed at 1 s while the ICA's clock says 0: held, and answered once the CLOCK
    for 1 s arrives (it may take another path through the router)."""
    peer.clock(0.0)
    _until(lambda: ica.now_s == 0.0)
    _detect(peer, "v1", t_s=0.0)
    answers: queue.Queue = queue.Queue()

    def ask() -> None:
        answers.put(
            peer.ask(keys.request(J, "agent-1"), _request(ch45, "v1", t_s=1.0), (Response, Reject))
        )

    asking = threading.Thread(target=ask)
    asking.start()
    _until(lambda: len(ica._held) == 1)
    assert answers.empty()
    peer.clock(1.0)
    asking.join(10)
    answer, _ = answers.get(timeout=1.0)
    assert isinstance(answer, Response) and answer.t_s[0] == pytest.approx(1.0)


def test_an_old_clock_changes_nothing(ica, peer):
    peer.clock(2.0)
    _until(lambda: ica.now_s == 2.0)
    stale = Clock(1, 1.0, "lockstep", 1.0, False, now_ns())  # an earlier step, repeated
    peer.session.put(keys.clock(J), encode(stale))
    _until(lambda: ica.stats.ignored_clocks == 1)
    assert ica.now_s == 2.0


# -- the vehicle agent ----------------------------------------------------------------
@pytest.fixture
def agent(endpoint, ch45, ica) -> Iterator[Agent]:
    session = open_session(connect=endpoint)
    a = Agent(session, "agent-1", ch45, ica.ica.config, log=LOG)
    thread = threading.Thread(target=a.run, daemon=True)
    thread.start()
    yield a
    a.inbox.stopping.set()
    thread.join(10)
    a.close()
    session.close()


def _vehicle(ch45, t_s: float, dist_m: float) -> VehicleState:
    route = ch45.route(LANE, OUT)
    x, y = route.points(np.array([-dist_m]))[0]
    return VehicleState(
        "v1", route.id, LANE, dist_m, 15.0, float(x), float(y), 180.0, 5.0, 1.8, 15.0,
        True, t_s, False, -1, -1, -1, False, False, "agent-1", np.zeros(0),
    )  # fmt: skip


def test_the_agent_answers_each_state_with_a_command_and_flies_a_confirmed_plan(
    agent, ica, peer, ch45
):
    """Lockstep: a STATE naming a new vehicle in the region hands it to the agent, which
    announces it (DETECT) and asks for its plan (REQUEST) before it answers the STATE;
    its COMMAND carries the plan the ICA confirmed, by position from the plan's start."""
    commands: queue.Queue = queue.Queue()
    sub = peer.session.declare_subscriber(
        keys.command(J, "agent-1"), lambda s: commands.put(decode(s.payload.to_bytes(), Command))
    )
    for t in (0.0, 0.05):
        peer.clock(t)
        _until(lambda t=t: ica.now_s == t and agent.clock is not None and agent.clock.t_s == t)
        dist = 45.0 - 15.0 * t
        state = State("agent-1", peer.step, 0, t, (_vehicle(ch45, 0.0, dist),), now_ns())
        peer.session.put(keys.state(J, "agent-1"), encode(state))
        cmd = commands.get(timeout=10.0)
        assert (cmd.agent, cmd.step, cmd.part) == ("agent-1", peer.step, 0)
        plans = [p for p in cmd.setpoints if p.seq >= 0 and len(p.s_m)]
        if plans:
            break
    assert ica.ica.knows("v1") and "v1" in ica.ica.confirmed
    (plan,) = plans
    conf = ica.ica.confirmed["v1"].confirmation
    assert plan.vin == "v1" and plan.seq == conf.seq
    assert plan.t0_s == pytest.approx(conf.tss.t_s[0])
    assert plan.s_m[0] == pytest.approx(-dist, abs=0.5)  # it starts where the vehicle is
    assert np.all(np.diff(plan.s_m) >= 0.0) and not math.isnan(plan.wake_s)
    # the same STATE again (the gateway missed the COMMAND): the same COMMAND again
    peer.session.put(keys.state(J, "agent-1"), encode(state))
    again = commands.get(timeout=10.0)
    assert again.setpoints[0].seq == plan.seq and np.array_equal(again.setpoints[0].s_m, plan.s_m)
    assert ica.stats.confirmed == 1
    sub.undeclare()
