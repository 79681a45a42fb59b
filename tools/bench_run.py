"""Benchmark: how fast a 10-minute run at volume 500 goes, and its cost against a light.

Runs, one after the other in fresh processes (libsumo runs one simulation per
process), the same seed under enhanced DICA and under the optimised
fixed-cycle light, ``repeat`` times each, alternating, and reports the best
wall time of each, the real-time factor (simulated / wall seconds) and the
ratio of the two. Targets: at least 50x real time, at most 1.5x the light.

With ``--peds N`` both run on the chapter 4-5 layout with sidewalks (``ch45-walk``)
with N people an hour at every crossing, and enhanced DICA once more without them,
for the cost of serving people (the ratio of the two enhanced runs). With
``--cav-share P`` both run with a share ``1 - P`` of human drivers, and enhanced DICA
once more with none, for the cost of serving them (the greens, their shrinking and
the audit), with the p99 of one green.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from dica.tools import options

ROOT = Path(__file__).resolve().parents[1]


def one(algorithm: str, volume: float, duration: float, seed: int, extra: tuple = ()) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable,
            "-m",
            "dica.tools.cli",
            "run",
            "--algorithm",
            algorithm,
            "--volume",
            f"{volume:g}",
            "--duration",
            f"{duration:g}",
            "--seed",
            str(seed),
            "--out",
            tmp,
            "--quiet",
            *extra,
        ]
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if p.returncode not in (0, 1):
            raise RuntimeError(f"{algorithm}: {p.stderr.strip().splitlines()[-1:]}")
        return json.loads((Path(tmp) / "metrics.json").read_text())


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(prog="dica bench run", description=__doc__.splitlines()[0])
    options.add(p, "--volume", "--duration", "--seed", "--json", volume=options.VOLUME_500)
    p.add_argument("--repeat", type=int, default=3, help="runs of each controller (default 3)")
    p.add_argument(
        "--peds", type=float, default=0.0,
        help="people an hour at every crossing, on ch45-walk (default 0: ch45)",
    )  # fmt: skip
    p.add_argument(
        "--cav-share", type=float, default=1.0,
        help="share of connected vehicles, the rest human drivers (default 1: none)",
    )  # fmt: skip
    args = options.parse(p, argv)
    walk = ("--layout", "ch45-walk", "--peds", f"{args.peds:g}") if args.peds else ()
    mixed = args.cav_share < 1.0
    if mixed:
        walk = (*walk, "--cav-share", f"{args.cav_share:g}")
    runs = {"enhanced": walk, "fixed": walk}
    if args.peds:
        runs["enhanced, no people"] = ("--layout", "ch45-walk")
    if mixed:
        runs["enhanced, no humans"] = ()
    best: dict[str, dict] = {}
    for _ in range(args.repeat):
        for name, extra in runs.items():
            m = one(name.split(",")[0], args.volume, args.duration, args.seed, extra)
            if name not in best or m["wall_s"] < best[name]["wall_s"]:
                best[name] = m
    e, f = best["enhanced"], best["fixed"]
    result = {
        "volume": args.volume,
        "duration_s": args.duration,
        "seed": args.seed,
        "enhanced_wall_s": e["wall_s"],
        "enhanced_real_time_factor": e["real_time_factor"],
        "enhanced_request_median_ms": e["requests"]["median_ms"],
        "enhanced_request_p99_ms": e["requests"]["p99_ms"],
        "fixed_wall_s": f["wall_s"],
        "fixed_real_time_factor": f["real_time_factor"],
        "wall_ratio_enhanced_to_fixed": e["wall_s"] / f["wall_s"],
        "collisions": e["collisions"] + f["collisions"],
    }
    if args.peds:
        alone = best["enhanced, no people"]
        w = e["walkers"]
        result.update(
            peds=args.peds,
            people=w["generated"],
            person_hits=w["person_hits"] + w["sumo_person_collisions"],
            enhanced_no_people_wall_s=alone["wall_s"],
            wall_ratio_people_to_none=e["wall_s"] / alone["wall_s"],
        )
    if mixed:
        alone = best["enhanced, no humans"]
        result.update(
            cav_share=args.cav_share,
            humans=e["humans"]["count"],
            green_p99_ms=e["requests"].get("green_p99_ms"),
            enhanced_no_humans_wall_s=alone["wall_s"],
            wall_ratio_humans_to_none=e["wall_s"] / alone["wall_s"],
        )
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"10-min-style run, volume {args.volume:g}, seed {args.seed}, best of {args.repeat}:\n"
            f"  enhanced DICA: {e['wall_s']:.1f} s wall, {e['real_time_factor']:.0f}x real time "
            f"(request median {e['requests']['median_ms']:.2f} ms, "
            f"p99 {e['requests']['p99_ms']:.2f} ms)\n"
            f"  fixed light:   {f['wall_s']:.1f} s wall, {f['real_time_factor']:.0f}x real time\n"
            f"  ratio enhanced / fixed: {result['wall_ratio_enhanced_to_fixed']:.2f}"
        )
        if args.peds:
            print(
                f"  with {args.peds:g} people an hour a crossing ({result['people']} people, "
                f"{result['person_hits']} touched): enhanced without them "
                f"{result['enhanced_no_people_wall_s']:.1f} s wall; ratio with / without "
                f"{result['wall_ratio_people_to_none']:.2f}"
            )
        if mixed:
            print(
                f"  with {result['humans']} human drivers (share {args.cav_share:g} connected):"
                f" green p99 {result['green_p99_ms']:.2f} ms; enhanced without them "
                f"{result['enhanced_no_humans_wall_s']:.1f} s wall; ratio with / without "
                f"{result['wall_ratio_humans_to_none']:.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
