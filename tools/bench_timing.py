"""``dica bench timing``: the real-time cluster under imperfect links, swept.

Each point is one real-time run of the whole cluster (tools/run_cluster.sh) with
the link emulator between every role and the router, at one fault profile:
one-way delay with jitter, loss, duplication and reordering of Zenoh data.
For each it reports safety (overlaps by the independent monitor, SUMO's
collisions, unconfirmed entries, vehicles lost), throughput, trip time, plan
adherence (actual minus planned entry time), the plans that came too late to
be flown, and the agents' unanswered queries; as a table, a JSON file and a
plot, and with ``--write`` into BENCHMARKS.md between its timing markers.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from dica.tools import options

ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = "<!-- timing:begin -->", "<!-- timing:end -->"


@dataclass(frozen=True, slots=True)
class Profile:
    name: str
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0
    dup: float = 0.0
    reorder: float = 0.0

    def args(self) -> list[str]:
        out = ["--delay", f"{self.delay_ms:g}", "--jitter", f"{self.jitter_ms:g}"]
        out += ["--loss", f"{self.loss:g}", "--dup", f"{self.dup:g}"]
        return [*out, "--reorder", f"{self.reorder:g}"]


SWEEP = (
    Profile("none"),
    Profile("50 ms", 50, 25),
    Profile("100 ms", 100, 50),
    Profile("200 ms", 200, 100),
    Profile("300 ms", 300, 150),
    Profile("100 ms, 10 % loss", 100, 50, 0.10),
    Profile("200 ms, 20 % loss", 200, 100, 0.20),
    Profile("100 ms, 30 % loss", 100, 50, 0.30),
    Profile("300 ms, 30 % loss, 5 % dup+reorder", 300, 150, 0.30, 0.05, 0.05),
)
WORST = SWEEP[-1]


def run_point(p: Profile, seed: int, args: argparse.Namespace, out: Path) -> dict:
    d = out / f"{p.name.replace(' ', '').replace(',', '_').replace('%', 'pc')}-s{seed}"
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(d), "--no-record"]
    cmd += ["--clock", "realtime", "--speed", f"{args.speed:g}", "--agents", str(args.agents)]
    cmd += ["--volume", f"{args.volume:g}", "--duration", f"{args.duration:g}", "--seed", str(seed)]
    cmd += p.args() if p.name != "none" else []
    if args.cav_share < 1.0:
        cmd += ["--cav-share", f"{args.cav_share:g}"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    row: dict = {"profile": p.name, "seed": seed, **asdict(p), "wall_s": time.perf_counter() - t0}
    try:
        m = json.loads((d / "metrics.json").read_text())
    except (OSError, ValueError):
        row["error"] = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no metrics"]
        return row
    t = m.get("timing", {})
    agents = (m.get("roles") or {}).get("agents") or {}
    queries = sum(a.get("queries", 0) for a in agents.values())
    row.update(
        exit=proc.returncode,
        complete=m.get("complete"),
        overlaps=m["collisions"],
        sumo_collisions=m["sumo_collisions"],
        unconfirmed=m.get("unconfirmed_entries"),
        lost=(m.get("accounted") or {}).get("lost"),
        generated=m["generated"],
        crossed=m["crossed"],
        throughput=m["throughput"],
        mean_trip_s=m["mean_trip_time_s"],
        adherence_p99_s=t.get("entry_adherence_p99_s"),
        plans_accepted=t.get("plans_accepted"),
        plans_refused=t.get("plans_refused"),
        unanswered=(sum(a.get("no_answer", 0) for a in agents.values()) / queries)
        if queries
        else None,
        lead_s=max((a.get("lead_s", 0.0) for a in agents.values()), default=None),
        command_age_p99_ms=(m.get("command_age_ms") or {}).get("p99"),
        # the pace kept: sim seconds a wall second over the speed asked (1: it kept up)
        pace=m["sim_time_s"] / m["wall_s"] / args.speed if m.get("wall_s") else None,
    )
    h = m.get("humans")
    if h is not None:  # human drivers: the audit, and their greens dropped late
        row.update(
            humans=h["count"],
            greens=h["given_green"],
            humans_outside=h["outside_envelope"],
            humans_on_red=h["entered_on_red"],
            greens_dropped=m.get("greens_dropped_late"),
        )
    return row


def table(rows: list[dict]) -> str:
    humans = any("humans" in r for r in rows)
    head = (
        "| profile | seed | overlaps / SUMO / unconfirmed / lost | crossed / generated | "
        "mean trip (s) | adherence p99 (s) | plans refused | queries unanswered | lead (s) |"
        + (" pace kept | humans: greens (dropped late), outside / on red |" if humans else "")
    )
    lines = [head, "|" + "---|" * (11 if humans else 9)]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['profile']} | {r['seed']} | run failed: {r['error'][0]} |||||||")
            continue
        safety = f"{r['overlaps']} / {r['sumo_collisions']} / {r['unconfirmed']} / {r['lost']}"
        unans = f"{100 * r['unanswered']:.0f} %" if r["unanswered"] is not None else "n/a"
        adh = r["adherence_p99_s"]
        lines.append(
            f"| {r['profile']} | {r['seed']} | {safety} | {r['crossed']} / {r['generated']} "
            f"({r['throughput']:.2f}) | {_n(r['mean_trip_s'])} | "
            f"{'n/a' if adh is None else f'{adh:.3f}'} | "
            f"{r['plans_refused']} of {r['plans_accepted'] + r['plans_refused']} | {unans} | "
            f"{_n(r['lead_s'])} |"
            + (
                f" {_n(r['pace'])} | {r['greens']} of {r['humans']} ({r['greens_dropped']}), "
                f"{r['humans_outside']} / {r['humans_on_red']} |"
                if humans and "humans" in r
                else ""
            )
        )
    return "\n".join(lines)


def _n(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if "error" not in r]
    names = list(dict.fromkeys(r["profile"] for r in ok))
    x = range(len(names))

    def series(key: str) -> list[float]:
        out = []
        for n in names:
            vals = [r[key] for r in ok if r["profile"] == n and r[key] is not None]
            out.append(sum(vals) / len(vals) if vals else float("nan"))
        return out

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    panels = [
        ("collisions (overlaps + SUMO + unconfirmed entries)", None),
        ("throughput (crossed / generated)", "throughput"),
        ("mean trip time [s]", "mean_trip_s"),
        ("plan adherence, p99 |actual - planned entry| [s]", "adherence_p99_s"),
    ]
    for ax, (title, key) in zip(axes.flat, panels, strict=True):
        if key is None:
            vals = [
                sum(
                    r["overlaps"] + r["sumo_collisions"] + (r["unconfirmed"] or 0)
                    for r in ok
                    if r["profile"] == n
                )
                for n in names
            ]
            ax.bar(x, vals, color="#c0392b")
            ax.set_ylim(0, max(1, max(vals, default=0) * 1.2))
            for i, v in enumerate(vals):  # a zero bar is invisible: say it
                ax.annotate(f"{v:g}", (i, v), ha="center", va="bottom", fontsize=9)
        else:
            ys = series(key)
            ax.plot(list(x), ys, "o-", color="#2c3e50")
            # from zero, so that rounding noise or a small change does not look like a trend
            top = max([y for y in ys if y == y] + [0.0])
            ax.set_ylim(0, max(top * 1.15, 0.1 if key == "adherence_p99_s" else 1.0))
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xticks(list(x))
        ax.set_xticklabels(names, rotation=35, ha="right", fontsize=8)
    fig.suptitle("Real-time cluster under imperfect links (faults on every role's link)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_benchmarks(text: str) -> None:
    path = ROOT / "BENCHMARKS.md"
    doc = path.read_text()
    if BEGIN in doc and END in doc:
        rest = doc[doc.index(END) + len(END) :]
        doc = doc[: doc.index(BEGIN)] + BEGIN + "\n" + text + "\n" + END + rest
    else:
        doc = doc.rstrip() + "\n\n" + BEGIN + "\n" + text + "\n" + END + "\n"
    path.write_text(doc)


def main(argv: list[str] | None = None) -> int:
    p = options.Parser(
        prog="dica bench timing",
        description="Real-time cluster runs across fault profiles (delay with jitter, loss, "
        "duplication, reordering on every role's link): safety, throughput, trip time and "
        "plan adherence against the fault level. Takes about the runs' duration each, over "
        "--jobs at a time.",
    )
    options.add(
        p, "--duration", "--speed", "--volume", "--agents", "--json",
        duration={"default": 120.0, "help": "sim seconds per run (default 120)"},
        volume=options.VOLUME_500, agents={"default": 2, "help": "vehicle agents (default 2)"},
    )  # fmt: skip
    p.add_argument("--seeds", default="12", help="comma-separated seeds (default 12)")
    p.add_argument(
        "--profiles",
        default="sweep",
        help="sweep (the 9 profiles), worst (300 ms + 50 %% jitter, 30 %% loss, 5 %% dup and "
        "reorder), or names from the sweep separated by ';'",
    )
    p.add_argument("--jobs", type=int, default=2, help="runs at a time (default 2)")
    p.add_argument(
        "--cav-share",
        type=float,
        default=1.0,
        help="share of connected vehicles (default 1); below it, human drivers too, and the "
        "table adds the pace the run kept and the humans' audit",
    )
    options.add(
        p,
        "--out",
        out={
            "default": ROOT / "runs" / "bench-timing",
            "help": "where the runs go (default runs/bench-timing)",
        },
    )
    p.add_argument("--write", action="store_true", help="put the table and plot into BENCHMARKS.md")
    args = options.parse(p, argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s]
    except ValueError:
        print("dica bench timing: --seeds wants integers", file=sys.stderr)
        return 2
    if args.profiles == "sweep":
        profiles = list(SWEEP)
    elif args.profiles == "worst":
        profiles = [WORST]
    else:
        by_name = {q.name: q for q in SWEEP}
        names = [n.strip() for n in args.profiles.split(";") if n.strip()]
        unknown = [n for n in names if n not in by_name]
        if unknown:
            print(f"dica bench timing: unknown profile(s) {unknown}", file=sys.stderr)
            return 2
        profiles = [by_name[n] for n in names]
    if not (0 < args.speed <= 10 and 10 <= args.duration <= 7200 and 1 <= args.jobs <= 8):
        print(
            "dica bench timing: --speed in (0, 10], --duration 10-7200, --jobs 1-8", file=sys.stderr
        )
        return 2
    if not 0.0 <= args.cav_share <= 1.0:
        print("dica bench timing: --cav-share must be between 0 and 1", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    points = [(q, s) for q in profiles for s in seeds]
    from tqdm import tqdm

    with ThreadPoolExecutor(args.jobs) as pool, tqdm(total=len(points), unit="run") as bar:
        futures = [pool.submit(run_point, q, s, args, args.out) for q, s in points]
        rows = []
        for f in futures:
            rows.append(f.result())
            bar.update()
    (args.out / "timing.json").write_text(json.dumps(rows, indent=2))
    text = table(rows)
    print(json.dumps(rows, indent=2) if args.json else text)
    plot(rows, args.out / "timing.png")
    if args.write:
        img = ROOT / "docs" / "timing" / "timing.png"
        plot(rows, img)
        meta = (
            f"Real-time runs at speed {args.speed:g}, {args.duration:g} s each, volume "
            f"{args.volume:g}, {args.agents} agents, seeds {args.seeds}; faults on every role's "
            f"link; measured {time.strftime('%Y-%m-%d')} with `dica bench timing`.\n\n"
        )
        write_benchmarks(meta + text + "\n\n![timing sweep](docs/timing/timing.png)")
    bad = [r for r in rows if "error" in r or r["overlaps"] or r["sumo_collisions"]
           or r["unconfirmed"] or r["lost"]]  # fmt: skip
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
