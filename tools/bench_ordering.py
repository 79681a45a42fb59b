"""Benchmark: the EV ordering solvers (exact, GA, exhaustive) on this junction's geometry.

Ordering problems are drawn the way reactive DICA meets them on the chapter
4-5 intersection: a few lanes, each with a queue whose vehicles become free
to enter one after another (the first within 4 s, the next 1.5-3 s later),
routes drawn from the lane's own, the first of each queue entering at speed
and the rest pulling away from the stop line, separations measured with
DICA's own conflict test (:mod:`ica.core.separation`). The EV is a random
vehicle of the first lane. Times are counted from the event, so "within 1 %"
compares EV entry times measured from the moment the EV was detected.

Printed: the exact solver's time on 20 vehicles in 4 lanes (median, p99; wall
time, and CPU time, which other load on a shared host does not inflate), the
share of events on which the GA's EV entry is within 1 % of the exact one,
and each solver's wall time per event.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np

from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import Kinematics
from dica.ica.core.ordering import (
    EXHAUSTIVE_LIMIT,
    Problem,
    better,
    count_orders,
    exact,
    exhaustive,
    ga,
)
from dica.ica.core.separation import SeparationModel
from dica.ica.core.zones import ConflictTables, Shape
from dica.tools import options


def event(
    inter: Intersection, model: SeparationModel, rng: np.random.Generator, sizes: list[int]
) -> Problem:
    """One ordering problem: ``sizes[i]`` vehicles queued in each of len(sizes) lanes."""
    lanes = list(rng.choice(inter.in_lanes, size=len(sizes), replace=False))
    routes, speeds, release, lane_of = [], [], [], []
    for li, (lane, n) in enumerate(zip(lanes, sizes, strict=True)):
        options = inter.routes_from(lane)
        t = float(rng.uniform(0.0, 4.0))
        for q in range(n):
            r = options[int(rng.integers(len(options)))]
            routes.append(r)
            if q == 0:
                speeds.append(float(rng.uniform(3.0, r.speed_cap_mps)))
            else:
                speeds.append(model.stop_and_go_entry_mps(r))
                t += float(rng.uniform(1.5, 3.0))
            release.append(t)
            lane_of.append(li)
    ev = int(rng.integers(sizes[0]))  # lane 0's vehicles come first in the index order
    return Problem(np.array(lane_of), np.array(release), model.matrix(routes, speeds), ev)


def _stats(ms: list[float]) -> dict:
    a = np.array(ms)
    return {
        "n": len(a),
        "median_ms": float(np.median(a)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
    }


def run(inter: Intersection, fixed: int, events: int, seed: int, limit: int) -> dict:
    rng = np.random.default_rng(seed)
    tables = ConflictTables(inter, 0.25)
    shape = Shape.of(5.0, 1.8)
    tables.precompute(shape)
    model = SeparationModel(inter, tables, shape, Kinematics(), 0.25)
    exact(event(inter, model, rng, [2, 1]))  # the compiled code is loaded before timing

    t_exact20, cpu_exact20 = [], []
    for _ in range(fixed):
        p = event(inter, model, rng, [5, 5, 5, 5])
        c0 = time.process_time()
        t_exact20.append(exact(p).solve_s * 1e3)
        cpu_exact20.append((time.process_time() - c0) * 1e3)

    t_exact, t_ga, t_ex, within, same, delay_gap, refused, sizes = [], [], [], 0, 0, [], 0, []
    for _ in range(events):
        n = int(rng.integers(3, 21))
        n_lanes = int(rng.integers(2, min(8, n) + 1))
        split = np.ones(n_lanes, dtype=int) + rng.multinomial(n - n_lanes, [1 / n_lanes] * n_lanes)
        p = event(inter, model, rng, [int(x) for x in split])
        sizes.append(n)
        e = exact(p)
        g = ga(p, seed=int(rng.integers(2**31)))
        t_exact.append(e.solve_s * 1e3)
        t_ga.append(g.solve_s * 1e3)
        if g.ev_entry_s <= e.ev_entry_s * 1.01 + 1e-9:
            within += 1
        if not better(e.key(), g.key()):
            same += 1
        delay_gap.append(g.delay_s - e.delay_s)
        if count_orders(p) <= limit:
            t_ex.append(exhaustive(p, limit).solve_s * 1e3)
        else:
            refused += 1
    return {
        "host": platform.node(),
        "python": platform.python_version(),
        "exact_20_in_4_lanes": _stats(t_exact20),
        "exact_20_in_4_lanes_cpu": _stats(cpu_exact20),
        "events": events,
        "event_sizes": {"min": min(sizes), "max": max(sizes), "mean": float(np.mean(sizes))},
        "ga_within_1pct_of_exact_ev_entry": within / events,
        "ga_as_good_as_exact_on_both_keys": same / events,
        "ga_extra_delay_of_others_s_mean": float(np.mean(delay_gap)),
        "exact": _stats(t_exact),
        "ga": _stats(t_ga),
        "exhaustive": {**_stats(t_ex), "refused": refused, "limit_orders": limit}
        if t_ex
        else {"n": 0, "refused": refused, "limit_orders": limit},
    }


def render(r: dict) -> str:
    e20 = r["exact_20_in_4_lanes"]
    within = 100 * r["ga_within_1pct_of_exact_ev_entry"]
    lines = [
        f"exact, 20 vehicles in 4 lanes ({e20['n']} problems): median {e20['median_ms']:.2f} ms, "
        f"p99 {e20['p99_ms']:.2f} ms, max {e20['max_ms']:.2f} ms (target p99 <= 10 ms)",
        f"  the same in CPU time (what other load on the host cannot inflate): median "
        f"{r['exact_20_in_4_lanes_cpu']['median_ms']:.2f} ms, "
        f"p99 {r['exact_20_in_4_lanes_cpu']['p99_ms']:.2f} ms",
        f"{r['events']} events of {r['event_sizes']['min']}-{r['event_sizes']['max']} vehicles "
        f"(mean {r['event_sizes']['mean']:.1f}):",
        f"  GA's EV entry within 1 % of exact's: {within:.1f} % of events (target >= 95 %)",
        f"  GA as good as exact on both keys: {100 * r['ga_as_good_as_exact_on_both_keys']:.1f} %;"
        f" the others' extra delay under GA: {r['ga_extra_delay_of_others_s_mean']:.2f} s mean",
    ]
    for name in ("exact", "ga", "exhaustive"):
        s = r[name]
        if s["n"]:
            lines.append(
                f"  {name:<10} median {s['median_ms']:8.2f} ms  p99 {s['p99_ms']:8.2f} ms  "
                f"max {s['max_ms']:8.2f} ms"
            )
    ex = r["exhaustive"]
    lines.append(
        f"  exhaustive refused {ex['refused']} of {r['events']} events "
        f"(over {ex['limit_orders']:,} orders)"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(
        prog="dica bench ordering",
        description="Time of the EV ordering solvers on problems drawn on the chapter 4-5 "
        "junction, and how close the GA comes to the exact optimum.",
    )
    options.add(p, "--json", "--seed")
    p.add_argument("--fixed", type=int, default=200, help="20-vehicle problems timed (default 200)")
    p.add_argument("--events", type=int, default=300, help="events of 3-20 vehicles (default 300)")
    p.add_argument(
        "--limit",
        type=int,
        default=EXHAUSTIVE_LIMIT,
        help=f"exhaustive search's limit in orders (default {EXHAUSTIVE_LIMIT:,})",
    )
    args = options.parse(p, argv)
    if args.fixed < 1 or args.events < 1 or args.limit < 1:
        print(
            "dica bench ordering: --fixed, --events and --limit must be at least 1", file=sys.stderr
        )
        return 2
    from dica.tools.args import UsageError, intersection

    try:
        inter = intersection(argparse.Namespace(net=None, junction=None, layout="ch45"))
    except UsageError as e:
        print(f"dica bench ordering: {e}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    result = run(inter, args.fixed, args.events, args.seed, args.limit)
    result["wall_s"] = time.perf_counter() - t0
    print(json.dumps(result, indent=2) if args.json else render(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
