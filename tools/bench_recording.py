"""Benchmark: what recording costs a run, and what it writes.

Runs the same ``dica run`` (default junction, volume 500, 600 s, one seed)
with and without ``--record``, alternating, ``--repeats`` times each, and
compares the medians of the loop's wall time (the "simulated in" figure, which
leaves out start-up that both share) and of the whole command. Prints the
ratio (the target is at most 1.5), the file's size and its number of chunks.
Figures on a shared machine move by 2x between runs; compare the ratio, which
is taken within one run.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dica.tools import options

ROOT = Path(__file__).resolve().parent.parent
LOOP = re.compile(r"simulated in ([0-9.]+) s")


def one_run(out: Path, record: bool, volume: int, duration_s: float) -> tuple[float, float]:
    """(loop seconds, whole command seconds) of one ``dica run``."""
    cmd = [sys.executable, "-m", "dica.tools.cli", "run", "--volume", str(volume)]
    cmd += ["--duration", str(duration_s), "--out", str(out)]
    if record:
        cmd.append("--record")
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=True)
    whole = time.perf_counter() - t0
    m = LOOP.search(p.stdout + p.stderr)
    if m is None:
        raise RuntimeError("dica run printed no 'simulated in' figure")
    return float(m.group(1)), whole


def main(argv: list[str] | None = None) -> int:
    ap = options.Parser(prog="bench_recording", description=__doc__.split("\n\n")[0])
    options.add(ap, "--volume", "--duration", volume=options.VOLUME_500)
    ap.add_argument("--repeats", type=int, default=3)
    args = options.parse(ap, argv)
    if args.repeats < 1 or args.duration <= 0:
        print("bench_recording: need --repeats >= 1 and --duration > 0", file=sys.stderr)
        return 2
    plain, rec = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            plain.append(one_run(Path(tmp) / f"p{i}", False, args.volume, args.duration))
            rec.append(one_run(Path(tmp) / f"r{i}", True, args.volume, args.duration))
        rrd = Path(tmp) / "r0" / "spacetime.rrd"
        size_mb = rrd.stat().st_size / 1e6
        from rerun.chunk import RrdReader

        n_chunks = sum(1 for _ in RrdReader(rrd).stream())
    p_loop, p_whole = np.median(plain, axis=0)
    r_loop, r_whole = np.median(rec, axis=0)
    print(f"dica run, {args.duration:g} s at volume {args.volume}, median of {args.repeats}:")
    print(f"  loop:  {p_loop:.1f} s plain, {r_loop:.1f} s with --record: {r_loop / p_loop:.2f}x")
    print(
        f"  whole: {p_whole:.1f} s plain, {r_whole:.1f} s with --record: {r_whole / p_whole:.2f}x"
    )
    print(f"  recording: {size_mb:.2f} MB in {n_chunks} chunks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
