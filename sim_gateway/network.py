"""Several junctions of a route file's net, each signal-free under its own ICA, in one
process (``dica run --junctions``).

SUMO drives the file's vehicles between the junctions; each junction takes a
vehicle over in its region (:meth:`Traffic.adopt`), its ICA core plans the
crossing, and once the vehicle's rear is out SUMO's driver has it again until
the next junction's region. A vehicle is one junction's at a time. Each
junction confirms a crossing only if its exit lane will have room beyond it
(the downstream-space rule, :mod:`ica.core.dica`), so a queue from the next
junction backs up on the link and not into the one behind it. The other
junctions of the net stay as the net has them (their lights or priorities).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from dica.ica.core.controller import build_controller
from dica.ica.core.intersection import Intersection
from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.embedded import LocalDrivers, open_recording, record_step, request_figures
from dica.sim_gateway.route_file import check_handovers
from dica.sim_gateway.runconfig import RunConfig, RunError, RunResult
from dica.sim_gateway.sumo_io import import_libsumo, start_sumo
from dica.sim_gateway.world import World


def run_network(
    cfg: RunConfig,
    inters: Sequence[Intersection],
    progress: Callable[[float, int, int], None] | None = None,
    rrd_path: Path | None = None,
) -> RunResult:
    """Run the route file through ``inters``, each junction under its own ICA core.

    The recording, if asked for, shows the first junction's views.
    """
    if not cfg.routes_path:
        raise RunError("several junctions take their vehicles from a route file (--routes)")
    spec = cfg.controller_spec()
    for inter in inters:
        schedule_for(cfg, inter, spec.config.step_s)  # each approach checked before SUMO
    for line in check_handovers(inters, spec.config.kinematics):
        print(f"note: {line}", file=sys.stderr)
    icas = [build_controller(spec, inter) for inter in inters]
    for ica in icas:
        ica.prepare()
    _, _, horizon = schedule_for(cfg, inters[0], spec.config.step_s)
    if rrd_path is not None and len(inters) > 1:
        print(
            f"note: the recording shows junction {inters[0].junction_id}, the first of "
            f"{len(inters)}",
            file=sys.stderr,
        )
    ls = import_libsumo()
    cmd = start_sumo(ls, cfg, spec.config.step_s)
    try:
        recorder = open_recording(inters[0], rrd_path)
        world = World(
            ls, cfg, inters[0], spec.config, [], horizon, want_xy=bool(recorder),
            predict_s=cfg.plan_lead_s, more=tuple(inters[1:]),
        )  # fmt: skip
        drivers = [LocalDrivers(ica, cfg) for ica in icas]
        try:
            while True:
                each = world.step_each()
                for j, d, seen in zip(world.junctions, drivers, each, strict=True):
                    world.refresh_network_room(j, seen)
                    world.apply(d.step(world.t, seen), j)
                    world.counted_confirmed(j)
                if recorder is not None:
                    record_step(recorder, drivers[0], each[0], cfg, world.t)
                world.end_step(progress)
                if world.done():
                    break
        finally:
            if recorder is not None:
                recorder.close()
        result = world.result(merged_requests(drivers), cmd)
        if len(drivers) > 1:
            for j, d in zip(world.junctions, drivers, strict=True):
                result.extra["junctions"][j.inter.junction_id]["requests"] = d.requests()
        return result
    finally:
        ls.close()


def merged_requests(drivers: Sequence[LocalDrivers]) -> dict:
    """The run's requests over every junction's ICA: counts and rejections added, the
    request times' median and p99 over all of them."""
    if len(drivers) == 1:
        return drivers[0].requests()
    rejections: dict[str, int] = {}
    for d in drivers:
        for why, n in d.rejections.items():
            rejections[why] = rejections.get(why, 0) + n
    return request_figures([x for d in drivers for x in d.link.compute_s], rejections)
