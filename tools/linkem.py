"""A user-space link emulator: proxies between Zenoh clients and their router that
delay, jitter, lose, duplicate and reorder real traffic.

The kernel's netem is not available here (and would need root), so the faults
are made in user space, on the real bytes a real Zenoh session sends. Each
proxy stands for one process's radio link: the process connects to the
proxy's port instead of the router's, and the proxy forwards to the router.

* ``udp`` proxies forward datagrams. A Zenoh session over ``udp/`` sends each
  batch of messages as one datagram (large messages as several fragments),
  so dropping, duplicating or holding back a datagram loses, repeats or
  reorders whole Zenoh messages. Delay and jitter apply per datagram, in
  order unless reordering is asked for.
* ``tcp`` proxies forward a byte stream: delay and jitter only (a stream
  cannot lose or reorder without breaking the connection).

Faults are per role (the proxy's group), one-way (each direction gets them),
and read from a JSON profile file that the emulator re-reads whenever it
changes, so a run's link can be degraded or healed while it is running
(``dica link set``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import random
import signal
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

log = logging.getLogger("dica")

TRANSPORTS = ("tcp", "udp")
REORDER_HOLD_MS = 20.0  # [ms] how long a datagram picked for reordering is held back extra

# Zenoh 1.x wire ids (zenoh-protocol): transport messages, and network messages in a FRAME
_FRAME, _FRAGMENT = 0x05, 0x06
_DATA = {0x1D, 0x1C, 0x1B, 0x1A}  # PUSH, REQUEST, RESPONSE, RESPONSE_FINAL


def is_data(datagram: bytes) -> bool:
    """Whether a Zenoh-over-UDP datagram carries data (a publication, a query or a
    reply) rather than session or declaration traffic.

    Only data datagrams are lost, duplicated or reordered: in a deployment the
    session and its declarations travel on a reliable channel, and Zenoh does
    not resend a lost declaration over UDP, so losing one would model a broken
    router, not a bad radio link. A FRAME is classed by its first network
    message (our data is sent ``express``: one message per batch); fragments
    are data.
    """
    if not datagram:
        return False
    kind = datagram[0] & 0x1F
    if kind == _FRAGMENT:
        return True
    if kind != _FRAME:
        return False
    i = 1
    while i < len(datagram) and datagram[i] & 0x80:  # the sequence number (varint)
        i += 1
    i += 1
    more = bool(datagram[0] & 0x80)  # Z: extensions follow
    while more and i < len(datagram):
        head = datagram[i]
        more = bool(head & 0x80)
        enc = head & 0x60
        i += 1
        if enc == 0x20:  # a varint
            while i < len(datagram) and datagram[i] & 0x80:
                i += 1
            i += 1
        elif enc == 0x40:  # length-prefixed bytes
            n, shift = 0, 0
            while i < len(datagram):
                b = datagram[i]
                i += 1
                n |= (b & 0x7F) << shift
                shift += 7
                if not b & 0x80:
                    break
            i += n
    return i < len(datagram) and (datagram[i] & 0x1F) in _DATA


class LinkError(ValueError):
    """A fault profile or proxy spec that cannot be used."""


@dataclass(frozen=True, slots=True)
class Faults:
    """One-way faults of a link, applied to each direction on its own."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0  # extra delay, uniform in [0, jitter_ms]
    loss: float = 0.0  # probability a datagram is dropped
    dup: float = 0.0  # probability a datagram is sent twice
    reorder: float = 0.0  # probability a datagram is held back so later ones overtake it

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
    """One process's link: clients connect to ``listen_port``, traffic goes to the router."""

    name: str
    role: str  # the profile group whose faults apply
    transport: str
    listen_port: int
    router_port: int
    host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        if self.transport not in TRANSPORTS:
            raise LinkError(f"proxy {self.name}: transport must be tcp or udp")

    @property
    def endpoint(self) -> str:
        """What the proxied process connects to."""
        return f"{self.transport}/{self.host}:{self.listen_port}"


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
    """What one proxy did, per direction: up (client to router) and down."""

    up: int = 0
    down: int = 0
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
            if p.transport == "tcp" and f.lossy:
                log.error("%s is a tcp link: loss, dup and reorder need udp; ignored", p.name)
        self.faults = new
        log.info("faults now %s", {k: asdict(v) for k, v in new.items()})

    # -- scheduling ----------------------------------------------------------
    def _delay_s(self, f: Faults) -> float:
        return (f.delay_ms + (self.rng.uniform(0.0, f.jitter_ms) if f.jitter_ms else 0.0)) / 1e3

    async def run(self, ready: asyncio.Event | None = None) -> None:
        servers = []
        for p in self.proxies:
            if p.transport == "tcp":
                servers.append(await self._serve_tcp(p))
            else:
                servers.append(await self._serve_udp(p))
        if ready is not None:
            ready.set()
        try:
            while True:
                self.reload()
                await asyncio.sleep(0.2)
        finally:
            for s in servers:
                s.close()

    # -- udp -------------------------------------------------------------------
    async def _serve_udp(self, p: Proxy):
        loop = asyncio.get_running_loop()
        emu = self

        class Lane:
            """Delivery in order, unless a datagram is picked for reordering."""

            def __init__(self) -> None:
                self.last = 0.0

            def when(self, f: Faults, c: Counters, data: bool) -> float | None:
                if not data:
                    at = max(time.monotonic() + emu._delay_s(f), self.last)
                    self.last = at
                    return at
                if f.loss and emu.rng.random() < f.loss:
                    c.dropped += 1
                    return None
                at = max(time.monotonic() + emu._delay_s(f), self.last)
                if f.reorder and emu.rng.random() < f.reorder:
                    c.reordered += 1
                    return at + REORDER_HOLD_MS / 1e3  # later datagrams pass it
                self.last = at
                return at

        def send_later(at: float, fn, data: bytes) -> None:
            loop.call_at(loop.time() + max(at - time.monotonic(), 0.0), fn, data)

        class Upstream(asyncio.DatagramProtocol):
            def __init__(self, front: Front, addr) -> None:
                self.front, self.addr = front, addr
                self.lane = Lane()
                self.transport: asyncio.DatagramTransport | None = None

            def connection_made(self, transport) -> None:
                self.transport = transport

            def datagram_received(self, data: bytes, _addr) -> None:
                c = emu.counters[p.name]
                c.down += 1
                f = emu.faults_of(p.role)
                payload = is_data(data)
                at = self.lane.when(f, c, payload)
                if at is None:
                    return
                out = self.front.transport
                send_later(at, lambda d: out.sendto(d, self.addr), data)
                if payload and f.dup and emu.rng.random() < f.dup:
                    c.duplicated += 1
                    send_later(at, lambda d: out.sendto(d, self.addr), data)

        class Front(asyncio.DatagramProtocol):
            def __init__(self) -> None:
                self.transport: asyncio.DatagramTransport | None = None
                self.ups: dict[tuple, tuple[Upstream, Lane]] = {}
                self.opening: set[asyncio.Task] = set()

            def connection_made(self, transport) -> None:
                self.transport = transport

            def datagram_received(self, data: bytes, addr) -> None:
                up = self.ups.get(addr)
                if up is None:
                    proto = Upstream(self, addr)
                    self.ups[addr] = (proto, Lane())
                    task = loop.create_task(self._open(addr, proto, data))
                    self.opening.add(task)
                    task.add_done_callback(self.opening.discard)
                    return
                self._forward(up[0], up[1], data)

            async def _open(self, addr, proto: Upstream, first: bytes) -> None:
                await loop.create_datagram_endpoint(
                    lambda: proto, remote_addr=(p.host, p.router_port)
                )
                self._forward(proto, self.ups[addr][1], first)

            def _forward(self, proto: Upstream, lane: Lane, data: bytes) -> None:
                c = emu.counters[p.name]
                c.up += 1
                f = emu.faults_of(p.role)
                payload = is_data(data)
                at = lane.when(f, c, payload)
                if at is None or proto.transport is None:
                    return
                send_later(at, proto.transport.sendto, data)
                if payload and f.dup and emu.rng.random() < f.dup:
                    c.duplicated += 1
                    send_later(at, proto.transport.sendto, data)

        transport, _ = await loop.create_datagram_endpoint(
            Front, local_addr=(p.host, p.listen_port)
        )
        return transport

    # -- tcp -------------------------------------------------------------------
    async def _serve_tcp(self, p: Proxy):
        async def pump(reader, writer, up: bool) -> None:
            queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()
            last = 0.0

            async def deliver() -> None:
                while True:
                    at, data = await queue.get()
                    wait = at - time.monotonic()
                    if wait > 0:
                        await asyncio.sleep(wait)
                    if not data:
                        writer.close()
                        return
                    writer.write(data)
                    await writer.drain()

            task = asyncio.create_task(deliver())
            c = self.counters[p.name]
            try:
                while True:
                    data = await reader.read(65536)
                    if up:
                        c.up += 1
                    else:
                        c.down += 1
                    at = max(time.monotonic() + self._delay_s(self.faults_of(p.role)), last)
                    last = at
                    queue.put_nowait((at, data))
                    if not data:
                        break
                await task
            except (ConnectionError, asyncio.CancelledError):
                task.cancel()
                with contextlib.suppress(Exception):
                    writer.close()

        async def handle(reader, writer) -> None:
            try:
                r2, w2 = await asyncio.open_connection(p.host, p.router_port)
            except OSError:
                writer.close()
                return
            await asyncio.gather(pump(reader, w2, True), pump(r2, writer, False))

        return await asyncio.start_server(handle, p.host, p.listen_port)


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


