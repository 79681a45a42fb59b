"""How messages travel: Zenoh sessions, one inbox per process, clean stops.

Every role opens a client session from a JSON5 config (``deploy/zenoh/``),
optionally pointed at another router with ``--connect``. Zenoh callbacks only
put what arrived into one FIFO :class:`Inbox` (no Zenoh calls, no blocking
inside callbacks); the role's own loop takes items in arrival order. A
SIGTERM or SIGINT sets :attr:`Inbox.stopping`, so each role closes its
session and flushes its files before it exits.
"""

from __future__ import annotations

import json
import logging
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dica.deploy import ZENOH_CONFIGS, seal
from dica.schemas import keys

DEFAULT_CLIENT_CONFIG = ZENOH_CONFIGS / "client.json5"

# what this process seals what it sends with and opens what it acts on with (dica.deploy.seal);
# an open site passes everything through
GUARD = seal.NONE


def use_guard(guard: seal.Guard) -> None:
    global GUARD
    GUARD = guard


def writer(key: str, action: str) -> str | None:
    """Who must have sealed a message on ``key`` (:func:`keys.writer_of`); on a site of
    several junctions, where each ICA has its own key, the ICA of the key's junction."""
    name = keys.writer_of(key, action)
    if name == "ica" and GUARD.keyring is not None:
        own = keys.ica_name(key.split("/")[1])  # a key writer_of names is dica/<j>/...
        if GUARD.knows(own):
            return own
    return name


def known_writer(name: str) -> bool:
    """Whether ``name`` holds a key of this site (every name, on an open site)."""
    return GUARD.knows(name)


def refused() -> dict[str, int]:
    """The messages this process refused so far, by why (see :func:`note_refused`)."""
    return GUARD.refused()


_told: dict[str, int] = {}


def note_refused(log: logging.Logger) -> None:
    """Log the messages refused since the last call: forged, unsealed, or sealed by a
    writer the key does not belong to (an attack, or a misconfigured site)."""
    now = GUARD.refused()
    new = {k: n - _told.get(k, 0) for k, n in now.items() if n > _told.get(k, 0)}
    if new:
        log.warning("refused messages not sealed by their key's writer: %s", new)
        _told.update(now)


class LinkError(Exception):
    """A session that cannot be opened, or a config that cannot be read."""


def open_session(
    config_path: str | Path | None = None,
    connect: str | None = None,
    mode=None,
    waiting_note_s: float = 10.0,
):
    """A Zenoh session from a JSON5 config file; ``connect`` replaces its endpoints.

    A client may wait for its router without end (``timeout_ms: -1``): a
    router that is down and one that refuses the log-in look the same, so
    every ``waiting_note_s`` a log line says where it is waiting.
    """
    import zenoh

    path = Path(config_path) if config_path else DEFAULT_CLIENT_CONFIG
    try:
        conf = zenoh.Config.from_file(str(path))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps([e for e in connect.split(",") if e]))
        if mode:
            conf.insert_json5("mode", json.dumps(mode))
        where = ", ".join(json.loads(conf.get_json("connect/endpoints") or "[]")) or "(none)"
        opened = threading.Event()

        def note() -> None:
            waited = 0.0
            while not opened.wait(waiting_note_s):
                waited += waiting_note_s
                logging.getLogger("dica").warning(
                    "no session after %.0f s: no router at %s has let this client in "
                    "(is it up? are the credentials in %s right?)",
                    waited, where, path,
                )  # fmt: skip

        threading.Thread(target=note, daemon=True).start()
        try:
            return zenoh.open(conf)
        finally:
            opened.set()
    except FileNotFoundError:
        raise LinkError(f"no Zenoh config at {path}") from None
    except Exception as e:  # zenoh.ZError and friends carry a readable message
        raise LinkError(f"cannot open a Zenoh session ({path}): {e}") from None


@dataclass(frozen=True, slots=True)
class Item:
    what: str  # which declaration it came from
    payload: bytes
    key: str
    query: Any = None  # a zenoh.Query to reply to, for queryables
    arrived_ns: int = field(default_factory=time.time_ns)  # wall clock when it arrived


