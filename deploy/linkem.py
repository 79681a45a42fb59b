"""A user-space link emulator: proxies between Zenoh clients and their router that
delay, jitter, lose, duplicate and reorder real traffic.

The kernel's netem is not available here (and would need root), so the faults
are made in user space, on the real bytes a real Zenoh session sends. Each
proxy stands for one process's radio link: the process connects to the
proxy's port instead of the router's, and the proxy forwards to the router.

Zenoh over TCP sends its messages in batches, each behind a two-byte length.
A proxy reads the stream batch by batch and applies the faults to whole
batches, one way, in each direction on its own:

* delay and jitter: each batch is held ``delay + U(0, jitter)``, in order;
* loss, duplication and reordering: only batches that carry data (a
  publication, a query or a reply; our data is sent ``express``, one message
  per batch) are dropped, sent twice, or held back behind later ones. Zenoh
  then sees what a lossy radio link would give it: gaps in its sequence
  numbers (the data is gone), and repeated or late batches (which it
  discards). Session and declaration batches are only delayed: in a
  deployment they travel on a reliable channel, and losing one would model a
  broken router, not a bad link.

Over UDP (``udp/`` locators) the same faults could be put on batchs, but
Zenoh 1.10 over UDP lost most messages of a few kilobytes (our REQUESTs and
RESPONSEs) under 50 ms of jitter with no loss at all, so the emulator keeps
to TCP. A TLS stream (``--secure``) cannot be read batch by batch: it gets
delay and jitter only.

Faults are per role (the proxy's group) and read from a JSON profile file
that the emulator re-reads whenever it changes, so a run's link can be
degraded or healed while it is running (``dica link set``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import random
import signal
from dataclasses import asdict, dataclass, fields
from pathlib import Path

log = logging.getLogger("dica")

REORDER_HOLD_MS = 20.0  # [ms] how long a batch picked for reordering is held back extra
CHUNK = 65536  # [bytes] what a byte-stream (TLS) proxy reads at a time

# Zenoh 1.x wire ids (zenoh-protocol): transport messages, and network messages in a FRAME
_FRAME, _FRAGMENT = 0x05, 0x06
_DATA = {0x1D, 0x1C, 0x1B, 0x1A}  # PUSH, REQUEST, RESPONSE, RESPONSE_FINAL


def is_data(batch: bytes) -> bool:
    """Whether a Zenoh batch (without its length prefix) carries data (a
    publication, a query or a reply) rather than session or declaration traffic.

    A FRAME is classed by its first network message (our data is sent
    ``express``: one message per batch); fragments of a large message are data.
    """
    if not batch:
        return False
    kind = batch[0] & 0x1F
    if kind == _FRAGMENT:
        return True
    if kind != _FRAME:
        return False
    i = 1
    while i < len(batch) and batch[i] & 0x80:  # the sequence number (varint)
        i += 1
    i += 1
    more = bool(batch[0] & 0x80)  # Z: extensions follow
    while more and i < len(batch):
        head = batch[i]
        more = bool(head & 0x80)
        enc = head & 0x60
        i += 1
        if enc == 0x20:  # a varint
            while i < len(batch) and batch[i] & 0x80:
                i += 1
            i += 1
        elif enc == 0x40:  # length-prefixed bytes
            n, shift = 0, 0
            while i < len(batch):
                b = batch[i]
                i += 1
                n |= (b & 0x7F) << shift
                shift += 7
                if not b & 0x80:
                    break
            i += n
    return i < len(batch) and (batch[i] & 0x1F) in _DATA


class LinkError(ValueError):
    """A fault profile or proxy spec that cannot be used."""


@dataclass(frozen=True, slots=True)
class Faults:
    """One-way faults of a link, applied to each direction on its own."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0  # extra delay, uniform in [0, jitter_ms]
    loss: float = 0.0  # probability a data batch is dropped
    dup: float = 0.0  # probability a data batch is sent twice
    reorder: float = 0.0  # probability a data batch is held back so later ones overtake it

    def __post_init__(self) -> None:
        for name in ("delay_ms", "jitter_ms"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 10_000.0):
                raise LinkError(f"{name} must be between 0 and 10000 ms, got {v!r}")
        for name in ("loss", "dup", "reorder"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 0.9):
                raise LinkError(f"{name} must be a probability between 0 and 0.9, got {v!r}")

    @property
    def lossy(self) -> bool:
        return self.loss > 0 or self.dup > 0 or self.reorder > 0

    @classmethod
    def from_dict(cls, d: dict) -> Faults:
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise LinkError(f"unknown fault(s) {sorted(unknown)}: use {sorted(known)}")
        return cls(**d)


