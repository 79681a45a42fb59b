"""The cluster's processes as `dica` subcommands: router, ica, agent, gateway, observer.

Each role is one process talking only through Zenoh; `tools/run_cluster.sh`
starts them together on one host, `docs/deploy.md` says how to run each on
its own host. Every role stops cleanly on SIGTERM or Ctrl-C (closing its
Zenoh session and flushing its files) and exits 0 at the end of the run
announced on the sim clock.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import NoReturn

from dica.tools import options
from dica.tools.args import (
    add_run_args,
    headway_s,
    intersection,
    intersections,
    report_run,
    run_config,
)
from dica.tools.options import UsageError

# the roles that place the lanes' lines: each must place them as the gateway does
ROUTES_HELP = (
    "the run's route file (give every role the gateway's): where its longest, widest "
    "vehicle type turning sweeps over the place a vehicle waits at a lane's line, that "
    "line moves back, for every role alike"
)


def _add_link_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--zenoh-config",
        type=Path,
        help="Zenoh JSON5 config (default deploy/zenoh/client.json5)",
    )
    p.add_argument(
        "--connect",
        help="router endpoint(s), comma-separated, e.g. tcp/10.0.0.2:7447 (replaces the config's)",
    )
    p.add_argument(
        "--keyring",
        type=Path,
        help="a secured site's keyring.json: act only on messages sealed by the one role "
        "that may write each key (see dica secure-config)",
    )
    p.add_argument(
        "--seal", type=Path, help="this role's signing key (NAME.seal): seal what it sends"
    )
    options.add(p, "--verbose")


def _session(args: argparse.Namespace, role: str, signer: str | None = None):
    """The role's logger and Zenoh session; on a secured site its seal and keyring first."""
    from dica.deploy.seal import SealError, load_guard
    from dica.deploy.transport import LinkError, open_session, setup_logging, use_guard

    log = setup_logging(role, args.verbose)
    try:
        use_guard(load_guard(signer or role, args.seal, args.keyring))
    except SealError as e:
        raise UsageError(str(e)) from None
    try:
        return open_session(args.zenoh_config, args.connect), log
    except LinkError as e:
        raise UsageError(str(e)) from None


# -- router --------------------------------------------------------------------
def cmd_router(args: argparse.Namespace) -> int:
    import zenoh

    from dica.deploy import ZENOH_CONFIGS
    from dica.deploy.transport import Inbox, setup_logging

    log = setup_logging("router", args.verbose)
    path = args.config or ZENOH_CONFIGS / "router.json5"
    say_ready = _log_refused(log) if args.log_refused else _say_ready
    try:
        conf = zenoh.Config.from_file(str(path))
        if args.listen:
            conf.insert_json5("listen/endpoints", json.dumps(args.listen.split(",")))
        if args.connect:  # the neighbouring roadside units' routers: a mesh, routed by Zenoh
            conf.insert_json5("connect/endpoints", json.dumps(args.connect.split(",")))
            conf.insert_json5("connect/timeout_ms", "-1")  # a neighbour may come up later
        session = zenoh.open(conf)
    except Exception as e:
        raise UsageError(f"the Zenoh router would not start ({path}): {e}") from None
    inbox = Inbox()
    inbox.stop_on_signals()
    log.info("router %s listening on %s", session.info.zid(), args.listen or f"(from {path})")
    say_ready()
    while not inbox.stopping.wait(0.5):
        pass
    session.close()
    log.info("router stopped")
    return 0


def _say_ready() -> None:
    print("ready", flush=True)


def _log_refused(log):
    """Log the messages the router's access rules refuse, with the user that sent them.

    Zenoh reports each decision of its access control at trace level, on
    standard output, allowed ones too; this keeps the refusals (as warnings on
    standard error) and says "ready" on the real standard output. When a
    client declares a key, Zenoh weighs that key once against every kind of
    message (put, query, reply), so a well-behaved client is "refused" once for
    each such kind it never sends: those are logged from their second time on;
    a refused declaration (a subscriber, a queryable, a token) at once; then
    every hundredth time, and every refusal seen more than once is listed when
    the router stops.
    """
    import atexit
    import os
    import re
    import threading
    from collections import Counter

    import zenoh

    real = os.dup(1)
    r, w = os.pipe()
    os.dup2(w, 1)
    ansi = re.compile(r"\x1b\[[0-9;]*m")
    who = re.compile(r"Username\(([^)]*)\).* is unauthorized to (.*)$")

    seen: Counter[tuple[str, str]] = Counter()

    def keep() -> None:
        with os.fdopen(r, errors="replace") as lines:
            for line in lines:
                m = who.search(ansi.sub("", line))
                if not m:
                    continue
                what = (m.group(1), m.group(2).strip())
                seen[what] += 1
                first = 1 if what[1].startswith(("Declare", "Liveliness")) else 2
                if seen[what] == first or seen[what] % 100 == 0:
                    log.warning("refused %s: %s (%d times so far)", *what, seen[what])

    def summary() -> None:
        repeated = {f"{u}: {w}": n for (u, w), n in seen.items() if n > 1}
        if repeated:
            log.warning("refused, more than once: %s", json.dumps(repeated))

    threading.Thread(target=keep, daemon=True).start()
    atexit.register(summary)
    zenoh.init_log_from_env_or("error,zenoh::net::routing::interceptor::access_control=trace")
    return lambda: os.write(real, b"ready\n")


