"""``dica``: one command for scenarios, geometry, request streams and benchmarks.

Every subcommand has ``--help``. Bad input ends with one line on stderr and
exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
from pathlib import Path

from dica.tools import options
from dica.tools.args import add_run_args, intersection, intersections, report_run, run_config
from dica.tools.options import UsageError

EXAMPLES = """examples:
  dica scenario build --layout ch45 --out nets/
  dica geometry --layout ch3
  dica run --volume 500 --duration 600
  dica stream --volume 500 --vehicles 1000 --variant enhanced
  dica experiment --layout ch45 --algorithms enhanced,fixed,actuated --out runs/ch4
  dica report runs/ch4
  dica bench ica --json
  dica run --algorithm rdica --solver exact --volume 300 --ev-prob 0.02
  dica bench ordering
  dica view runs/run-enhanced-20250101-120000 --web --port 9090
"""


# -- scenario -------------------------------------------------------------------
def cmd_scenario(args: argparse.Namespace) -> int:
    from dica.sim_gateway.scenario import ScenarioError, build_scenario

    try:
        sc = build_scenario(args.layout, args.out)
    except ScenarioError as e:
        raise UsageError(str(e)) from None
    print(f"{sc.layout}: junction {sc.junction_id} in {sc.net_path}")
    return 0


# -- geometry -------------------------------------------------------------------
def cmd_geometry(args: argparse.Namespace) -> int:
    from dica.ica.core.crosswalk import spans
    from dica.ica.core.zones import ConflictTables, Shape

    inter = intersection(args)
    tables = ConflictTables(inter, margin_m=args.margin)
    shape = Shape.of(5.0, 1.8)
    over = spans(inter.routes, inter.crosswalks, shape.length_m, shape.width_m, args.margin)
    rows = []
    for r in inter.routes:
        conflicting = [
            o.id for o in inter.routes if o is not r and not tables.compatible(r, shape, o, shape)
        ]
        rows.append(
            {
                "route": r.id,
                "turn": r.turn.value,
                "cross_length_m": round(r.cross_length_m, 3),
                "speed_cap_kmh": round(r.speed_cap_mps * 3.6, 1),
                "conflicts_with": len(conflicting),
                "compatible_with": len(inter.routes) - 1 - len(conflicting),
                # the crossings it passes over: the front positions over which a car touches
                "crossings": [
                    {"crossing": c, "s_from_m": round(a, 2), "s_to_m": round(b, 2)}
                    for c, a, b in over[r.id]
                ],
            }
        )
    walks = [
        {"crossing": c.id, "length_m": round(c.length_m, 2), "width_m": round(c.width_m, 2),
         "crosses": list(c.crosses)}
        for c in inter.crosswalks
    ]  # fmt: skip
    if args.json:
        doc = {"junction": inter.junction_id, "routes": rows, "crossings": walks}
        print(json.dumps(doc, indent=2))
        return 0
    print(
        f"junction {inter.junction_id}: {len(rows)} routes, region {inter.comm_length_m} m, "
        f"{len(walks)} pedestrian crossings"
    )
    head = ("route", "turn", "length m", "cap km/h", "conflicts", "compatible", "crossings")
    print(
        f"{head[0]:<24} {head[1]:<8} {head[2]:>9} {head[3]:>9} {head[4]:>9} {head[5]:>10}  "
        f"{head[6]}"
    )
    for row in rows:
        passes = ", ".join(
            f"{x['crossing']} ({x['s_from_m']:.1f} to {x['s_to_m']:.1f} m)"
            for x in row["crossings"]
        )
        print(
            f"{row['route']:<24} {row['turn']:<8} {row['cross_length_m']:>9.2f} "
            f"{row['speed_cap_kmh']:>9.1f} {row['conflicts_with']:>9} {row['compatible_with']:>10}"
            f"  {passes or '-'}"
        )
    for w in walks:
        print(
            f"crossing {w['crossing']}: {w['length_m']:.1f} m across, {w['width_m']:.1f} m wide, "
            f"over {' and '.join(w['crosses']) or 'no road named'}"
        )
    return 0


# -- stream ----------------------------------------------------------------------
def cmd_stream(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from dica.ica.core.config import IcaConfig, Techniques
    from dica.sim_gateway.audit import conflicts, kinematic_violations
    from dica.sim_gateway.stream import StreamSpec, flown, run_stream

    try:
        tech = Techniques.parse(args.variant)
        cfg = IcaConfig(techniques=tech, margin_m=args.margin)
    except ValueError as e:
        raise UsageError(str(e)) from None
    inter = intersection(args)
    spec = StreamSpec(volume_per_10min=args.volume, n_vehicles=args.vehicles, seed=args.seed)
    out = options.out_dir(args.out or Path("runs") / time.strftime("stream-%Y%m%d-%H%M%S"))

    t0 = time.perf_counter()
    with tqdm(total=args.vehicles, desc="confirmed", unit="veh", disable=args.quiet) as bar:
        res = run_stream(inter, cfg, spec, progress=bar.update)
    wall = time.perf_counter() - t0
    summary = res.summary()
    summary["wall_s"] = wall
    if args.audit:
        fl = flown(res)
        with tqdm(total=1, desc="audit", disable=args.quiet) as bar:
            bad = conflicts(fl, cfg.margin_m)
            kin = cfg.kinematics
            limits = [
                (f.vin, p)
                for f in fl
                for p in kinematic_violations(f, cfg.caps.road_mps, kin.accel_mps2, kin.decel_mps2)
            ]
            bar.update()
        summary["audit"] = {"conflicts": len(bad), "limit_violations": len(limits)}

    config = {
        "junction": inter.junction_id,
        "net": str(args.net) if args.net else f"layout:{args.layout}",
        "ica": _jsonable(dataclasses.asdict(cfg)),
        "stream": dataclasses.asdict(spec),
    }
    (out / "config.json").write_text(json.dumps(config, indent=2))
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    with (out / "vehicles.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            ["vin", "route", "turn", "arrival_s", "entry_s", "exit_s", "delay_s", "iterations"]
        )
        for v in res.vehicles:
            c = v.confirmation
            w.writerow(
                [v.vin, v.route.id, v.route.turn.value, f"{v.arrival_s:.2f}"]
                + (
                    [
                        f"{c.entry_time_s:.3f}",
                        f"{c.exit_time_s:.3f}",
                        f"{c.delay_s:.3f}",
                        c.iterations,
                    ]
                    if c
                    else ["", "", "", ""]
                )
            )
    print(json.dumps(summary, indent=2))
    print(f"wrote {out}/summary.json, vehicles.csv, config.json")
    audit = summary.get("audit", {})
    return 1 if audit.get("conflicts") or audit.get("limit_violations") else 0


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


# -- run -------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from dica.sim_gateway.embedded import RunError, run
    from dica.sim_gateway.outputs import write_outputs

    cfg, inter = run_config(args)
    out = options.out_dir(
        args.out or Path("runs") / time.strftime(f"run-{cfg.algorithm}-%Y%m%d-%H%M%S")
    )
    total = None if cfg.until_left else cfg.duration_s
    with tqdm(total=total, desc="sim time", unit="s", disable=args.quiet) as bar:
        last = [cfg.begin_s]

        def tick(t: float, waiting: int, crossed: int) -> None:
            if t - last[0] >= 1.0:
                bar.set_postfix(waiting=waiting, crossed=crossed, refresh=False)
                bar.update(t - last[0])
                last[0] = t

        try:
            rrd = out / "spacetime.rrd" if args.record else None
            if cfg.junction_ids:
                from dica.sim_gateway.network import run_network

                result = run_network(
                    cfg, intersections(cfg), progress=tick, rrd_path=rrd, run_dir=out
                )
            else:
                result = run(cfg, inter, progress=tick, rrd_path=rrd, run_dir=out)
        except RunError as e:
            raise UsageError(str(e)) from None
    write_outputs(out, cfg, result)
    if result.net_trips is not None:  # several junctions: each vehicle's whole trip too
        from dica.sim_gateway.network_trips import write_trips_csv

        write_trips_csv(out / "trips.csv", result.net_trips)
    return report_run(out, result)


# -- view ------------------------------------------------------------------------
SECURE_CONFIG_DESCRIPTION = """\
Writes a secured site into --out, readable by its owner only:
  router.json5      the router of deploy/zenoh/secure/router.json5: TLS only, log-in
                    required, and each user allowed exactly its own keys, nothing else
  router-2.json5 .. with --rsus N: the router of each further roadside unit, with a
                    certificate of its own (rsu-<k>), logging in to the routers before
                    it; routers pass the site's keys to one another and keep their own
                    clients to their rules
  users.txt         one random password per role and per agent
  ica.json5, gateway.json5, observer.json5, <agent>.json5
                    each one's client config (--zenoh-config), with its password and
                    the site's CA certificate; copy each to the host that runs it
  ca.pem            the site's CA certificate
  site.json         the junctions it serves, for issuing agents later

  dica secure-config --out site/ --agents car-17,car-18 --host 10.0.0.1 --junction C
  dica secure-config --out site/ --add-agent car-19      # one more vehicle
  dica secure-config --out site/ --revoke-agent car-17   # a stolen or retired one
  dica secure-config --out site/ --junction J1 --junction J2 --ica-per-junction --rsus 2