@dataclass(frozen=True, slots=True)
class Proxy:
    """One process's link: clients connect to ``listen_port``, traffic goes to the router.

    ``framed``: the stream is Zenoh's own (TCP), read batch by batch; False for
    a TLS stream, which only gets delay and jitter.
    """

    name: str
    role: str  # the profile group whose faults apply
    listen_port: int
    router_port: int
    framed: bool = True
    host: str = "127.0.0.1"
    router_host: str | None = None  # the router's host, if not this one (another host's)

    @property
    def endpoint(self) -> str:
        """What the proxied process connects to (its scheme is the router's)."""
        return f"{self.host}:{self.listen_port}"


def write_profile(path: Path, faults: dict[str, Faults]) -> None:
    """Write the per-role fault profile atomically (a running emulator picks it up)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps({role: asdict(f) for role, f in faults.items()}, indent=2))
    os.replace(tmp, path)


def read_profile(path: Path) -> dict[str, Faults]:
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, json.JSONDecodeError) as e:
        raise LinkError(f"cannot read the fault profile {path}: {e}") from None
    if not isinstance(raw, dict):
        raise LinkError(f"{path}: the profile must map roles to faults")
    return {str(role): Faults.from_dict(d) for role, d in raw.items()}


@dataclass(slots=True)
class Counters:
    """What one proxy did: batches (or chunks) up (client to router) and down."""

    up: int = 0
    down: int = 0
    data: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0


class Emulator:
    """Runs every proxy of a spec in one asyncio loop; faults from the profile file."""

    def __init__(self, proxies: list[Proxy], profile: Path, seed: int = 1) -> None:
        self.proxies = proxies
        self.profile_path = profile
        self.faults: dict[str, Faults] = {}
        self.rng = random.Random(seed)
        self.counters = {p.name: Counters() for p in proxies}
        self._mtime = -1.0

    def faults_of(self, role: str) -> Faults:
        return self.faults.get(role) or self.faults.get("all") or Faults()

    def reload(self) -> None:
        try:
            mtime = self.profile_path.stat().st_mtime
        except FileNotFoundError:
            mtime = 0.0
        if mtime == self._mtime:
            return
        self._mtime = mtime
        try:
            new = read_profile(self.profile_path)
        except LinkError as e:
            log.error("kept the old faults: %s", e)
            return
        for p in self.proxies:
            f = new.get(p.role) or new.get("all") or Faults()
            if not p.framed and f.lossy:
                log.error("%s is a TLS link: loss, dup and reorder cannot apply; ignored", p.name)
        self.faults = new
        log.info("faults now %s", {k: asdict(v) for k, v in new.items()})

    async def run(self, ready: asyncio.Event | None = None) -> None:
        servers = [await asyncio.start_server(self._handler(p), p.host, p.listen_port)
                   for p in self.proxies]  # fmt: skip
        if ready is not None:
            ready.set()
        try:
            while True:
                self.reload()
                await asyncio.sleep(0.2)
        finally:
            for s in servers:
                s.close()

    def _handler(self, p: Proxy):
        async def handle(reader, writer) -> None:
            try:
                r2, w2 = await asyncio.open_connection(p.router_host or p.host, p.router_port)
            except OSError:
                writer.close()
                return
            pumps = [
                asyncio.create_task(self._pump(p, reader, w2, up=True)),
                asyncio.create_task(self._pump(p, r2, writer, up=False)),
            ]
            # either side closing ends the link, as a broken radio link would; so does the
            # emulator stopping (its handlers cancelled: they end quietly, not as errors
            # asyncio's stream callback would log)
            try:
                _, pending = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
            except asyncio.CancelledError:
                pending = set(pumps)
            for t in pending:
                t.cancel()
            for w in (writer, w2):
                with contextlib.suppress(Exception):
                    w.close()

        return handle

    async def _pump(self, p: Proxy, reader, writer, up: bool) -> None:
        """One direction: read batches, schedule each (or drop, repeat, hold it back).

        Batches are sent at strictly increasing times, so they stay in order
        (asyncio runs timers due at the same moment in no set order), except
        one held back for reordering, which later ones overtake.
        """
        loop = asyncio.get_running_loop()
        c = self.counters[p.name]
        last = 0.0

        def send(data: bytes) -> None:
            if not writer.is_closing():
                writer.write(data)

        while True:
            data = await self._read(p, reader)
            if data is None:
                break
            if up:
                c.up += 1
            else:
                c.down += 1
            f = self.faults_of(p.role)
            at = max(loop.time() + self._delay_s(f), last + 1e-6)
            if p.framed and is_data(data[2:]):
                c.data += 1
                if f.loss and self.rng.random() < f.loss:
                    c.dropped += 1
                    continue
                if f.reorder and self.rng.random() < f.reorder:
                    c.reordered += 1
                    loop.call_at(at + REORDER_HOLD_MS / 1e3, send, data)
                    continue
                if f.dup and self.rng.random() < f.dup:
                    c.duplicated += 1
                    loop.call_at(at, send, data)
                    at += 1e-6
            last = at
            loop.call_at(at, send, data)
        await asyncio.sleep(max(last - loop.time(), 0.0) + 0.01)  # what is on its way arrives

    @staticmethod
    async def _read(p: Proxy, reader) -> bytes | None:
        """The next batch with its length prefix (framed), or the next chunk; None at the end."""
        try:
            if not p.framed:
                data = await reader.read(CHUNK)
                return data or None
            head = await reader.readexactly(2)
            return head + await reader.readexactly(int.from_bytes(head, "little"))
        except asyncio.IncompleteReadError:
            return None

    def _delay_s(self, f: Faults) -> float:
        return (f.delay_ms + (self.rng.uniform(0.0, f.jitter_ms) if f.jitter_ms else 0.0)) / 1e3


def serve(proxies: list[Proxy], profile: Path, seed: int = 1, stats: Path | None = None) -> None:
    """Run the emulator until SIGTERM or SIGINT; write per-proxy counters to ``stats``."""
    emu = Emulator(proxies, profile, seed)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        ready = asyncio.Event()
        task = asyncio.create_task(emu.run(ready))
        await ready.wait()
        print("ready", flush=True)
        await stop.wait()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task

    asyncio.run(main())
    if stats is not None:
        stats.write_text(json.dumps({k: asdict(v) for k, v in emu.counters.items()}, indent=2))


# -- the command line: dica link serve | set | show ------------------------------------------
SPEC = "spec.json"
PROFILE = "faults.json"
STATS = "stats.json"


def write_spec(directory: Path, proxies: list[Proxy], seed: int = 1) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / SPEC
    path.write_text(json.dumps({"seed": seed, "proxies": [asdict(p) for p in proxies]}, indent=2))
    return path


def read_spec(directory: Path) -> tuple[list[Proxy], int]:
    try:
        raw = json.loads((directory / SPEC).read_text())
        return [Proxy(**p) for p in raw["proxies"]], int(raw.get("seed", 1))
    except FileNotFoundError:
        raise LinkError(f"no link emulator spec in {directory} ({SPEC})") from None
    except (OSError, ValueError, TypeError, KeyError) as e:
        raise LinkError(f"cannot read {directory / SPEC}: {e}") from None
