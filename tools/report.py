"""``dica report DIR``: markdown tables and PNG plots from a directory of runs.

Every ``metrics.json`` below DIR (with its ``config.json``) is one run. Runs
are grouped by layout, algorithm, volume and demand shape (and, where a run
sets them, its junctions, route file, start, share of connected vehicles and
people) and averaged over seeds, as the dissertation reports them. Collisions
are summed, the minimum gap is the smallest seen.

Beside the dissertation's trip time (from the region's entry line) the
tables give the time in the system and the delay counted from the scheduled
arrival at that line, and the vehicles not yet in the region at the end.

The saturation volume of a controller is the highest volume of the grid up
to which every volume keeps throughput at or above ``SATURATION_RHO`` and
its delay bounded: the mean delay from the scheduled arrival of the last
third of the run (vehicles still in the system counted with their delay so
far) at most ``GROWTH`` times the middle third's plus ``SLACK_S``. Above
saturation queues grow all run long, and so does that delay. The
dissertation's rho counts every vehicle due by the end, so in a 10-minute
run a light whose cycle is long has up to a red phase's arrivals still
waiting and rho under 0.95 at volumes its queues keep up with; the report
therefore also gives the saturation volume by the settled throughput:
crossed over generated among the vehicles due at least ``SETTLE_S`` before
the end.

Runs with emergency vehicles (``--ev-prob``) form their own tables and get a
chapter 5 table: EVs' and normal vehicles' trip times apart, and reactive
DICA's solver time per EV event and per run. Reactive DICA is listed by its
solver (``rdica-exact``, ``rdica-ga``, ``rdica-exhaustive``).
"""

from __future__ import annotations

import csv
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from dica.tools import options
from dica.tools.network_report import load_network_runs
from dica.tools.network_report import write_report as write_network_report

FIELDS = [
    ("throughput", "rho", "{:.3f}"),
    ("mean_trip_time_s", "mean tau [s]", "{:.2f}"),
    ("std_trip_time_s", "std tau [s]", "{:.2f}"),
    ("max_trip_time_s", "max tau [s]", "{:.1f}"),
    ("stopped_rate", "eta", "{:.3f}"),
    ("crawled_rate", "crawled", "{:.3f}"),  # below 1 m/s, stops included
    ("effective_mean_trip_time_s", "tau_e [s]", "{:.2f}"),
    ("mean_delay_s", "delay [s]", "{:.2f}"),
    ("mean_system_time_s", "time in system [s]", "{:.2f}"),
    ("mean_system_delay_s", "delay from schedule [s]", "{:.2f}"),
    ("not_in_region_at_end", "not in region at end", "{:.1f}"),
]
SATURATION_RHO = 0.95
SETTLE_S = 120.0  # [s] a vehicle due this long before the end has had time to cross
GROWTH = 1.5
SLACK_S = 5.0


def load_runs(root: Path) -> list[dict]:
    """Every run under ``root`` (a metrics.json beside a config.json); one whose files
    cannot be read as a run's (cut short, edited, another tool's) is left out with a note
    naming it, not the whole report."""
    runs = []
    for m in sorted(root.rglob("metrics.json")):
        cfg_path = m.parent / "config.json"
        if not cfg_path.exists():
            continue
        try:
            run = _load_run(m, cfg_path)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
            print(f"note: {m.parent}: not a run dica report can read ({type(e).__name__}: "
                  f"{' '.join(str(e).split())}); left out", file=sys.stderr)  # fmt: skip
            continue
        if run is not None:
            runs.append(run)
    return runs


def _load_run(m: Path, cfg_path: Path) -> dict | None:
    metrics = json.loads(m.read_text())
    if "network_run" in metrics:  # a dica network run: tools/network_report.py
        return None
    cfg = json.loads(cfg_path.read_text())["run"]
    weights = cfg.get("approach_weights") or []
    shape = []
    if weights:
        shape.append("weights " + ",".join(f"{a}={w:g}" for a, w in weights))
    if cfg.get("volume_end_per_10min") is not None:
        shape.append(f"to {cfg['volume_end_per_10min']:g}")
    if cfg.get("ev_prob"):
        shape.append(f"p_EV {cfg['ev_prob']:g}")
    shape += _settings(cfg)
    layout = Path(cfg["net_path"]).name.split(".")[0].split("-tls")[0]
    algorithm = cfg["algorithm"]
    if algorithm == "rdica":
        algorithm = f"rdica-{cfg.get('solver', 'exact')}"
        if "max_added_delay_s" in cfg:  # (runs before the bound have no such key)
            bound = float(cfg["max_added_delay_s"])
            algorithm += f" (bound {bound:g} s)" if math.isfinite(bound) else " (no bound)"
    return {
        "settled_throughput": _settled_throughput(m.parent, cfg),
        "dir": m.parent,
        "layout": layout,
        "algorithm": algorithm,
        "volume": cfg["volume_per_10min"],
        "shape": "; ".join(shape),
        "seed": cfg["seed"],
        "metrics": metrics,
    }