# -- ica -----------------------------------------------------------------------
def cmd_ica(args: argparse.Namespace) -> int:
    from dica.ica.core.controller import ControllerSpec, build_controller
    from dica.ica.core.ev_event import ReactiveConfig
    from dica.ica.journal import Journal, JournalError
    from dica.ica.service import IcaService, write_stats

    inter = intersection(args)
    try:
        # reactive DICA's revoked vehicles drop their plans and ask again: the ICA cannot
        # re-plan a vehicle over a link that may lose the new plan after the old one is gone
        reactive = ReactiveConfig(
            solver=args.solver,
            seed=args.seed,
            replan_revoked=False,
            max_added_delay_s=args.max_added_delay,
        )
        spec = ControllerSpec.of(
            args.algorithm, args.margin, args.time_pad, args.platoon, headway_s(args),
            args.run_up, args.exit_spacing, args.tile_size, reactive,
        )  # fmt: skip
        spec = dataclasses.replace(
            spec, config=dataclasses.replace(spec.config, max_request_age_s=args.max_age)
        ).with_green_late(args.green_late)
    except ValueError as e:
        raise UsageError(str(e)) from None
    ica = build_controller(spec, inter)
    ica.prepare()  # before serving: no request waits for it
    journal_path = args.journal or (args.out / "ica-journal.msgpack" if args.out else None)
    session, log = _session(args, _ica_signer(args, inter.junction_id))
    try:
        service = IcaService(session, ica, inter.junction_id, log)
        service.inbox.stop_on_signals()
        if journal_path is not None:
            if journal_path.exists():
                done = service.restore(journal_path)
                log.info(
                    "journal %s replayed: %d detections, %d confirmations, %d cancels%s; "
                    "%d confirmations held",
                    journal_path, done.detects, done.confirmations, done.cancels,
                    " (a torn last record dropped)" if done.truncated else "",
                    len(ica.confirmed),
                )  # fmt: skip
            service.journal = Journal(journal_path, sync=not args.no_sync)
        service.wait_alone()
        service.serve()
    except (JournalError, RuntimeError) as e:
        session.close()
        raise UsageError(str(e)) from None
    stats_path = args.out / "ica.json" if args.out else None
    log.info("ICA for junction %s (%s) serving", inter.junction_id, args.algorithm)
    try:
        service.run(idle_exit_s=args.idle_exit, stats_path=stats_path)
    finally:
        service.close()
        session.close()
        log.info("stopped: %s", json.dumps(service.stats.as_dict()))
        service.note_reactive()
        if stats_path is not None:
            write_stats(stats_path, service.stats)
    return 0


def _ica_signer(args: argparse.Namespace, junction: str) -> str:
    """The name the ICA seals with: ``ica``, or on a secured site of several junctions,
    where each ICA has its own key, its junction's ICA's (``ica-<J>``)."""
    from dica.deploy.seal import Keyring, SealError
    from dica.schemas.keys import ica_name

    if args.keyring is None or args.seal is None:
        return "ica"
    try:
        known = Keyring(args.keyring).names()
    except SealError as e:
        raise UsageError(str(e)) from None
    return ica_name(junction) if ica_name(junction) in known else "ica"


