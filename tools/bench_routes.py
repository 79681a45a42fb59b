"""Benchmark: a user's net and demand file, one junction signal-free, against SUMO alone.

Builds (or takes) a net and a SUMO route file, then runs, alternating in fresh
processes, ``repeat`` times each: SUMO alone on the same net and file (its own
drivers and priority rules everywhere: the floor any run on that net pays),
and ``dica run --routes`` with the junction under enhanced DICA (the world
takes each vehicle over in the region, measures the room beyond, and checks
every step). Reports the best wall time of each and their ratio, the run's
real-time factor and its request times. Without ``--net``: a 3x3 grid of
3-lane streets at 50 km/h, 200 m blocks, with SUMO's randomTrips demand of a
vehicle every 1.5 s over the whole net, and its centre junction.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dica.tools import options

ROOT = Path(__file__).resolve().parents[1]


def default_demand(d: Path, duration_s: float) -> tuple[Path, Path, str]:
    """The built-in case: a 3x3 city grid and a random trip every 1.5 s, seed 5."""
    import sumo

    from dica.sim_gateway.scenario import netconvert_binary

    net, trips = d / "grid.net.xml", d / "grid.trips.xml"
    gen = str(Path(netconvert_binary()).with_name("netgenerate"))
    subprocess.run(
        [gen, "--grid", "--grid.number", "3", "--grid.length", "200",
         "--default.lanenumber", "3", "--default.speed", "13.89", "--no-turnarounds", "true",
         "-o", str(net)],
        check=True, capture_output=True,
    )  # fmt: skip
    random_trips = Path(sumo.SUMO_HOME) / "tools" / "randomTrips.py"
    subprocess.run(
        [sys.executable, str(random_trips), "-n", str(net), "-o", str(trips), "-p", "1.5",
         "-e", f"{duration_s:g}", "--seed", "5", "--validate"],
        check=True, capture_output=True, cwd=d,  # its routes.rou.xml lands beside the net
    )  # fmt: skip
    return net, trips, "B1"


def sumo_alone(net: Path, routes: Path, duration_s: float) -> float:
    """Wall seconds of SUMO on its own with the run's step and options, no control."""
    from dica.sim_gateway.sumo_io import sumo_command

    code = (
        "import contextlib, io, sys, time\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    import libsumo\n"
        "cmd = sys.argv[1:]\n"
        "t = time.perf_counter()\n"
        "libsumo.start(cmd)\n"
        f"while libsumo.simulation.getTime() < {duration_s!r} - 1e-9:\n"
        "    libsumo.simulation.step()\n"
        "libsumo.close()\n"
        "print(time.perf_counter() - t)\n"
    )
    cmd = sumo_command(str(net), 0.05, ("-r", str(routes)))
    p = subprocess.run([sys.executable, "-c", code, *cmd], capture_output=True, text=True)
    if p.returncode != 0:
        raise options.UsageError(f"SUMO alone could not run it: {_last_line(p.stderr)}")
    return float(p.stdout.strip().splitlines()[-1])


def dica_run(net: Path, routes: Path, junction: str, duration_s: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "dica.tools.cli", "run", "--net", str(net), "--junction",
               junction, "--routes", str(routes), "--duration", f"{duration_s:g}",
               "--out", tmp, "--quiet"]  # fmt: skip
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if p.returncode not in (0, 1):
            raise options.UsageError(_last_line(p.stderr).removeprefix("dica: "))
        return json.loads((Path(tmp) / "metrics.json").read_text())


def _last_line(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[-1] if lines else "(nothing said)"


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(prog="dica bench routes", description=__doc__.splitlines()[0])
    options.add(p, "--net", "--junction", "--routes", "--json")
    p.add_argument("--duration", type=float, default=900.0, help="simulated s (default 900)")
    p.add_argument("--repeat", type=int, default=3, help="runs of each (default 3)")
    args = options.parse(p, argv)
    if not (args.repeat >= 1 and args.duration > 0.0):
        raise options.UsageError("--repeat wants 1 or more runs, --duration a time above 0 s")
    if (args.net is None) != (args.routes is None):
        raise options.UsageError("give --net, --junction and --routes together, or none")
    with tempfile.TemporaryDirectory(prefix="dica-bench-routes-") as tmp:
        if args.net is None:
            net, routes, junction = default_demand(Path(tmp), args.duration)
        else:
            # the runs start in the project's directory: the user's paths from here
            net, routes = Path(args.net).resolve(), Path(args.routes).resolve()
            junction = args.junction
            for what, path in (("net", net), ("route file", routes)):
                if not path.is_file():
                    raise options.UsageError(f"{what} not found: {path}")
        alone, best = [], None
        started = time.perf_counter()
        for _ in range(args.repeat):
            alone.append(sumo_alone(net, routes, args.duration))
            m = dica_run(net, routes, junction, args.duration)
            if best is None or m["wall_s"] < best["wall_s"]:
                best = m
    result = {
        "net": str(args.net or "3x3 grid, 3 lanes, 50 km/h, 200 m blocks"),
        "junction": junction,
        "duration_s": args.duration,
        "crossings": best["crossed"],
        "sumo_alone_wall_s": min(alone),
        "dica_wall_s": best["wall_s"],
        "dica_real_time_factor": best["real_time_factor"],
        "wall_ratio_dica_to_sumo_alone": best["wall_s"] / min(alone),
        "request_median_ms": best["requests"]["median_ms"],
        "request_p99_ms": best["requests"]["p99_ms"],
        "collisions": best["collisions"] + best["sumo_collisions"],
        "bench_wall_s": time.perf_counter() - started,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"{result['net']}, junction {junction}, {args.duration:g} s, best of {args.repeat}:\n"
            f"  SUMO alone:           {result['sumo_alone_wall_s']:.1f} s wall\n"
            f"  enhanced DICA at {junction}: {result['dica_wall_s']:.1f} s wall, "
            f"{result['dica_real_time_factor']:.0f}x real time, {result['crossings']} crossings, "
            f"request median {result['request_median_ms']:.2f} ms, "
            f"p99 {result['request_p99_ms']:.2f} ms\n"
            f"  ratio DICA / SUMO alone: {result['wall_ratio_dica_to_sumo_alone']:.2f}; "
            f"collisions {result['collisions']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