def _settings(cfg: dict) -> list[str]:
    """What else sets runs apart that their seeds must not be averaged across: the
    junctions, a route file, the share of connected vehicles, people, a later start (a
    default run of a built-in layout has none of them)."""
    out = []
    if cfg.get("junction_ids"):
        out.append("junctions " + ",".join(cfg["junction_ids"]))
    elif cfg.get("junction_id") not in (None, "C"):
        out.append(f"junction {cfg['junction_id']}")
    if cfg.get("routes_path"):
        out.append(f"routes {Path(cfg['routes_path']).name}")
    if cfg.get("begin_s"):
        out.append(f"from {cfg['begin_s']:g} s")
    if cfg.get("cav_share", 1.0) != 1.0:
        out.append(f"connected {cfg['cav_share']:g}")
    if cfg.get("peds_per_h"):
        out.append(f"people {cfg['peds_per_h']:g}/h")
    return out


def _settled_throughput(run: Path, cfg: dict) -> float | None:
    """Crossed / generated among the vehicles due at least SETTLE_S before the end."""
    path = run / "vehicles.csv"
    if cfg.get("until_left") or not path.exists():
        return None
    cut = float(cfg["duration_s"]) - SETTLE_S
    with path.open() as fh:
        due = [r for r in csv.DictReader(fh) if float(r["depart_s"]) <= cut]
    return sum(bool(r["exited_s"]) for r in due) / len(due) if due else None


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def aggregate(runs: list[dict]) -> dict[tuple, dict]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in runs:
        groups[(r["layout"], r["shape"], r["algorithm"], r["volume"])].append(r)
    out = {}
    for key, rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2], kv[0][3])):
        row = {f: _mean([r["metrics"].get(f) for r in rs]) for f, _, _ in FIELDS}
        row["generated"] = _mean([r["metrics"]["generated"] for r in rs])
        row["settled_throughput"] = _mean([r["settled_throughput"] for r in rs])
        row["collisions"] = sum(r["metrics"]["collisions"] for r in rs)
        row["sumo_collisions"] = sum(r["metrics"].get("sumo_collisions", 0) for r in rs)
        gaps = [r["metrics"]["min_gap_m"] for r in rs if r["metrics"]["min_gap_m"] is not None]
        row["min_gap_m"] = min(gaps) if gaps else None
        row["wall_s"] = _mean([r["metrics"].get("wall_s") for r in rs])
        row["seeds"] = sorted(r["seed"] for r in rs)
        per: dict[str, list[float]] = defaultdict(list)
        for r in rs:
            for a, v in (r["metrics"].get("mean_trip_time_by_approach_s") or {}).items():
                per[a].append(v)
        row["by_approach"] = {a: float(np.mean(v)) for a, v in sorted(per.items())}
        thirds = [r["metrics"].get("system_delay_by_third_s") or [None] * 3 for r in rs]
        row["delay_by_third_s"] = [_mean([t[k] for t in thirds]) for k in range(3)]
        row["ev"] = _ev_row(rs)
        row["runs"] = rs
        out[key] = row
    return out


def bounded(row: dict) -> bool:
    """Delay from the schedule not growing through the run (see the module docstring)."""
    _, middle, last = row["delay_by_third_s"]
    return middle is not None and last is not None and last <= GROWTH * middle + SLACK_S


