"""Several junctions of a route file's net, each signal-free under its own ICA, in one
process (``dica run --junctions``, ``dica network``), or the same junctions run by
lights and measured alike (the network baselines).

SUMO drives the file's vehicles between the junctions; each junction takes a
vehicle over in its region (:meth:`Traffic.adopt`), its ICA core plans the
crossing, and once the vehicle's rear is out SUMO's driver has it again until
the next junction's region. A vehicle is one junction's at a time. Each
junction confirms a crossing only if its exit lane will have room beyond it
(the downstream-space rule, :mod:`ica.core.dica`), so a queue from the next
junction backs up on the link and not into the one behind it, and the network
gate (:mod:`sim_gateway.network_gate`) lets vehicles into the links only while
no cycle of them can fill, so no cycle of full links stands still. The other
junctions of the net stay as the net has them (their lights or priorities).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from dica.ica.core.config import REACTIVE
from dica.ica.core.controller import build_controller
from dica.ica.core.gridlock import QUEUE_GAP_M
from dica.ica.core.intersection import Intersection
from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.embedded import (
    LocalDrivers,
    open_recording,
    record_step,
    request_figures,
)
from dica.sim_gateway.ev_corridor import EvCorridor
from dica.sim_gateway.light_control import CorridorPreemption, light_of
from dica.sim_gateway.max_pressure import MaxPressure
from dica.sim_gateway.network_trips import read_trips, summarize_trips
from dica.sim_gateway.route_file import check_handovers
from dica.sim_gateway.runconfig import RunConfig, RunError, RunResult
from dica.sim_gateway.sumo_io import import_libsumo, start_sumo
from dica.sim_gateway.world import World

if TYPE_CHECKING:
    from dica.sim_gateway.network_cluster import Cluster

LIGHT_CONTROLS = ("program", "max-pressure", "preempt")
NETWORK_RRD = "network.rrd"  # beside the junctions' recordings: the network from above


def run_network(
    cfg: RunConfig,
    inters: Sequence[Intersection],
    progress: Callable[[float, int, int], None] | None = None,
    rrd_path: Path | None = None,
    run_dir: Path | None = None,
    until_empty_after_s: float | None = None,
    lights: str | None = None,
    cluster: Cluster | None = None,
) -> RunResult:
    """Run the route file through ``inters``, each junction under its own ICA core, or
    by the net's lights, watched and measured alike: ``lights`` ``program`` runs them as
    the net (and the SUMO options' additional files) have them, ``max-pressure`` under
    :class:`~sim_gateway.max_pressure.MaxPressure`, ``preempt`` as the net has them with
    emergency-vehicle pre-emption at each (:class:`~sim_gateway.light_control.
    CorridorPreemption`).

    With ``run_dir`` SUMO's trip records go there (unless the SUMO options name a file
    of their own) and the result has the network's trips (``extra["network"]``,
    ``result.net_trips``). With ``until_empty_after_s`` the run ends early once that
    time is past and every vehicle has left. With ``rrd_path`` each junction is recorded
    with its own views (:func:`recording_path`). With ``cluster`` the junctions' ICAs
    and the vehicles' agents are processes reached over Zenoh
    (:mod:`sim_gateway.network_cluster`) instead of cores in this process.
    """
    if not cfg.routes_path:
        raise RunError("several junctions take their vehicles from a route file (--routes)")
    if lights not in (None, *LIGHT_CONTROLS):
        raise RunError(f"unknown light control {lights!r}; known: {', '.join(LIGHT_CONTROLS)}")
    light = lights is not None
    spec = cfg.controller_spec()
    for inter in inters:
        schedule_for(cfg, inter, spec.config.step_s)  # each approach checked before SUMO
    # refused here, said once SUMO has the vehicle types and the links are found long
    # enough for them (World)
    notes = [] if light else check_handovers(inters, spec.config.kinematics)
    icas = [] if light or cluster else [build_controller(spec, inter) for inter in inters]
    for ica in icas:
        ica.prepare()
    _, _, horizon = schedule_for(cfg, inters[0], spec.config.step_s)
    if cluster is not None:
        cluster.wait_for_peers()
    info = trip_file(cfg, run_dir)
    if info is not None and str(info) not in cfg.sumo_args:
        more = ("--tripinfo-output", str(info), "--tripinfo-output.write-unfinished", "true")
        cfg = replace(cfg, sumo_args=(*cfg.sumo_args, *more))
    ls = import_libsumo()
    cmd = start_sumo(ls, cfg, spec.config.step_s)
    closed = False
    try:
        recorders, top = [], None
        if rrd_path is not None and icas:
            recorders = [
                open_recording(x, recording_path(rrd_path, x, k), f"dica {x.junction_id}")
                for k, x in enumerate(inters)
            ]
            if len(inters) > 1:
                from dica.sim_gateway.recording.network_view import NetworkView

                top = NetworkView(ls, inters, rrd_path.with_name(NETWORK_RRD))
                top.geometry()
        world = World(
            ls, cfg, inters[0], spec.config, [], horizon,
            want_xy=bool(recorders) or cluster is not None,
            predict_s=cluster.predict_s if cluster else cfg.plan_lead_s,
            more=tuple(inters[1:]), signalised=light,
        )  # fmt: skip
        for line in notes:
            print(f"note: {line}", file=sys.stderr)
        gate = world.gate
        if gate is not None and gate.closes and gate.rule == "cycle":
            print(
                f"note: the network gate holds the queue on the {len(gate.links)} links between "
                f"the junctions to {gate.capacity_m:.0f} m (about "
                f"{gate.capacity_m / (5.0 + QUEUE_GAP_M):.0f} cars), their least cycle's capacity,"
                " so the network cannot lock; --no-network-gate lifts it",
                file=sys.stderr,
            )
        elif gate is not None and gate.closes:
            least = min(gate.room_cap_m.values())
            print(
                f"note: the network gate guards {len(gate.guarded)} of the {len(gate.links)} links"
                " between the junctions (every cycle of links passes one): a vehicle is let in "
                "only with room on those its route takes (the least holds "
                f"{least:.0f} m, about {least / (5.0 + QUEUE_GAP_M):.0f} cars), so the network "
                "cannot lock; --no-network-gate lifts it",
                file=sys.stderr,
            )
        drivers = [LocalDrivers(ica, cfg) for ica in icas]
        # EVs tell the junctions ahead of them that they are coming (reactive DICA's)
        corridor, by_junction = None, {}
        if spec.algorithm in REACTIVE and cfg.ev_notices and not light:
            corridor = EvCorridor(ls, inters, spec.config.step_s)
            # who takes each junction's notices: its core in process, or its ICA over Zenoh
            takers = cluster.drivers if cluster is not None else icas
            by_junction = {
                j.inter.junction_id: x for j, x in zip(world.junctions, takers, strict=True)
            }
        if world.walkers is not None and (cluster is not None or light):
            raise RunError(
                "--peds in a network runs embedded and signal-free for now (dica run "
                "--junctions ...), not over a cluster or under lights"
            )
        for d in drivers[: len(recorders)]:
            d.walks = []  # the walkers' slots, for each junction's recording
        pressure = None
        if lights == "max-pressure":
            ids = dict.fromkeys(light_of(ls, x) for x in inters)
            pressure = MaxPressure(ls, ids)
        elif lights == "preempt":
            pressure = CorridorPreemption(ls, list(dict.fromkeys(light_of(ls, x) for x in inters)))
        try:
            while True:
                if pressure is not None:
                    pressure.step(world.t)
                each = world.step_each()
                if corridor is not None and corridor.due():  # before the step's requests
                    for jid, notice in corridor.notices(world.t):
                        by_junction[jid].ev_coming(notice, world.t)
                if cluster is not None:
                    cluster.decide(world, each)
                if world.walkers is not None:  # the roadside asks first, each its own ICA
                    for j, d in zip(world.junctions, drivers, strict=True):
                        d.walk(world.walkers, world.t, j.inter.junction_id)
                for j, d, seen in zip(world.junctions, drivers, each, strict=False):
                    world.refresh_network_room(j, seen)
                    world.apply(d.step(world.t, seen), j)
                    world.counted_confirmed(j)
                for rec, d, seen in zip(recorders, drivers, each, strict=False):
                    record_step(rec, d, seen, cfg, world.t, world.walkers)
                if top is not None:
                    top.step(world.t, world.junctions, drivers, world.walkers)
                world.end_step(progress)
                if world.done() or world.emptied(until_empty_after_s):
                    break
                if cluster is not None:
                    cluster.checkpoint(world, cmd)
        except BaseException as e:
            if cluster is not None:
                cluster.stopped(world, cmd, e)
            raise
        finally:
            for rec in recorders:
                rec.close()
            if top is not None:
                top.close()
        # a cluster's ICAs are processes of their own: they keep the request figures
        result = world.result({} if cluster else merged_requests(drivers), cmd)
        if cluster is not None:
            cluster.finish(world, result)
        if isinstance(pressure, MaxPressure):
            result.extra["max_pressure_switches"] = pressure.switches
        elif pressure is not None:
            result.extra["preemption"] = pressure.summary()
        if len(drivers) > 1:
            for j, d in zip(world.junctions, drivers, strict=True):
                result.extra["junctions"][j.inter.junction_id]["requests"] = d.requests()
        for j, ica in zip(world.junctions, icas, strict=False):
            summary = ica.summary()  # reactive DICA's, per junction (None: another)
            if summary is not None and len(icas) > 1:
                result.extra["junctions"][j.inter.junction_id]["reactive"] = summary
            elif summary is not None:
                result.extra["reactive"] = summary
        waiting = world.waiting_ids()
        scheduled = dict(world.hold.scheduled) if world.hold is not None else {}
        end = world.t
        vt = ls.vehicletype
        ev_types = {x for x in vt.getIDList() if vt.getVehicleClass(x) == "emergency"}
        ls.close()
        closed = True
        if info is not None:  # SUMO writes the unfinished trips as it closes
            trips = read_trips(info, scheduled, end, ev_types, waiting)
            result.net_trips = trips
            result.extra["network"] = summarize_trips(trips, len(waiting))
        return result
    finally:
        if not closed:
            ls.close()


def recording_path(rrd_path: Path, inter: Intersection, k: int) -> Path:
    """Where junction ``k``'s recording goes: the first at ``rrd_path``, each other beside
    it as ``<stem>-<junction>.rrd`` (``dica view`` opens them all, one recording each); a
    junction id's ``/`` (SUMO allows it) written ``%2F``."""
    if k == 0:
        return rrd_path
    name = inter.junction_id.replace("%", "%25").replace("/", "%2F")
    return rrd_path.with_name(f"{rrd_path.stem}-{name}{rrd_path.suffix}")


def trip_file(cfg: RunConfig, run_dir: Path | None) -> Path | None:
    """Where SUMO writes its trip records: the file the SUMO options name, else
    ``tripinfo.xml`` in ``run_dir`` (None: neither)."""
    args = list(cfg.sumo_args)
    for flag in ("--tripinfo-output", "--tripinfo"):
        if flag in args[:-1]:
            return Path(args[args.index(flag) + 1])
    return None if run_dir is None else Path(run_dir) / "tripinfo.xml"


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