class Inbox:
    """One FIFO for everything a role receives, fed by Zenoh callbacks."""

    def __init__(self) -> None:
        self._q: queue.Queue[Item] = queue.Queue()
        self.stopping = threading.Event()

    def sample_cb(self, what: str):
        """Publications, each only if its key's writer sealed it (on a secured site)."""

        def cb(sample) -> None:
            key = str(sample.key_expr)
            body = GUARD.take(sample.payload.to_bytes(), writer(key, "put"))
            if body is not None:
                self._q.put(Item(what, body, key))

        return cb

    def query_cb(self, what: str):
        """Queries, each only if its key's asker sealed it; refused ones go unanswered."""

        def cb(query) -> None:
            key = str(query.key_expr)
            payload = query.payload.to_bytes() if query.payload is not None else b""
            body = GUARD.take(payload, writer(key, "query"))
            if body is None:
                query.drop()
                return
            self._q.put(Item(what, body, key, query))

        return cb

    def liveliness_cb(self, what: str):
        def cb(sample) -> None:
            import zenoh

            kind = b"+" if sample.kind == zenoh.SampleKind.PUT else b"-"
            self._q.put(Item(what, kind, str(sample.key_expr)))

        return cb

    def get(self, timeout: float | None = None) -> Item | None:
        try:
            return self._q.get(timeout=timeout)
        except queue.Empty:
            return None

    def put(self, item: Item) -> None:
        """Add an item of the role's own (the answer of an asynchronous query)."""
        self._q.put(item)

    def drain(self) -> list[Item]:
        """Everything waiting now, in arrival order, without blocking."""
        out = []
        while True:
            try:
                out.append(self._q.get_nowait())
            except queue.Empty:
                return out

    def backlog(self) -> int:
        return self._q.qsize()

    def stop_on_signals(self) -> None:
        """SIGTERM / SIGINT end the role's loop instead of killing it mid-write."""

        def handler(signum, _frame) -> None:
            logging.getLogger("dica").info("signal %d: stopping", signum)
            self.stopping.set()

        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, handler)


class Publisher:
    """A Zenoh publisher that never drops (Zenoh's default for puts is to drop under
    congestion, which would stall a lockstep step), sends without batching, and
    seals what it sends on a secured site."""

    def __init__(self, session, key: str) -> None:
        import zenoh

        self._pub = session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )

    def put(self, payload: bytes) -> None:
        self._pub.put(GUARD.out(payload))

    @property
    def matching_status(self):
        return self._pub.matching_status

    def undeclare(self) -> None:
        self._pub.undeclare()


def publisher(session, key: str) -> Publisher:
    return Publisher(session, key)


def put(session, key: str, payload: bytes) -> None:
    """A one-off publication that is never dropped under congestion."""
    import zenoh

    session.put(
        key, GUARD.out(payload), congestion_control=zenoh.CongestionControl.BLOCK, express=True
    )


def reply(query, key: str, payload: bytes) -> None:
    """Answer a query once and finish it (the querier then stops waiting at once)."""
    try:
        query.reply(key, GUARD.out(payload), express=True)
    finally:
        query.drop()


def reply_body(reply_, key: str) -> bytes | None:
    """The payload of a query's reply, if it is one to act on: on the exact key asked,
    and (on a secured site) sealed by the one who may answer on it."""
    if reply_.ok is None or str(reply_.ok.key_expr) != key:
        return None
    return GUARD.take(reply_.ok.payload.to_bytes(), writer(key, "reply"))


def every_answer() -> dict:
    """Query options that deliver every reply from every queryable: Zenoh's default
    keeps one reply per key, which a second (rogue) queryable answering first on the
    same key would then hide from the asker; this way the asker sees both and keeps
    the one sealed by the key's writer."""
    import zenoh

    return {"consolidation": zenoh.ConsolidationMode.NONE, "target": zenoh.QueryTarget.ALL}


def query_payload(payload: bytes) -> bytes:
    """What a query carries: sealed on a secured site."""
    return GUARD.out(payload)


def setup_logging(role: str, verbose: bool = False) -> logging.Logger:
    logging.basicConfig(
        stream=sys.stderr,
        level=logging.DEBUG if verbose else logging.INFO,
        format=f"%(asctime)s {role} %(levelname)s %(message)s",
    )
    return logging.getLogger("dica")