def saturation(agg: dict[tuple, dict], rho: str = "throughput") -> dict[tuple, dict]:
    """Per (layout, algorithm) of the steady-volume runs: the saturation volume and its row,
    by the throughput ``rho`` ("throughput" or "settled_throughput").

    ``volume`` is None when even the lowest volume is saturated; ``above`` is
    True when no volume of the grid was.
    """
    series: dict[tuple, list[tuple[float, dict]]] = defaultdict(list)
    for (layout, shape, alg, vol), row in agg.items():
        if not shape:
            series[(layout, alg)].append((vol, row))
    out = {}
    for key, pts in sorted(series.items()):
        pts.sort(key=lambda p: p[0])
        best = None
        for vol, row in pts:
            if row[rho] is None or row[rho] < SATURATION_RHO or not bounded(row):
                break
            best = (vol, row)
        out[key] = {
            "volume": best[0] if best else None,
            "row": best[1] if best else None,
            "above": best is not None and best[0] == pts[-1][0],
            "volumes": [v for v, _ in pts],
        }
    return out


def _saturation_lines(agg: dict[tuple, dict]) -> list[str]:
    by_rho = saturation(agg)
    by_settled = saturation(agg, "settled_throughput")
    lines = ["## Saturation", ""]
    lines.append(
        f"Highest volume up to which throughput stays >= {SATURATION_RHO} and the delay from "
        f"the schedule bounded (last third <= {GROWTH} x middle third + {SLACK_S:g} s); "
        f"by the dissertation's rho, and by the settled throughput (vehicles due "
        f"{SETTLE_S:g} s or more before the end). Figures at the first."
    )
    lines.append("")
    head = ["layout", "algorithm", "saturation volume", "by settled throughput", "rho", "eta"]
    head += ["tau [s]", "tau_e [s]", "time in system [s]", "delay from schedule [s]"]
    head.append("volumes tried")
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    for (layout, alg), s in by_rho.items():
        row = s["row"]
        cells = [layout, alg, _volume(s), _volume(by_settled[(layout, alg)])]
        for k, fmt in (
            ("throughput", "{:.3f}"),
            ("stopped_rate", "{:.3f}"),
            ("mean_trip_time_s", "{:.2f}"),
            ("effective_mean_trip_time_s", "{:.2f}"),
            ("mean_system_time_s", "{:.2f}"),
            ("mean_system_delay_s", "{:.2f}"),
        ):
            cells.append("-" if row is None else _fmt(fmt, row[k]))
        cells.append(",".join(f"{v:g}" for v in s["volumes"]))
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _volume(s: dict) -> str:
    if s["volume"] is None:
        return f"< {s['volumes'][0]:g}"
    return (">= " if s["above"] else "") + f"{s['volume']:g}"


EV_FIELDS = [
    ("ev_count", "EVs", "{:.0f}"),
    ("ev_mean", "EV mean tau [s]", "{:.2f}"),
    ("ev_from_arrival", "EV mean from arrival [s]", "{:.2f}"),
    ("ev_max", "EV max tau [s]", "{:.1f}"),
    ("normal_mean", "normal mean tau [s]", "{:.2f}"),
    ("normal_max", "normal max tau [s]", "{:.1f}"),
    ("solve_ms_event", "solver [ms / event]", "{:.2f}"),
    ("solve_s_run", "solver [s / run]", "{:.3f}"),
    ("refused", "refused events", "{:.0f}"),
    ("added_max", "most added to a vehicle [s]", "{:.2f}"),
    ("replanned_later", "most a re-plan came later [s]", "{:.2f}"),
]


def _ev_row(rs: list[dict]) -> dict | None:
    """Chapter 5's figures of a group: EVs and normal vehicles apart, solver time."""
    if not any("ev" in r["metrics"] for r in rs):
        return None

    def group(name: str, key: str) -> float | None:
        return _mean([(r["metrics"].get(name) or {}).get(key) for r in rs])

    reactive = [r["metrics"]["reactive"] for r in rs if "reactive" in r["metrics"]]
    events = sum(x["events"] for x in reactive)
    solve = sum(x["solve_s_total"] for x in reactive)
    return {
        "ev_count": float(sum((r["metrics"].get("ev") or {}).get("crossed", 0) for r in rs)),
        "ev_mean": group("ev", "mean_trip_time_s"),
        "ev_from_arrival": group("ev", "mean_trip_time_from_arrival_s"),
        "ev_max": group("ev", "max_trip_time_s"),
        "normal_mean": group("normal", "mean_trip_time_s"),
        "normal_max": group("normal", "max_trip_time_s"),
        "solve_ms_event": solve / events * 1e3 if events else None,
        "solve_s_run": solve / len(reactive) if reactive else None,
        "refused": float(sum(x["refused"] for x in reactive)) if reactive else None,
        # over the seeds: by the ordering model, and measured on the revoked vehicles' plans
        "added_max": _most(reactive, "added_delay_max_s"),
        "replanned_later": _most(reactive, "replanned_later_max_s"),
        "normal_max_by_seed": {
            r["seed"]: (r["metrics"].get("normal") or {}).get("max_trip_time_s") for r in rs
        },
    }