def _parser():
    import argparse

    p = argparse.ArgumentParser(
        prog="dica link",
        description="A user-space link emulator between Zenoh clients and their router: "
        "one-way delay and jitter (tcp or udp links), loss, duplication and reordering of "
        "Zenoh data messages (udp links). tools/run_cluster.sh starts it with --delay, "
        "--jitter, --loss, --dup, --reorder and --faulty; `dica link set` changes the faults "
        "of a running one.",
    )
    sub = p.add_subparsers(dest="action", required=True)
    s = sub.add_parser("serve", help="run the proxies of DIR/spec.json (faults: DIR/faults.json)")
    s.add_argument("dir", type=Path)
    t = sub.add_parser("set", help="change the faults of a running emulator (one role or all)")
    t.add_argument("dir", type=Path, help="the emulator's directory (RUN_DIR/link)")
    t.add_argument(
        "--role",
        default="all",
        help="whose link: ica, gateway, observer, agents, or all (default all)",
    )
    for name, unit in (("delay", "ms"), ("jitter", "ms")):
        t.add_argument(f"--{name}", type=float, help=f"one-way {name} [{unit}]")
    for name in ("loss", "dup", "reorder"):
        t.add_argument(f"--{name}", type=float, help=f"{name} probability of a data datagram")
    w = sub.add_parser("show", help="print the faults now in force and what each proxy did")
    w.add_argument("dir", type=Path)
    return p


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s link %(levelname)s %(message)s")
    try:
        if args.action == "serve":
            proxies, seed = read_spec(args.dir)
            serve(proxies, args.dir / PROFILE, seed, stats=args.dir / STATS)
            return 0
        if args.action == "set":
            read_spec(args.dir)
            now = read_profile(args.dir / PROFILE)
            old = asdict(now.get(args.role) or now.get("all") or Faults())
            new = {
                "delay_ms": args.delay,
                "jitter_ms": args.jitter,
                "loss": args.loss,
                "dup": args.dup,
                "reorder": args.reorder,
            }
            old.update({k: v for k, v in new.items() if v is not None})
            now[args.role] = Faults.from_dict(old)
            write_profile(args.dir / PROFILE, now)
            print(json.dumps({k: asdict(v) for k, v in now.items()}, indent=2))
            return 0
        proxies, _ = read_spec(args.dir)
        now = read_profile(args.dir / PROFILE)
        print(json.dumps({k: asdict(v) for k, v in now.items()}, indent=2))
        for p in proxies:
            print(f"{p.name:12} {p.role:10} {p.endpoint} -> router port {p.router_port}")
        if (args.dir / STATS).exists():
            print((args.dir / STATS).read_text())
        return 0
    except LinkError as e:
        print(f"dica link: {e}", file=sys.stderr)
        return 2
