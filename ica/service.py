"""The ICA process: the DICA core behind a Zenoh queryable.

Keys (``schemas.keys``): REQUESTs arrive as queries on ``dica/<j>/request``
and are answered with a RESPONSE or a REJECT; DETECTs on ``dica/<j>/detect``
get an ACK or a REJECT. Every new confirmation is also published on
``dica/<j>/confirmed/<vin>`` for observers. The ICA's clock is the sim CLOCK
(``sim/<j>/clock``): it never takes a vehicle's word for the time, so a
request planned ahead of the clock waits (briefly) for the clock to catch up
instead of moving the ICA's time. A repeated request (same VIN and sequence
number) gets the same confirmation, never a second reservation. Bytes that are
not a valid message get a REJECT with the reason when a reply is possible,
and are logged; the ICA keeps serving.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ica.core.dica import Dica
from ica.core.request import Confirmation, Reason, Rejection, RequestError
from schemas import keys
from schemas.codec import DecodeError, decode, encode, now_ns
from schemas.convert import reject_from_core, request_to_core, response_from_core
from schemas.link import Inbox, Item, put, reply
from schemas.messages import Ack, Clock, Detect, Reject, Request

HOLD_S = 2.0  # [s wall] longest a request may wait for the clock to reach its time


@dataclass(slots=True)
class Stats:
    requests: int = 0
    confirmed: int = 0
    repeated: int = 0
    detects: int = 0
    bad_messages: int = 0
    acks: int = 0
    rejections: dict[str, int] = field(default_factory=dict)
    compute_s: list[float] = field(default_factory=list)

    def as_dict(self) -> dict:
        rt = np.array(self.compute_s) if self.compute_s else np.zeros(1)
        return {
            "requests": self.requests,
            "confirmed": self.confirmed,
            "repeated": self.repeated,
            "detects": self.detects,
            "bad_messages": self.bad_messages,
            "acks": self.acks,
            "rejections": dict(self.rejections),
            "compute_median_ms": float(np.median(rt) * 1e3),
            "compute_p99_ms": float(np.percentile(rt, 99) * 1e3),
        }


class IcaService:
    """One junction's ICA: owns the core, answers the wire, publishes confirmations."""

    def __init__(self, session, ica: Dica, junction: str, log: logging.Logger) -> None:
        self.session = session
        self.ica = ica
        self.junction = junction
        self.log = log
        self.inbox = Inbox()
        self.now_s = 0.0
        self.ended = False
        self.stats = Stats()
        self._held: list[tuple[float, Item]] = []
        self._published: set[tuple[str, int]] = set()
        j = junction
        self._decls = [
            session.declare_queryable(keys.request(j), self.inbox.query_cb("request")),
            session.declare_queryable(keys.detect(j), self.inbox.query_cb("detect")),
            session.declare_subscriber(keys.clock(j), self.inbox.sample_cb("clock")),
            session.declare_subscriber(keys.ack(j), self.inbox.sample_cb("ack")),
        ]
        self._token = session.liveliness().declare_token(keys.ica_alive(j))

    def run(self, idle_exit_s: float | None = None) -> None:
        """Serve until SIGTERM, the run's end on the clock, or ``idle_exit_s`` of silence."""
        last = time.monotonic()
        while not self.inbox.stopping.is_set() and not self.ended:
            item = self.inbox.get(timeout=0.1)
            self._expire_held()
            if item is None:
                if idle_exit_s is not None and time.monotonic() - last > idle_exit_s:
                    break
                continue
            last = time.monotonic()
            try:
                self._dispatch(item)
            except Exception:  # a bug must not take the junction's controller down
                self.log.exception("could not handle %s on %s", item.what, item.key)

    def close(self) -> None:
        for _, item in self._held:
            self._reject(item.query, "?", -1, Reason.BAD_TIME, "the ICA is stopping")
        self._held.clear()
        self._token.undeclare()
        for d in self._decls:
            d.undeclare()

    # -- messages ------------------------------------------------------------
    def _dispatch(self, item: Item) -> None:
        if item.what == "clock":
            self._on_clock(item)
        elif item.what == "request":
            self._on_request(item)
        elif item.what == "detect":
            self._on_detect(item)
        elif item.what == "ack":
            try:
                decode(item.payload, Ack)
                self.stats.acks += 1
            except DecodeError as e:
                self._bad(item, e)

    def _on_clock(self, item: Item) -> None:
        try:
            clock = decode(item.payload, Clock)
        except DecodeError as e:
            self._bad(item, e)
            return
        if clock.t_s > self.now_s:
            self.now_s = clock.t_s
            self.ica.advance(self.now_s)
        held, self._held = self._held, []
        for since, h in held:
            self._on_request(h, since)
        self.ended = clock.end

    def _on_request(self, item: Item, since: float | None = None) -> None:
        try:
            msg = decode(item.payload, Request)
        except DecodeError as e:
            self._bad(item, e)
            self._reject(item.query, "?", -1, Reason.BAD_MESSAGE, f"{e.why.value}: {e.detail}")
            return
        if not _is_chunk(msg.vin):
            self._reject(item.query, "?", msg.seq, Reason.BAD_STATE, "VIN has key characters")
            return
        if msg.t0_s > self.now_s + 1e-9:
            # planned at a time the ICA's clock has not reached: the CLOCK for it
            # may still be on its way (another path through the router); wait for it
            self._held.append((since if since is not None else time.monotonic(), item))
            return
        self.stats.requests += 1
        t_c = time.perf_counter()
        answer = self.ica.handle(request_to_core(msg), self.now_s)
        self.stats.compute_s.append(time.perf_counter() - t_c)
        if isinstance(answer, Confirmation):
            payload = encode(response_from_core(answer))
            if (answer.vin, answer.seq) in self._published:
                self.stats.repeated += 1
            else:
                # published before the reply: observers have it before the vehicle acts on it
                self._published.add((answer.vin, answer.seq))
                self.stats.confirmed += 1
                put(self.session, keys.confirmed(self.junction, keys.chunk(answer.vin)), payload)
            reply(item.query, item.key, payload)
            return
        self._count(answer)
        reply(item.query, item.key, encode(reject_from_core(answer)))

    def _on_detect(self, item: Item) -> None:
        try:
            msg = decode(item.payload, Detect)
        except DecodeError as e:
            self._bad(item, e)
            self._reject(item.query, "?", -1, Reason.BAD_MESSAGE, f"{e.why.value}: {e.detail}")
            return
        self.stats.detects += 1
        if not _is_chunk(msg.vin):
            self._reject(item.query, "?", -1, Reason.BAD_STATE, "VIN has key characters")
            return
        try:
            self.ica.detect(msg.vin, msg.lane, msg.t_s)
        except RequestError as e:
            self._count(Rejection(msg.vin, -1, e.reason, e.detail))
            self._reject(item.query, msg.vin, -1, e.reason, e.detail)
            return
        reply(item.query, item.key, encode(Ack(msg.vin, -1, Detect.KIND, now_ns())))

    # -- helpers -------------------------------------------------------------
    def _expire_held(self) -> None:
        if not self._held:
            return
        now = time.monotonic()
        keep = []
        for since, item in self._held:
            if now - since > HOLD_S:
                self._reject(item.query, "?", -1, Reason.BAD_TIME, "planned ahead of the clock")
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


def _is_chunk(name: str) -> bool:
    try:
        keys.chunk(name)
    except keys.KeyChunkError:
        return False
    return True


def write_stats(path: Path, stats: Stats) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stats.as_dict(), indent=2))
