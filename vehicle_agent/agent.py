"""A vehicle-agent process: hosts one or many vehicles, each its own state machine.

The gateway hands a vehicle to an agent by naming it in the STATE it sends on
``sim/<j>/state/<agent>``; from then on the agent steps that vehicle's
machine on every STATE, reaches the ICA with Zenoh queries (DETECT, REQUEST),
acknowledges each RESPONSE on ``dica/<j>/ack/<vin>``, and answers every STATE
with one COMMAND on ``sim/<j>/command/<agent>`` (the gateway's lockstep clock
waits for it). A liveliness token ``sim/<j>/alive/<agent>`` tells the gateway
the agent is up, and that it died.
"""

from __future__ import annotations

import logging
import math
import time

from ica.core.config import IcaConfig
from ica.core.intersection import Intersection
from ica.core.request import Confirmation, Reason, Rejection, Request
from schemas import keys
from schemas.codec import DecodeError, decode, encode, now_ns
from schemas.convert import reject_to_core, request_from_core, response_to_core
from schemas.link import Inbox, publisher, put
from schemas.messages import Ack, Clock, Command, Detect, Reject, Response, Setpoint, State
from vehicle_agent.machine import Observation, Vehicle

REALTIME_BRAKE_STEPS = 200  # 10 s at 0.05 s: beyond any stop from the road's speed


class ZenohLink:
    """A vehicle's link to the ICA: Zenoh queries with a timeout.

    No answer in time becomes a NO_ANSWER rejection; the machine then asks
    again later with the same sequence number, so a REQUEST the ICA did get
    is answered with the confirmation it already made.
    """

    def __init__(self, session, junction: str, timeout_s: float, log: logging.Logger) -> None:
        self.session = session
        self.junction = junction
        self.timeout_s = timeout_s
        self.log = log
        self.rtt_s: list[float] = []

    def _ask(self, key: str, payload: bytes, *kinds):
        t = time.perf_counter()
        replies = self.session.get(key, payload=payload, timeout=self.timeout_s)
        for r in replies:
            if r.ok is None:
                continue
            try:
                msg = decode(r.ok.payload.to_bytes(), *kinds)
            except DecodeError as e:
                self.log.warning("bad reply on %s: %s", key, e)
                continue
            self.rtt_s.append(time.perf_counter() - t)
            return msg
        return None

    def detect(self, vin: str, lane: str, t_s: float) -> Rejection | None:
        msg = Detect(vin, lane, t_s, now_ns())
        answer = self._ask(keys.detect(self.junction), encode(msg), Ack, Reject)
        if answer is None:
            return Rejection(vin, -1, Reason.NO_ANSWER, "no answer to DETECT")
        return reject_to_core(answer) if isinstance(answer, Reject) else None

    def request(self, req: Request, now_s: float) -> Confirmation | Rejection:
        payload = encode(request_from_core(req))
        answer = self._ask(keys.request(self.junction), payload, Response, Reject)
        if answer is None:
            return Rejection(req.vin, req.seq, Reason.NO_ANSWER, "no answer to REQUEST")
        if isinstance(answer, Reject):
            return reject_to_core(answer)
        if answer.vin != req.vin or answer.seq != req.seq:
            return Rejection(req.vin, req.seq, Reason.BAD_MESSAGE, "a RESPONSE for someone else")
        ack = Ack(answer.vin, answer.seq, Response.KIND, now_ns())
        put(self.session, keys.ack(self.junction, answer.vin), encode(ack))
        return response_to_core(answer)


class Agent:
    """Vehicles hosted by this process, stepped on every STATE from the gateway."""

    def __init__(
        self,
        session,
        agent_id: str,
        inter: Intersection,
        config: IcaConfig,
        *,
        retry_s: float = 0.5,
        timeout_s: float = 1.0,
        log: logging.Logger,
    ) -> None:
        self.session = session
        self.agent_id = keys.chunk(agent_id)
        self.inter = inter
        self.config = config
        self.retry_s = retry_s
        self.log = log
        j = inter.junction_id
        self.link = ZenohLink(session, j, timeout_s, log)
        self.inbox = Inbox()
        self.vehicles: dict[str, Vehicle] = {}
        self.hosted = 0
        self.ended = False
        self.realtime = False  # then braking profiles reach to the stop (late messages)
        self._decls = [
            session.declare_subscriber(keys.state(j, self.agent_id), self.inbox.sample_cb("state")),
            session.declare_subscriber(keys.clock(j), self.inbox.sample_cb("clock")),
        ]
        self._pub = publisher(session, keys.command(j, self.agent_id))
        self._token = session.liveliness().declare_token(keys.agent_alive(j, self.agent_id))

    def run(self) -> None:
        while not self.inbox.stopping.is_set() and not self.ended:
            item = self.inbox.get(timeout=0.1)
            if item is None:
                continue
            try:
                if item.what == "state":
                    self._on_state(decode(item.payload, State))
                elif item.what == "clock":
                    clock = decode(item.payload, Clock)
                    self.ended = clock.end
                    self.realtime = clock.mode == "realtime"
            except DecodeError as e:
                self.log.warning("dropped a bad %s message: %s", item.what, e)

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()
        for d in self._decls:
            d.undeclare()

    def _on_state(self, state: State) -> None:
        setpoints = []
        for vs in state.vehicles:
            v = self.vehicles.get(vs.vin)
            if v is None:
                v = self._adopt(vs)
                if v is None:
                    continue
            obs = Observation(
                t_s=state.t_s,
                lane=vs.lane,
                dist_to_entry_m=vs.dist_to_entry_m,
                speed_mps=vs.speed_mps,
                head=vs.head,
                detected_s=vs.detected_s,
                exited=vs.exited,
            )
            cmd = v.step(obs, self.link)
            if cmd is not None:
                setpoints.append(
                    Setpoint(cmd.vin, cmd.t0_s, cmd.speeds, cmd.speed_mode, cmd.wake_s)
                )
            if vs.exited:
                del self.vehicles[vs.vin]
        out = Command(self.agent_id, state.step, state.part, tuple(setpoints), now_ns())
        self._pub.put(encode(out))

    def _adopt(self, vs) -> Vehicle | None:
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
        v.brake_steps = REALTIME_BRAKE_STEPS if self.realtime else 1
        self.vehicles[vs.vin] = v
        self.hosted += 1
        return v

    def summary(self) -> dict:
        import numpy as np

        rtt = np.array(self.link.rtt_s) if self.link.rtt_s else np.full(1, math.nan)
        return {
            "agent": self.agent_id,
            "hosted": self.hosted,
            "queries": len(self.link.rtt_s),
            "rtt_median_ms": float(np.median(rtt) * 1e3),
            "rtt_p99_ms": float(np.percentile(rtt, 99) * 1e3),
        }
