"""A run's files: metrics.json, vehicles.csv, timeseries.csv and config.json."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

from sim_gateway.metrics import summarize_ev
from sim_gateway.runconfig import RunConfig, RunResult


def write_outputs(out: Path, cfg: RunConfig, result: RunResult, mode: str = "embedded") -> None:
    """Write everything a run produced; the same files in the embedded and cluster modes."""
    out.mkdir(parents=True, exist_ok=True)
    metrics = dict(result.metrics)
    metrics["collisions"] = result.safety["overlaps"]
    metrics["min_gap_m"] = result.safety["min_gap_m"]
    metrics["sumo_collisions"] = result.sumo_collisions
    metrics["requests"] = result.requests
    metrics["safety"] = result.safety
    metrics["sim_time_s"] = result.sim_time_s
    metrics["wall_s"] = result.wall_s
    metrics["real_time_factor"] = result.sim_time_s / result.wall_s if result.wall_s > 0 else None
    metrics["mode"] = mode
    metrics.update(result.extra)
    if cfg.ev_prob > 0:  # emergency vehicles and the others apart
        end = result.sim_time_s if cfg.until_left else cfg.duration_s
        metrics.update(summarize_ev(result.trips, end))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    config = {
        "mode": mode,
        "run": dataclasses.asdict(cfg),
        "sumo_command": result.sumo_command,
        "signal": result.signal,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2, default=list))
    # runs without emergency vehicles keep the file exactly as it was (no "ev" column)
    with_ev = cfg.ev_prob > 0
    with (out / "vehicles.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "vin",
                "route",
                "turn",
                "depart_s",
                "entered_s",
                "confirmed_s",
                "exited_s",
                "trip_time_s",
                "free_flow_s",
                "stopped",
            ]
            + (["ev"] if with_ev else [])
        )
        for tr in result.trips.trips.values():
            tau = tr.exited_s - tr.entered_s if tr.exited_s and tr.entered_s is not None else None
            w.writerow(
                [
                    tr.vin,
                    tr.route_id,
                    tr.turn,
                    f"{tr.depart_s:.2f}",
                    _f(tr.entered_s),
                    _f(tr.confirmed_s),
                    _f(tr.exited_s),
                    _f(tau),
                    _f(tr.free_flow_s),
                    int(tr.stopped),
                ]
                + ([int(tr.ev)] if with_ev else [])
            )
    with (out / "timeseries.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "waiting", "crossed", "generated", "flow_ratio"])
        log = result.trips
        for row in zip(log.t_s, log.waiting, log.crossed_cum, log.generated_cum, strict=True):
            ratio = f"{row[2] / row[3]:.4f}" if row[3] else ""
            w.writerow([f"{row[0]:.2f}", *row[1:], ratio])


def _f(x: float | None) -> str:
    return "" if x is None else f"{x:.3f}"
