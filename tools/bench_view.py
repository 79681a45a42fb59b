"""Benchmark: size of a recording and the time Rerun's web viewer takes to show all of it.

Makes a 10-minute recording at volume 500 with ``dica run --record`` (or takes
``--rrd``), serves it with ``rerun --serve-web`` on 127.0.0.1 and opens it in
Debian's headless Chromium with software WebGL (``tools/install_chromium.sh``
installs it). "Shown" means: the viewer has the recording up to its last time
(read from the viewer's own state) and has drawn a frame. The clock starts when
the page is asked for, so it includes loading the viewer itself; an almost empty
recording is measured the same way in the same run, and the difference is the
cost of the data. ``--repeat N`` measures both N times, alternating, and gives
medians; every measurement is printed with the load average beside it, since
other work on the machine changes the figures up to 2x.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dica.tools import options

ROOT = Path(__file__).resolve().parent.parent


def shown_after_s(rrd: Path, timeout_s: float) -> float:
    """Seconds from opening the page until the whole recording is drawn."""
    from dica.tools.webshot import Browser, Viewer, last_time_ns, wait_loaded

    end = last_time_ns(rrd)
    with Viewer([rrd]) as viewer, Browser() as browser:
        t0 = time.monotonic()
        browser.open(viewer.url)
        wait_loaded(browser, end, timeout_s)
        return time.monotonic() - t0


def empty_recording(path: Path) -> Path:
    import rerun as rr

    rec = rr.RecordingStream("dica")
    rec.save(path)
    rec.set_time("sim_time", duration=1.0)
    rec.log("counts/vehicles", rr.Scalars(0.0))
    rec.disconnect()
    return path


def chunks(rrd: Path) -> int:
    from rerun.chunk import RrdReader

    return sum(1 for _ in RrdReader(rrd).stream())


def main(argv: list[str] | None = None) -> int:
    ap = options.Parser(prog="bench_view", description=__doc__.split("\n\n")[0])
    ap.add_argument("--rrd", type=Path, help="measure this recording instead of making one")
    options.add(ap, "--volume", "--duration", volume=options.VOLUME_500)
    ap.add_argument("--timeout", type=float, default=900.0, help="[s] before giving up")
    ap.add_argument(
        "--repeat", type=int, default=1, help="measurements of each recording, alternating"
    )
    args = options.parse(ap, argv)
    if args.rrd is not None and not args.rrd.is_file():
        print(f"bench_view: no recording {args.rrd}", file=sys.stderr)
        return 2
    if args.repeat < 1:
        print("bench_view: --repeat must be at least 1", file=sys.stderr)
        return 2
    subprocess.run(["bash", str(ROOT / "tools" / "install_chromium.sh")], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        rrd = args.rrd
        if rrd is None:
            out = Path(tmp) / "run"
            cmd = [sys.executable, "-m", "dica.tools.cli", "run", "--volume", str(args.volume)]
            cmd += ["--duration", str(args.duration), "--record", "--quiet", "--out", str(out)]
            subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
            rrd = out / "spacetime.rrd"
        empty = empty_recording(Path(tmp) / "empty.rrd")
        size_mb = rrd.stat().st_size / 1e6
        print(f"recording: {size_mb:.2f} MB in {chunks(rrd)} chunks", flush=True)
        bases, fulls = [], []
        for i in range(args.repeat):
            for name, path, got in (("empty", empty, bases), ("whole", rrd, fulls)):
                load = os.getloadavg()[0]
                got.append(shown_after_s(path, args.timeout))
                print(f"  {i + 1} {name}: {got[-1]:.1f} s (load average {load:.1f})", flush=True)
    base, full = statistics.median(bases), statistics.median(fulls)
    what = "median of " if args.repeat > 1 else ""
    print(f"web viewer, whole recording shown after {what}{full:.1f} s "
          f"(an empty recording: {base:.1f} s; the data: {full - base:.1f} s; "
          f"load average {os.getloadavg()[0]:.1f})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