def _most(rows: list[dict], key: str) -> float | None:
    vals = [x[key] for x in rows if x.get(key) is not None]
    return max(vals) if vals else None


def _fmt(fmt: str, v: float | None) -> str:
    return "-" if v is None else fmt.format(v)


def markdown(agg: dict[tuple, dict], images: list[str]) -> str:
    lines = ["# Run report", ""]
    if any(len(s["volumes"]) > 1 for s in saturation(agg).values()):
        lines += _saturation_lines(agg)
    by_table: dict[tuple, list] = defaultdict(list)
    for key, row in agg.items():
        by_table[(key[0], key[1])].append((key, row))
    for (layout, shape), rows in by_table.items():
        lines += [f"## {layout}" + (f" ({shape})" if shape else ""), ""]
        head = ["algorithm", "volume", *[h for _, h, _ in FIELDS]]
        head += ["collisions", "SUMO collisions", "min gap [m]", "wall [s]", "seeds"]
        if shape:
            head.append("mean tau by approach [s]")
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        for key, row in rows:
            cells = [key[2], f"{key[3]:g}"] + [_fmt(f, row[k]) for k, _, f in FIELDS]
            cells += [
                str(row["collisions"]),
                str(row["sumo_collisions"]),
                _fmt("{:.2f}", row["min_gap_m"]),
                _fmt("{:.1f}", row["wall_s"]),
                ",".join(map(str, row["seeds"])),
            ]
            if shape:
                cells.append(", ".join(f"{a} {v:.2f}" for a, v in row["by_approach"].items()))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        lines += _ev_table(rows)
    if images:
        lines += ["## Plots", ""] + [f"![{Path(i).stem}]({i})" for i in images] + [""]
    return "\n".join(lines)


def _ev_table(rows: list[tuple[tuple, dict]]) -> list[str]:
    """Chapter 5: EVs and normal vehicles apart, and the targets' ratios."""
    rows = [(k, r) for k, r in rows if r.get("ev") is not None]
    if not rows:
        return []
    lines = [
        "### Emergency vehicles and the others (chapter 5)",
        "",
        "Trip times from the region's entry line (the dissertation's clock); the EV mean "
        "from the scheduled arrival also counts any wait to get into the region.",
        "",
    ]
    head = ["algorithm", "volume", *[h for _, h, _ in EV_FIELDS]]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    for key, row in rows:
        ev = row["ev"]
        cells = [key[2], f"{key[3]:g}"] + [_fmt(f, ev[k]) for k, _, f in EV_FIELDS]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    by = {(k[2], k[3]): r["ev"] for k, r in rows}
    volumes = sorted({k[3] for k, _ in rows})
    ratios = []
    for alg in sorted({k[2] for k, _ in rows if k[2].startswith("rdica")}):
        for vol in volumes:
            mine, light, plain = (
                by.get((alg, vol)),
                by.get(("reactive-light", vol)),
                by.get(("enhanced", vol)),
            )
            if mine is None:
                continue
            ev_ratio = _ratio(mine["ev_mean"], light and light["ev_mean"])
            ev_arrival = _ratio(mine["ev_from_arrival"], light and light["ev_from_arrival"])
            normal = _ratio(mine["normal_max"], plain and plain["normal_max"])
            worst = _worst_seed(mine, plain)
            ratios.append(f"| {alg} | {vol:g} | {ev_ratio} | {ev_arrival} | {normal} | {worst} |")
    if ratios:
        lines += [
            "| algorithm | volume | EV mean tau / reactive light's (target <= 0.5) | "
            "the same from arrival | normal max tau / enhanced DICA's (target <= 1.10) | "
            "the same, worst seed |",
            "|---|---|---|---|---|---|",
            *ratios,
            "",
        ]
    return lines


def _worst_seed(mine: dict, plain: dict | None) -> str:
    worst = worst_seed(mine, plain)
    return "-" if worst is None else f"{worst[0]:.2f} (seed {worst[1]})"


