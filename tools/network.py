"""``dica network``: a network of junctions, every one signal-free under its own ICA or
run by lights, with origin-destination demand or a route file, measured per vehicle
over the whole network.

The built-in networks (``--layout corridor|grid``, :mod:`sim_gateway.network_layouts`)
are built from the same plain XML for every control, with priority junctions for
the signal-free run and lights for the baselines; a user's net (``--net``) runs as
it is (``static``: its own lights) or with its lights rebuilt actuated. The demand
comes from ``--routes`` or is drawn per entry (``--volume`` vehicles per hour on
every road into the network, turning by ``--turns`` at each junction, seeded), and
the run goes on after the demand until every vehicle has left (at most ``--drain``
seconds). Writes metrics.json (``network``: the network's figures from SUMO's own
trip records; ``junctions``: each junction's), trips.csv (one row per vehicle),
vehicles.csv (one row per crossing), the demand and config.json.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

from dica.tools import options
from dica.tools.options import UsageError

CONTROLS = ("dica", "static", "actuated", "coordinated", "max-pressure", "preempt")
# how run_network runs each control's lights (None: signal-free)
LIGHTS_BY_CONTROL = {"dica": None, "static": "program", "actuated": "program",
                     "coordinated": "program", "max-pressure": "max-pressure",
                     "preempt": "preempt"}  # fmt: skip
# the lights each control's net is built with
# controls that drive every chosen junction's light (the others run the net's lights as
# they are, and its unsignalised junctions by the net's own right of way)
LIGHTS_EACH = ("max-pressure", "preempt")
NET_LIGHTS = {"static": "static", "actuated": "actuated", "coordinated": "static",
              "max-pressure": "static", "preempt": "static"}  # fmt: skip
DESCRIPTION = (
    "A network of junctions, every one signal-free under its own ICA (--control dica) or run "
    "by lights with safe clearances: static (fixed-time programs), actuated (SUMO's actuated "
    "lights), coordinated (fixed-time with green-wave offsets for the demand's main flows, "
    "SUMO's tlsCoordinator), max-pressure (the standard adaptive network controller) or "
    "preempt (fixed-time with emergency-vehicle pre-emption at each light 20 s ahead of the "
    "EV). The "
    "built-in networks (--layout corridor|grid) are built from the same plain XML for every "
    "control; your net (--net) runs as it is or with its lights rebuilt actuated (its own "
    "programs for static, coordinated, max-pressure and preempt). Vehicles come from "
    "--routes, or are drawn: --volume vehicles per hour on every road into the network, "
    "turning by --turns at each junction, for --duration seconds; the run goes on until "
    "every vehicle has left (at most --drain seconds more). Writes metrics.json (network: "
    "delay and travel time from each vehicle's scheduled departure, from SUMO's own trip "
    "records; junctions: each junction's figures), trips.csv (a row per vehicle), "
    "vehicles.csv (a row per crossing), the demand and config.json. Exit status 1 if "
    "anything collided. Signal-free, a vehicle asks once the one ahead of it has entered "
    "the junction (the dissertation's rule, as the network results were made); dica run "
    "--junctions and the cluster let it follow as a platoon, so their runs differ from "
    "this one's."
)


def _turns(text: str) -> tuple[float, float, float]:
    try:
        parts = tuple(float(x) for x in text.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or any(not (x >= 0.0 and math.isfinite(x)) for x in parts) or not sum(parts):
        raise UsageError(f"--turns wants three ratios LEFT,THROUGH,RIGHT >= 0, got {text!r}")
    return parts  # type: ignore[return-value]


def _entry(text: str) -> tuple[str, float]:
    road, _, vph = text.partition("=")
    try:
        value = float(vph)
    except ValueError:
        value = math.nan
    if not road or not (math.isfinite(value) and value >= 0.0):
        raise UsageError(f"--entry-volume wants ROAD=VEHICLES_PER_HOUR, got {text!r}")
    return road, value


def parser() -> options.Parser:
    p = options.Parser(
        prog="dica network",
        description=DESCRIPTION,
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument("--layout", choices=["corridor", "grid"], default=None,
                       help="built-in network: corridor (four junctions in a row) or grid "
                       "(3x3); 2 lanes each way, 250 m blocks, 50 km/h (default grid)")  # fmt: skip
    where.add_argument("--net", type=Path, help="a SUMO .net.xml of your own")
    p.add_argument("--junctions", default="all",
                   help="with --net: the junctions under control, all (every junction where "
                   "two roads or more come in, default) or J1,J2,...")  # fmt: skip
    p.add_argument("--control", choices=CONTROLS, default="dica",
                   help="dica: every junction signal-free under its own ICA (default); static: "
                   "fixed-time lights (netconvert's programs, or your net's own); actuated: "
                   "SUMO's actuated lights; coordinated: fixed-time with green-wave offsets; "
                   "max-pressure: adaptive, junction by junction; preempt: fixed-time, each "
                   "light pre-empted for an emergency vehicle 20 s before it reaches the "
                   "line")  # fmt: skip
    p.add_argument(
        "--algorithm",
        default="enhanced",
        help="with --control dica: the DICA variant (default enhanced)",
    )
    p.add_argument("--routes", type=Path, help="a SUMO route file instead of drawn demand")
    p.add_argument("--no-network-gate", dest="network_gate", action="store_false",
                   help="with --control dica: no bound on what the links between the "
                   "junctions hold (by default the network gate bounds it, so the network "
                   "cannot lock)")  # fmt: skip
    p.add_argument("--ev-notices", action="store_true",
                   help="with --algorithm rdica: each emergency vehicle tells the junctions "
                   "ahead on its route that it is coming, and each clears a short queue in the "
                   "EV's lanes before it arrives (by default each junction reacts once the EV "
                   "is in its own region; docs/results.md: helps a busy corridor, costs a grid "
                   "near saturation)")  # fmt: skip
    p.add_argument("--network-gate-rule", choices=options.GATE_RULES, default="route",
                   help="with --control dica: route (default: a vehicle let in holds room on "
                   "each guarded link of its route ahead, the few links every cycle passes, "
                   "none promised more than its capacity) or cycle (the whole network at "
                   "most its least cycle's capacity)")  # fmt: skip
    p.add_argument(
        "--volume",
        type=float,
        default=300.0,
        help="vehicles per hour on every road into the network (default 300)",
    )
    p.add_argument("--entry-volume", action="append", type=_entry, default=[],
                   metavar="ROAD=VPH", help="vehicles per hour on one road into the network "
                   "instead of --volume (repeat for more roads; e.g. the corridor's "
                   "arterial: W00_J00 and E30_J30)")  # fmt: skip
    p.add_argument("--turns", type=_turns, default=(0.2, 0.6, 0.2), metavar="L,T,R",
                   help="turning ratios at each junction (default 0.2,0.6,0.2)")  # fmt: skip
    p.add_argument("--ev-prob", type=float, default=0.0, metavar="P",
                   help="each drawn vehicle an emergency vehicle with probability P (default 0; "
                   "a route file's are those of an emergency vClass). --algorithm rdica lets "
                   "them through each junction first")  # fmt: skip
    p.add_argument("--seed", type=int, default=12, help="the drawn demand's seed (default 12)")
    p.add_argument("--duration", type=float, default=600.0,
                   help="seconds of the drawn demand (default 600); with --routes the file's "
                   "demand runs as it is, and the run may end once the network is empty after "
                   "this long")  # fmt: skip
    p.add_argument("--drain", type=float, default=900.0,
                   help="at most this long after the demand for every vehicle to leave "
                   "(default 900)")  # fmt: skip
    p.add_argument("--out", type=Path, help="output directory (default runs/network-...)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--record", action="store_true",
                   help="with --control dica: also write each junction's Rerun space-time "
                   "views, OUT/spacetime.rrd (the first) and OUT/spacetime-<junction>.rrd, "
                   "and the network from above, OUT/network.rrd (open them all with dica "
                   "view OUT)")  # fmt: skip
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except UsageError as e:
        print(f"dica network: {e}", file=sys.stderr)
        return 2


def _main(argv: list[str] | None) -> int:
    from tqdm import tqdm

    from dica.ica.netfile import NetworkError, load_intersection
    from dica.sim_gateway.network import run_network
    from dica.sim_gateway.network_trips import write_trips_csv
    from dica.sim_gateway.od_demand import DemandError, OdDemand, write_od_routes
    from dica.sim_gateway.outputs import write_outputs
    from dica.sim_gateway.runconfig import RunConfig, RunError
    from dica.sim_gateway.scenario import ScenarioError
    from dica.tools.args import fleet

    args = parser().parse_args(argv)
    for name in ("volume", "duration", "drain"):
        x = getattr(args, name)
        if not (math.isfinite(x) and x >= 0.0) or (name == "duration" and x <= 0.0):
            unit = "vehicles per hour" if name == "volume" else "seconds"
            raise UsageError(f"--{name} must be a number of {unit} > 0, got {x}")
    if not 0.0 <= args.ev_prob <= 1.0:
        raise UsageError(f"--ev-prob is a probability, 0 to 1, got {args.ev_prob}")
    if args.routes is not None and args.ev_prob:
        raise UsageError("--ev-prob draws emergency vehicles into the drawn demand; a route "
                         "file's are those of a vType with vClass=\"emergency\"")  # fmt: skip
    if args.net is None and args.junctions != "all":
        raise UsageError("--junctions chooses junctions of --net; a built-in layout runs all")
    if args.control != "dica" and args.algorithm != "enhanced":
        raise UsageError(f"--algorithm is DICA's; --control {args.control} runs lights")
    if args.control != "dica" and args.record:
        raise UsageError("--record draws the ICAs' reservations: it needs --control dica")
    if args.ev_notices and (args.control != "dica" or args.algorithm != "rdica"):
        raise UsageError("--ev-notices applies to --control dica --algorithm rdica only")
    layout = args.layout or ("grid" if args.net is None else None)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = options.out_dir(
        args.out or Path("runs") / f"network-{layout or 'net'}-{args.control}-{stamp}"
    )
    try:
        net, free_net, junctions = _nets(args, layout, out)
        # each junction read first: one the net lacks is named as such, before the demand
        sized = fleet(args.routes, None) if args.control == "dica" else None
        inters = [load_intersection(str(net), j, fleet=sized) for j in junctions]
        routes = args.routes
        n = None
        if routes is None:
            routes = out / "od.rou.xml"
            demand = OdDemand(
                args.volume,
                args.duration,
                args.seed,
                args.turns,
                tuple(args.entry_volume),
                args.ev_prob,
            )
            n = write_od_routes(free_net, junctions, demand, routes)
        elif not routes.is_file():
            raise UsageError(f"route file not found: {routes}")
        extra: tuple[str, ...] = ()
        if args.control == "coordinated":
            extra = ("--additional-files", str(_offsets(net, routes, out)))
        cfg = RunConfig(
            net_path=str(net), junction_id=junctions[0], routes_path=str(routes),
            junction_ids=junctions if len(junctions) > 1 else (), algorithm=args.algorithm,
            duration_s=args.duration + args.drain, seed=args.seed, sumo_args=extra,
            network_gate=args.network_gate, network_gate_rule=args.network_gate_rule,
            ev_notices=args.ev_notices,
        )  # fmt: skip
    except (RunError, NetworkError, ScenarioError, DemandError) as e:
        raise UsageError(str(e)) from None
    total = cfg.duration_s
    with tqdm(total=total, desc="sim time", unit="s", disable=args.quiet) as bar:
        last = [0.0]

        def tick(t: float, waiting: int, crossed: int) -> None:
            if t - last[0] >= 1.0:
                bar.set_postfix(crossed=crossed, refresh=False)
                bar.update(t - last[0])
                last[0] = t

        try:
            result = run_network(
                cfg, inters, progress=tick, run_dir=out, until_empty_after_s=args.duration,
                rrd_path=out / "spacetime.rrd" if args.record else None,
                lights=LIGHTS_BY_CONTROL[args.control],
            )  # fmt: skip
        except RunError as e:
            raise UsageError(str(e)) from None
    result.extra["network_run"] = {
        "layout": layout, "net": str(args.net or net), "control": args.control,
        "algorithm": args.algorithm if args.control == "dica" else None,
        "junctions": list(junctions), "routes": str(routes),
        "volume_vph": None if args.routes else args.volume,
        "entry_vph": None if args.routes else dict(args.entry_volume),
        "turns": None if args.routes else list(args.turns), "seed": args.seed,
        "ev_prob": None if args.routes else args.ev_prob,
        "demand_s": args.duration, "drawn_vehicles": n, "ev_notices": cfg.ev_notices,
    }  # fmt: skip
    write_outputs(out, dataclasses.replace(cfg), result)
    if result.net_trips is not None:
        write_trips_csv(out / "trips.csv", result.net_trips)
    return _report(out, result, args.control)


def _nets(args, layout: str | None, out: Path) -> tuple[Path, Path, tuple[str, ...]]:
    """The net the control runs on, the signal-free one the demand is drawn on (the same
    roads), and the junctions under control."""
    from dica.sim_gateway.network_layouts import build_network
    from dica.tools.args import chosen_junctions

    if layout is not None:
        free = build_network(layout, out / "net")
        lit = free
        if args.control != "dica":
            lit = build_network(layout, out / "net", NET_LIGHTS[args.control], free)
        return lit.net_path, free.net_path, free.junctions
    if not args.net.is_file():
        raise UsageError(f"network file not found: {args.net}")
    junctions = chosen_junctions(args.net, args.junctions, args.routes)
    if args.control != "dica":
        from dica.sim_gateway.scenario import unlit

        dark = unlit(args.net, junctions)
        shown = ", ".join(dark[:6]) + (", ..." if len(dark) > 6 else "")
        if dark and (len(dark) == len(junctions) or args.control in LIGHTS_EACH):
            raise UsageError(
                f"--control {args.control} runs the lights of {args.net.name}, and "
                f"{len(dark)} of the {len(junctions)} chosen junctions have none ({shown}): "
                "give the net lights (netconvert --tls.guess, or --tls.set with their ids) "
                "or choose the junctions that have them with --junctions"
            )
        if dark:
            print(
                f"note: {len(dark)} of the {len(junctions)} junctions have no light in "
                f"{args.net.name} ({shown}); under --control {args.control} they keep the "
                "net's own right of way",
                file=sys.stderr,
            )
    if args.control == "actuated":
        return _actuated(args.net, out / "net"), args.net, junctions
    return args.net, args.net, junctions


def _offsets(net: Path, routes: Path, out: Path) -> Path:
    """Green-wave offsets of the net's fixed-time lights for the demand's main flows, by
    SUMO's own tlsCoordinator (at 0.9 x the limit, the demand's drivers' pace from a
    standing start), as an additional file."""
    import subprocess

    import sumo

    tool = Path(sumo.SUMO_HOME) / "tools" / "tlsCoordinator.py"
    offsets = out / "offsets.add.xml"
    cmd = [sys.executable, str(tool), "-n", str(net), "-r", str(routes), "-o", str(offsets),
           "--speed-factor", "0.9"]  # fmt: skip
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    if p.returncode != 0 or not offsets.is_file():
        tail = " | ".join(p.stderr.strip().splitlines()[-3:])
        raise UsageError(f"tlsCoordinator could not coordinate {net.name}: {tail}")
    return offsets


def _actuated(net: Path, out_dir: Path) -> Path:
    """The user's net with its lights rebuilt actuated (the junctions without stay so),
    its geometry as it was (no flags that redraw the junctions)."""
    from dica.sim_gateway.scenario import NETCONVERT_FLAGS, rebuilt_actuated

    return rebuilt_actuated(net, out_dir, "-actuated", NETCONVERT_FLAGS[:4])


def _report(out: Path, result, control: str) -> int:
    from dica.tools.args import report_people

    n = result.extra.get("network", {})
    run = result.extra["network_run"]

    def f(x: float | None, d: int = 1) -> str:
        return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{d}f}"

    left = ""  # the unfinished, by where they were at the end
    parts = [
        (n.get("in_net_at_end", 0), "still in the net"),
        (n.get("waiting_to_enter_at_end", 0), "waiting to enter"),
        (n.get("removed_on_the_way", 0), "taken out by SUMO"),
    ]
    if any(k for k, _ in parts):
        left = " (" + ", ".join(f"{k} {what}" for k, what in parts if k) + "); over the finished:"
    print(
        f"{run['layout'] or Path(run['net']).name}, {control}: {n.get('vehicles', 0)} vehicles, "
        f"{n.get('finished', 0)} finished{left or ';'} mean delay {f(n.get('mean_delay_s'))} s "
        f"(p95 {f(n.get('p95_delay_s'))} s), mean travel time {f(n.get('mean_travel_time_s'))} s, "
        f"{f(n.get('mean_stops'), 2)} stops per vehicle"
    )
    ev = n.get("emergency")
    if ev:
        print(
            f"emergency vehicles: {ev['finished']} of {ev['vehicles']} finished; mean travel "
            f"time {f(ev['mean_travel_time_s'])} s, {f(ev['mean_travel_to_free_flow'], 2)} x "
            f"free flow (worst {f(ev['max_travel_to_free_flow'], 2)} x); the others' mean delay "
            f"{f(n['normal']['mean_delay_s'])} s"
        )
    stood = result.extra.get("stood_inside", 0)
    unconfirmed = result.extra.get("unconfirmed_entries", 0)
    print(
        f"safety: {result.safety['overlaps']} overlaps (independent check), "
        f"{result.sumo_collisions} SUMO collisions at the junctions "
        f"({result.extra.get('sumo_collisions_elsewhere', 0)} elsewhere), "
        f"{stood} vehicles stood inside a junction, {unconfirmed} unconfirmed entries"
    )
    touched = report_people(result)
    still = result.extra.get("longest_standstill_s", 0.0)
    if still >= 60.0:
        print(f"note: for {still:.0f} s vehicles waited and none crossed (a network locked?)")
    gate = result.extra.get("network_gate")
    if gate:
        if gate["rule"] == "cycle":
            peak, bound = gate["peak_m"], gate["capacity_m"]
            print(f"network gate: the queue on the links peaked at {peak:.0f} of {bound:.0f} m")
        else:
            print(
                f"network gate: the fullest link was promised {gate['peak_share']:.0%} of its "
                f"capacity at most (the queue on the links peaked at {gate['peak_m']:.0f} m)"
            )
    print(
        f"{result.simulated_s:.0f} s simulated in {result.wall_s:.1f} s; wrote {out}/metrics.json"
    )
    bad = result.safety["overlaps"] or result.sumo_collisions or unconfirmed or touched
    if control == "dica":
        bad = bad or stood
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
