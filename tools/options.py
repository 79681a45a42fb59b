"""Every command-line option of ``dica`` and its roles, defined once.

An :class:`Option` is a flag's type, default, range, help and which
controllers it applies to. Commands add options by name (:func:`add`) and
parse with :class:`Parser`; :func:`check` then refuses, in one line and with
one text per option, a value out of range or an option given to a controller
that does not take it. The defaults come from the settings they fill
(:class:`~dica.ica.core.config.IcaConfig`,
:class:`~dica.sim_gateway.runconfig.RunConfig`), and the ranges a run's
settings must keep from :data:`dica.sim_gateway.runconfig.LIMITS`, so a value a
command refuses and one a run refuses read the same.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from dica.ica.core.config import SOLVERS, IcaConfig
from dica.sim_gateway.runconfig import (
    GATE_RULES,
    LIGHTS,
    LIMITS,
    REVOCATIONS,
    Limit,
    RunConfig,
)
from dica.sim_gateway.scenario import LAYOUTS


class UsageError(Exception):
    """Bad input from the user: reported as one line, exit status 2."""


class Parser(argparse.ArgumentParser):
    """argparse, but a bad command line is one line on stderr (and exit status 2),
    like every other refusal of ``dica``."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _run(name: str) -> Any:
    return next(f.default for f in dataclasses.fields(RunConfig) if f.name == name)


_ICA = IcaConfig()
RDICA = ("rdica",)


@dataclass(frozen=True, slots=True)
class Option:
    """One command-line option. ``only_for``: the algorithms it applies to (None: all);
    given with another it is refused rather than ignored."""

    flag: str
    help: str
    type: Callable[[str], Any] | None = None
    default: Any = None
    limit: Limit | None = None
    choices: tuple[str, ...] | None = None
    action: Any = None
    metavar: str | None = None
    only_for: tuple[str, ...] | None = None
    required: bool = False
    key: str = ""  # its name in the registry where two commands' options share a flag

    @property
    def name(self) -> str:
        return self.key or self.flag

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")

    def add(self, p: argparse.ArgumentParser, **change: Any) -> None:
        o = dataclasses.replace(self, **change) if change else self
        kw: dict[str, Any] = {"help": o.help}
        if o.action is not None:
            kw["action"] = o.action
        if o.type is not None:
            kw["type"] = o.type
        if o.choices is not None:
            kw["choices"] = o.choices
        if o.metavar is not None:
            kw["metavar"] = o.metavar
        if o.required:
            kw["required"] = True
        # an option that applies to some algorithms only is left unset, so that one the
        # user gave can be told from the default (check() fills the default in)
        kw["default"] = None if o.only_for is not None else o.default
        if o.only_for is not None and o.action is None:
            _LATE[o.dest] = o
        p.add_argument(o.flag, **kw)


def seconds_or_auto(text: str) -> float | str:
    """A number of seconds, or ``auto`` (the agent's lead: measured)."""
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"wants a number of seconds or auto, got {text!r}"
        ) from None


_LATE: dict[str, Option] = {}  # dest -> option whose default check() fills in

ALGORITHMS_HELP = (
    "DICA: basic, enhanced, t1..t4 (t2+4); rdica (reactive DICA: emergency vehicles first, "
    "see --solver); baselines: fifo, concurrent, tiles"
)