def worst_seed(mine: dict, plain: dict | None) -> tuple[float, int] | None:
    """The largest per-seed ratio of the normal vehicles' longest trips, and its seed."""
    if plain is None:
        return None
    theirs = plain["normal_max_by_seed"]
    pairs = [
        (a / theirs[s], s)
        for s, a in mine["normal_max_by_seed"].items()
        if a is not None and theirs.get(s)
    ]
    return max(pairs) if pairs else None


def _ratio(a: float | None, b: float | None) -> str:
    return "-" if a is None or not b else f"{a / b:.2f}"


def plots(agg: dict[tuple, dict], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    images = []
    tables: dict[tuple, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for key, row in agg.items():
        tables[(key[0], key[1])][key[2]].append((key[3], row))
    for (layout, shape), algs in tables.items():
        tag = layout + ("-" + "".join(c if c.isalnum() else "_" for c in shape) if shape else "")
        fig, axes = plt.subplots(2, 2, figsize=(10, 7))
        panels = [
            ("mean_trip_time_s", "mean trip time [s]"),
            ("throughput", "throughput rho"),
            ("effective_mean_trip_time_s", "effective mean trip time tau_e [s]"),
            ("std_trip_time_s", "std of trip time [s]"),
        ]
        for ax, (field, label) in zip(axes.ravel(), panels, strict=True):
            for alg, pts in sorted(algs.items()):
                pts = sorted(pts, key=lambda p: p[0])
                ax.plot([p[0] for p in pts], [p[1][field] for p in pts], marker="o", label=alg)
            ax.set_xlabel("volume [veh / 10 min]")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        axes[0, 0].legend()
        fig.suptitle(f"{layout} {shape}".strip())
        fig.tight_layout()
        name = f"metrics_{tag}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        images.append(name)

        # trip-time histograms, waiting over time and gaps at the highest volume
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
        for alg, pts in sorted(algs.items()):
            vol, row = max(pts, key=lambda p: p[0])
            taus = []
            for r in row["runs"]:
                with (r["dir"] / "vehicles.csv").open() as fh:
                    taus += [
                        float(x["trip_time_s"]) for x in csv.DictReader(fh) if x["trip_time_s"]
                    ]
            if taus:
                axes[0].hist(taus, bins=40, histtype="step", label=f"{alg} ({vol:g})")
            first = row["runs"][0]["dir"] / "timeseries.csv"
            if first.exists():
                with first.open() as fh:
                    ts = list(csv.DictReader(fh))
                axes[1].plot(
                    [float(x["t_s"]) for x in ts],
                    [int(x["waiting"]) for x in ts],
                    label=f"{alg} ({vol:g})",
                    lw=0.8,
                )
            counts = np.sum(
                [r["metrics"]["safety"]["gap_hist_counts"] for r in row["runs"]], axis=0
            )
            edges = row["runs"][0]["metrics"]["safety"]["gap_hist_edges_m"]
            axes[2].step(edges[:-1], counts, where="post", label=f"{alg} ({vol:g})")
        axes[0].set_xlabel("trip time [s]")
        axes[0].set_ylabel("vehicles")
        axes[1].set_xlabel("simulated time [s]")
        axes[1].set_ylabel("vehicles waiting")
        axes[2].set_xlabel("gap between vehicle rectangles [m] (bin start)")
        axes[2].set_ylabel("pair-steps near the junction")
        axes[2].set_yscale("log")
        for ax in axes:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        name = f"distributions_{tag}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        images.append(name)

        evs = {alg: pts for alg, pts in algs.items() if any(r.get("ev") for _, r in pts)}
        if evs:
            fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
            panels = [
                ("ev_mean", "EVs' mean trip time [s]"),
                ("normal_mean", "normal vehicles' mean trip time [s]"),
                ("normal_max", "normal vehicles' max trip time [s]"),
            ]
            for ax, (field, label) in zip(axes, panels, strict=True):
                for alg, pts in sorted(evs.items()):
                    pts = sorted((p for p in pts if p[1].get("ev")), key=lambda p: p[0])
                    ax.plot([p[0] for p in pts], [p[1]["ev"][field] for p in pts], marker="o",
                            label=alg)  # fmt: skip
                ax.set_xlabel("volume [veh / 10 min]")
                ax.set_ylabel(label)
                ax.grid(alpha=0.3)
            axes[0].legend(fontsize=8)
            fig.suptitle(f"{layout} {shape}: emergency vehicles (chapter 5)".strip())
            fig.tight_layout()
            name = f"ev_{tag}.png"
            fig.savefig(out / name, dpi=110)
            plt.close(fig)
            images.append(name)
            name = _ev_targets_plot(
                plt, evs, f"{layout} {shape}".strip(), out / f"ev-targets_{tag}.png"
            )
            if name:
                images.append(name)
    return images


def _ev_targets_plot(plt, evs: dict[str, list], title: str, path: Path) -> str | None:
    """Chapter 5's two targets per volume for each reactive DICA: the EVs' mean trip
    against the reactive light's, and the worst seed's longest normal trip against plain
    DICA's."""
    light = dict(evs.get("reactive-light", []))
    plain = dict(evs.get("enhanced", []))
    mine = {alg: sorted(pts, key=lambda p: p[0]) for alg, pts in evs.items()
            if alg.startswith("rdica")}  # fmt: skip
    if not mine or not (light or plain):
        return None
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for alg, pts in sorted(mine.items()):
        ev = [(v, r["ev"]["ev_mean"] / light[v]["ev"]["ev_mean"]) for v, r in pts
              if v in light and r["ev"]["ev_mean"] and light[v]["ev"]["ev_mean"]]  # fmt: skip
        worst = [(v, w[0]) for v, r in pts if v in plain
                 for w in [worst_seed(r["ev"], plain[v]["ev"])] if w is not None]  # fmt: skip
        for ax, series in ((axes[0], ev), (axes[1], worst)):
            if series:
                ax.plot(*zip(*series, strict=True), marker="o", label=alg)
    for ax, target, label in (
        (axes[0], 0.5, "EVs' mean trip / reactive light's"),
        (axes[1], 1.10, "longest normal trip / plain DICA's, worst seed"),
    ):
        ax.axhline(target, color="k", linestyle="--", linewidth=1, label=f"target {target:g}")
        ax.set_xlabel("volume [veh / 10 min]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{title}: reactive DICA's two targets".strip())
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(
        prog="dica report",
        description="Tables (markdown) and plots (PNG) from a directory of `dica run` outputs, "
        "averaged over seeds.",
    )
    p.add_argument("runs", type=Path, help="directory holding run directories (any depth)")
    options.add(
        p, "--out", "--json", out={"help": "where report.md and the PNGs go (default RUNS/report)"},
        json={"help": "also write report.json"},
    )  # fmt: skip
    args = options.parse(p, argv)
    if not args.runs.is_dir():
        print(f"dica report: no such directory: {args.runs}", file=sys.stderr)
        return 2
    runs = load_runs(args.runs)
    network_runs = load_network_runs(args.runs)
    if not runs and not network_runs:
        print(
            f"dica report: no runs (metrics.json with config.json) under {args.runs}",
            file=sys.stderr,
        )
        return 2
    out = args.out or args.runs / "report"
    out.mkdir(parents=True, exist_ok=True)
    if network_runs:
        groups, n = write_network_report(network_runs, out)
        print(
            f"{len(network_runs)} network runs in {groups} groups; wrote {out}/networks.md "
            f"and {n} plots"
        )
        if not runs:
            return 0
    agg = aggregate(runs)
    images = plots(agg, out)
    (out / "report.md").write_text(markdown(agg, images))
    if args.json:
        settled = saturation(agg, "settled_throughput")
        sat = [
            {
                "layout": k[0],
                "algorithm": k[1],
                "saturation_volume": s["volume"],
                "above": s["above"],
                "volumes": s["volumes"],
                "saturation_volume_settled": settled[k]["volume"],
                "above_settled": settled[k]["above"],
            }
            for k, s in saturation(agg).items()
        ]
        rows = [
            {
                "layout": k[0],
                "shape": k[1],
                "algorithm": k[2],
                "volume": k[3],
                **{f: v for f, v in row.items() if f != "runs"},
            }
            for k, row in agg.items()
        ]
        (out / "report.json").write_text(
            json.dumps({"groups": rows, "saturation": sat}, indent=2, default=str)
        )
    print(f"{len(runs)} runs in {len(agg)} groups; wrote {out}/report.md and {len(images)} plots")
    return 0


if __name__ == "__main__":
    sys.exit(main())
