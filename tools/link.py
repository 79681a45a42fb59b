"""``dica link``: run, change and show the link emulator (:mod:`dica.deploy.linkem`)."""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import asdict
from pathlib import Path

from dica.deploy.linkem import (
    PROFILE,
    STATS,
    Faults,
    LinkError,
    read_profile,
    read_spec,
    serve,
    write_profile,
)
from dica.tools import options


def parser() -> options.Parser:
    p = options.Parser(
        prog="dica link",
        description="A user-space link emulator between Zenoh clients and their router: "
        "one-way delay and jitter, and loss, duplication and reordering of the Zenoh batches "
        "that carry data. tools/run_cluster.sh starts it with --delay, "
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
        t.add_argument(f"--{name}", type=float, help=f"{name} probability of a data batch")
    w = sub.add_parser("show", help="print the faults now in force and what each proxy did")
    w.add_argument("dir", type=Path)
    return p


def main(argv: list[str]) -> int:
    args = options.parse(parser(), argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s link %(levelname)s %(message)s")
    try:
        if args.action == "serve":
            proxies, seed = read_spec(args.dir)
            serve(proxies, args.dir / PROFILE, seed, stats=args.dir / STATS)
            return 0
        if args.action == "set":
            proxies, _ = read_spec(args.dir)
            roles = sorted({p.role for p in proxies})
            if args.role != "all" and args.role not in roles:  # a typo would change nothing
                raise LinkError(
                    f"--role {args.role!r}: this emulator's roles are {', '.join(roles)}, or all"
                )
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
