"""``dica report`` for networks: ``dica network`` runs grouped by layout, demand and control,
averaged over seeds, with the signal-free network against the best light.

The figures are the network's, per vehicle from SUMO's own trip records: delay
and travel time from the scheduled departure (waiting to be inserted included),
stops, and the share of vehicles that finished. The comparison takes the best of
the adaptive and coordinated lights (actuated, coordinated fixed-time,
max-pressure) by mean delay at each demand, as the network issue states it.
Runs with emergency vehicles (``--ev-prob``) are their own demand, and get a table
of the EVs' trips against their free flow beside the others' delay; reactive DICA
is its own control (``dica-rdica``), as are the pre-empting lights (``preempt``).
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

CONTROL_ORDER = ("dica", "dica-rdica", "max-pressure", "actuated", "coordinated", "static",
                 "preempt")  # fmt: skip
BEST_LIGHTS = ("actuated", "coordinated", "max-pressure")
FIELDS = ("mean_delay_s", "p95_delay_s", "mean_travel_time_s", "mean_stops", "finished_rate")


def load_network_runs(root: Path) -> list[dict]:
    """Every ``dica network`` run below ``root``."""
    runs = []
    for m in sorted(root.rglob("metrics.json")):
        try:
            metrics = json.loads(m.read_text())
        except (OSError, ValueError) as e:  # cut short or not JSON: not this report's to read
            print(f"note: {m.parent}: its metrics.json cannot be read ({type(e).__name__}); "
                  "left out", file=sys.stderr)  # fmt: skip
            continue
        if not isinstance(metrics, dict):
            continue
        run = metrics.get("network_run")
        if not run or "network" not in metrics:
            continue
        runs.append({"dir": m.parent, "run": run, "metrics": metrics})
    return runs


def demand_label(run: dict) -> str:
    if run.get("volume_vph") is None:
        return f"routes {Path(run['routes']).name}"
    label = f"{run['volume_vph']:g}/h per entry"
    for road, vph in sorted((run.get("entry_vph") or {}).items()):
        label += f", {road} {vph:g}/h"
    label += f", {run['demand_s']:g} s"
    if run.get("ev_prob"):
        label += f", EV p {run['ev_prob']:g}"
    return label


def control_label(run: dict) -> str:
    """The control, and DICA's variant where it is not the default enhanced one."""
    algo = run.get("algorithm")
    if run["control"] == "dica" and algo not in (None, "enhanced"):
        ahead = "-ahead" if run.get("ev_notices") else ""  # the EVs' notices ahead
        return f"dica-{algo}{ahead}"
    return run["control"]


def busiest_vph(demand: str) -> float:
    """The most vehicles per hour a demand label gives any road in (0: a route file)."""
    found = [float(x) for x in re.findall(r"([0-9.]+)/h", demand)]
    return max(found) if found else 0.0


def _case_key(case: tuple[str, str]) -> tuple:
    return (case[0], busiest_vph(case[1]), case[1])


def aggregate(runs: list[dict]) -> dict[tuple[str, str, str], dict]:
    """(layout, demand, control) -> the figures averaged over seeds, collisions summed."""
    groups: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for r in runs:
        layout = r["run"]["layout"] or Path(r["run"]["net"]).name
        groups[(layout, demand_label(r["run"]), control_label(r["run"]))].append(r)
    out = {}
    for key, rs in groups.items():
        row: dict = {"seeds": sorted(r["run"]["seed"] for r in rs)}
        for f in FIELDS:
            vals = [r["metrics"]["network"].get(f) for r in rs]
            vals = [v for v in vals if v is not None and np.isfinite(v)]
            row[f] = float(np.mean(vals)) if vals else None
        row["vehicles"] = float(np.mean([r["metrics"]["network"]["vehicles"] for r in rs]))
        row["collisions"] = sum(
            r["metrics"]["collisions"] + r["metrics"]["sumo_collisions"] for r in rs
        )
        row["stood_inside"] = sum(r["metrics"].get("stood_inside", 0) for r in rs)
        evs = [r["metrics"]["network"] for r in rs if "emergency" in r["metrics"]["network"]]
        if evs:
            row["ev"] = {f: _mean([n["emergency"][f] for n in evs]) for f in EV_FIELDS}
            row["ev"]["vehicles"] = sum(n["emergency"]["vehicles"] for n in evs)
            row["ev"]["worst_ratio"] = max(
                (n["emergency"]["max_travel_to_free_flow"] for n in evs), default=None
            )
            row["ev"]["normal_delay_s"] = _mean([n["normal"]["mean_delay_s"] for n in evs])
        out[key] = row
    return out


EV_FIELDS = ("mean_travel_time_s", "mean_free_flow_s", "mean_travel_to_free_flow", "mean_stops")


def _mean(vals: list) -> float | None:
    vals = [v for v in vals if v is not None and np.isfinite(v)]
    return float(np.mean(vals)) if vals else None


def _order(control: str) -> int:
    return CONTROL_ORDER.index(control) if control in CONTROL_ORDER else len(CONTROL_ORDER)


def _f(v: float | None, fmt: str = "{:.1f}") -> str:
    return "n/a" if v is None else fmt.format(v)


