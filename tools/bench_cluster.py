"""Benchmark: the cluster's transport and its lockstep speed.

1. REQUEST -> RESPONSE round trip over Zenoh on loopback (client -> router ->
   ICA process and back), measured by a client in this process:
   * ``repeat``: the same REQUEST again (same VIN and sequence number), which
     the ICA answers from the confirmation it stored: wire, codec and
     dispatch only;
   * ``fresh``: a new vehicle's first REQUEST (after its DETECT) on an empty
     junction: the above plus one confirmation by the enhanced core.
   Target: p99 <= 5 ms.
2. The lockstep real-time factor of a 10-minute run at volume 500 through
   ``tools/run_cluster.sh`` (router, ICA, observer, agents, gateway), next to
   the embedded run of the same seed. Target: >= 10x real time.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dica.tools import options
from dica.tools.loopback import router_and_ica

ROOT = Path(__file__).resolve().parents[1]
DICA = [sys.executable, "-m", "dica.tools.cli"]


def round_trips(n: int) -> dict:
    from dica.ica.convert import request_from_core
    from dica.ica.core.proposal import propose
    from dica.ica.netfile import load_intersection
    from dica.schemas import keys
    from dica.schemas.codec import decode, encode, now_ns
    from dica.schemas.messages import Clock, Detect, Response
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    route = next(r for r in inter.routes if r.turn.value == "through")
    with router_and_ica(sc.junction_id) as (session, _ica):
        j = sc.junction_id

        def ask(key: str, payload: bytes):
            (r,) = list(session.get(key, payload=payload, timeout=5.0))
            return decode(r.ok.payload.to_bytes())

        t = 0.0
        step = 0

        def tick(dt: float) -> None:
            nonlocal t, step
            t += dt
            step += 1
            session.put(keys.clock(j), encode(Clock(step, t, "lockstep", 1.0, False, now_ns())))

        out: dict[str, list[float]] = {"repeat": [], "fresh": []}
        tick(0.05)
        time.sleep(0.2)
        for k in range(n + 20):  # the first 20 of each warm up
            tick(60.0)  # everyone confirmed before has left: an empty junction
            time.sleep(0.002)
            vin = f"b{k:05d}"
            detect = encode(Detect(vin, route.in_lane, t, False, 10.0, now_ns()))
            req = propose(route, vin=vin, seq=0, t0_s=t, dist_to_entry_m=40.0, speed_mps=12.0)
            payload = encode(request_from_core(req))
            ask(keys.detect(j, "bench"), detect)
            t0 = time.perf_counter()
            answer = ask(keys.request(j, "bench"), payload)
            t1 = time.perf_counter()
            assert isinstance(answer, Response), answer
            again = ask(keys.request(j, "bench"), payload)
            t2 = time.perf_counter()
            assert isinstance(again, Response)
            if k >= 20:
                out["fresh"].append(t1 - t0)
                out["repeat"].append(t2 - t1)
    return {
        name: {
            "n": len(v),
            "median_ms": float(np.median(v) * 1e3),
            "p99_ms": float(np.percentile(v, 99) * 1e3),
        }
        for name, v in out.items()
    }


def lockstep(volume: float, duration: float, seed: int, agents: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        common = ["--volume", f"{volume:g}", "--duration", f"{duration:g}", "--seed", str(seed)]
        t0 = time.perf_counter()
        p = subprocess.run(
            [
                "bash",
                "tools/run_cluster.sh",
                "--out",
                f"{tmp}/cl",
                "--agents",
                str(agents),
                *common,
            ],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        whole = time.perf_counter() - t0
        if p.returncode != 0:
            raise SystemExit(f"bench cluster: the cluster run failed:\n{p.stderr[-2000:]}")
        m = json.loads(Path(f"{tmp}/cl/metrics.json").read_text())
        e = subprocess.run(
            [*DICA, "run", *common, "--out", f"{tmp}/emb", "--quiet"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        if e.returncode != 0:
            raise SystemExit(f"bench cluster: the embedded run failed:\n{e.stderr[-2000:]}")
        me = json.loads(Path(f"{tmp}/emb/metrics.json").read_text())
    return {
        "agents": agents,
        "cluster_wall_s": m["wall_s"],
        "cluster_real_time_factor": m["real_time_factor"],
        "cluster_whole_script_s": whole,
        "step_wait_median_ms": m["step_wait_median_ms"],
        "step_wait_p99_ms": m["step_wait_p99_ms"],
        "embedded_wall_s": me["wall_s"],
        "embedded_real_time_factor": me["real_time_factor"],
        "wall_ratio_cluster_to_embedded": m["wall_s"] / me["wall_s"],
        "same_crossed": m["crossed"] == me["crossed"],
        "collisions": m["collisions"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = options.Parser(
        prog="dica bench cluster",
        description="REQUEST round trip over Zenoh on loopback, and the lockstep real-time "
        "factor of a cluster run next to the embedded run of the same seed.",
    )
    ap.add_argument("--requests", type=int, default=500, help="round trips per kind (500)")
    options.add(
        ap, "--volume", "--duration", "--seed", "--agents", "--json",
        volume=options.VOLUME_500,
        agents={"default": 2, "help": "vehicle-agent processes (default 2)"},
    )  # fmt: skip
    ap.add_argument("--skip-run", action="store_true", help="only the round trips")
    args = options.parse(ap, argv)
    if args.requests < 1:
        ap.error("--requests must be at least 1")
    res = {"round_trip": round_trips(args.requests)}
    if not args.skip_run:
        res["lockstep"] = lockstep(args.volume, args.duration, args.seed, args.agents)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    for name, r in res["round_trip"].items():
        print(f"round trip {name:6s}: median {r['median_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms")
    if "lockstep" in res:
        r = res["lockstep"]
        print(
            f"lockstep, {r['agents']} agents: {r['cluster_wall_s']:.1f} s "
            f"({r['cluster_real_time_factor']:.1f}x real time); embedded "
            f"{r['embedded_wall_s']:.1f} s ({r['embedded_real_time_factor']:.1f}x); "
            f"ratio {r['wall_ratio_cluster_to_embedded']:.2f}; step wait median "
            f"{r['step_wait_median_ms']:.2f} ms, p99 {r['step_wait_p99_ms']:.2f} ms"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