# -- agent ---------------------------------------------------------------------
def cmd_agent(args: argparse.Namespace) -> int:
    import threading

    from dica.ica.core.controller import ControllerSpec
    from dica.schemas.keys import KeyChunkError
    from dica.vehicle_agent.agent import Agent

    if args.junctions:
        from dica.tools.args import chosen_junctions

        ids = chosen_junctions(args.net, args.junctions, args.routes)
        inters = [intersection(argparse.Namespace(**{**vars(args), "junction": j})) for j in ids]
    else:
        inters = [intersection(args)]
    lead = None if args.lead == "auto" else args.lead
    try:
        config = ControllerSpec.of("enhanced", args.margin).config
    except ValueError as e:
        raise UsageError(str(e)) from None
    session, log = _session(args, f"agent {args.id}", signer=args.id)
    try:
        # one machine per vehicle and junction: a vehicle this agent hosts keeps it from
        # one junction to the next (the gateway hands it on), and asks each one's ICA
        agents = [
            Agent(session, args.id, x, config, retry_s=args.retry, lead_s=lead, log=log)
            for x in inters
        ]
    except KeyChunkError as e:
        session.close()
        raise UsageError(f"--id: {e}") from None
    agents[0].inbox.stop_on_signals()
    for a in agents[1:]:  # one signal stops them all
        a.inbox.stopping = agents[0].inbox.stopping
    names = ", ".join(x.junction_id for x in inters)
    log.info("vehicle agent %s up for junction%s %s", args.id, "s" * (len(inters) > 1), names)
    stopping = agents[0].inbox.stopping

    def serve(a: Agent) -> None:
        try:
            a.run()
        finally:
            stopping.set()  # the run's end (or a failure) at one junction ends them all

    threads = [threading.Thread(target=serve, args=(a,), name=a.inter.junction_id) for a in agents]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        stopping.set()
        for t in threads:
            if t.is_alive():
                t.join()
        for a in agents:
            a.close()
        session.close()
        for a in agents:
            log.info("stopped at %s: %s", a.inter.junction_id, json.dumps(a.summary()))
    return 0


# -- gateway -------------------------------------------------------------------
def cmd_gateway(args: argparse.Namespace) -> int:
    from dica.sim_gateway.gateway import Fleet, ZenohDrivers, run_gateway
    from dica.sim_gateway.outputs import write_outputs
    from dica.sim_gateway.runconfig import LIGHTS, RunError

    if args.algorithm in LIGHTS:
        raise UsageError("the cluster runs ICA controllers; run the light baselines with dica run")
    cfg, inter = run_config(args)
    if cfg.algorithm == "rdica":  # the cluster's way: no ICA re-plans over a link
        cfg = dataclasses.replace(cfg, revocation="drop")
    out = options.out_dir(args.out or Path("runs") / time.strftime("cluster-%Y%m%d-%H%M%S"))
    inters = intersections(cfg) if cfg.junction_ids else [inter]
    session, log = _session(args, "gateway")
    fleet = Fleet()  # a vehicle keeps its agent from one junction to the next
    try:
        drivers = [
            ZenohDrivers(
                session,
                x.junction_id,
                cfg,
                agents=args.agents,
                observers=args.observers,
                per_agent=args.per_agent,
                clock=args.clock,
                speed=args.speed,
                step_timeout_s=args.step_timeout,
                resend_s=args.resend,
                fleet=fleet,
                log=log,
            )
            for x in inters
        ]
    except RunError as e:
        session.close()
        raise UsageError(str(e)) from None
    drivers[0].inbox.stop_on_signals()
    for d in drivers[1:]:  # one signal stops every junction's waits
        d.inbox.stopping = drivers[0].inbox.stopping
    last = [0.0]

    def tick(t: float, waiting: int, crossed: int) -> None:
        if t - last[0] >= args.progress_every:
            log.info("t=%.0f s  waiting=%d  crossed=%d", t, waiting, crossed)
            last[0] = t

    def checkpoint(result, why: str | None) -> None:
        write_outputs(out, cfg, result, mode="cluster", incomplete=why)

    try:
        if cfg.junction_ids:
            result = _run_network_gateway(args, cfg, inters, drivers, out, tick, checkpoint)
        else:
            result = run_gateway(session, cfg, inter, drivers[0],
                                 peers_timeout_s=args.peers_timeout, progress=tick,
                                 checkpoint=checkpoint,
                                 checkpoint_every_s=args.checkpoint_every)  # fmt: skip
    except RunError as e:
        log.error("%s", e)
        raise UsageError(str(e)) from None
    finally:
        for d in drivers:
            d.close()
        session.close()
    write_outputs(out, cfg, result, mode="cluster")
    if result.net_trips is not None:
        from dica.sim_gateway.network_trips import write_trips_csv

        write_trips_csv(out / "trips.csv", result.net_trips)
    log.info("wrote %s", out / "metrics.json")
    return report_run(out, result)


