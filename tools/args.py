"""What several `dica` subcommands share beyond their options: the junction and the
run the options name, a run's headline figures.

The options themselves are defined once, in :mod:`dica.tools.options`;
`tools/cli.py` (the offline commands) and `tools/roles.py` (the cluster's
processes) both build on these two modules and on nothing of each other.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path

from dica.ica.core.config import MAX_ADDED_DELAY_S
from dica.tools import options
from dica.tools.options import UsageError


def fleet(routes, algorithm: str | None) -> tuple[float, float] | None:
    """The longest and the widest vehicle the ICA's plans may meet: a route file's largest
    type, or the drawn demand's car (None under lights, which plan nothing). Where one that
    size turning sweeps over the place a vehicle waits at a lane's line, that line moves
    back (:mod:`ica.core.waiting`)."""
    from dica.sim_gateway.route_file import CAR_SIZE, fleet_size
    from dica.sim_gateway.runconfig import LIGHTS, RunError

    if algorithm in LIGHTS:
        return None
    if not routes:
        return CAR_SIZE
    try:
        return fleet_size(Path(routes))
    except RunError as e:
        raise UsageError(str(e)) from None


def intersection(args: argparse.Namespace):
    from dica.ica.netfile import NetworkError, load_intersection
    from dica.sim_gateway.scenario import ScenarioError, default_scenario

    sized = fleet(getattr(args, "routes", None), getattr(args, "algorithm", None))
    try:
        if args.net:
            return load_intersection(args.net, args.junction, fleet=sized)
        sc = default_scenario(args.layout)
        return load_intersection(sc.net_path, sc.junction_id, fleet=sized)
    except (NetworkError, ScenarioError) as e:
        raise UsageError(str(e)) from None


def run_config(args: argparse.Namespace):
    """The RunConfig and intersection the run options name (shared with `dica gateway`)."""

    from dica.sim_gateway.runconfig import LIGHTS, RunConfig, RunError

    junctions: tuple[str, ...] = ()
    if getattr(args, "junctions", None):
        junctions = chosen_junctions(args.net, args.junctions, getattr(args, "routes", None))
        args.junction = junctions[0]
    if args.net:
        net, junction = str(args.net), args.junction
    else:
        from dica.sim_gateway.scenario import ScenarioError, default_scenario

        tls = None
        if args.algorithm in LIGHTS and args.algorithm != "allway-stop":  # that one: no light
            tls = "actuated" if args.algorithm == "actuated" else "static"
        try:
            sc = default_scenario(args.layout, tls=tls)
        except ScenarioError as e:
            raise UsageError(str(e)) from None
        net, junction = str(sc.net_path), sc.junction_id
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
            sumo_args=_sumo_args(args.sumo_args),
            tile_m=args.tile_size,
            approach_weights=_weights(args.approach_weights),
            volume_end_per_10min=args.volume_end,
            ramp_s=args.ramp if args.ramp is not None else args.duration,
            time_pad_s=args.time_pad,
            green_late_s=getattr(args, "green_late", 0.0),
            lead_s=getattr(args, "lead", 0.0),
            window_s=getattr(args, "window", 0.0),
            ev_prob=_ev_prob(args),
            solver=args.solver,
            max_added_delay_s=getattr(args, "max_added_delay", MAX_ADDED_DELAY_S),
            revocation=getattr(args, "revocation", "replan"),
            platoon=args.platoon,
            headway_s=headway_s(args),
            run_up=getattr(args, "run_up", True),
            exit_spacing=getattr(args, "exit_spacing", True),
            routes_path=str(args.routes) if getattr(args, "routes", None) else None,
            begin_s=getattr(args, "begin", 0.0),
            junction_ids=junctions if len(junctions) > 1 else (),
            network_gate=getattr(args, "network_gate", True),
            network_gate_rule=getattr(args, "network_gate_rule", "route"),
            ev_notices=getattr(args, "ev_notices", False),
            peds_per_h=getattr(args, "peds", 0.0) or 0.0,
            cav_share=getattr(args, "cav_share", 1.0),
        )
    except RunError as e:
        raise UsageError(str(e)) from None
    return cfg, inter


def chosen_junctions(net: Path, text: str, routes=None) -> tuple[str, ...]:
    """--junctions: the ids it names, or every junction of ``net`` where two roads or
    more come in (``all``) that the ICA can serve; each one it cannot is left to the net's
    own control, with a note saying why: one it cannot read, or one with an exit road too
    short to let the route file's longest vehicle onto (``routes``: the route file)."""
    from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M
    from dica.ica.core.gridlock import short_exits
    from dica.ica.core.limits import Kinematics
    from dica.ica.netfile import NetworkError, crossing_junctions, load_intersection

    if text.strip() == "all":
        try:
            found = crossing_junctions(net)
        except NetworkError as e:
            raise UsageError(str(e)) from None
        if not found:
            raise UsageError(f"{net} has no junction where two roads or more come in")
        sized = fleet(routes, None)  # never None: no light's algorithm is named
        longest = sized[0]
        served, notes = [], []
        for j in found:
            try:
                inter = load_intersection(net, j, fleet=sized)
            except NetworkError as e:
                why = str(e).removeprefix(f"junction {j!r}: ")
                notes.append(f"junction {j} stays as the net has it: {why}")
                continue
            short = short_exits(inter, longest, Kinematics().decel_mps2, ROOM_GAP_M, ROOM_SLACK_M)
            if short:
                e, m, want = short[0]
                notes.append(f"junction {j} stays as the net has it: its exit {e} is {m:.1f} m "
                             f"long, and a {longest:g} m vehicle let onto it needs {want:.1f} m "
                             "of room beyond the junction")  # fmt: skip
                continue
            served.append(j)
        if not served:  # one line: the first reason
            why = notes[0].replace(" stays as the net has it", "") if notes else ""
            raise UsageError(f"{net}: the ICA can serve none of its junctions ({why})")
        for line in notes:
            print(f"note: {line}", file=sys.stderr)
        return tuple(served)
    ids = tuple(x.strip() for x in text.split(","))
    if not all(ids):
        raise UsageError(f"--junctions wants all or J1,J2,..., got {text!r}")
    if len(set(ids)) < len(ids):
        raise UsageError(f"--junctions names a junction twice: {','.join(ids)}")
    return ids