def markdown(agg: dict[tuple[str, str, str], dict], images: list[str]) -> str:
    lines = ["# Networks", ""]
    by_case: dict[tuple[str, str], dict[str, dict]] = defaultdict(dict)
    for (layout, demand, control), row in agg.items():
        by_case[(layout, demand)][control] = row
    lines += [
        "| layout | demand | control | seeds | vehicles | finished | mean delay [s] | "
        "p95 delay [s] | mean travel [s] | stops | collisions | stood inside |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (layout, demand), controls in sorted(by_case.items(), key=lambda kv: _case_key(kv[0])):
        for c in sorted(
            controls, key=lambda c: CONTROL_ORDER.index(c) if c in CONTROL_ORDER else 9
        ):
            r = controls[c]
            lines.append(
                f"| {layout} | {demand} | {c} | {','.join(map(str, r['seeds']))} | "
                f"{r['vehicles']:.0f} | {_f(r['finished_rate'], '{:.3f}')} | "
                f"{_f(r['mean_delay_s'])} | {_f(r['p95_delay_s'])} | "
                f"{_f(r['mean_travel_time_s'])} | {_f(r['mean_stops'], '{:.2f}')} | "
                f"{r['collisions']} | {r['stood_inside']} |"
            )
    lines += ["", "## Signal-free against the best light", ""]
    lines += [
        "| layout | demand | best light | its mean delay [s] | DICA's [s] | ratio | "
        "finished: DICA / best light |",
        "|---|---|---|---|---|---|---|",
    ]
    for (layout, demand), controls in sorted(by_case.items(), key=lambda kv: _case_key(kv[0])):
        lit = {c: r for c, r in controls.items() if c in BEST_LIGHTS and r["mean_delay_s"]}
        if "dica" not in controls or not lit:
            continue
        best = min(lit, key=lambda c: lit[c]["mean_delay_s"])
        d, b = controls["dica"], lit[best]
        ratio = d["mean_delay_s"] / b["mean_delay_s"] if d["mean_delay_s"] is not None else None
        lines.append(
            f"| {layout} | {demand} | {best} | {_f(b['mean_delay_s'])} | "
            f"{_f(d['mean_delay_s'])} | {_f(ratio, '{:.2f}')} | "
            f"{_f(d['finished_rate'], '{:.3f}')} / {_f(b['finished_rate'], '{:.3f}')} |"
        )
    lines += _ev_table(by_case)
    for img in images:
        lines += ["", f"![{img}]({img})"]
    return "\n".join(lines) + "\n"


def _ev_table(by_case: dict[tuple[str, str], dict[str, dict]]) -> list[str]:
    """The emergency vehicles' trips per control, where the runs had any: their travel
    time against their free flow, and against the pre-empting lights'; the others'
    delay against plain DICA's."""
    rows = []
    for (layout, demand), controls in sorted(by_case.items(), key=lambda kv: _case_key(kv[0])):
        pre = controls.get("preempt", {}).get("ev")
        plain = controls.get("dica", {}).get("ev")
        for c in sorted(controls, key=_order):
            ev = controls[c].get("ev")
            if ev is None:
                continue
            vs_pre = (
                ev["mean_travel_time_s"] / pre["mean_travel_time_s"]
                if pre and ev["mean_travel_time_s"] and pre["mean_travel_time_s"]
                else None
            )
            vs_plain = (
                ev["normal_delay_s"] / plain["normal_delay_s"]
                if plain and ev["normal_delay_s"] is not None and plain["normal_delay_s"]
                else None
            )
            rows.append(
                f"| {layout} | {demand} | {c} | {ev['vehicles']} | "
                f"{_f(ev['mean_travel_time_s'])} | {_f(ev['mean_free_flow_s'])} | "
                f"{_f(ev['mean_travel_to_free_flow'], '{:.2f}')} / "
                f"{_f(ev['worst_ratio'], '{:.2f}')} | {_f(ev['mean_stops'], '{:.2f}')} | "
                f"{_f(vs_pre, '{:.2f}')} | {_f(ev['normal_delay_s'])} | "
                f"{_f(vs_plain, '{:.2f}')} |"
            )
    if not rows:
        return []
    return [
        "", "## Emergency vehicles", "",
        "| layout | demand | control | EVs | EV mean travel [s] | EV free flow [s] | "
        "x free flow (mean / worst) | EV stops | EV travel / preempt's | others' mean delay "
        "[s] | others' delay / plain DICA's |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
    ]  # fmt: skip


def plots(agg: dict[tuple[str, str, str], dict], out: Path) -> list[str]:
    """Per layout: mean delay against the busiest road in's volume, a line per control."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    images = []
    layouts = sorted({k[0] for k in agg})
    for layout in layouts:
        series: dict[str, list[tuple[float, float]]] = defaultdict(list)
        for (lay, demand, control), row in agg.items():
            if lay != layout or row["mean_delay_s"] is None or not busiest_vph(demand):
                continue
            series[control].append((busiest_vph(demand), row["mean_delay_s"]))
        if not series:
            continue
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for control in sorted(
            series, key=lambda c: CONTROL_ORDER.index(c) if c in CONTROL_ORDER else 9
        ):
            pts = sorted(series[control])
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=control)
        ax.set_xlabel("vehicles per hour on the busiest road in")
        ax.set_ylabel("mean delay from the scheduled departure [s]")
        ax.set_title(f"{layout}: mean delay per vehicle")
        ax.grid(alpha=0.3)
        ax.legend()
        name = f"network-{layout}-delay.png"
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        images.append(name)
    return images


def write_report(runs: list[dict], out: Path) -> tuple[int, int]:
    """Write ``networks.md`` (and its plots) into ``out``; (groups, plots)."""
    agg = aggregate(runs)
    images = plots(agg, out)
    (out / "networks.md").write_text(markdown(agg, images))
    return len(agg), len(images)
