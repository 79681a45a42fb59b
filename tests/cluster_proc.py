"""Cluster runs from tests: stopping one that hangs, and showing why it hung."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path


def logs_tail(out: Path, lines: int = 20) -> str:
    """The last ``lines`` lines of each log under ``out/logs`` (a CI run keeps no files)."""
    logs = sorted((out / "logs").glob("*.log")) if (out / "logs").is_dir() else []
    if not logs:
        return f"(no logs under {out / 'logs'})"
    parts = []
    for log in logs:
        tail = log.read_text(errors="replace").splitlines()[-lines:]
        parts.append(f"--- {log.name} (last {len(tail)} lines)\n" + "\n".join(tail))
    return "\n".join(parts)


def stop_cluster(proc: subprocess.Popen, grace_s: float = 20.0) -> None:
    """Stop a ``run_cluster.sh`` still running (``start_new_session``). Each role runs
    in a process group of its own, so a SIGKILL of the script's group would leave them
    running, loading the machine for every later test: SIGTERM lets the script stop
    them all; its group is killed only if it has not ended after ``grace_s``."""
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.communicate(timeout=grace_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
