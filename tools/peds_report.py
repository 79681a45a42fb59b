"""The report of `tools/peds.sh`: vehicle delay and people's waits per control, vehicle
volume and pedestrian volume, over the seeds run, as a Markdown table (peds.md) and a
plot (peds.png) beside the runs.

    python -m dica.tools.peds_report runs/peds
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

CONTROLS = ("enhanced", "actuated", "fixed")


def _runs(root: Path) -> dict[tuple[str, int, int], list[dict]]:
    """Per (control, vehicles per 10 min, people an hour), the metrics of each seed."""
    out: dict[tuple[str, int, int], list[dict]] = defaultdict(list)
    for path in sorted(root.glob("*-v*-p*-s*/metrics.json")):
        if path.parent.name.endswith(".tmp"):  # not finished (peds.sh renames it when done)
            continue
        control, v, p, _s = path.parent.name.rsplit("-", 3)
        out[(control, int(v[1:]), int(p[1:]))].append(json.loads(path.read_text()))
    return out


def _mean(xs: list[float | None]) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def _f(x: float | None, digits: int = 1) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def rows(runs: dict[tuple[str, int, int], list[dict]]) -> list[dict]:
    """One row per (control, volume, people): means over the seeds, worst cases over all."""
    table = []
    for (control, v, p), ms in sorted(runs.items(), key=lambda kv: (kv[0][1], kv[0][2], kv[0][0])):
        walkers = [m.get("walkers") for m in ms if m.get("walkers")]
        table.append(
            {
                "control": control,
                "volume": v,
                "peds": p,
                "seeds": len(ms),
                "delay_s": _mean([m.get("mean_delay_s") for m in ms]),
                "crossed": sum(m["crossed"] for m in ms),
                "generated": sum(m["generated"] for m in ms),
                "wait_s": _mean([w["mean_wait_s"] for w in walkers]),
                "max_wait_s": max((w["max_wait_s"] or 0.0 for w in walkers), default=None),
                # the ICA's part of it: its ask to the start it gave (none under a light)
                "max_go_s": max(
                    (w["max_ask_to_go_s"] for w in walkers if w.get("max_ask_to_go_s") is not None),
                    default=None,
                ),
                "people": sum(w["generated"] for w in walkers),
                "people_crossed": sum(w["crossed"] for w in walkers),
                "vehicle_hits": sum(m["collisions"] + m["sumo_collisions"] for m in ms),
                "person_hits": sum(w["person_hits"] for w in walkers),
                "sumo_person": sum(w["sumo_person_collisions"] for w in walkers),
            }
        )
    return table


def _longest(r: dict) -> str:
    """The longest wait at the kerb, and in brackets the ICA's part of it (its bound)."""
    go = r.get("max_go_s")
    return _f(r["max_wait_s"]) + ("" if go is None else f" ({go:.1f})")


def markdown(table: list[dict]) -> str:
    head = (
        "| control | veh/10 min | people/h a crossing | seeds | vehicle delay [s] | "
        "vehicles crossed | people wait [s] | longest wait (ask to go) [s] | people crossed | "
        "vehicle-vehicle | vehicle-person (check / SUMO) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['control']} | {r['volume']} | {r['peds']} | {r['seeds']} | {_f(r['delay_s'])} | "
        f"{r['crossed']}/{r['generated']} | {_f(r['wait_s'])} | {_longest(r)} | "
        f"{r['people_crossed']}/{r['people']} | {r['vehicle_hits']} | "
        f"{r['person_hits']} / {r['sumo_person']} |"
        for r in table
    ]
    return head + "\n".join(lines) + "\n"


def plot(table: list[dict], path: Path) -> None:
    """Vehicle delay and people's wait against people an hour, a line per control and
    vehicle volume."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    volumes = sorted({r["volume"] for r in table})
    styles = {"enhanced": "-", "actuated": "--", "fixed": ":"}
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, v in enumerate(volumes):
        for control in CONTROLS:
            pts = sorted(
                (r["peds"], r) for r in table if r["volume"] == v and r["control"] == control
            )
            if not pts:
                continue
            x = [p for p, _ in pts]
            label = f"{control} {v}/10 min"
            kw = {"color": colours[i % len(colours)], "linestyle": styles[control], "marker": "o"}
            a.plot(x, [r["delay_s"] for _, r in pts], label=label, **kw)
            wx = [p for p, r in pts if r["wait_s"] is not None]
            b.plot(wx, [r["wait_s"] for p, r in pts if r["wait_s"] is not None], label=label, **kw)
    a.set(xlabel="people an hour at each crossing", ylabel="vehicle mean delay [s]")
    b.set(xlabel="people an hour at each crossing", ylabel="people's mean wait at the kerb [s]")
    a.set_title("vehicles")
    b.set_title("people on foot")
    b.legend(fontsize=7, ncol=1, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="peds_report", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="the directory tools/peds.sh wrote")
    args = ap.parse_args(argv)
    runs = _runs(args.out)
    if not runs:
        print(f"peds_report: no finished runs in {args.out}", file=sys.stderr)
        return 2
    table = rows(runs)
    text = markdown(table)
    (args.out / "peds.md").write_text(text)
    plot(table, args.out / "peds.png")
    print(text)
    print(f"peds_report: {args.out / 'peds.md'}, {args.out / 'peds.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