OPTIONS: dict[str, Option] = {
    o.name: o
    for o in (
        # -- the junction
        Option(
            "--layout",
            "built-in intersection: ch3 (2 lanes in, 1 out), ch45 (3 in, 2 out; default), "
            "skewed or tee; each with -walk (ch45-walk, ...) has sidewalks and a crossing "
            "over every arm",
            choices=LAYOUTS,
            default="ch45",
        ),
        Option("--net", "any SUMO .net.xml instead of a built-in layout", Path),
        Option("--junction", "the junction's id in --net (needs --net)"),
        Option(
            "--junctions",
            "several junctions of --net, each signal-free under its own ICA: J1,J2,... or "
            "all (every junction where two roads or more come in); the others stay as the "
            "net has them. Needs --routes; instead of --junction",
            metavar="all|J1,J2,...",
        ),
        Option(
            "--network-gate",
            "with --junctions: bound what the links between the junctions hold, so the "
            "network cannot lock (default; see --network-gate-rule); --no-network-gate: no "
            "bound (the network carries more, and may stand still)",
            action=argparse.BooleanOptionalAction,
            default=True,
        ),
        Option(
            "--ev-notices",
            "with --junctions and --algorithm rdica: each emergency vehicle tells the junctions "
            "ahead on its route that it is coming, and each clears a short queue in the EV's "
            "lanes before it arrives; default off: each junction reacts once the EV is in its "
            "own region (docs/results.md: helps a busy corridor, costs a grid near saturation)",
            action=argparse.BooleanOptionalAction,
            default=False,
        ),
        Option(
            "--network-gate-rule",
            "the network gate's bound: route (default: a vehicle let in holds room on each "
            "guarded link of its route ahead, the few links every cycle passes, and none is "
            "promised more than its capacity) or cycle (the whole network holds at most its "
            "smallest cycle's capacity)",
            choices=GATE_RULES,
            default="route",
        ),
        # -- the controller
        Option(
            "--algorithm",
            ALGORITHMS_HELP + "; lights (dica run only): fixed (optimised fixed-cycle light), "
            "actuated (SUMO's actuated light), reactive-light (31/13/83 s program with "
            "emergency-vehicle pre-emption)",
            default=_run("algorithm"),
        ),
        Option(
            "--solver",
            "rdica's ordering solver: exact (dynamic programme, default), ga (the "
            "dissertation's genetic algorithm) or exhaustive (every order, refuses large sets)",
            choices=SOLVERS,
            default=_run("solver"),
            only_for=RDICA,
        ),
        Option(
            "--max-added-delay",
            "rdica: the most delay emergency vehicles' reorderings may add to any one other "
            "vehicle, summed over every reordering it meets [s] (default 2; inf: no bound, "
            "the dissertation's); the solvers keep it on the re-plans they foresee, and a run "
            "says if the real ones went over it",
            float,
            _run("max_added_delay_s"),
            LIMITS["max_added_delay_s"],
            only_for=RDICA,
            metavar="S",
        ),
        Option(
            "--revocation",
            "rdica's revoked vehicles: replan (the ICA plans them again in the solver's order, "
            "at once; default) or drop (each drops its plan, stops short of the line and asks "
            "again, answering the ICA one step later: what the cluster does)",
            choices=REVOCATIONS,
            default=_run("revocation"),
            only_for=RDICA,
        ),
        Option(
            "--tile-size",
            "the tiles baseline's tile edge [m] (default 1)",
            float,
            _run("tile_m"),
            LIMITS["tile_m"],
            only_for=("tiles",),
        ),
        Option(
            "--variant",
            "a DICA variant: basic, enhanced, or t1..t4 / t2+4 (default enhanced)",
            default="enhanced",
        ),
        Option(
            "--margin",
            "the ICA's safety margin per side [m] (default 0.25)",
            float,
            _ICA.margin_m,
            LIMITS["margin_m"],
        ),
        Option(
            "--time-pad",
            "the ICA grows every confirmed occupancy interval by this on each side [s]: the "
            "declared bound on how far off its plan in time a vehicle may be (default 0)",
            float,
            _ICA.time_pad_s,
            LIMITS["time_pad_s"],
        ),
        Option(
            "--green-late",
            "how late after its green time a human driver's head may still turn green [s]: "
            "the envelope allows for it and the roadside drops a later green, keeping the "
            "head red (default 0: the simulation's roadside is never late; run_cluster.sh "
            "sets it from the link's delay in real time)",
            float,
            _ICA.green_late_s,
            LIMITS["green_late_s"],
        ),
        Option(
            "--platoon",
            "a vehicle may ask once the vehicle ahead of it in its lane flies its plan, and "
            "crosses behind it as a platoon (default); --no-platoon: only once that vehicle "
            "has entered the junction, the dissertation's rule",
            action=argparse.BooleanOptionalAction,
            default=True,
        ),
        Option(
            "--headway",
            "a follower keeps behind its lane leader's plan by this time [s] as well as by "
            "twice the margin in space (default 0.3 s with platoons, 0 without)",
            float,
            limit=LIMITS["headway_s"],
        ),
        Option(
            "--run-up",
            "a vehicle that must wait enters the junction at speed: it slows to as little as "
            "0.5 m/s, or stands back as far as pulling away to the crossing cap needs "
            "(default); --no-run-up: it slows to 2 m/s at least, else stops at the line",
            action=argparse.BooleanOptionalAction,
            default=True,
        ),
        Option(
            "--exit-spacing",
            "a vehicle may leave the junction faster than a slower vehicle ahead on its exit "
            "lane, late enough that the road's driver never brakes behind it (default); "
            "--no-exit-spacing: never faster than it (checkFV's cap alone)",
            action=argparse.BooleanOptionalAction,
            default=True,
        ),
        Option(
            "--max-age",
            "oldest observation a REQUEST may be planned from [sim s] (default 1)",
            float,
            _ICA.max_request_age_s,
            Limit("--max-age", 0.0, 60.0, "s", lo_open=True),
        ),
        # -- the traffic
        Option(
            "--volume",
            "vehicles per 10 min (100-500 in the dissertation; default 300)",
            float,
            _run("volume_per_10min"),
            LIMITS["volume_per_10min"],
        ),
        Option(
            "--volume-end",
            "volume reached by --ramp seconds (linear)",
            float,
            limit=LIMITS["volume_end_per_10min"],
        ),
        Option(
            "--ramp",
            "seconds over which the volume ramps (default: the duration)",
            float,
            limit=Limit("--ramp", 1.0, 1e6, "s"),
        ),
        Option(
            "--vehicles",
            "how many vehicles (default 500)",
            int,
            500,
            Limit("--vehicles", 1, 100_000),
        ),
        Option(
            "--seed", "the random demand's seed (default 12)", int, _run("seed"), LIMITS["seed"]
        ),
        Option(
            "--duration",
            "simulated seconds (default 600)",
            float,
            _run("duration_s"),
            LIMITS["duration_s"],
        ),
        Option(
            "--until-left",
            "instead: generate N vehicles and run until all have left",
            int,
            limit=LIMITS["until_left"],
        ),
        Option(
            "--ev-prob",
            "probability that an arriving vehicle is an emergency vehicle, at most one in the "
            "region at a time (default 0.02 for rdica and reactive-light, else 0; with "
            "--routes, the file's vehicles of the emergency vClass are its EVs)",
            float,
            limit=LIMITS["ev_prob"],
        ),
        Option(
            "--peds",
            "people on foot: N persons an hour at every pedestrian crossing of the junction(s), "
            "held at the kerb until the ICA gives them the crossing (a net with crossings, "
            "e.g. --layout ch45-walk; default 0)",
            float,
            default=0.0,
            limit=LIMITS["peds_per_h"],
            metavar="N",
        ),
        Option(
            "--cav-share",
            "mixed traffic: the share of connected automated vehicles, 0 to 1 (default 1); "
            "the others are SUMO's own drivers, each held at a signal head of its lane that "
            "the ICA turns green once it has reserved every way the driver may cross",
            float,
            default=1.0,
            limit=LIMITS["cav_share"],
            metavar="P",
        ),
        Option(
            "--approach-weights",
            "relative demand per approach, e.g. N_in=1,S_in=1,E_in=0.3,W_in=0.3 (default equal)",
        ),
        Option("--sumo-args", "extra SUMO options, verbatim, e.g. '--fcd-output f.xml'"),
        Option(
            "--routes",
            "a SUMO demand file (routes, trips or flows with their vehicle types) instead of "
            "the random demand: SUMO drives its vehicles through --net and the junction "
            "takes each over in its region (needs --net; --volume and --seed then do not "
            "apply; the fixed light keeps the net's own greens)",
            Path,
            metavar="FILE.rou.xml",
        ),
        Option(
            "--begin",
            "with --routes: the simulated time the run starts at [s] (SUMO's --begin; "
            "default 0); --duration counts from it",
            float,
            _run("begin_s"),
            LIMITS["begin_s"],
        ),
        Option(
            "--lead",
            "vehicles plan each REQUEST this far ahead of what they observed [s], from where "
            "their stop law will have taken them: what a link with delay needs (default 0)",
            float,
            _run("lead_s"),
            LIMITS["lead_s"],
        ),
        Option(
            "--window",
            "collect the REQUESTs of this many seconds and decide them in the order that "
            "delays them least, each lane's order kept (0: first come, first served; "
            "default). Vehicles then plan at least this far ahead (--lead); DICA's "
            "controllers only",
            float,
            _run("window_s"),
            LIMITS["window_s"],
        ),
        Option(
            "--retry",
            "sim seconds before a rejected vehicle asks again (default 0.5)",
            float,
            _run("retry_s"),
            LIMITS["retry_s"],
        ),
        # -- outputs
        Option("--out", "output directory", Path),
        Option("--quiet", "no progress bar", action="store_true"),
        Option("--json", "print the result as JSON", action="store_true"),
        # -- the cluster
        Option(
            "--agents",
            "vehicle-agent processes to wait for (default 1)",
            int,
            1,
            Limit("--agents", 1, 10_000),
        ),
        Option(
            "--observers",
            "observer processes to wait for (default 0)",
            int,
            0,
            Limit("--observers", 0, 10_000),
        ),
        Option(
            "--per-agent",
            "most vehicles one agent hosts (0: no limit)",
            int,
            0,
            Limit("--per-agent", 0, 10_000),
        ),
        Option(
            "--clock",
            "lockstep (default) or realtime",
            choices=("lockstep", "realtime"),
            default="lockstep",
        ),
        Option(
            "--speed",
            "realtime clock: x wall-clock speed (default 1)",
            float,
            1.0,
            Limit("--speed", 0.0, 100.0, lo_open=True),
        ),
        Option(
            "--step-timeout",
            "lockstep: wait per step [s] (default 30)",
            float,
            30.0,
            Limit("--step-timeout", 1.0, 3600.0, "s"),
        ),
        Option(
            "--resend",
            "lockstep: send a STATE again after this many wall seconds without its COMMAND "
            "(default 0.5)",
            float,
            0.5,
            Limit("--resend", 0.05, 30.0, "s"),
        ),
        Option(
            "--checkpoint-every",
            "write what the run knows (marked incomplete) every N sim seconds (default 30)",
            float,
            30.0,
            Limit("--checkpoint-every", 1.0, 3600.0, "s"),
        ),
        Option(
            "--peers-timeout",
            "wait for peers at start [s] (default 60)",
            float,
            60.0,
            Limit("--peers-timeout", 0.0, 3600.0, "s", lo_open=True),
        ),
        Option(
            "--progress-every",
            "log a line every N sim s (default 30)",
            float,
            30.0,
            Limit("--progress-every", 0.0, 86400.0, "s", lo_open=True),
        ),
        Option(
            "--idle-exit",
            "stop after this many seconds without traffic",
            float,
            limit=Limit("--idle-exit", 0.0, 86400.0, "s", lo_open=True),
        ),
        Option(
            "--port",
            "web viewer HTTP port on 127.0.0.1 (with --web; default 9090)",
            int,
            9090,
            Limit("--port", 1, 65535),
        ),
        Option(
            "--grpc-port",
            "port of the live recording on 127.0.0.1 (default 9876)",
            int,
            9876,
            Limit("--grpc-port", 1, 65535),
        ),
        Option("--verbose", "debug logging", action="store_true"),
        # -- a secured site (dica secure-config)
        Option("--out", "the site's directory", Path, required=True, key="site"),
        Option(
            "--agents",
            "a new site's vehicle agents: a number N (agent-1 ... agent-N, as run_cluster.sh "
            "names them) or comma-separated names, each its --id (default 1)",
            default="1",
            key="site-agents",
        ),
        Option(
            "--add-agent",
            "issue identities to more agents on the site in --out (comma-separated names)",
            metavar="NAMES",
        ),
        Option(
            "--revoke-agent",
            "withdraw agents' identities on the site in --out (comma-separated names)",
            metavar="NAMES",
        ),
        Option(
            "--host",
            "a new site: a name or address clients reach the router by; repeat for more "
            "(the router's certificate is valid for these only; the first is the clients' "
            "default endpoint; default 127.0.0.1 and localhost)",
            action="append",
        ),
        Option(
            "--days",
            "a new site: certificate lifetime (default 365)",
            int,
            limit=Limit("--days", 1, 36_500),
        ),
        Option(
            "--junction",
            "a new site: a junction it serves (the roles' --junction); repeat for more; the "
            "rules name these and no other (default C, the built-in layouts' junction)",
            action="append",
            key="site-junction",
        ),
        Option(
            "--ica-per-junction",
            "a new site of several junctions: each junction's ICA its own log-in and seal "
            "(ica-<J>.json5, ica-<J>.seal), kept to its own junction's keys, instead of one "
            "ICA identity for them all",
            action="store_true",
        ),
        Option(
            "--rsus",
            "a new site of several roadside units: one router each (router.json5, "
            "router-2.json5, ...), each with a certificate of its own, logging in to the "
            "routers before it to make a mesh (default 1)",
            int,
            limit=Limit("--rsus", 1, 64),
        ),
        Option(
            "--force",
            "replace a site written before; with --add-agent, a new password for an agent the "
            "site has",
            action="store_true",
        ),
    )
}


