"""A Zenoh router and an ICA as real processes on 127.0.0.1, for tests and benchmarks."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DICA = [sys.executable, "-m", "tools.cli"]


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


def _start_router(endpoint: str, config: Path | None = None) -> subprocess.Popen:
    """A `dica router` process listening on ``endpoint``, once it says it is ready."""
    extra = ["--config", str(config)] if config is not None else []
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
def router(config: Path | None = None, scheme: str = "tcp") -> Iterator[str]:
    """A fresh router on a free loopback port (``config``: its JSON5); yields its endpoint."""
    endpoint = f"{scheme}/127.0.0.1:{free_port()}"
    proc = _start_router(endpoint, config)
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
    from schemas import keys
    from schemas.link import open_session

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