def intersections(cfg) -> list:
    """The intersections of a run of several junctions (its first is run_config's)."""
    from dica.ica.netfile import NetworkError, load_intersection

    try:
        sized = fleet(cfg.routes_path, cfg.algorithm)
        return [load_intersection(cfg.net_path, j, fleet=sized) for j in cfg.junction_ids]
    except NetworkError as e:
        raise UsageError(str(e)) from None


def report_run(out: Path, result) -> int:
    """Print a run's headline figures; exit status 1 if anything collided (vehicles with
    each other, or with people)."""
    m = result.metrics
    print(
        f"{m['generated']} generated, {m['crossed']} crossed (rho {m['throughput']:.3f}), "
        f"mean trip {_num(m['mean_trip_time_s'])} s, "
        f"tau_e {_num(m['effective_mean_trip_time_s'])} s, "
        f"stopped {_num(m['stopped_rate'])}"
    )
    unconfirmed = result.extra.get("unconfirmed_entries", 0)
    elsewhere = result.extra.get("sumo_collisions_elsewhere", 0)
    beyond = f" ({elsewhere} more elsewhere in the net, among SUMO's drivers)" if elsewhere else ""
    print(
        f"safety: {result.safety['overlaps']} overlaps (independent check), "
        f"{result.sumo_collisions} SUMO collisions{beyond}, "
        f"min gap {_num(result.safety['min_gap_m'])} m, {unconfirmed} unconfirmed entries"
    )
    touched = report_people(result)
    if result.extra.get("ended_short"):
        print(
            f"note: {result.extra['ended_short']} vehicles had no way on to their destination "
            "that the junctions serve (no way back from the road their lane led to, or only "
            "by a U-turn at a junction that had sent them round once already) and left the "
            "net at that road's end"
        )
    summaries = _reactive(result.extra)
    bound = next((r["max_added_delay_s"] for r in summaries if r.get("max_added_delay_s")), None)
    added = max((r.get("added_delay_max_s") or 0.0 for r in summaries), default=0.0)
    if bound is not None and added > bound + 1e-6:
        print(
            f"note: reorderings added up to {added:.1f} s to a vehicle, over the {bound:g} s "
            "bound (--max-added-delay): the solvers keep it on the plans they foresee, and "
            "near saturation the real ones can come later"
        )
    print(
        f"{result.simulated_s:.0f} s simulated in {result.wall_s:.1f} s; wrote {out}/metrics.json"
    )
    collided = result.safety["overlaps"] or result.sumo_collisions or unconfirmed or touched
    return 1 if collided else 0


