"""The report of a mixed-traffic grid (``dica experiment --cav-shares ...``): per vehicle
volume and share of connected vehicles, DICA's mean delay from the scheduled arrival
beside the lights' and the all-way stop's, the safety counts and the human drivers'
audit, and the share at which DICA's delay drops below the better light's, as a
Markdown table (mixed.md) and a plot (mixed.png) beside the runs.

    python -m dica.tools.mixed_report runs/mixed

Reads ``OUT/<layout>/<algorithm>/c<share>/v<volume>/s<seed>/metrics.json``. The lights
serve everyone alike, but their drivers are the same mix (SUMO's imperfect drivers for
the human share), so each share is compared with the lights at that share when they
were run at it, else with the lights at the nearest share run.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

DICA = "enhanced"
LIGHTS = ("actuated", "fixed")
STOP = "allway-stop"


def _runs(root: Path) -> dict[tuple[str, float, float], list[dict]]:
    """Per (algorithm, share, volume), the metrics of each seed."""
    out: dict[tuple[str, float, float], list[dict]] = defaultdict(list)
    for path in sorted(root.glob("*/*/c*/v*/s*/metrics.json")):
        cell = path.parent
        alg, share, vol = cell.parents[2].name, cell.parents[1].name, cell.parent.name
        try:
            key = (alg, float(share[1:]), float(vol[1:]))
        except ValueError:
            continue  # a ramp or another grid's cell
        out[key].append(json.loads(path.read_text()))
    return out


def _mean(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def _f(x: float | None, digits: int = 1) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _cell(ms: list[dict]) -> dict:
    """Means over the seeds of one cell, sums of the safety counts."""
    hum = [m["humans"] for m in ms if m.get("humans")]
    by = [m.get("by_driver") or {} for m in ms]
    return {
        "seeds": len(ms),
        "delay_s": _mean([m.get("mean_system_delay_s") for m in ms]),
        "human_delay_s": _mean([b.get("human", {}).get("mean_system_delay_s") for b in by]),
        "connected_delay_s": _mean([b.get("connected", {}).get("mean_system_delay_s") for b in by]),
        "throughput": _mean([m.get("throughput") for m in ms]),
        "collisions": sum(m["collisions"] + m["sumo_collisions"] for m in ms),
        "on_red": sum(h["entered_on_red"] for h in hum),
        "outside": sum(h["outside_envelope"] for h in hum),
        "wait_s": _mean([h.get("mean_wait_for_green_s") for h in hum]),
        "max_wait_s": max((h.get("max_wait_for_green_s") or 0.0 for h in hum), default=None),
        # the share of human drivers given their green rolling towards the line
        "rolled": (
            sum(h.get("rolling_greens", 0) for h in hum) / n
            if (n := sum(h["count"] for h in hum))
            else None
        ),
    }


def table(runs: dict[tuple[str, float, float], list[dict]]) -> dict:
    """Every cell, per algorithm, share and volume."""
    return {key: _cell(ms) for key, ms in runs.items()}


def _nearest(cells: dict, alg: str, share: float, vol: float) -> dict | None:
    got = [(abs(s - share), s) for (a, s, v) in cells if a == alg and v == vol]
    if not got:
        return None
    return cells[(alg, min(got)[1], vol)]


def best_light(cells: dict, share: float, vol: float) -> tuple[str, float] | None:
    """The better light at ``share`` (or the nearest share run) and its delay."""
    got = []
    for light in LIGHTS:
        c = _nearest(cells, light, share, vol)
        if c is not None and c["delay_s"] is not None:
            got.append((c["delay_s"], light))
    if not got:
        return None
    d, light = min(got)
    return light, d


def _below(cells: dict, vol: float) -> list[tuple[float, float]]:
    """Per share run at ``vol``: (share, DICA's delay less the better light's)."""
    shares = sorted(s for (a, s, v) in cells if a == DICA and v == vol)
    diff = []
    for s in shares:
        light = best_light(cells, s, vol)
        d = cells[(DICA, s, vol)]["delay_s"]
        if light is not None and d is not None:
            diff.append((s, d - light[1]))
    return diff


def crossover(cells: dict, vol: float) -> float | None:
    """The share from which on DICA's delay stays below the better light's at every
    share run, linear between the last share where it is not and the next (the lowest
    share if it is below at every one; None if it is not below at the highest)."""
    diff = _below(cells, vol)
    if not diff or diff[-1][1] >= 0.0:
        return None
    last = max((i for i, (_, x) in enumerate(diff) if x >= 0.0), default=None)
    if last is None:
        return diff[0][0]
    (s0, x0), (s, x) = diff[last], diff[last + 1]
    return s0 + (s - s0) * x0 / (x0 - x)


def below_before(cells: dict, vol: float) -> list[float]:
    """The shares below the :func:`crossover` at which DICA was below the better light
    all the same (the line is not monotone there)."""
    x = crossover(cells, vol)
    return [s for s, d in _below(cells, vol) if d < 0.0 and (x is None or s < x)]


def markdown(cells: dict) -> str:
    vols = sorted({v for (_, _, v) in cells})
    shares = sorted({s for (a, s, _) in cells if a == DICA})
    out = [
        "| veh/10 min | share connected | seeds | DICA delay [s] | humans / connected [s] | "
        "standing humans' wait for green mean / max [s] | humans given green rolling | "
        "actuated [s] | fixed [s] | all-way stop [s] | "
        "DICA throughput | collisions | on red / outside envelope |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in vols:
        stop = _nearest(cells, STOP, 0.0, v)
        for s in shares:
            c = cells.get((DICA, s, v))
            if c is None:
                continue
            act, fix = _nearest(cells, "actuated", s, v), _nearest(cells, "fixed", s, v)
            out.append(
                f"| {v:g} | {s:g} | {c['seeds']} | {_f(c['delay_s'])} | "
                f"{_f(c['human_delay_s'])} / {_f(c['connected_delay_s'])} | "
                f"{_f(c['wait_s'])} / {_f(c['max_wait_s'])} | {_f(c['rolled'], 2)} | "
                f"{_f(act and act['delay_s'])} | {_f(fix and fix['delay_s'])} | "
                f"{_f(stop and stop['delay_s']) if s == 0.0 else ''} | "
                f"{_f(c['throughput'], 3)} | {c['collisions']} | {c['on_red']} / {c['outside']} |"
            )
    out += ["", "| veh/10 min | share at which DICA's delay drops below the better light's |",
            "|---|---|"]  # fmt: skip
    for v in vols:
        x = crossover(cells, v)
        text = "not within the shares run" if x is None else f"{x:.2f}"
        also = below_before(cells, v)
        if also:
            text += f" (below it at {', '.join(f'{s:g}' for s in also)} as well)"
        out.append(f"| {v:g} | {text} |")
    others = [
        (a, v, c)
        for (a, s, v), c in sorted(cells.items())
        if a != DICA and c["collisions"]  # the lights' and the stop's own collisions
    ]
    for a, v, c in others:
        out.append(f"\n{a} at {v:g}/10 min: {c['collisions']} collisions over its seeds")
    return "\n".join(out) + "\n"


def plot(cells: dict, path: Path) -> None:
    """DICA's delay against the share of connected vehicles, a panel per volume, with
    the lights' and the all-way stop's for scale and the crossover marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vols = sorted({v for (a, _, v) in cells if a == DICA})
    fig, axes = plt.subplots(1, len(vols), figsize=(3.3 * len(vols), 3.6), squeeze=False)
    for ax, v in zip(axes[0], vols, strict=True):
        for alg, style in ((DICA, "o-"), ("actuated", "s--"), ("fixed", "^:")):
            pts = sorted((s, c["delay_s"]) for (a, s, vv), c in cells.items()
                         if a == alg and vv == v and c["delay_s"] is not None)  # fmt: skip
            if pts:
                ax.plot(*zip(*pts, strict=True), style, label="DICA" if alg == DICA else alg)
        stop = _nearest(cells, STOP, 0.0, v)
        if stop is not None and stop["delay_s"] is not None:
            ax.plot([0.0], [stop["delay_s"]], "kx", markersize=9, label="all-way stop")
        x = crossover(cells, v)
        if x is not None:
            ax.axvline(x, color="grey", linewidth=0.8)
            ax.text(x, ax.get_ylim()[1] * 0.9, f" {x:.2f}", color="grey", fontsize=8)
        ax.set_yscale("log")
        ax.set(title=f"{v:g} veh / 10 min", xlabel="share of connected vehicles")
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("mean delay from scheduled arrival [s]")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mixed_report", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="the grid directory of dica experiment --cav-shares")
    args = ap.parse_args(argv)
    if not args.out.is_dir():
        print(f"mixed_report: {args.out} is not a directory", file=sys.stderr)
        return 2
    cells = table(_runs(args.out))
    if not any(a == DICA for (a, _, _) in cells):
        print(f"mixed_report: no finished {DICA} runs with shares in {args.out}", file=sys.stderr)
        return 2
    text = markdown(cells)
    (args.out / "mixed.md").write_text(text)
    plot(cells, args.out / "mixed.png")
    print(text)
    print(f"mixed_report: {args.out / 'mixed.md'}, {args.out / 'mixed.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
