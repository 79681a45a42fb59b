"""Options and helpers that several `dica` subcommands share: the scenario and run
options, turning them into a run's configuration, and the one-line usage error.

`tools/cli.py` (the offline commands) and `tools/roles.py` (the cluster's
processes) both build on this module and on nothing of each other.
"""

from __future__ import annotations

import argparse
from pathlib import Path


class UsageError(Exception):
    """Bad input from the user: reported as one line, exit status 2."""


def intersection(args: argparse.Namespace):
    from dica.ica.netfile import NetworkError, load_intersection
    from dica.sim_gateway.scenario import ScenarioError, default_scenario

    try:
        if args.net:
            if not args.junction:
                raise UsageError("--net needs --junction (the junction id in that network)")
            return load_intersection(args.net, args.junction)
        sc = default_scenario(args.layout)
        return load_intersection(sc.net_path, sc.junction_id)
    except (NetworkError, ScenarioError) as e:
        raise UsageError(str(e)) from None


def add_net_args(p: argparse.ArgumentParser) -> None:
    from dica.sim_gateway.scenario import LAYOUTS

    p.add_argument(
        "--layout",
        choices=LAYOUTS,
        default="ch45",
        help="built-in intersection: ch3 (2 lanes in, 1 out) or ch45 (3 in, 2 out; default)",
    )
    p.add_argument("--net", type=Path, help="any SUMO .net.xml instead of a built-in layout")
    p.add_argument("--junction", help="junction id in --net")


def run_config(args: argparse.Namespace):
    """The RunConfig and intersection the run options name (shared with `dica gateway`)."""
    import shlex

    from dica.sim_gateway.runconfig import LIGHTS, RunConfig, RunError

    if args.net:
        if not args.junction:
            raise UsageError("--net needs --junction (the junction id in that network)")
        net, junction = str(args.net), args.junction
    else:
        from dica.sim_gateway.scenario import ScenarioError, default_scenario

        tls = None
        if args.algorithm in LIGHTS:
            tls = "actuated" if args.algorithm == "actuated" else "static"
        try:
            sc = default_scenario(args.layout, tls=tls)
        except ScenarioError as e:
            raise UsageError(str(e)) from None
        net, junction = str(sc.net_path), sc.junction_id
    if not 0 <= args.seed < 2**32:
        raise UsageError(f"--seed must be between 0 and {2**32 - 1}, got {args.seed}")
    if args.ramp is not None and not 1.0 <= args.ramp <= 1e6:
        raise UsageError(f"--ramp must be between 1 and 1000000 s, got {args.ramp:g}")
    inter = intersection(args)
    try:
        cfg = RunConfig(
            net_path=net,
            junction_id=junction,
            algorithm=args.algorithm,
            volume_per_10min=args.volume,
            seed=args.seed,
            duration_s=args.duration,
            until_left=args.until_left,
            margin_m=args.margin,
            sumo_args=tuple(shlex.split(args.sumo_args)) if args.sumo_args else (),
            tile_m=args.tile_size,
            approach_weights=_weights(args.approach_weights),
            volume_end_per_10min=args.volume_end,
            ramp_s=args.ramp if args.ramp is not None else args.duration,
            time_pad_s=args.time_pad,
            lead_s=getattr(args, "lead", 0.0),
            window_s=getattr(args, "window", 0.0),
            ev_prob=_ev_prob(args),
            solver=args.solver,
            revocation=getattr(args, "revocation", "replan"),
            platoon=args.platoon,
            headway_s=headway_s(args),
            run_up=getattr(args, "run_up", True),
            exit_spacing=getattr(args, "exit_spacing", True),
        )
    except RunError as e:
        raise UsageError(str(e)) from None
    return cfg, inter


def report_run(out: Path, result) -> int:
    """Print a run's headline figures; exit status 1 if anything collided."""
    m = result.metrics
    print(
        f"{m['generated']} generated, {m['crossed']} crossed (rho {m['throughput']:.3f}), "
        f"mean trip {_num(m['mean_trip_time_s'])} s, "
        f"tau_e {_num(m['effective_mean_trip_time_s'])} s, "
        f"stopped {_num(m['stopped_rate'])}"
    )
    unconfirmed = result.extra.get("unconfirmed_entries", 0)
    print(
        f"safety: {result.safety['overlaps']} overlaps (independent check), "
        f"{result.sumo_collisions} SUMO collisions, min gap {_num(result.safety['min_gap_m'])} m, "
        f"{unconfirmed} unconfirmed entries"
    )
    print(f"{result.sim_time_s:.0f} s simulated in {result.wall_s:.1f} s; wrote {out}/metrics.json")
    return 1 if result.safety["overlaps"] or result.sumo_collisions or unconfirmed else 0