def _run_network_gateway(args, cfg, inters, drivers, out: Path, tick, checkpoint):
    """Several junctions, each its own ICA process, as ``dica run --junctions`` runs them."""
    from dica.sim_gateway.network import run_network
    from dica.sim_gateway.network_cluster import Cluster

    cluster = Cluster(
        drivers,
        peers_timeout_s=args.peers_timeout,
        checkpoint=checkpoint,
        checkpoint_every_s=args.checkpoint_every,
    )
    return run_network(cfg, inters, progress=tick, run_dir=out, cluster=cluster)


# -- observer ------------------------------------------------------------------
def cmd_observer(args: argparse.Namespace) -> int:
    if args.junctions:
        return _network_observer(args)
    inter = intersection(args)
    session, log = _session(args, "observer")
    from dica.sim_gateway.observer import Observer

    live = args.grpc_port if args.live else None
    try:
        obs = Observer(
            session,
            inter,
            args.rrd,
            log,
            margin_m=args.margin,
            time_pad_s=args.time_pad,
            live_port=live,
        )
    except (OSError, RuntimeError) as e:
        _cannot_record(session, args, live, e)
    _record(obs, session, log, live, f"recording junction {inter.junction_id} into {args.rrd}")
    log.info(
        "wrote %s: %d steps, %d confirmations, %d reorderings, %d plans withdrawn, "
        "%d walkers' slots, %d human drivers' greens",
        args.rrd, obs.steps, obs.confirmations, obs.reorders, obs.withdrawn, obs.walks,
        obs.greens,
    )  # fmt: skip
    return 0


def _cannot_record(session, args: argparse.Namespace, live: int | None, e: Exception) -> NoReturn:
    session.close()
    what = f"port {live} on 127.0.0.1" if live else args.rrd
    raise UsageError(f"cannot write {what}: {e}") from None


def _record(obs, session, log, live: int | None, start: str) -> None:
    """An observer's run: until the run's end or a signal, then its file closed."""
    obs.inbox.stop_on_signals()
    log.info("%s", start)
    if live:
        log.info("live on rerun+http://127.0.0.1:%d/proxy (watch: dica view --live)", live)
    try:
        obs.run()
    finally:
        obs.close()
        session.close()


def _network_observer(args: argparse.Namespace) -> int:
    """The top view of several junctions (the cluster's network.rrd)."""
    from dica.ica.netfile import lane_shapes
    from dica.sim_gateway.network_observer import NetworkObserver
    from dica.sim_gateway.recording.network_view import route_lanes
    from dica.tools.args import chosen_junctions

    if not args.net:
        raise UsageError("--junctions needs --net")
    ids = chosen_junctions(args.net, args.junctions, args.routes)
    inters = [intersection(argparse.Namespace(**{**vars(args), "junction": j})) for j in ids]
    shapes = lane_shapes(args.net, route_lanes(inters))
    live = args.grpc_port if args.live else None
    session, log = _session(args, "observer")
    try:
        obs = NetworkObserver(session, inters, shapes, args.rrd, log, live_port=live)
    except (OSError, RuntimeError) as e:
        _cannot_record(session, args, live, e)
    _record(obs, session, log, live, f"recording the network of {','.join(ids)} from above "
            f"into {args.rrd}")  # fmt: skip
    log.info("wrote %s: %d moments, %d confirmations", args.rrd, obs.steps, obs.confirmations)
    return 0


