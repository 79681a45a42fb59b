"""``dica experiment``: a grid of SUMO runs on the machine's cores, resumable.

Each cell (algorithm x volume x seed) is one ``dica run`` in its own process
(libsumo runs one simulation per process) writing to
``OUT/<layout>/<algorithm>/v<volume>/s<seed>/``; a ramp from volume A to B
over the run writes to ``.../r<A>-<B>/s<seed>/``; on a net of the user's
(``--extra "--net NET --junction J"``) ``<layout>`` is ``<net>-<J>``. A cell whose
``metrics.json`` exists is skipped, so an interrupted grid picks up where it
stopped. Volumes go up to 2000 per 10 minutes; ``dica report`` finds each
controller's saturation volume in a grid of volumes.

With ``--cav-shares`` every cell is run at each share of connected vehicles, under
``<algorithm>/c<share>/``; ``python -m dica.tools.mixed_report OUT`` reports that grid.

Reactive DICA is named with its solver, ``rdica-exact``, ``rdica-ga`` or
``rdica-exhaustive`` (``rdica`` alone is ``rdica-exact``). Chapter 5's grid:

    dica experiment --algorithms enhanced,rdica-exact,rdica-ga,rdica-exhaustive,reactive-light \
        --duration 3600 --extra "--ev-prob 0.02" --out runs/ch5
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor, as_completed
from itertools import product
from pathlib import Path

from dica.tools import options


def _list_of(cast, what: str):
    """An argparse type: comma-separated values of one kind."""

    def parse(text: str) -> list:
        try:
            return [cast(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {what} separated by commas, got {text!r}"
            ) from None

    return parse


_floats = _list_of(float, "numbers")
_ints = _list_of(int, "integers")


def _ramp(text: str) -> tuple[float, float]:
    a, sep, b = text.partition("-")
    if not sep:
        raise ValueError(text)
    return float(a), float(b)


_ramps = _list_of(_ramp, "ramps FROM-TO (volumes)")


def parser() -> argparse.ArgumentParser:
    p = options.Parser(
        prog="dica experiment",
        description="Run a grid of SUMO simulations (algorithms x volumes x seeds) in parallel. "
        "Cells already done are skipped; run `dica report OUT` afterwards.",
    )
    options.add(p, "--layout")
    p.add_argument(
        "--algorithms",
        default="enhanced,fixed,actuated",
        help="comma-separated; reactive DICA as rdica-exact, rdica-ga or rdica-exhaustive",
    )
    p.add_argument(
        "--volumes",
        type=_floats,
        default=[100, 200, 300, 400, 500],
        help="vehicles per 10 min, comma-separated (past the dissertation's: 600,800,1000)",
    )
    p.add_argument(
        "--ramps",
        type=_ramps,
        default=[],
        help="also volumes rising linearly over the run, FROM-TO comma-separated (100-1000)",
    )
    p.add_argument("--seeds", type=_ints, default=[12, 21, 66])
    p.add_argument(
        "--cav-shares",
        type=_floats,
        default=[1.0],
        help="mixed traffic: shares of connected vehicles, comma-separated (0,0.25,0.5,0.75,1); "
        "each share's cells go to <algorithm>/c<share>/ (default 1 only, as before)",
    )
    options.add(p, "--duration")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel runs")
    options.add(p, "--out", "--quiet", out={"help": "grid directory", "required": True})
    p.add_argument("--extra", default="", help="extra options for every `dica run`, quoted")
    return p


def _place(layout: str, extra: list[str]) -> tuple[str, list[str]]:
    """Where the cells go and the layout's options for each run: a net of the user's
    (``--net`` in ``--extra``) names them by the net's file and junctions, and then no
    built-in layout is passed."""

    def after(flag: str) -> str | None:
        for i, tok in enumerate(extra):
            if tok == flag and i + 1 < len(extra):
                return extra[i + 1]
            if tok.startswith(flag + "="):
                return tok.split("=", 1)[1]
        return None

    net = after("--net")
    if net is None:
        return layout, ["--layout", layout]
    name = Path(net).name.split(".")[0]
    where = after("--junction") or after("--junctions")
    return (f"{name}-{where.replace(',', '+')}" if where else name), []


def _settings(cmd: list[str]) -> list[str]:
    """A cell's run options, but where it writes (the same cell, however --out is
    spelt)."""
    args = cmd[3:]
    k = args.index("--out")
    return args[:k] + args[k + 2 :]


def main(argv: list[str] | None = None) -> int:
    import shlex

    from tqdm import tqdm

    args = options.parse(parser(), argv)
    if args.jobs < 1:
        print("dica experiment: --jobs must be at least 1", file=sys.stderr)
        return 2
    algorithms = [a.strip() for a in args.algorithms.split(",") if a.strip()]
    try:
        named = [(alg, *_algorithm(alg)) for alg in algorithms]
    except ValueError as e:
        print(f"dica experiment: {e}", file=sys.stderr)
        return 2
    shapes = [(f"v{v:g}", v, ()) for v in args.volumes]
    shapes += [
        (f"r{a:g}-{b:g}", a, ("--volume-end", f"{b:g}", "--ramp", f"{args.duration:g}"))
        for a, b in args.ramps
    ]
    if any(not 0.0 <= c <= 1.0 for c in args.cav_shares):
        print("dica experiment: --cav-shares must be between 0 and 1", file=sys.stderr)
        return 2
    mixed = args.cav_shares != [1.0]
    try:
        extra = shlex.split(args.extra)
    except ValueError as e:  # an unclosed quote
        print(f"dica experiment: --extra {args.extra!r}: {e}", file=sys.stderr)
        return 2
    place, layout_args = _place(args.layout, extra)
    cells = []
    grid = product(named, args.cav_shares, shapes, args.seeds)
    for (alg, algorithm, solver), share, (name, vol, ramp), seed in grid:
        under = args.out / place / alg / (f"c{share:g}" if mixed else "")
        cell = under / name / f"s{seed}"
        cmd = [
            sys.executable,
            "-m",
            "dica.tools.cli",
            "run",
            *layout_args,
            "--algorithm",
            algorithm,
            *(["--solver", solver] if solver else []),
            "--volume",
            f"{vol:g}",
            "--seed",
            str(seed),
            "--duration",
            f"{args.duration:g}",
            "--out",
            str(cell),
            "--quiet",
            *ramp,
            *(["--cav-share", f"{share:g}"] if mixed else []),
            *extra,
        ]
        cells.append((cell, cmd))
    # a cell done with other settings (a --duration or --extra changed since) is not this
    # grid's: resuming would mix the two, so it is refused
    changed = [
        cell for cell, cmd in cells
        if (cell / "metrics.json").exists() and (cell / "command.json").exists()
        and json.loads((cell / "command.json").read_text()) != _settings(cmd)
    ]  # fmt: skip
    if changed:
        print(f"dica experiment: {changed[0]} was run with other settings than these "
              f"({len(changed)} cells): give another --out, or the same settings to resume",
              file=sys.stderr)  # fmt: skip
        return 2
    options.out_dir(args.out)
    (args.out / "experiment.json").write_text(
        json.dumps({"layout": place, "cells": [c[1][3:] for c in cells]}, indent=2)
    )
    todo = [(cell, cmd) for cell, cmd in cells if not (cell / "metrics.json").exists()]
    print(f"{len(cells)} cells, {len(cells) - len(todo)} already done, {len(todo)} to run")

    def one(cell: Path, cmd: list[str]) -> tuple[Path, int, str]:
        cell.mkdir(parents=True, exist_ok=True)
        (cell / "command.json").write_text(json.dumps(_settings(cmd)))  # for a resume
        # from the user's directory: a relative --out or path in --extra means theirs
        p = subprocess.run(cmd, capture_output=True, text=True)
        (cell / "run.log").write_text(p.stdout + p.stderr)
        tail = (p.stderr.strip().splitlines() or [""])[-1]
        return cell, p.returncode, tail

    failed = []
    with (
        ThreadPoolExecutor(max_workers=args.jobs) as pool,
        tqdm(total=len(todo), desc="runs", unit="run", disable=args.quiet) as bar,
    ):
        futures = [pool.submit(one, cell, cmd) for cell, cmd in todo]
        for f in as_completed(futures):
            cell, rc, tail = f.result()
            if rc == 1 and (cell / "metrics.json").exists():
                failed.append(f"{cell}: collisions reported")
            elif rc != 0:
                failed.append(f"{cell}: exit {rc}: {tail}")
            bar.update()
    for line in failed:
        print(f"dica experiment: {line}", file=sys.stderr)
    print(f"done; `dica report {args.out}` writes the tables and plots")
    return 1 if failed else 0


def _algorithm(name: str) -> tuple[str, str | None]:
    """A grid name as (``--algorithm``, ``--solver`` or None)."""
    if name == "rdica":
        return "rdica", "exact"
    if name.startswith("rdica-"):
        solver = name[len("rdica-") :]
        if solver not in ("exact", "ga", "exhaustive"):
            raise ValueError(
                f"unknown solver in {name!r}: use rdica-exact, rdica-ga, rdica-exhaustive"
            )
        return "rdica", solver
    return name, None


if __name__ == "__main__":
    sys.exit(main())
