"""Benchmark: milliseconds per simulation step spent recording a run with Rerun.

Vehicles drive along the chapter 4-5 junction's routes at constant speed; each
step logs all their footprints and their distance along the route (the
projection included), and one vehicle a second gets a confirmation (a real
proposed TSS). The budget in STACK-NOTES is about 2 ms per step for 30 vehicles.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ica.core.proposal import propose
from ica.netfile import load_intersection
from sim_gateway.recording import SpaceTimeRecorder
from sim_gateway.scenario import default_scenario

STEP_S = 0.05  # [s]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench_recording", description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=30)
    ap.add_argument("--steps", type=int, default=2000, help="0.05 s steps (default 2000)")
    ap.add_argument("--out", type=Path, help=".rrd to write (default: a temporary file)")
    args = ap.parse_args(argv)
    if args.vehicles < 1 or args.steps < 2:
        print("bench_recording: need --vehicles >= 1 and --steps >= 2", file=sys.stderr)
        return 2

    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    rng = np.random.default_rng(1)
    routes = [inter.routes[i % len(inter.routes)] for i in range(args.vehicles)]
    s0 = rng.uniform(-inter.comm_length_m, 0.0, args.vehicles)
    speed = rng.uniform(5.0, 15.0, args.vehicles)
    vins = [f"veh{i}" for i in range(args.vehicles)]
    rids = [r.id for r in routes]
    proposals = [
        propose(r, vin=f"c{i}", seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=12.0)
        for i, r in enumerate(inter.routes)
    ]

    with tempfile.TemporaryDirectory() as tmp:
        path = args.out or Path(tmp) / "bench.rrd"
        rec = SpaceTimeRecorder(inter, path)
        rec.geometry()
        step_times, conf_times = [], []
        for k in range(args.steps):
            t = k * STEP_S
            s = s0 + speed * t
            s = (s + inter.comm_length_m) % (inter.comm_length_m + 30.0) - inter.comm_length_m
            xy = np.array([r.points(si) for r, si in zip(routes, s, strict=True)])
            ahead = np.array([r.points(si + 0.5) for r, si in zip(routes, s, strict=True)])
            d = ahead - xy
            angle = np.degrees(np.arctan2(d[:, 0], d[:, 1]))  # SUMO: from north, clockwise
            t0 = time.perf_counter()
            rec.footprints(t, vins, xy[:, 0], xy[:, 1], angle, 5.0, 1.8, route_ids=rids)
            step_times.append(time.perf_counter() - t0)
            if k % round(1.0 / STEP_S) == 0:
                req = proposals[(k // 20) % len(proposals)]
                tss = req.tss
                route = inter.route(req.in_lane, req.out_lane)
                assert route is not None
                t0 = time.perf_counter()
                rec.confirmed(
                    f"c{k}", route.id, tss.t_s + t, tss.x_m, tss.y_m, tss.heading_rad,
                    5.0, 1.8, float(tss.t_s[0] + t + 2.0), float(tss.t_s[-1] + t),
                )  # fmt: skip
                conf_times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        rec.close()
        close_s = time.perf_counter() - t0
        size = path.stat().st_size

    ms = np.array(step_times) * 1e3
    print(
        f"{args.vehicles} vehicles, {args.steps} steps: footprints+progress "
        f"median {np.median(ms):.3f} ms/step, mean {ms.mean():.3f}, p99 {np.percentile(ms, 99):.3f}"
    )
    print(
        f"confirmed(): median {np.median(conf_times) * 1e3:.3f} ms per confirmation "
        f"({len(conf_times)} logged); close {close_s * 1e3:.0f} ms; file {size / 1e6:.2f} MB"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
