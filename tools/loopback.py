"""A Zenoh router and an ICA as real processes on 127.0.0.1, for tests and benchmarks,
and attempts to break a secured router's rules (:func:`tried`)."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DICA = [sys.executable, "-m", "dica.tools.cli"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs: list[subprocess.Popen]) -> None:
    """Stop each process group in reverse start order: SIGTERM, then SIGKILL."""
    for p in reversed(procs):
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


def _start_router(
    endpoint: str, config: Path | None = None, connect: str | None = None
) -> subprocess.Popen:
    """A `dica router` process listening on ``endpoint`` (and connected to the router
    at ``connect``, a mesh), once it says it is ready."""
    extra = ["--config", str(config)] if config is not None else []
    extra += ["--connect", connect] if connect else []
    router = subprocess.Popen(
        [*DICA, "router", *extra, "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=ROOT,
        start_new_session=True,
    )
    if router.stdout.readline().strip() != "ready":
        _stop([router])
        raise RuntimeError("the Zenoh router did not start")
    return router


@contextlib.contextmanager
def router(
    config: Path | None = None,
    scheme: str = "tcp",
    endpoint: str | None = None,
    connect: str | None = None,
) -> Iterator[str]:
    """A fresh router (``config``: its JSON5) on ``endpoint``, by default a free
    loopback port, connected to the router at ``connect`` if given; yields its
    endpoint. Give the endpoint to restart a router where its clients wait for it."""
    endpoint = endpoint or f"{scheme}/127.0.0.1:{free_port()}"
    proc = _start_router(endpoint, config, connect)
    try:
        yield endpoint
    finally:
        _stop([proc])


@contextlib.contextmanager
def router_and_ica(
    junction: str = "C", ica_args: tuple[str, ...] = (), ica_log: Path | None = None
) -> Iterator[tuple[object, subprocess.Popen]]:
    """A client session to a fresh router with an ICA serving ``junction``; both
    stopped by process group (SIGTERM, then SIGKILL) on exit."""
    from dica.deploy.transport import open_session
    from dica.schemas import keys

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs: list[subprocess.Popen] = []
    session = None
    try:
        procs.append(_start_router(endpoint))
        log = ica_log.open("w") if ica_log else subprocess.DEVNULL
        ica = subprocess.Popen(
            [*DICA, "ica", "--connect", endpoint, *ica_args],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            start_new_session=True,
        )
        procs.append(ica)
        session = open_session(connect=endpoint)
        deadline = time.monotonic() + 60
        while not list(session.liveliness().get(keys.ica_alive(junction), timeout=1.0)):
            if time.monotonic() > deadline or ica.poll() is not None:
                raise RuntimeError("the ICA never came up")
            time.sleep(0.2)
        yield session, ica
    finally:
        if session is not None:
            session.close()
        _stop(procs)


# -- attempts on a secured router ---------------------------------------------------
# Each attempt pits three sessions against each other: the attacker tries an action
# on a key; a witness does what the action is aimed at (it subscribes where the
# attacker puts, asks where the attacker serves, holds the token the attacker
# watches...); an owner does the same action the legitimate way. An attempt counts
# only once the owner's action has reached the witness: a refusal is then the
# router's doing, not a message still on its way.
ACTIONS = ("put", "subscribe", "queryable", "query", "reply", "token", "watch", "alive_query")


def client(config: Path, endpoint: str, **override: object):
    """A client session with the credentials of ``config`` (a role's JSON5) on
    ``endpoint``; raises ``zenoh.ZError`` within 3 s if the router refuses it.
    ``override``: config paths and values, e.g. ``{"transport/auth/usrpwd/user": "x"}``."""
    import json

    import zenoh

    conf = zenoh.Config.from_file(str(config))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("connect/timeout_ms", "3000")
    for key, value in override.items():
        conf.insert_json5(key, json.dumps(value))
    return zenoh.open(conf)


@dataclass(frozen=True, slots=True, eq=False)
class Attempt:
    """The attacker's ``action`` on ``key``, aimed at ``witness`` on ``witness_key``;
    ``owner`` does the same action on ``owner_key`` with the right to.

    | action | attacker | witness | through when |
    |---|---|---|---|
    | put | puts | subscribes | the witness hears it |
    | subscribe | subscribes | puts | the attacker hears it |
    | queryable | serves | asks | the witness gets its answer, or it gets the question |
    | query | asks | serves | it gets an answer, or the witness gets the question |
    | reply | serves ``serve_key``, answers on ``key`` | asks | the witness gets that answer |
    | token | holds a liveliness token | lists tokens | the witness lists ``key`` |
    | watch | liveliness subscriber | holds a token | it hears of the token |
    | alive_query | lists tokens | holds a token | it lists the token |

    Other queryables answer on the key they serve when it is one key (an agent's
    stats), or on the asked key when they serve many (the ICA's ``request/*``).
    For a token, ``owner_key`` must differ from ``key`` (the witness sees keys, not
    who holds them); the witness lists ``witness_key`` and ``owner_key``. Without
    an owner (a key nobody may use), the attempt is judged once the other
    attempts' owners got through: give it company.
    """

    action: str
    key: str
    witness: object  # zenoh.Session
    witness_key: str
    owner: object | None = None  # zenoh.Session
    owner_key: str = ""
    serve_key: str | None = None  # reply: where the attacker may serve (its own key)


class Inconclusive(AssertionError):
    """The owner's own action never reached the witness: the router (or the
    attempt) is broken, so a refusal would mean nothing."""


def got_through(attacker, attempt: Attempt, **kw: float) -> bool:
    """Whether ``attacker`` (a session) got ``attempt`` past the router."""
    return tried(attacker, [attempt], **kw)[0]


def tried(
    attacker, attempts: list[Attempt], settle_s: float = 0.3, timeout_s: float = 10.0
) -> list[bool]:
    """Try every attempt from ``attacker`` at once; whether each got through.

    Every message carries a marker of its attempt, so attempts do not mix. Give
    one action per call: a session hears its own puts and answers its own
    queries without the router, so mixing them on one attacker would pass
    through it. ``settle_s``: how long a refused message is waited for after
    every owner's got through.
    """
    actions = {a.action for a in attempts}
    if not actions <= set(ACTIONS) or len(actions) > 1:
        raise ValueError(f"one action per call, one of {', '.join(ACTIONS)}: got {actions}")
    trials = [_Trial(attacker, i, a) for i, a in enumerate(attempts)]
    try:
        deadline = time.monotonic() + timeout_s
        while not all(t.control_passed() for t in trials):
            if time.monotonic() > deadline:
                late = [f"{t.a.action} {t.a.owner_key}" for t in trials if not t.control_passed()]
                raise Inconclusive(f"owners never got through: {', '.join(late)}")
            for t in trials:
                t.fire()
            _pause(trials, 0.1)
        for t in trials:
            t.fire()
        _pause(trials, settle_s)
        return [t.through() for t in trials]
    finally:
        for t in trials:
            t.close()


def _pause(trials: list[_Trial], seconds: float) -> None:
    """Wait, answering the queries the trials' queryables got meanwhile."""
    end = time.monotonic() + seconds
    while True:
        for t in trials:
            t.answer()
        if time.monotonic() >= end:
            return
        time.sleep(0.01)


class _Trial:
    """One attempt's declarations and what each side got (filled by callbacks)."""

    def __init__(self, attacker, n: int, a: Attempt) -> None:
        self.attacker, self.a = attacker, a
        self.mark = f"attempt {n} by the attacker".encode()
        self.control = f"attempt {n} by the owner".encode()
        self.lock = threading.Lock()
        self.got: dict[str, list] = {"attacker": [], "witness": [], "owner": []}
        self.pending: list[tuple[object, str, bytes]] = []  # queries to answer: (query, key, what)
        self.decls: list = []
        act, key, wk, ok = a.action, a.key, a.witness_key, a.owner_key
        if act == "put":
            self._sub(a.witness, wk, "witness")
        elif act == "subscribe":
            self._sub(attacker, key, "attacker")
            if a.owner is not None:
                self._sub(a.owner, ok, "owner")
        elif act == "queryable":
            self._serve(attacker, key, "attacker", self.mark)
            if a.owner is not None:
                self._serve(a.owner, ok, "owner", self.control)
        elif act == "query":
            self._serve(a.witness, wk, "witness", b"the witness's answer")
        elif act == "reply":
            self._serve(attacker, a.serve_key or key, "attacker", self.mark, answer_on=key)
            if a.owner is not None:
                self._serve(a.owner, ok, "owner", self.control)
        elif act == "token":
            self.decls.append(attacker.liveliness().declare_token(key))
            if a.owner is not None:
                self.decls.append(a.owner.liveliness().declare_token(ok))
        else:  # watch, alive_query: the witness holds a token
            self.decls.append(a.witness.liveliness().declare_token(wk))
            if act == "watch":
                self._watch(attacker, key, "attacker")
                if a.owner is not None:
                    self._watch(a.owner, ok, "owner")

    # -- declarations, each recording into self.got[who]
    def _record(self, who: str, what: object) -> None:
        with self.lock:
            self.got[who].append(what)

    def _sub(self, session, key: str, who: str) -> None:
        cb = lambda s: self._record(who, s.payload.to_bytes())  # noqa: E731
        self.decls.append(session.declare_subscriber(key, cb))

    def _serve(self, session, key: str, who: str, what: bytes, answer_on: str | None = None):
        plain = "*" not in key

        def cb(query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            self._record(who, payload)
            on = answer_on or (key if plain else str(query.key_expr))
            with self.lock:
                self.pending.append((query, on, what))

        self.decls.append(session.declare_queryable(key, cb))

    def _watch(self, session, key: str, who: str) -> None:
        cb = lambda s: self._record(who, str(s.key_expr))  # noqa: E731
        self.decls.append(session.liveliness().declare_subscriber(key, cb, history=True))

    def _ask(self, session, key: str, who: str, payload: bytes) -> None:
        def cb(reply) -> None:
            if reply.ok is not None:
                self._record(who, reply.ok.payload.to_bytes())

        import zenoh

        # every answer from every queryable: one impostor's must not hide behind another's
        session.get(
            key, cb, payload=payload, timeout=2.0,
            target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
        )  # fmt: skip

    def _list(self, session, key: str, who: str) -> None:
        def cb(reply) -> None:
            if reply.ok is not None:
                self._record(who, str(reply.ok.key_expr))

        session.liveliness().get(key, cb, timeout=2.0)

    # -- the run
    def fire(self) -> None:
        """Send (again) what travels: puts, queries, token listings."""
        a, act = self.a, self.a.action
        if act == "put":
            self.attacker.put(a.key, self.mark)
            if a.owner is not None:
                a.owner.put(a.owner_key, self.control)
        elif act == "subscribe":
            a.witness.put(a.witness_key, self.mark)
        elif act in ("queryable", "reply"):
            self._ask(a.witness, a.witness_key, "witness", b"the witness's question")
        elif act == "query":
            self._ask(self.attacker, a.key, "attacker", self.mark)
            if a.owner is not None:
                self._ask(a.owner, a.owner_key, "owner", self.control)
        elif act == "token":  # where the attacker's token would be, and the owner's
            self._list(a.witness, a.witness_key, "witness")
            if a.owner is not None and a.owner_key != a.witness_key:
                self._list(a.witness, a.owner_key, "witness")
        elif act == "alive_query":
            self._list(self.attacker, a.key, "attacker")
            if a.owner is not None:
                self._list(a.owner, a.owner_key, "owner")

    def answer(self) -> None:
        with self.lock:
            pending, self.pending = self.pending, []
        for query, key, what in pending:
            with contextlib.suppress(Exception):  # a key the query does not accept
                query.reply(key, what)
            query.drop()

    def control_passed(self) -> bool:
        a, got = self.a, self._got()
        if a.owner is None:
            return True
        return {
            "put": lambda: self.control in got["witness"],
            "subscribe": lambda: self.mark in got["owner"],
            "queryable": lambda: self.control in got["witness"],
            "query": lambda: bool(got["owner"]),
            "reply": lambda: self.control in got["witness"],
            "token": lambda: a.owner_key in got["witness"],
            "watch": lambda: a.witness_key in got["owner"],
            "alive_query": lambda: a.witness_key in got["owner"],
        }[a.action]()

    def through(self) -> bool:
        a, got = self.a, self._got()
        return {
            "put": lambda: self.mark in got["witness"],
            "subscribe": lambda: self.mark in got["attacker"],
            "queryable": lambda: self.mark in got["witness"] or bool(got["attacker"]),
            "query": lambda: bool(got["attacker"]) or self.mark in got["witness"],
            "reply": lambda: self.mark in got["witness"],
            "token": lambda: a.key in got["witness"],
            "watch": lambda: a.witness_key in got["attacker"],
            "alive_query": lambda: a.witness_key in got["attacker"],
        }[a.action]()

    def _got(self) -> dict[str, list]:
        with self.lock:
            return {k: list(v) for k, v in self.got.items()}

    def close(self) -> None:
        self.answer()
        for d in reversed(self.decls):
            with contextlib.suppress(Exception):
                d.undeclare()
