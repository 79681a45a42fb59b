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

DEFAULT_CLIENT_CONFIG = Path(__file__).resolve().parent.parent / "deploy" / "zenoh" / "client.json5"


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
        def cb(sample) -> None:
            self._q.put(Item(what, sample.payload.to_bytes(), str(sample.key_expr)))

        return cb

    def query_cb(self, what: str):
        def cb(query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            self._q.put(Item(what, payload, str(query.key_expr), query))

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


def publisher(session, key: str):
    """A publisher that never drops (Zenoh's default for puts is to drop under
    congestion, which would stall a lockstep step) and sends without batching."""
    import zenoh

    return session.declare_publisher(
        key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
    )


def put(session, key: str, payload: bytes) -> None:
    """A one-off publication that is never dropped under congestion."""
    import zenoh

    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK, express=True)


def reply(query, key: str, payload: bytes) -> None:
    """Answer a query once and finish it (the querier then stops waiting at once)."""
    try:
        query.reply(key, payload, express=True)
    finally:
        query.drop()


def setup_logging(role: str, verbose: bool = False) -> logging.Logger:
    logging.basicConfig(
        stream=sys.stderr,
        level=logging.DEBUG if verbose else logging.INFO,
        format=f"%(asctime)s {role} %(levelname)s %(message)s",
    )
    return logging.getLogger("dica")
