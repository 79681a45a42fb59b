"""Origin-destination demand for a network of junctions: a volume per entry and turning
ratios, written as a SUMO route file.

Vehicles come into the network on every road that leads into one of its junctions
from outside, each at random (Poisson) at the entry's volume. At each junction a
vehicle turns left, goes through or turns right by the turning ratios (among the
turns its road has there), until a road takes it out of the network, where its
route ends. Seeded, so a run's demand is the same for every control compared on
it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# a city car: SUMO's passenger defaults, braking and accelerating at least as the ICA
# plans (ica.core.limits.Kinematics); every driver wants the limit (no spread of desired
# speeds), so a vehicle's free-flow time is the same whatever controls the junctions, and
# a plan flown at the road's speed is its driver's own pace
VTYPE = (
    '<vType id="car" vClass="passenger" length="5" width="1.8" accel="2.6" decel="4.5" '
    'sigma="0.5" speedFactor="1" speedDev="0"/>'
)
# an emergency vehicle: the same car as far as driving goes, SUMO's emergency class (which
# is what makes it one to the junctions it meets); written only when the demand has any
EV_VTYPE = (
    '<vType id="emergency" vClass="emergency" length="5" width="1.8" accel="2.6" decel="4.5" '
    'sigma="0.5" speedFactor="1" speedDev="0" color="1,0,0"/>'
)
TURNS = ("left", "through", "right")
_DIRS = {"left": ("l", "L"), "through": ("s",), "right": ("r", "R")}
MAX_CROSSINGS = 12  # a route turned this often goes straight on until it leaves


class DemandError(Exception):
    """The demand cannot be made for this net; the message is one line for a person."""


@dataclass(frozen=True)
class OdDemand:
    volume_vph: float  # vehicles per hour on every entry
    duration_s: float  # vehicles come in over [0, duration_s)
    seed: int = 12
    turns: tuple[float, float, float] = (0.2, 0.6, 0.2)  # left, through, right
    # vehicles per hour on particular entries (road ids), instead of volume_vph
    entry_vph: tuple[tuple[str, float], ...] = ()
    # each vehicle an emergency vehicle with this probability, drawn from a stream of its
    # own: the vehicles' times and routes are those of the same demand without
    ev_prob: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.volume_vph) and self.volume_vph >= 0.0):
            raise DemandError(
                f"volume must be a number of vehicles per hour >= 0, got {self.volume_vph}"
            )
        if len(self.turns) != 3 or any(not (x >= 0.0) for x in self.turns) or sum(self.turns) <= 0:
            raise DemandError(
                f"turning ratios are three numbers >= 0 (left, through, right), got {self.turns}"
            )
        if not 0.0 <= self.ev_prob <= 1.0:
            raise DemandError(f"the emergency-vehicle probability is 0 to 1, got {self.ev_prob}")
        for road, vph in self.entry_vph:
            if not (math.isfinite(vph) and vph >= 0.0):
                raise DemandError(f"the volume on {road} must be vehicles per hour >= 0, got {vph}")


@dataclass(frozen=True)
class Turns:
    """The network's roads as the demand walks them."""

    entries: tuple[str, ...]  # roads into the network from outside
    # (road, turn) -> the roads it may take next at the junction it leads to
    next: dict[tuple[str, str], tuple[str, ...]]
    inside: frozenset[str]  # roads that lead into one of the junctions


def read_turns(net_path: Path, junctions: Sequence[str]) -> Turns:
    """The entries and each road's turns at the chosen junctions, from SUMO's net."""
    import sumolib

    net = sumolib.net.readNet(str(net_path))
    chosen = set(junctions)
    entries, nxt, inside = [], {}, set()
    for e in net.getEdges():
        if e.getFunction() == "internal" or not e.allows("passenger"):
            continue
        if e.getToNode().getID() not in chosen:
            continue
        inside.add(e.getID())
        if e.getFromNode().getID() not in chosen:
            entries.append(e.getID())
        for turn, dirs in _DIRS.items():
            outs = sorted(
                {
                    c.getTo().getID()
                    for cons in e.getOutgoing().values()
                    for c in cons
                    if c.getDirection() in dirs and c.getTo().allows("passenger")
                }
            )
            if outs:
                nxt[(e.getID(), turn)] = tuple(outs)
    if not entries:
        raise DemandError(
            f"{net_path}: no road leads into the chosen junctions from outside, so no vehicle "
            "can be drawn coming in: choose the inner ones (--junctions) or give --routes"
        )
    return Turns(tuple(sorted(entries)), nxt, frozenset(inside))


def walk(turns: Turns, entry: str, ratios: Sequence[float], rng: np.random.Generator) -> list[str]:
    """One vehicle's roads from ``entry`` until one takes it out of the network."""
    route = [entry]
    road = entry
    while road in turns.inside and len(route) <= 3 * MAX_CROSSINGS:  # else it ends here
        options = [(t, turns.next.get((road, t), ())) for t in TURNS]
        if len(route) > MAX_CROSSINGS and options[1][1]:
            options = [options[1]]
        w = np.array([ratios[TURNS.index(t)] if outs else 0.0 for t, outs in options])
        if w.sum() <= 0.0:  # only turns the ratios exclude: take any
            w = np.array([1.0 if outs else 0.0 for _, outs in options])
            if w.sum() <= 0.0:
                break  # a dead end inside the network: the route ends here
        _, outs = options[int(rng.choice(len(options), p=w / w.sum()))]
        road = outs[int(rng.integers(len(outs)))]
        route.append(road)
    return route


def write_od_routes(net_path: Path, junctions: Sequence[str], demand: OdDemand, out: Path) -> int:
    """Write the demand as a route file; return how many vehicles it holds."""
    turns = read_turns(net_path, junctions)
    rng = np.random.default_rng(demand.seed)
    rows: list[tuple[float, str, list[str]]] = []
    own = dict(demand.entry_vph)
    unknown = sorted(set(own) - set(turns.entries))
    if unknown:
        raise DemandError(
            f"{unknown[0]} is not a road into the network; its roads in: {', '.join(turns.entries)}"
        )
    for entry in turns.entries:
        rate = own.get(entry, demand.volume_vph) / 3600.0
        t = 0.0
        while rate > 0.0:
            t += float(rng.exponential(1.0 / rate))
            if t >= demand.duration_s:
                break
            rows.append((round(t, 2), entry, walk(turns, entry, demand.turns, rng)))
    rows.sort(key=lambda r: (r[0], r[1]))
    ev = np.random.default_rng([demand.seed, 1]).random(len(rows)) < demand.ev_prob
    lines = ["<routes>", f"  {VTYPE}"] + ([f"  {EV_VTYPE}"] if ev.any() else [])
    for n, (t, _, edges) in enumerate(rows):
        kind = "emergency" if ev[n] else "car"
        lines.append(
            f'  <vehicle id="v{n:05d}" type="{kind}" depart="{t:.2f}" departLane="best" '
            f'departSpeed="max"><route edges="{" ".join(edges)}"/></vehicle>'
        )
    lines.append("</routes>")
    out.write_text("\n".join(lines) + "\n")
    return len(rows)
