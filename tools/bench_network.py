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
(flat memory: the two close). With ``--cluster S`` also the lockstep cluster of the
same grid for S simulated seconds (``run_cluster.sh --junctions all``: an ICA
process per junction, a router per roadside unit, two agents) next to the embedded
run of the same S: their real-time factors, each ICA process's request p99, and
whether the two made the same decisions.
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


def cluster(net: Path, routes: Path, duration_s: float, rsus: int, out: Path) -> dict:
    """The lockstep cluster of the grid and the embedded run of the same vehicles."""
    scen = ["--net", str(net), "--routes", str(routes), "--junctions", "all"]
    common = [*scen, "--duration", f"{duration_s:g}"]
    t0 = time.perf_counter()
    p = subprocess.run(
        ["bash", "tools/run_cluster.sh", "--out", str(out / "cl"), "--no-record",
         "--rsus", str(rsus), *common],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    whole = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"the cluster run failed: {p.stderr.strip().splitlines()[-3:]}")
    e, _ = _run([*DICA, "run", *common, "--out", str(out / "emb"), "--quiet"], cwd=ROOT)
    if e.returncode != 0:
        raise RuntimeError(f"the embedded run failed: {e.stderr.strip().splitlines()[-1:]}")
    m = json.loads((out / "cl" / "metrics.json").read_text())
    me = json.loads((out / "emb" / "metrics.json").read_text())
    p99 = {j: r["ica"]["compute_p99_ms"] for j, r in m["roles"].items()}  # each ICA's own
    same = (out / "cl" / "vehicles.csv").read_bytes() == (out / "emb" / "vehicles.csv").read_bytes()
    return {
        "duration_s": duration_s,
        "roadside_units": rsus,
        "cluster_wall_s": m["wall_s"],
        "cluster_real_time_factor": m["real_time_factor"],
        "cluster_whole_script_s": whole,
        "embedded_wall_s": me["wall_s"],
        "embedded_real_time_factor": me["real_time_factor"],
        "wall_ratio_cluster_to_embedded": m["wall_s"] / me["wall_s"],
        "ica_process_p99_ms": p99,
        "same_decisions": same,
        "collisions": m["collisions"] + m["sumo_collisions"],
    }


DICA = [sys.executable, "-m", "dica.tools.cli"]


def main(argv: list[str] | None = None) -> int:
    from dica.sim_gateway.network_layouts import build_network
    from dica.sim_gateway.od_demand import OdDemand, write_od_routes

    p = options.Parser(prog="dica bench network", description=__doc__.splitlines()[0])
    options.add(p, "--json")
    p.add_argument("--duration", type=float, default=3600.0, help="simulated s (default 3600)")
    p.add_argument("--volume", type=float, default=400.0,
                   help="vehicles per hour on each road in (default 400)")  # fmt: skip
    p.add_argument("--repeat", type=int, default=2, help="runs of each (default 2)")
    p.add_argument(
        "--cluster",
        type=float,
        default=0.0,
        metavar="S",
        help="also the lockstep cluster for S simulated s (default 0: not)",
    )
    p.add_argument("--rsus", type=int, default=3,
                   help="the cluster's roadside units, each a router (default 3)")  # fmt: skip
    args = options.parse(p, argv)
    if not (args.repeat >= 1 and args.duration > 0.0):
        raise options.UsageError("--repeat wants 1 or more runs, --duration a time above 0 s")
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
        lockstep = (
            cluster(free.net_path, routes, args.cluster, args.rsus, d / "cluster")
            if args.cluster > 0
            else None
        )
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
        "lockstep_cluster": lockstep,
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
        if lockstep is not None:
            c = lockstep
            print(
                f"  lockstep cluster, {c['duration_s']:g} s, 9 ICA processes, "
                f"{c['roadside_units']} routers, 2 agents: {c['cluster_wall_s']:.1f} s wall, "
                f"{c['cluster_real_time_factor']:.1f}x real time (embedded "
                f"{c['embedded_real_time_factor']:.0f}x, ratio "
                f"{c['wall_ratio_cluster_to_embedded']:.1f}); worst ICA process's p99 "
                f"{max(c['ica_process_p99_ms'].values()):.2f} ms; same decisions: "
                f"{'yes' if c['same_decisions'] else 'NO'}; collisions {c['collisions']}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
