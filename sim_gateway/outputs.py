"""A run's files: metrics.json, vehicles.csv, timeseries.csv and config.json (and
persons.csv with people on foot).

vehicles.csv times are seconds of simulation time: ``depart_s`` the scheduled
arrival at the region's entry line, ``inserted_s`` when SUMO placed the
vehicle upstream, ``entered_s`` when it crossed the entry line, ``exited_s``
when its rear left the junction; ``trip_time_s`` (the dissertation's tau)
counts from ``entered_s``, ``system_time_s`` and ``system_delay_s`` from
``depart_s`` (see :mod:`sim_gateway.metrics`).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any

from dica.sim_gateway.metrics import summarize_ev, summarize_mixed
from dica.sim_gateway.runconfig import RunConfig, RunResult

PERSON_COLUMNS = ("person", "depart_s", "crossing", "kerb_s", "go_s", "on_s", "off_s", "wait_s",
                  "speed_mps")  # fmt: skip


def write_outputs(
    out: Path,
    cfg: RunConfig,
    result: RunResult,
    mode: str = "embedded",
    incomplete: str | None = None,
) -> None:
    """Write everything a run produced; the same files in the embedded and cluster modes.

    ``incomplete`` says why the figures are not a finished run's (a checkpoint,
    a stop); each file is replaced atomically, so a crash mid-write leaves
    the previous version, never a torn or empty one.
    """
    out.mkdir(parents=True, exist_ok=True)
    metrics = dict(result.metrics)
    metrics["complete"] = incomplete is None
    if incomplete is not None:
        metrics["incomplete"] = incomplete
    metrics["collisions"] = result.safety["overlaps"]
    metrics["min_gap_m"] = result.safety["min_gap_m"]
    metrics["sumo_collisions"] = result.sumo_collisions
    metrics["requests"] = result.requests
    metrics["safety"] = result.safety
    metrics["sim_time_s"] = result.sim_time_s  # the clock at the end
    metrics["simulated_s"] = result.simulated_s  # the span run (from --begin)
    metrics["wall_s"] = result.wall_s
    metrics["real_time_factor"] = result.simulated_s / result.wall_s if result.wall_s > 0 else None
    metrics["mode"] = mode
    metrics.update(result.extra)
    # emergency vehicles and the others apart: drawn (--ev-prob) or a route file's
    with_ev = cfg.ev_prob > 0 or any(tr.ev for tr in result.trips.trips.values())
    if with_ev:
        end = result.sim_time_s if cfg.until_left else cfg.duration_s
        metrics.update(summarize_ev(result.trips, end))
    if cfg.cav_share < 1.0:  # human drivers and connected vehicles apart
        end = result.sim_time_s if cfg.until_left else cfg.duration_s
        metrics.update(summarize_mixed(result.trips, end))
    _atomic(out / "metrics.json", json.dumps(_strict(metrics), indent=2, allow_nan=False))
    config = {
        "mode": mode,
        "run": dataclasses.asdict(cfg),
        "sumo_command": result.sumo_command,
        "signal": result.signal,
    }
    _atomic(out / "config.json", json.dumps(config, indent=2, default=list))
    # runs without emergency vehicles keep the file exactly as it was (no "ev" column)
    mixed = cfg.cav_share < 1.0  # and those without human drivers keep it without "human"
    with _Replacing(out / "vehicles.csv") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "vin",
                "route",
                "turn",
                "depart_s",
                "inserted_s",
                "entered_s",
                "confirmed_s",
                "exited_s",
                "trip_time_s",
                "free_flow_s",
                "system_time_s",
                "system_delay_s",
                "stopped",
            ]
            + (["ev"] if with_ev else [])
            + (["human"] if mixed else [])
        )
        for tr in result.trips.trips.values():
            tau = tr.exited_s - tr.entered_s if tr.exited_s and tr.entered_s is not None else None
            w.writerow(
                [
                    tr.vin,
                    tr.route_id,
                    tr.turn,
                    f"{tr.depart_s:.2f}",
                    _f(tr.inserted_s),
                    _f(tr.entered_s),
                    _f(tr.confirmed_s),
                    _f(tr.exited_s),
                    _f(tau),
                    _f(tr.free_flow_s),
                    _f(tr.system_time_s),
                    _f(tr.system_delay_s),
                    int(tr.stopped),
                ]
                + ([int(tr.ev)] if with_ev else [])
                + ([int(tr.human)] if mixed else [])
            )
    if result.persons is not None:
        with _Replacing(out / "persons.csv") as fh:
            w = csv.DictWriter(fh, fieldnames=list(PERSON_COLUMNS))
            w.writeheader()
            w.writerows(result.persons)
    with _Replacing(out / "timeseries.csv") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "waiting", "crossed", "generated", "flow_ratio"])
        log = result.trips
        for row in zip(log.t_s, log.waiting, log.crossed_cum, log.generated_cum, strict=True):
            ratio = f"{row[2] / row[3]:.4f}" if row[3] else ""
            w.writerow([f"{row[0]:.2f}", *row[1:], ratio])


def _f(x: float | None) -> str:
    return "" if x is None else f"{x:.3f}"


def _strict(value: Any) -> Any:
    """``value`` with every NaN or infinity as null: JSON has neither, and readers other
    than Python's (jq, a browser's JSON.parse) refuse a file with them (the cluster's
    link figures are NaN where no message came)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    return value


def _atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class _Replacing:
    """A text file written beside ``path`` and moved over it only once complete."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tmp = path.with_name(path.name + ".tmp")

    def __enter__(self):
        self.fh = self.tmp.open("w", newline="")
        return self.fh

    def __exit__(self, exc_type, exc, tb) -> None:
        self.fh.close()
        if exc_type is None:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