The router reads users.txt and its rules only when it starts: restart it after
--add-agent or --revoke-agent. A revoked agent is refused from then on; until then
its open session and its log-ins go on.
"""


def cmd_secure_config(args: argparse.Namespace) -> int:
    from dica.deploy import site

    run = f"dica router --config {args.out.resolve() / 'router.json5'}"
    try:
        new_site_only = (
            args.host, args.days, args.junction, args.ica_per_junction or None, args.rsus
        )  # fmt: skip
        if (args.add_agent or args.revoke_agent) and any(x is not None for x in new_site_only):
            raise UsageError(
                "--host, --days, --junction, --ica-per-junction and --rsus make a new site "
                "(--agents)"
            )
        if args.add_agent:
            added = site.add_agents(args.out, args.add_agent, args.force)
            for name, path in added.items():
                print(f"{name + ':':10}dica agent --zenoh-config {path} --id {name} ...")
            print(f"restart the router to let {', '.join(added)} in: {run}")
            return 0
        if args.revoke_agent:
            gone = site.names(args.revoke_agent)
            left = site.revoke_agents(args.out, gone)
            print(f"revoked {', '.join(gone)}; the site's agents: {', '.join(left) or '(none)'}")
            print(f"restart the router to refuse them (until then they stay in): {run}")
            return 0
        hosts = tuple(args.host) if args.host else site.DEFAULT_HOSTS
        days = 365 if args.days is None else args.days
        junctions = args.junction or site.DEFAULT_JUNCTIONS
        rsus = 1 if args.rsus is None else args.rsus
        paths = site.write_secure_configs(
            args.out, args.force, hosts, days, args.agents, junctions, args.ica_per_junction,
            rsus,
        )  # fmt: skip
    except site.SecureConfigError as e:
        raise UsageError(str(e)) from None
    print(f"router:   {run}")
    for k in range(2, rsus + 1):
        before = "router 1's endpoint" if k == 2 else f"the endpoints of routers 1 to {k - 1}"
        print(f"router {k}: dica router --config {paths[site.router_file(k)]} --connect <{before}>")
    for user in site.site_roles(site.junction_names(junctions), args.ica_per_junction):
        role, _, j = user.partition("-")  # ica-<J>: the ICA of junction J
        more = f" --seal {paths[user + '.seal']} --junction {j}" if j else ""
        print(f"{user + ':':10}dica {role} --zenoh-config {paths[user + '.json5']}{more} ...")
    for name in site.agent_names(args.agents):
        print(f"{name + ':':10}dica agent --zenoh-config {paths[name + '.json5']} --id {name} ...")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from dica.tools import view

    try:
        return view.main(args)
    except view.ViewError as e:
        raise UsageError(str(e)) from None
    except view.ViewerFailed as e:
        print(f"dica: {e}", file=sys.stderr)
        return 1


# -- bench -----------------------------------------------------------------------
def cmd_bench(args: argparse.Namespace) -> int:
    if args.what == "ica":
        from dica.tools import bench_ica

        return bench_ica.main(args.rest)
    raise UsageError(f"unknown benchmark {args.what!r}")


def parser() -> argparse.ArgumentParser:
    p = options.Parser(
        prog="dica",
        description="Signal-free intersection control (DICA, enhanced DICA) for connected "
        "autonomous vehicles.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    from dica.tools.view import DESCRIPTION as VIEW_DESCRIPTION
    from dica.tools.view import add_arguments as view_arguments

    sc = sub.add_parser("scenario", help="build a built-in intersection with netconvert")
    sc.add_argument("action", choices=["build"])
    options.add(
        sc, "--layout", "--out",
        out={"help": "directory for the .net.xml and plain XML", "required": True},
    )  # fmt: skip
    sc.set_defaults(func=cmd_scenario)

    g = sub.add_parser(
        "geometry", help="routes, turn classes, conflicts and pedestrian crossings of a junction"
    )
    options.add(g, *options.NET, "--margin", "--json")
    g.set_defaults(func=cmd_geometry)

    s = sub.add_parser(
        "stream",
        help="feed a random request stream through the ICA core and audit the result",
        description="Vehicles arrive at random (the volume is the expected count per 10 min), "
        "request when head of their lane, and every confirmed trajectory is audited by an "
        "independent brute-force check. Writes summary.json, vehicles.csv and config.json.",
    )
    options.add(
        s, *options.NET, "--variant", "--volume", "--vehicles", "--seed", "--margin", "--out",
        "--quiet", out={"help": "output directory (default runs/stream-TIMESTAMP)"},
    )  # fmt: skip
    s.add_argument("--no-audit", dest="audit", action="store_false", help="skip the audit")
    s.set_defaults(func=cmd_stream)

    r = sub.add_parser(
        "run",
        help="one SUMO simulation (libsumo, embedded ICA) with metrics and a safety check",
        description="Vehicles arrive at random (the volume is the expected count per 10 min over "
        "all approaches; routes left/through/right 0.2/0.6/0.2; entry speed 0.4-1 x 70 km/h, or "
        "x the net's lower limit), or come from a SUMO route file (--routes), request when head "
        "of their lane and fly their confirmed trajectory in SUMO. Writes "
        "metrics.json, vehicles.csv, timeseries.csv and config.json. Exit status 1 if any "
        "collision was seen (vehicles with each other, or with people: --peds).",
    )
    add_run_args(r)
    options.add(
        r, "--junctions", "--network-gate", "--network-gate-rule", "--ev-notices", "--run-up",
        "--exit-spacing",
        "--lead", "--window",
        "--revocation", "--out", "--quiet",
        out={"help": "output directory (default runs/run-ALG-TIMESTAMP)"},
    )  # fmt: skip
    r.add_argument(
        "--record",
        action="store_true",
        help="also write OUT/spacetime.rrd (Rerun space-time visuals; open with dica view OUT)",
    )
    r.set_defaults(func=cmd_run)

    from dica.tools.roles import add_role_parsers

    add_role_parsers(sub)

    v = sub.add_parser(
        "view",
        help="open a run's Rerun recording (desktop viewer, or --web on 127.0.0.1)",
        description=VIEW_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    view_arguments(v)
    v.set_defaults(func=cmd_view)

    sc = sub.add_parser(
        "secure-config",
        help="Zenoh configs of a secured site: TLS, log-ins, one identity per vehicle agent, "
        "each allowed only its own keys",
        description=SECURE_CONFIG_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    options.add(
        sc, "site", "--host", "--days", "site-junction", "--ica-per-junction", "--rsus", "--force"
    )
    options.add(sc.add_mutually_exclusive_group(), "site-agents", "--add-agent", "--revoke-agent")
    sc.set_defaults(func=cmd_secure_config)

    sub.add_parser("experiment", help="a grid of runs in parallel, resumable (see its --help)")
    sub.add_parser(
        "link",
        help="the link emulator: delay, jitter, loss, duplication, reordering (see its --help)",
    )
    sub.add_parser("report", help="markdown tables and PNG plots from runs (see its --help)")
    sub.add_parser(
        "network",
        help="a network of junctions (built-in corridor or 3x3 grid, or your net), every "
        "one signal-free or by lights, measured per vehicle (see its --help)",
    )

    b = sub.add_parser(
        "bench",
        help="benchmarks: ica (seconds per REQUEST per DICA variant), run (real-time factor), "
        "cluster (Zenoh round trip, lockstep real-time factor), timing (the real-time "
        "cluster under delay, jitter, loss, duplication and reordering), ordering (the EV "
        "ordering solvers), routes (a user's net and demand file against SUMO alone), network "
        "(the 3x3 grid, every junction signal-free, against SUMO alone)",
    )
    b.add_argument("what", choices=list(BENCHES))
    b.add_argument(
        "rest",
        nargs=argparse.REMAINDER,
        help="options of the benchmark (see dica bench ica --help)",
    )
    b.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        return _dispatch(argv)
    except UsageError as e:
        print(f"dica: {e}", file=sys.stderr)
        return 2
    except SystemExit as e:  # --help, or a command line refused in one line (options.Parser)
        return e.code if isinstance(e.code, int) else 1
    except KeyboardInterrupt:
        print("dica: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head and the like
        sys.stderr.close()
        return 0


BENCHES = ("ica", "run", "cluster", "timing", "ordering", "routes", "network")


def _dispatch(argv: list[str]) -> int:
    # these subcommands parse their own options (and --help)
    if argv and argv[0] in ("experiment", "report", "link", "network"):
        from dica.tools import experiment, link, network, report

        cmds = {"experiment": experiment, "report": report, "link": link, "network": network}
        return cmds[argv[0]].main(argv[1:])
    if len(argv) >= 2 and argv[0] == "bench" and argv[1] in BENCHES:
        from dica.tools import (
            bench_cluster,
            bench_ica,
            bench_network,
            bench_ordering,
            bench_routes,
            bench_run,
            bench_timing,
        )

        bench = {
            "ica": bench_ica,
            "run": bench_run,
            "cluster": bench_cluster,
            "timing": bench_timing,
            "ordering": bench_ordering,
            "routes": bench_routes,
            "network": bench_network,
        }[argv[1]]
        return bench.main(argv[2:])
    args = options.parse(parser(), argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
