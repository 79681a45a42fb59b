"""``dica view RUN_DIR``: open a run's Rerun recording in the desktop or the web viewer.

The ``rerun`` console script is a wrapper that starts the real viewer as a
child process, so the viewer is started in a process group of its own and
stopped as a group: a Ctrl-C or SIGTERM here never leaves a viewer (and its
web and gRPC ports) behind.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import FrameType
from urllib.parse import quote

from dica.tools import options

DESCRIPTION = """Open the Rerun recording (.rrd) of a run directory, or watch a run live.

Without --web, starts Rerun's desktop viewer on the recording. With --web,
serves the web viewer on 127.0.0.1 only (for a headless host: forward the
ports, e.g. ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876 HOST) and prints
the URL to open; Ctrl-C stops the viewer. Every .rrd directly in RUN_DIR is
opened (RUN_DIR may also be an .rrd file). With --live (no RUN_DIR), attaches
to an observer started with --live (run_cluster.sh --live) on
127.0.0.1:--grpc-port and shows the run as it happens; the observer writes the
same .rrd meanwhile. Exit status 2 when there is no recording to open."""

READY_TIMEOUT_S = 20.0  # [s] until the web viewer's port must accept connections
STOP_GRACE_S = 3.0  # [s] between SIGTERM and SIGKILL of the viewer's group


class ViewError(Exception):
    """Nothing to view, or no viewer to view it with; one line for a person (exit 2)."""


class ViewerFailed(Exception):
    """The viewer itself did not come up; one line for a person (exit 1)."""


def find_recordings(run_dir: Path) -> list[Path]:
    """The .rrd files of a run: RUN_DIR itself if it is one, else those directly in it."""
    if run_dir.is_file():
        if run_dir.suffix != ".rrd":
            raise ViewError(f"{run_dir} is not a .rrd recording")
        return [run_dir]
    if not run_dir.is_dir():
        raise ViewError(f"no run directory {run_dir}")
    found = sorted(p for p in run_dir.glob("*.rrd") if p.is_file())
    if not found:
        raise ViewError(f"no .rrd recording in {run_dir} (was the run recorded?)")
    return found


def rerun_binary() -> str:
    """The ``rerun`` next to this Python first, so the viewer matches the SDK that wrote."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file() and os.access(here, os.X_OK):
        return str(here)
    found = shutil.which("rerun")
    if found is None:
        raise ViewError("the rerun viewer was not found; install rerun-sdk (bash tools/setup.sh)")
    return found


def viewer_command(files: list[Path], web: bool, port: int, grpc_port: int) -> list[str]:
    cmd = [rerun_binary()]
    if web:
        cmd += [
            "--serve-web",
            "--bind",
            "127.0.0.1",
            "--web-viewer-port",
            str(port),
            "--port",
            str(grpc_port),
        ]
    return cmd + [str(f) for f in files]


def live_source(grpc_port: int) -> str:
    """Where a live observer serves its recording."""
    return f"rerun+http://127.0.0.1:{grpc_port}/proxy"


def web_url(port: int, grpc_port: int) -> str:
    return f"http://127.0.0.1:{port}/?url={quote(live_source(grpc_port), safe='')}"


def _port_open(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def stop_group(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM the viewer's whole process group, SIGKILL it if it lingers."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=STOP_GRACE_S)
    except ProcessLookupError:
        return
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(files: list[Path], web: bool, port: int, grpc_port: int, live: bool = False) -> int:
    """Start the viewer, wait for it to end or for Ctrl-C/SIGTERM, and stop its group.

    ``live``: the data comes from an observer's gRPC server on ``grpc_port``;
    the web viewer's own (empty) server then takes a free port.
    """
    if live and not _port_open(grpc_port):
        raise ViewError(
            f"nothing serves a live recording on 127.0.0.1:{grpc_port}; start the run "
            "with run_cluster.sh --live (or dica observer --live)"
        )
    own_grpc = free_port() if live else grpc_port
    if web:
        busy = [p for p in (port, own_grpc) if _port_open(p)]
        if busy:
            raise ViewError(f"port {busy[0]} on 127.0.0.1 is in use; choose another with --port")
    if live and web:  # the page connects to the observer itself (see web_url)
        cmd = viewer_command([], True, port, own_grpc)
    elif live:
        cmd = [rerun_binary(), live_source(grpc_port)]
    else:
        cmd = viewer_command(files, web, port, grpc_port)
    proc = subprocess.Popen(cmd, start_new_session=True)

    def on_term(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        if web:
            deadline = time.monotonic() + READY_TIMEOUT_S
            while not _port_open(port):
                if proc.poll() is not None:
                    raise ViewerFailed(f"the web viewer exited with status {proc.returncode}")
                if time.monotonic() > deadline:
                    raise ViewerFailed(f"the web viewer did not open port {port} in time")
                time.sleep(0.1)
            print(f"web viewer: {web_url(port, grpc_port)}  (Ctrl-C to stop)", flush=True)
        return proc.wait()
    except KeyboardInterrupt:
        return 130
    finally:
        stop_group(proc)
        signal.signal(signal.SIGTERM, previous)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "run_dir", type=Path, nargs="?", metavar="RUN_DIR", help="run directory (or an .rrd)"
    )
    p.add_argument("--web", action="store_true", help="serve the web viewer on 127.0.0.1")
    p.add_argument(
        "--live",
        action="store_true",
        help="watch a running observer (started with --live) instead of a file",
    )
    options.add(
        p, "--port", "--grpc-port",
        grpc_port={"help": "port the web viewer streams the recording from (with --web), or "
                   "the live observer's port (with --live); default 9876"},
    )  # fmt: skip


def main(args: argparse.Namespace) -> int:
    """Entry point for ``dica view``; raises ViewError (exit 2) or ViewerFailed (exit 1)."""
    if args.web and args.port == args.grpc_port:
        raise ViewError("--port and --grpc-port must differ")
    if args.live:
        if args.run_dir is not None:
            raise ViewError("--live watches a running observer; give no RUN_DIR with it")
        return run([], args.web, args.port, args.grpc_port, live=True)
    if args.run_dir is None:
        raise ViewError("give a RUN_DIR (or an .rrd), or --live")
    files = find_recordings(args.run_dir)
    return run(files, args.web, args.port, args.grpc_port)
