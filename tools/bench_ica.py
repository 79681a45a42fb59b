"""Benchmark: seconds per REQUEST for basic DICA, each technique alone, and enhanced DICA.

Enhanced DICA (exact intervals, so basic DICA's decisions) and the
dissertation's enhanced DICA (``t1+2+3+4``, estimated intervals) are timed
side by side; ``t3`` is the dissertation's technique 3 alone.

A heavy stream on the chapter 4-5 intersection is run once; whenever the
confirmed set holds about n = 5, 10 or 20 vehicles, the state and the incoming
request are kept. Under the head-vehicle rule this junction never holds many
more than 20 confirmed vehicles (measured up to 6000 vehicles per 10 min), so
the n = 40 states are synthetic and labelled so: a real state of 17 or more
vehicles plus the same vehicles 6 s later under new VINs (except those of the
requester's own lane, which would stand ahead of it).

Every variant then answers exactly those requests from exactly those states
(its own interval method applied to the confirmed trajectories), best of
``repeat`` timings each, each with the exit-spacing separations looked up
anew: a run meets new speed pairs all the time, and a cache warmed by the
other variants' answers to the same requests would hide their cost. Ratios
to basic DICA are taken per request, so machine noise mostly cancels. Every
variant runs with exit spacing, as the ICA does by default: where checkFV's
cap binds, a request is planned twice.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import statistics
import sys
import time
from dataclasses import dataclass

import numpy as np

from dica.ica.core.config import IcaConfig, Techniques
from dica.ica.core.controller import Controller, ControllerSpec, build_controller
from dica.ica.core.handover import clear_separations
from dica.ica.core.intersection import Intersection
from dica.ica.core.request import Confirmation, Request, Tss
from dica.ica.core.zones import ConflictTables
from dica.sim_gateway.stream import StreamSpec, run_stream
from dica.tools import options

BUCKETS = {5: (4, 6), 10: (9, 11), 20: (17, 23)}
SYNTHETIC_N = 40
SYNTHETIC_SHIFT_S = 6.0
VARIANTS = ("basic", "t1", "t2", "t3", "t4", "t2+4", "t1+2+3+4", "enhanced")
DISSERTATION_PCT = {"t1": 11.0, "t2": 59.0, "t3": 13.0, "t2+4": 6.0, "t1+2+3+4": 0.4}


@dataclass
class Snapshot:
    n: int
    now_s: float
    request: Request
    confirmed: list[tuple[Confirmation, float, float, str]]  # confirmation, length, width, lane


def _shifted(c: Confirmation, dt: float) -> Confirmation:
    tss = Tss(c.tss.t_s + dt, c.tss.x_m, c.tss.y_m, c.tss.heading_rad)
    return dataclasses.replace(
        c,
        vin=c.vin + "+",
        tss=tss,
        entry_time_s=c.entry_time_s + dt,
        exit_time_s=c.exit_time_s + dt,
    )


def collect(inter: Intersection, per_bucket: int, seed: int) -> dict[int, list[Snapshot]]:
    """Run one heavy stream and keep up to ``per_bucket`` states per n."""
    found: dict[int, list[Snapshot]] = {n: [] for n in (*BUCKETS, SYNTHETIC_N)}

    def keep(ica: Controller, req: Request, now: float) -> None:
        n = len(ica.confirmed)
        conf = [
            (c.confirmation, c.dtot.shape.length_m, c.dtot.shape.width_m, c.dtot.route.in_lane)
            for c in ica.confirmed.values()
        ]
        for b, (lo, hi) in BUCKETS.items():
            if lo <= n <= hi and len(found[b]) < per_bucket:
                found[b].append(Snapshot(n, now, req, conf))
        if n >= 17 and len(found[SYNTHETIC_N]) < per_bucket:
            more = [
                (_shifted(c, SYNTHETIC_SHIFT_S), ln, w, lane)
                for c, ln, w, lane in conf
                if lane != req.in_lane  # nobody new ahead of the requester in its own lane
            ]
            found[SYNTHETIC_N].append(Snapshot(n + len(more), now, req, conf + more))

    for volume in (600.0, 3000.0, 6000.0):
        spec = StreamSpec(volume_per_10min=volume, n_vehicles=6 * per_bucket + 100, seed=seed)
        run_stream(inter, IcaConfig(exit_spacing=True), spec, before_request=keep)
        if all(len(v) >= per_bucket for v in found.values()):
            break
    return found


def time_variant(
    inter: Intersection,
    variant: str,
    snaps: list[Snapshot],
    repeat: int,
    shared: dict[bool, ConflictTables],
) -> list[float]:
    cfg = IcaConfig(techniques=Techniques.parse(variant), exit_spacing=True)
    spec = ControllerSpec(variant, cfg)
    exact = cfg.techniques.exact_oti
    if exact not in shared:  # the offline tables of this interval kind, built once
        shared[exact] = ConflictTables(inter, cfg.margin_m, exact_oti=exact)
    out = []
    for snap in snaps:
        best = float("inf")
        for _ in range(repeat):
            ica = build_controller(spec, inter, shared[exact])
            for conf, length, width, lane in snap.confirmed:
                ica.adopt(conf, length, width, lane)
            ica.detect(snap.request.vin, snap.request.in_lane, snap.now_s)
            clear_separations()
            t = time.perf_counter()
            answer = ica.handle(snap.request, snap.now_s)
            best = min(best, time.perf_counter() - t)
            if not isinstance(answer, Confirmation):
                raise RuntimeError(f"{variant}: replayed request rejected: {answer}")
        out.append(best)
    return out


def run(
    per_bucket: int = 25,
    repeat: int = 3,
    seed: int = 12,
    layout: str = "ch45",
    variants: tuple[str, ...] = VARIANTS,
) -> dict:
    from dica.ica.netfile import load_intersection
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario(layout)
    inter = load_intersection(sc.net_path, sc.junction_id)
    snaps = collect(inter, per_bucket, seed)
    shared: dict[bool, ConflictTables] = {}
    variants = ("basic", *[v for v in variants if v != "basic"])  # the ratios' reference
    times = {
        v: {n: time_variant(inter, v, snaps[n], repeat, shared) for n in snaps} for v in variants
    }
    result: dict = {
        "machine": f"{platform.machine()} python {platform.python_version()}",
        "layout": layout,
        "requests_per_bucket": {str(n): len(snaps[n]) for n in snaps},
        "mean_n_per_bucket": {
            str(n): float(np.mean([s.n for s in snaps[n]])) if snaps[n] else None for n in snaps
        },
        "synthetic_buckets": [str(SYNTHETIC_N)],
        "variants": {},
    }
    for v in variants:
        row = {}
        for n in snaps:
            t = np.array(times[v][n])
            base = np.array(times["basic"][n])
            row[str(n)] = {
                "median_s": float(np.median(t)) if len(t) else None,
                "p99_s": float(np.percentile(t, 99)) if len(t) else None,
                "pct_of_basic": float(np.median(t / base) * 100) if len(t) else None,
            }
        all_ratio = [
            a / b for n in snaps for a, b in zip(times[v][n], times["basic"][n], strict=True)
        ]
        row["all"] = {
            "pct_of_basic": float(statistics.median(all_ratio) * 100) if all_ratio else None,
            "dissertation_pct": DISSERTATION_PCT.get(v),
        }
        result["variants"][v] = row
    return result


def render(result: dict) -> str:
    ns = list(result["requests_per_bucket"])
    synth = set(result["synthetic_buckets"])
    lines = [
        f"ICA benchmark on {result['layout']} ({result['machine']}); requests per n: "
        + ", ".join(f"n={k}: {v}" for k, v in result["requests_per_bucket"].items()),
        "",
        "| variant | "
        + " | ".join(f"n={n}{' (synthetic)' if n in synth else ''} median / p99 [ms]" for n in ns)
        + " | % of basic (median ratio) | dissertation |",
        "|---|" + "---|" * (len(ns) + 2),
    ]
    for v, row in result["variants"].items():
        cells = []
        for n in ns:
            c = row[str(n)]
            cells.append(
                "-"
                if c["median_s"] is None
                else f"{c['median_s'] * 1e3:.2f} / {c['p99_s'] * 1e3:.2f}"
            )
        pct = row["all"]["pct_of_basic"]
        ref = row["all"]["dissertation_pct"]
        lines.append(
            f"| {v} | "
            + " | ".join(cells)
            + f" | {pct:.1f} % | "
            + ("-" if ref is None else f"{ref} %")
            + " |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(
        prog="dica bench ica",
        description="Seconds per REQUEST of basic DICA, each chapter-4 technique alone and "
        "enhanced DICA, on the same states and requests; ratios to basic.",
    )
    options.add(p, "--json", "--seed")
    p.add_argument("--per-bucket", type=int, default=25, help="requests timed per n (default 25)")
    p.add_argument(
        "--repeat", type=int, default=3, help="timings per request, best kept (default 3)"
    )
    p.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated DICA variants to time (basic always, as the reference)",
    )
    args = options.parse(p, argv)
    if args.per_bucket < 1 or args.repeat < 1:
        p.error("--per-bucket and --repeat must be at least 1")
    variants = tuple(v.strip() for v in args.variants.split(",") if v.strip())
    for v in variants:
        try:
            Techniques.parse(v)
        except ValueError as e:
            p.error(str(e))
    result = run(args.per_bucket, args.repeat, args.seed, variants=variants)
    print(json.dumps(result, indent=2) if args.json else render(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