def add_role_parsers(sub) -> None:
    r = sub.add_parser(
        "router",
        help="a Zenoh router (every other role connects to it)",
        description="Runs a Zenoh router in this process until SIGTERM or Ctrl-C.",
    )
    r.add_argument("--config", type=Path, help="router JSON5 (default deploy/zenoh/router.json5)")
    r.add_argument("--listen", help="endpoint(s) to listen on, e.g. tcp/127.0.0.1:7447")
    r.add_argument(
        "--connect",
        help="other routers' endpoint(s) to connect to, comma-separated: roadside units' "
        "routers in a mesh (Zenoh routes between them; each link needs one side to connect)",
    )
    r.add_argument(
        "--log-refused",
        action="store_true",
        help="log every message its access rules refuse, with the user who sent it (costs "
        "some CPU: Zenoh traces every decision, and the router keeps the refusals)",
    )
    options.add(r, "--verbose")
    r.set_defaults(func=cmd_router)

    i = sub.add_parser(
        "ica",
        help="the intersection control agent: a Zenoh queryable answering REQUESTs",
        description="Serves dica/<junction>/request, dica/<junction>/detect and the "
        "walkers' dica/<junction>/walk, publishes "
        "confirmations on dica/<junction>/confirmed/<vin>, follows the sim clock. Stops on "
        "SIGTERM or when the clock announces the end of the run.",
    )
    options.add(
        i, *options.NET, "--algorithm", "--solver", "--max-added-delay", "--seed", *options.PLAN,
        "--max-age",
        "--tile-size", "--out", "--idle-exit", "--routes",
        routes={"help": ROUTES_HELP},
        algorithm={"help": options.ALGORITHMS_HELP + " (revoked vehicles drop their plans "
                   "and ask again)"},
        seed={"help": "rdica's GA seed (the run's seed; default 12)"},
        out={"help": "directory for ica.json (request statistics) and, unless --journal says "
             "otherwise, the journal ica-journal.msgpack"},
    )  # fmt: skip
    i.add_argument(
        "--journal",
        type=Path,
        help="journal every detection, confirmation and cancel here before answering, and "
        "replay it first if it exists (a restarted ICA keeps its promises)",
    )
    i.add_argument(
        "--no-sync",
        action="store_true",
        help="do not fsync each journal record (faster, less safe)",
    )
    _add_link_args(i)
    i.set_defaults(func=cmd_ica)

    a = sub.add_parser(
        "agent",
        help="a vehicle-agent process hosting the vehicles the gateway hands it",
        description="Each hosted vehicle is a state machine (approaching, requesting, "
        "confirmed, crossing, exited) that requests when head of its lane and flies its "
        "confirmed trajectory. How many vehicles one process hosts is set on the gateway "
        "(--per-agent).",
    )
    a.add_argument("--id", required=True, help="this agent's name (letters, digits, _.:-+)")
    options.add(
        a, *options.NET, "--junctions", "--margin", "--retry", "--lead", "--routes",
        routes={"help": ROUTES_HELP},
        junctions={"help": "serve several junctions of --net (J1,J2,... or all, as the "
                   "gateway's --junctions): the agent keeps each vehicle it hosts from one "
                   "junction to the next"},
        lead={"type": options.seconds_or_auto, "default": "auto",
              "help": "realtime: how far ahead of its observation a REQUEST's plan starts "
              "[sim s]; auto (default) uses the measured round trip plus a margin. Lockstep "
              "always plans from the observed state."},
    )  # fmt: skip
    _add_link_args(a)
    a.set_defaults(func=cmd_agent)

    o = sub.add_parser(
        "observer",
        help="record vehicle footprints and confirmed DTOTs into a Rerun .rrd",
        description="Listens to the vehicle states and the ICA's confirmations and writes a "
        "space-time recording (open it with dica view). With --live it also serves the "
        "recording over gRPC on 127.0.0.1 while it writes, for dica view --live. Stops at the "
        "run's end or on SIGTERM.",
    )
    options.add(
        o, *options.NET, "--junctions", "--margin", "--time-pad", "--routes",
        routes={"help": ROUTES_HELP},
        junctions={"help": "instead of --junction: the network of these junctions of --net "
                   "(J1,J2,... or all) from above, every junction's vehicles and confirmed "
                   "plans in one recording (run_cluster.sh writes it as network.rrd)",
                   "metavar": "all|J1,J2,..."},
    )  # fmt: skip
    o.add_argument("--rrd", type=Path, required=True, help="the .rrd file to write")
    o.add_argument(
        "--live",
        action="store_true",
        help="also serve the recording on 127.0.0.1 as it is made (watch: dica view --live)",
    )
    options.add(o, "--grpc-port")
    _add_link_args(o)
    o.set_defaults(func=cmd_observer)

    g = sub.add_parser(
        "gateway",
        help="SUMO through libsumo, keyed to Zenoh: states out, commands in",
        description="Steps SUMO, publishes the clock and each agent's vehicle states, applies "
        "the agents' commands, and writes the same metrics.json, vehicles.csv and "
        "timeseries.csv as dica run. Waits for the ICA and --agents agents first.",
    )
    add_run_args(g, algorithm={"help": options.ALGORITHMS_HELP})
    options.add(
        g, "--junctions", "--network-gate", "--network-gate-rule", "--ev-notices", "--agents",
        "--observers",
        "--per-agent", "--clock",
        "--speed", "--step-timeout",
        "--resend", "--checkpoint-every", "--peers-timeout", "--progress-every", "--out",
        out={"help": "output directory (default runs/cluster-TIMESTAMP)"},
    )  # fmt: skip
    _add_link_args(g)
    g.set_defaults(func=cmd_gateway)