def _reactive(extra: dict) -> list[dict]:
    """The reorderings' figures of a run: the embedded run's, or each ICA process's in a
    cluster (its roles' statistics, one ICA or one per junction)."""
    if extra.get("reactive"):
        return [extra["reactive"]]
    roles = extra.get("roles") or {}
    icas = [roles["ica"]] if isinstance(roles.get("ica"), dict) else [
        r["ica"] for r in roles.values() if isinstance(r, dict) and isinstance(r.get("ica"), dict)
    ]  # fmt: skip
    return [x["reactive"] for x in icas if isinstance(x.get("reactive"), dict)]


def report_people(result) -> int:
    """Print the people's safety line, if the run had people on foot; how many touches
    either check counted (a vehicle touching a person is a collision like any other)."""
    walkers = result.extra.get("walkers")
    if not walkers:
        return 0
    hits, sumo_hits = walkers["person_hits"], walkers["sumo_person_collisions"]
    elsewhere = walkers.get("sumo_person_collisions_elsewhere", 0)
    print(
        f"people: {hits} steps a vehicle touched a person (independent check), "
        f"{sumo_hits} SUMO person collisions at the junctions ({elsewhere} elsewhere), "
        f"closest {_num(walkers['min_person_gap_m'])} m"
    )
    return hits + sumo_hits


def _sumo_args(text: str | None) -> tuple[str, ...]:
    """--sumo-args split as a shell would; an unclosed quote is one clear line."""
    try:
        return tuple(shlex.split(text)) if text else ()
    except ValueError as e:
        raise UsageError(f"--sumo-args {text!r}: {e}") from None


def _weights(text: str | None) -> tuple[tuple[str, float], ...]:
    if not text:
        return ()
    out = []
    for item in text.split(","):
        name, _, value = item.partition("=")
        try:
            weight = float(value)
        except ValueError:
            raise UsageError(f"--approach-weights wants EDGE=WEIGHT,..., got {item!r}") from None
        if not (math.isfinite(weight) and weight >= 0.0):
            raise UsageError(f"--approach-weights wants finite weights of 0 or more, got {item!r}")
        out.append((name.strip(), weight))
    return tuple(out)


def _ev_prob(args: argparse.Namespace) -> float:
    """--ev-prob, or the dissertation's 0.02 for the algorithms that act on EVs (0 with a
    route file: its EVs are its vehicles of SUMO's emergency class)."""
    if args.ev_prob is not None:
        return args.ev_prob
    if getattr(args, "routes", None):
        return 0.0
    return 0.02 if args.algorithm in ("rdica", "reactive-light") else 0.0


def _num(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"


PLATOON_HEADWAY_S = 0.3  # [s] a platoon follower's default time headway


def headway_s(args: argparse.Namespace) -> float:
    """--headway, or its default for --platoon / --no-platoon."""
    if args.headway is not None:
        return args.headway
    return PLATOON_HEADWAY_S if args.platoon else 0.0


RUN = (*options.NET, "--algorithm", "--solver", "--max-added-delay", "--tile-size",
       *options.TRAFFIC, "--margin", "--time-pad", "--green-late", "--platoon",
       "--headway")  # fmt: skip


def add_run_args(p: argparse.ArgumentParser, **changes: dict) -> None:
    """The scenario, traffic and controller options of a run (shared with `dica gateway`)."""
    options.add(p, *RUN, **changes)