def _weights(text: str | None) -> tuple[tuple[str, float], ...]:
    if not text:
        return ()
    out = []
    for item in text.split(","):
        name, _, value = item.partition("=")
        try:
            out.append((name.strip(), float(value)))
        except ValueError:
            raise UsageError(f"--approach-weights wants EDGE=WEIGHT,..., got {item!r}") from None
    return tuple(out)


def _ev_prob(args: argparse.Namespace) -> float:
    """--ev-prob, or the dissertation's 0.02 for the algorithms that act on EVs."""
    if args.ev_prob is not None:
        return args.ev_prob
    return 0.02 if args.algorithm in ("rdica", "reactive-light") else 0.0


def _num(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"


PLATOON_HEADWAY_S = 0.3  # [s] a platoon follower's default time headway


def add_platoon_arg(p: argparse.ArgumentParser) -> None:
    """--platoon / --no-platoon and --headway, shared by runs, the gateway and the ICA."""
    p.add_argument(
        "--platoon",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="a vehicle may ask once the vehicle ahead of it in its lane flies its plan, and "
        "crosses behind it as a platoon (default); --no-platoon: only once that vehicle has "
        "entered the junction, the dissertation's rule",
    )
    p.add_argument(
        "--headway",
        type=float,
        help="a follower keeps behind its lane leader's plan by this time [s] as well as by "
        f"twice the margin in space (default {PLATOON_HEADWAY_S:g} s with platoons, 0 without)",
    )


def add_plan_args(p: argparse.ArgumentParser) -> None:
    """--run-up and --exit-spacing: how the ICA plans (runs, the ICA)."""
    p.add_argument(
        "--run-up",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="a vehicle that must wait enters the junction at speed: it slows to as little "
        "as 0.5 m/s, or stands back as far as pulling away to the crossing cap needs "
        "(default); --no-run-up: it slows to 2 m/s at least, else stops at the line",
    )
    p.add_argument(
        "--exit-spacing",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="a vehicle may leave the junction faster than a slower vehicle ahead on its exit "
        "lane, late enough that the road's driver never brakes behind it (default); "
        "--no-exit-spacing: never faster than it (checkFV's cap alone)",
    )


def headway_s(args: argparse.Namespace) -> float:
    """--headway, or its default for --platoon / --no-platoon."""
    if args.headway is not None:
        return args.headway
    return PLATOON_HEADWAY_S if args.platoon else 0.0


def add_run_args(r: argparse.ArgumentParser) -> None:
    """Scenario and traffic options of a run (shared with `dica gateway`)."""
    add_net_args(r)
    r.add_argument(
        "--algorithm",
        default="enhanced",
        help="DICA: basic, enhanced, t1..t4 (t2+4); rdica (reactive DICA: emergency vehicles "
        "first, see --solver); baselines: fifo, concurrent, tiles, fixed (optimised "
        "fixed-cycle light), actuated (SUMO's actuated light), reactive-light (31/13/83 s "
        "program with emergency-vehicle pre-emption)",
    )
    r.add_argument(
        "--ev-prob",
        type=float,
        help="probability that an arriving vehicle is an emergency vehicle, at most one in the "
        "region at a time (default 0.02 for rdica and reactive-light, else 0)",
    )
    r.add_argument(
        "--solver",
        choices=("exact", "ga", "exhaustive"),
        default="exact",
        help="rdica's ordering solver: exact (dynamic programme, default), ga (the "
        "dissertation's genetic algorithm) or exhaustive (every order, refuses large sets)",
    )
    r.add_argument("--tile-size", type=float, default=1.0, help="tile edge for tiles [m]")
    r.add_argument(
        "--approach-weights",
        help="relative demand per approach, e.g. N_in=1,S_in=1,E_in=0.3,W_in=0.3 (default equal)",
    )
    r.add_argument("--volume-end", type=float, help="volume reached by --ramp seconds (linear)")
    r.add_argument(
        "--ramp", type=float, help="seconds over which the volume ramps (default: duration)"
    )
    r.add_argument(
        "--volume",
        type=float,
        default=300.0,
        help="vehicles per 10 min (100-500 in the dissertation)",
    )
    r.add_argument("--seed", type=int, default=12)
    r.add_argument("--duration", type=float, default=600.0, help="simulated seconds (default 600)")
    r.add_argument(
        "--until-left", type=int, help="instead: generate N vehicles and run until all have left"
    )
    r.add_argument("--margin", type=float, default=0.25, help="safety margin per side [m]")
    r.add_argument(
        "--time-pad",
        type=float,
        default=0.0,
        help="the ICA grows every confirmed occupancy interval by this on each side [s]: "
        "the declared bound on how far off its plan in time a vehicle may be (default 0)",
    )
    add_platoon_arg(r)
    r.add_argument("--sumo-args", help="extra SUMO options, verbatim, e.g. '--fcd-output f.xml'")