def add(p: argparse.ArgumentParser, *names: str, **changes: dict[str, Any]) -> None:
    """Add the registry's options ``names`` (their flags, or their keys) to ``p``;
    ``changes`` maps an option's dest to what differs for this command (its help, its
    default), never its range."""
    for name in names:
        o = OPTIONS[name]
        o.add(p, **changes.get(o.dest, {}))


VOLUME_500 = {"default": 500.0, "help": "vehicles per 10 min (default 500)"}  # the benchmarks'
NET = ("--layout", "--net", "--junction")
PLAN = ("--margin", "--time-pad", "--green-late", "--platoon", "--headway", "--run-up",
        "--exit-spacing")  # fmt: skip
TRAFFIC = ("--volume", "--volume-end", "--ramp", "--seed", "--duration", "--until-left",
           "--ev-prob", "--peds", "--cav-share", "--approach-weights", "--sumo-args", "--routes",
           "--begin")  # fmt: skip


def check(args: argparse.Namespace) -> None:
    """Refuse what the options cannot serve, in one line each: a value out of its range,
    an option given to an algorithm that does not take it. Fills in the defaults of the
    options that apply to some algorithms only."""
    values = vars(args)
    for o in OPTIONS.values():
        v = values.get(o.dest)
        number = isinstance(v, (int, float)) and not isinstance(v, bool)
        if o.limit is not None and number and not o.limit.holds(v):
            raise UsageError(o.limit.text(v))
    algorithm = values.get("algorithm")
    for dest, o in _LATE.items():
        if dest not in values:
            continue
        if values[dest] is None:
            setattr(args, dest, o.default)
        elif algorithm is not None and algorithm not in o.only_for:
            raise UsageError(
                f"{o.flag} applies to {', '.join(o.only_for)} only; --algorithm {algorithm} "
                "does not take it"
            )
    if values.get("ev_notices"):
        if algorithm is not None and algorithm not in RDICA:
            raise UsageError(
                f"--ev-notices applies to rdica only; --algorithm {algorithm} does not take it"
            )
        if not values.get("junctions"):
            raise UsageError("--ev-notices tells the junctions ahead: give a network (--junctions)")
    if values.get("junction") and values.get("net") is None and "layout" in values:
        raise UsageError(
            "--junction names a junction of --net; a built-in --layout has one junction"
        )
    if values.get("routes") is not None and values.get("net") is None:
        raise UsageError("--routes needs --net (the network its routes run on)")
    if values.get("junctions"):
        if values.get("junction"):
            raise UsageError("--junction names one junction, --junctions several: give one")
        if values.get("net") is None:
            raise UsageError("--junctions names junctions of --net: give --net")
        if "routes" in values and values.get("routes") is None:
            raise UsageError("--junctions takes its vehicles from a route file: give --routes")
    elif values.get("net") is not None and not values.get("junction"):
        raise UsageError("--net needs --junction (the junction id in that network)")


def out_dir(path: Path) -> Path:
    """``path`` made (with its parents) to write a run into, or a one-line refusal."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"cannot write into {path}: {e.strerror or e}") from None
    if not path.is_dir():
        raise UsageError(f"{path} is not a directory")
    return path


# options whose value is itself options: ``--sumo-args --junction-taz`` is read as
# ``--sumo-args=--junction-taz`` (argparse would take the lone value for an option of its own)
VERBATIM = ("--sumo-args", "--extra")


def joined(argv: list[str], flags: tuple[str, ...] = VERBATIM) -> list[str]:
    """``argv`` with each of ``flags`` joined to the value after it (``--flag=value``)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] in flags and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def parse(p: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse and :func:`check`; a refusal is one line and exit status 2."""
    args = p.parse_args(joined(sys.argv[1:] if argv is None else argv))
    try:
        check(args)
    except UsageError as e:
        command = getattr(args, "command", None)  # a subcommand of dica's own parser
        prog = f"{p.prog} {command}" if command else p.prog
        p.exit(2, f"{prog}: {e} (see {prog} --help)\n")
    return args


__all__ = ["LIGHTS", "OPTIONS", "Option", "Parser", "UsageError", "add", "check", "out_dir"]
