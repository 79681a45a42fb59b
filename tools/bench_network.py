"""Benchmark: the built-in 3x3 grid, every junction signal-free, against SUMO alone.

Draws the grid's origin-destination demand (``--volume`` vehicles per hour on each
of its 12 roads in), then runs, alternating in fresh processes, ``repeat`` times
each: SUMO alone on the grid with its fixed-time lights and the same vehicles (the
floor any control on that net pays), and ``dica network`` with all nine junctions
under enhanced DICA (the world takes each vehicle over in each region, measures
the room beyond, counts the network gate and checks every step), each for
``--duration`` simulated seconds on one core. Reports the best wall time of each
and their ratio, the signal-free run's real-time factor, each ICA's request p99,
and the peak memory of a run of the whole duration and of one a third as long
(flat memory: the two close).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dica.tools import options
from dica.tools.bench_routes import sumo_alone

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], cwd: Path | None = None) -> tuple[subprocess.CompletedProcess, float]:
    """Run ``cmd``; its result and its peak resident memory [MiB] (its own, from wait4)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=cwd)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        done = subprocess.CompletedProcess(
            cmd, proc.returncode, out.read().decode(), err.read().decode()
        )
    return done, usage.ru_maxrss / 1024.0


def dica_network(routes: Path, duration_s: float, out: Path) -> tuple[dict, float]:
    cmd = [sys.executable, "-m", "dica.tools.cli", "network", "--layout", "grid",
           "--routes", str(routes), "--duration", f"{duration_s:g}", "--drain", "0",
           "--out", str(out), "--quiet"]  # fmt: skip
    p, rss = _run(cmd, cwd=ROOT)
    if p.returncode not in (0, 1):
        raise RuntimeError(f"dica network failed: {p.stderr.strip().splitlines()[-1:]}")
    return json.loads((out / "metrics.json").read_text()), rss


def main(argv: list[str] | None = None) -> int:
    from dica.sim_gateway.network_layouts import build_network
    from dica.sim_gateway.od_demand import OdDemand, write_od_routes

    p = options.Parser(prog="dica bench network", description=__doc__.splitlines()[0])
    options.add(p, "--json")
    p.add_argument("--duration", type=float, default=3600.0, help="simulated s (default 3600)")
    p.add_argument("--volume", type=float, default=400.0,
                   help="vehicles per hour on each road in (default 400)")  # fmt: skip
    p.add_argument("--repeat", type=int, default=2, help="runs of each (default 2)")
    args = options.parse(p, argv)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dica-bench-network-") as tmp:
        d = Path(tmp)
        free = build_network("grid", d / "net")
        lit = build_network("grid", d / "net", "static", free)
        routes = d / "od.rou.xml"
        n = write_od_routes(
            free.net_path, free.junctions, OdDemand(args.volume, args.duration), routes
        )
        alone, best, rss = [], None, 0.0
        for i in range(args.repeat):
            wall = sumo_alone(lit.net_path, routes, args.duration)
            alone.append(wall)
            m, peak = dica_network(routes, args.duration, d / f"run{i}")
            rss = max(rss, peak)
            if best is None or m["wall_s"] < best["wall_s"]:
                best = m
        third, rss_third = dica_network(routes, args.duration / 3.0, d / "third")
    per_ica = {j: x["requests"]["p99_ms"] for j, x in best["junctions"].items()}
    result = {
        "net": "built-in 3x3 grid, 2 lanes each way, 250 m blocks, 50 km/h",
        "volume_vph_per_entry": args.volume,
        "vehicles": n,
        "duration_s": args.duration,
        "sumo_alone_wall_s": min(alone),
        "dica_wall_s": best["wall_s"],
        "dica_real_time_factor": best["real_time_factor"],
        "wall_ratio_dica_to_sumo_alone": best["wall_s"] / min(alone),
        "request_p99_ms_per_ica": per_ica,
        "request_p99_ms_worst_ica": max(per_ica.values()),
        "requests": best["requests"]["count"],
        "peak_rss_mib": rss,
        "peak_rss_mib_third_duration": rss_third,
        "third_duration_real_time_factor": third["real_time_factor"],
        "collisions": best["collisions"] + best["sumo_collisions"],
        "bench_wall_s": time.perf_counter() - started,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"{result['net']}, {args.volume:g} vehicles/h per road in ({n} vehicles), "
            f"{args.duration:g} s, best of {args.repeat}:\n"
            f"  SUMO alone (fixed-time lights): {result['sumo_alone_wall_s']:.1f} s wall\n"
            f"  every junction signal-free:     {result['dica_wall_s']:.1f} s wall, "
            f"{result['dica_real_time_factor']:.0f}x real time, {result['requests']} requests, "
            f"worst ICA's p99 {result['request_p99_ms_worst_ica']:.2f} ms\n"
            f"  ratio signal-free / SUMO alone: {result['wall_ratio_dica_to_sumo_alone']:.1f}\n"
            f"  peak memory: {rss:.0f} MiB ({rss_third:.0f} MiB over a third of the time); "
            f"collisions {result['collisions']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
