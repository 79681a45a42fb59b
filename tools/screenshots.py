"""Screenshots of every view of a recording, for docs/recording.md, made as a user sees them.

Runs ``dica run --record`` (the default junction, volume 500, 120 s), serves the
recording with ``rerun --serve-web`` on 127.0.0.1, opens it in Debian's headless
Chromium (installed by ``tools/install_chromium.sh`` when missing), moves the
time cursor to ``--at`` and saves the whole layout and then each view alone
(the viewer is sent a layout with only that view). Software rendering is slow:
the whole script takes a few minutes.

    .venv/bin/python -m tools.screenshots [--out docs/recording] [--at 80] [--rrd FILE]
"""

from __future__ import annotations

import io
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dica.tools import options

ROOT = Path(__file__).resolve().parent.parent
WIDTH_PX, HEIGHT_PX = 1600, 1000  # the browser window
DOC_WIDTH_PX = 1280  # the saved PNGs


def ensure_chromium() -> None:
    from shutil import which

    if which("chromium") and which("chromedriver"):
        return
    subprocess.run(["bash", str(ROOT / "tools" / "install_chromium.sh")], check=True)


def make_recording(out: Path, volume: int, duration_s: float, seed: int) -> Path:
    cmd = [sys.executable, "-m", "dica.tools.cli", "run", "--volume", str(volume)]
    cmd += ["--duration", str(duration_s), "--seed", str(seed), "--record", "--quiet"]
    cmd += ["--out", str(out)]
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return out / "spacetime.rrd"


def save_png(png: bytes, path: Path) -> None:
    """Scaled to DOC_WIDTH_PX and reduced to 256 colours: small files for the docs."""
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("RGB")
    h = round(img.height * DOC_WIDTH_PX / img.width)
    img = img.resize((DOC_WIDTH_PX, h), Image.LANCZOS).quantize(colors=256, dither=0)
    img.save(path, optimize=True)


def layouts(rrd_dir: Path):
    """The recorder's own views, each alone, plus the lane charts together."""
    import rerun.blueprint as rrb

    from dica.ica.netfile import load_intersection
    from dica.sim_gateway.recording import SpaceTimeRecorder, approach_of
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    with SpaceTimeRecorder(inter, rrd_dir / "layout.rrd") as rec:
        v = rec.views()
        lanes = sorted(rec.lanes, key=lambda ln: (ln.rsplit("_", 1)[1], ln))
        n_cols = len({approach_of(ln) for ln in lanes})

    def alone(*views, **kw) -> rrb.Blueprint:
        body = views[0] if len(views) == 1 else rrb.Horizontal(*views, **kw)
        return rrb.Blueprint(
            body,
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed"),
        )

    return {
        "top-view": alone(v["top"]),
        "lane-charts": alone(rrb.Grid(*(v[ln] for ln in lanes), grid_columns=n_cols)),
        "lane-chart": alone(v["N_in_1"] if "N_in_1" in v else v[lanes[0]]),
        "conflict-points": alone(v["zones"]),
        "tables": alone(
            v["counts"], v["confirmed"], v["rejected"], v["reorders"], column_shares=[2, 4, 3, 3]
        ),
    }


def settled(browser, before: bytes, timeout_s: float = 60.0) -> bytes:
    """The window once it differs from ``before`` and two pictures 2 s apart agree:
    the viewer has taken the new layout and drawn it."""
    deadline = time.monotonic() + timeout_s
    prev = browser.screenshot()
    while time.monotonic() < deadline:
        time.sleep(2.0)
        shot = browser.screenshot()
        if shot == prev and shot != before:
            return shot
        prev = shot
    return prev


def main(argv: list[str] | None = None) -> int:
    ap = options.Parser(prog="screenshots", description=__doc__.split("\n\n")[0])
    options.add(
        ap,
        "--out",
        out={
            "default": ROOT / "docs" / "recording",
            "help": "where the PNGs go (default docs/recording)",
        },
    )
    ap.add_argument("--at", type=float, default=80.0, help="sim time of the pictures [s]")
    ap.add_argument("--rrd", type=Path, help="use this recording instead of making one")
    ap.add_argument("--timeout", type=float, default=600.0, help="[s] for the viewer to load")
    args = options.parse(ap, argv)
    if args.at <= 0:
        print("screenshots: --at must be positive", file=sys.stderr)
        return 2
    ensure_chromium()
    from dica.tools.webshot import (
        Browser,
        Viewer,
        last_time_ns,
        set_time,
        show_blueprint,
        wait_loaded,
    )

    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        rrd = args.rrd or make_recording(Path(tmp) / "run", 500, max(120.0, args.at + 20), 12)
        pictures = layouts(Path(tmp))
        with Viewer([rrd]) as viewer, Browser(WIDTH_PX, HEIGHT_PX) as browser:
            browser.open(viewer.url)
            took = wait_loaded(browser, last_time_ns(rrd), args.timeout)
            print(f"screenshots: the viewer showed the recording after {took:.0f} s", flush=True)
            set_time(browser, args.at)
            browser.move_to(WIDTH_PX // 2, 60)  # no tooltip over the time box
            last = settled(browser, b"")
            save_png(last, args.out / "overview.png")
            for name, bp in pictures.items():
                show_blueprint(viewer, rrd, bp)
                last = settled(browser, last)
                save_png(last, args.out / f"{name}.png")
                print(f"screenshots: {args.out / name}.png", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
