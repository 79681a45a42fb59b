"""People on foot: their demand, the roadside that holds them at the kerb until the
ICA gives them the crossing, and what each one waited.

A walker is one of SUMO's persons. Its plan under an ICA is three stages: walk
up the sidewalk to the kerb (:data:`WAIT_BACK_M` short of the walking area),
wait there, walk across and on. When it starts to wait, the roadside sees it,
as a kerb-side detector or a push button would, and asks the junction's ICA to
cross (:class:`WalkAsk`); the ICA's answer is the moment the crossing is the
walker's, and at that moment the roadside ends the wait
(``person.removeStage``). A waiting person is off SUMO's pedestrian model, so a
crowd at the kerb never blocks the people coming across. The crossings have
priority in SUMO, so nothing else would make a person wait: who waits, and for
how long, is the ICA's doing. Under a light (``hold`` off) people walk one
stage and obey the light's pedestrian signals; they are only measured.

The demand (``--peds N``) is N persons an hour at every crossing, each starting
:data:`WALK_IN_M` up a sidewalk at one end of the crossing and going as far down
one at its other end; directions are even. Its draws come from a stream of their
own, so adding people changes no vehicle's arrival.

Each walker's wait is measured the same way under every control: from reaching
the kerb to stepping onto the crossing, less the time the few steps between take
at its own speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dica.ica.core.crosswalk import CORNER_GROW_M, CORNER_M
from dica.ica.core.intersection import Intersection
from dica.ica.core.waiting import sidewalk_sweeps
from dica.ica.netfile import sidewalks
from dica.sim_gateway.runconfig import RunError

WALK_IN_M = 40.0  # [m] walkers start and end this far along the sidewalks from the junction
KERB_REACH_M = 8.0  # [m] a sidewalk's end this close to a crossing's end is at that kerb
# [m] a walker waits this far up the sidewalk from its end, off the walking area (where the
# people coming across walk on)
WAIT_BACK_M = 1.0
PATH_FACTOR = 1.5  # a walking area's path from a kerb to a crossing, to the straight line
# the type a walker crosses with once the ICA gave it the crossing: SUMO's own would wait
# for a gap in the vehicles at a crossing without priority (most nets' guessed crossings),
# and step off late, after its slot; the ICA has cleared its way, so it goes (and takes
# SUMO's pedestrian type again once across)
GO_TYPE = "dica_walker_go"
WALK_TYPE = "DEFAULT_PEDTYPE"
ASK_AGAIN_S = 1.0  # [s] a WALK unanswered (a lost link, a restarting ICA) is asked again
KERB_WAIT_S = 1e6  # [s] a held walker's waiting stage: until the roadside ends it
PED_STREAM = 0x9ED  # the demand's random stream, apart from the vehicles'


def check_sidewalks(net_path: Path, inter: Intersection, length_m: float, width_m: float) -> None:
    """Refuse, in one line, a run with people whose largest vehicle, turning at ``inter``,
    reaches over a sidewalk (a 7 m truck on a tight corner cuts it): people walk there
    outside every crossing's reservation, and such a truck touched them (a test grid's
    B1 with trucks and people: 792 steps in 400 s)."""
    swept = sidewalk_sweeps(inter.routes, sidewalks(net_path, inter.junction_id), length_m,
                            width_m)  # fmt: skip
    if swept:
        route, lane = swept[0]
        more = f" (and {len(swept) - 1} more)" if len(swept) > 1 else ""
        raise RunError(
            f"junction {inter.junction_id}: a {length_m:g} m x {width_m:g} m vehicle turning "
            f"on {route} reaches over the sidewalk {lane}{more}, where people walk outside "
            "every crossing's reservation: run such vehicles without people on foot, or "
            "people without them"
        )


@dataclass(frozen=True, slots=True)
class WalkAsk:
    """A walker at the kerb asks to cross (the roadside's WALK request)."""

    person: str
    crossing: str
    junction: str
    ready_s: float
    walk_m: float  # [m] from where it stands until off the corner beyond the crossing
    speed_mps: float  # its own walking speed, as the roadside reads it
    side: int  # the crossing's end it starts from (0: its centre line's first point)
    near_m: float  # [m] from where it stands to that end, round the corner
    near_lo_m: float  # [m] the same as the crow flies, to the nearest of the end's edge


@dataclass(slots=True)
class Walker:
    """One person's passage over the crossings of the run's junctions."""

    pid: str
    depart_s: float
    planned: str  # the crossing its walk was drawn for
    from_edge: str = ""  # the sidewalk it comes along, and where on it the kerb is
    kerb_at: tuple[float, bool] = (0.0, True)
    kerb_near_m: float = 0.0  # [m] from its kerb to the crossing
    far_m: float = 0.0  # [m] from the crossing to the sidewalk beyond (off the corner)
    side: int = 0  # the crossing's end its kerb is at
    kerb_s: float | None = None  # at the kerb (began to wait there; under a light, passed it)
    near_m: float = 0.0  # [m] from there to the crossing
    near_lo_m: float = 0.0  # [m] the same as the crow flies (the least it may walk)
    speed_mps: float = 0.0
    asked_s: float | None = None
    go_s: float | None = None  # the ICA's start (None: not given yet, or no ICA)
    slot_end_s: float | None = None
    on_s: float | None = None  # stepped onto the crossing
    off_s: float | None = None  # left it
    crossing: str | None = None  # the crossing it is at or on
    arrived_s: float | None = None
    clear_s: float | None = None  # off the crossing and its corners (on a sidewalk again)
    overran: bool = False  # still on the crossing when its slot ended
    # a route file's person: seen on the walking area before a crossing of ours, held there
    # (its own plan runs on), its own type taken again once across
    stranger: bool = False
    own_type: str = WALK_TYPE

    @property
    def wait_s(self) -> float | None:
        """Kerb to crossing, less the free walk between."""
        if self.kerb_s is None or self.on_s is None:
            return None
        free = self.near_m / self.speed_mps if self.speed_mps > 0 else 0.0
        return max(self.on_s - self.kerb_s - free, 0.0)


@dataclass(frozen=True, slots=True)
class Leg:
    """One drawn walk: at ``t_s`` from ``from_edge`` (at ``from_pos``) across ``crossing``
    to ``to_edge`` (to ``to_pos``). On ``from_edge`` the kerb is at ``kerb_pos``, which
    the walker reaches going up the edge (``forward``) or down it."""

    t_s: float
    crossing: str
    from_edge: str
    from_pos: float
    to_edge: str
    to_pos: float
    kerb_pos: float = 0.0
    forward: bool = True
    near_m: float = 0.0  # [m] from the kerb to the crossing's near end
    far_m: float = 0.0  # [m] from its far end to the sidewalk it goes on along
    side: int = 0  # the crossing's end it starts from


def _sidewalk(ls, edge: str) -> str | None:
    """The edge's first lane people may walk on, or None."""
    for i in range(ls.edge.getLaneNumber(edge)):
        lane = f"{edge}_{i}"
        if "pedestrian" in ls.lane.getAllowed(lane):
            return lane
    return None


Side = list[tuple[str, float, float, bool, float]]


def kerbs(ls, inter: Intersection) -> dict[str, tuple[Side, Side]]:
    """Per crossing of ``inter``, the sidewalks at each of its two ends: ``(edge, pos,
    kerb_pos, forward, near_m)``, ``pos`` being :data:`WALK_IN_M` from the junction along
    the edge (or its far end), ``kerb_pos`` :data:`WAIT_BACK_M` from its junction end,
    ``forward`` whether the edge runs towards the junction, ``near_m`` how far the kerb
    is from the crossing's end."""
    jid = inter.junction_id
    near: list[tuple[str, np.ndarray, float, float, bool]] = []
    for edge in ls.edge.getIDList():
        if edge.startswith(":"):
            continue
        to_j, from_j = ls.edge.getToJunction(edge) == jid, ls.edge.getFromJunction(edge) == jid
        if not (to_j or from_j):
            continue
        lane = _sidewalk(ls, edge)
        if lane is None:
            continue
        shape = ls.lane.getShape(lane)
        length = ls.lane.getLength(lane)
        point = np.array(shape[-1] if to_j else shape[0])
        pos = max(length - WALK_IN_M, 0.0) if to_j else min(WALK_IN_M, length)
        kerb = max(length - WAIT_BACK_M, 0.0) if to_j else min(WAIT_BACK_M, length)
        near.append((edge, point, pos, kerb, to_j))
    out = {}
    for c in inter.crosswalks:
        ends = (c.shape[0], c.shape[-1])
        sides: tuple[list, list] = ([], [])
        for edge, point, pos, kerb, forward in near:
            d = [float(np.linalg.norm(point - e)) for e in ends]
            k = int(d[1] < d[0])
            if d[k] <= KERB_REACH_M:
                # round the corner, not straight across it
                sides[k].append((edge, pos, kerb, forward, PATH_FACTOR * d[k] + WAIT_BACK_M))
        out[c.id] = sides
    return out


def to_end_edge(xy: np.ndarray, shape: np.ndarray, width_m: float, side: int) -> float:
    """How far ``xy`` is, as the crow flies, from the edge of a crossing's end ``side``
    (the line across its strip there, ``width_m`` long): no walker there reaches the
    crossing sooner than that walk."""
    end, nxt = (shape[0], shape[1]) if side == 0 else (shape[-1], shape[-2])
    along = nxt - end
    along = along / max(float(np.hypot(*along)), 1e-9)
    if float(np.dot(xy - end, along)) > 0.0:  # past the end's edge: on the crossing already
        return 0.0
    half = np.array([-along[1], along[0]]) * width_m / 2.0
    a, ab = end - half, 2.0 * half
    k = float(np.clip(np.dot(xy - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0))
    return float(np.hypot(*(xy - (a + k * ab))))


def draw_legs(
    ends: dict[str, tuple[Side, Side]],
    per_hour: float,
    duration_s: float,
    seed: int,
) -> list[Leg]:
    """Poisson arrivals of ``per_hour`` walkers at every crossing that has a sidewalk at
    both ends, over ``duration_s``, each from a sidewalk at one end to one at the other
    (direction and sidewalks uniform); in time order."""
    rng = np.random.default_rng([seed, PED_STREAM])
    legs = []
    for crossing in sorted(ends):
        a, b = ends[crossing]
        if not a or not b or per_hour <= 0.0:
            continue
        t = 0.0
        while True:
            t += float(rng.exponential(3600.0 / per_hour))
            if t >= duration_s:
                break
            side = 0 if rng.random() < 0.5 else 1
            src, dst = (a, b) if side == 0 else (b, a)
            (fe, fp, kp, fw, nm), (te, tp, _, _, fm) = (
                src[rng.integers(len(src))],
                dst[rng.integers(len(dst))],
            )
            legs.append(
                Leg(round(t, 2), crossing, fe, fp, te, tp, kp, fw, nm, fm - WAIT_BACK_M, side)
            )
    legs.sort(key=lambda x: (x.t_s, x.crossing))
    return legs


@dataclass
class Walkers:
    """The run's persons: put in as drawn, held at the kerb and let go (``hold``), and
    measured."""

    ls: object
    inters: tuple[Intersection, ...]
    legs: list[Leg]
    hold: bool = True
    people: dict[str, Walker] = field(default_factory=dict)
    asks: list[WalkAsk] = field(default_factory=list)
    # this step's walkers seen across, whose slot ends now: (person, crossing, junction)
    cleared: list[tuple[str, str, str]] = field(default_factory=list)
    _next: int = 0
    # per crossing id: its junction, centre line, length and width
    _crossing_of: dict[str, tuple[str, np.ndarray, float, float]] = field(default_factory=dict)
    _held: dict[str, Walker] = field(default_factory=dict)  # waiting for the ICA's go
    _radius: dict[str, float] = field(default_factory=dict)  # [m] each person's body
    # this step's persons as SUMO places them (for the person check)
    present: list[str] = field(default_factory=list)
    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    radius_m: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if self.hold and GO_TYPE not in self.ls.vehicletype.getIDList():
            self.ls.vehicletype.copy(WALK_TYPE, GO_TYPE)
            self.ls.vehicletype.setParameter(GO_TYPE, "junctionModel.jmIgnoreFoeProb", "1")
            self.ls.vehicletype.setParameter(GO_TYPE, "junctionModel.jmIgnoreFoeSpeed", "100")
        for inter in self.inters:
            for c in inter.crosswalks:
                self._crossing_of[c.id] = (inter.junction_id, c.shape, c.length_m, c.width_m)

    def step(self, t: float) -> list[WalkAsk]:
        """After SUMO's step to ``t``: put in who is due, see who reached a kerb (held and
        asking, with ``hold``), who stepped onto or off a crossing or is across (off its
        far corner: :attr:`cleared`), and who arrived. The asks are this step's;
        :meth:`answer` gives each its start."""
        ls = self.ls
        while self._next < len(self.legs) and self.legs[self._next].t_s <= t + 1e-9:
            leg = self.legs[self._next]
            pid = f"p{self._next:05d}"
            ls.person.add(pid, leg.from_edge, leg.from_pos, t)
            if self.hold:  # up to the kerb, wait there (off the sidewalk) for the go, cross
                ls.person.appendWalkingStage(pid, [leg.from_edge], leg.kerb_pos)
                ls.person.appendWaitingStage(pid, KERB_WAIT_S, "at the kerb")
            ls.person.appendWalkingStage(pid, [leg.from_edge, leg.to_edge], leg.to_pos)
            self.people[pid] = Walker(
                pid, t, leg.crossing, leg.from_edge, (leg.kerb_pos, leg.forward), leg.near_m,
                leg.far_m, leg.side,
            )  # fmt: skip
            self._next += 1
        for pid in ls.simulation.getArrivedPersonIDList():
            w = self.people.get(pid)
            if w is not None and w.arrived_s is None:
                w.arrived_s = t
        asks = []
        cleared: list[tuple[str, str, str]] = []
        ids = ls.person.getIDList()
        self.xy = np.array([ls.person.getPosition(p) for p in ids], dtype=float).reshape(-1, 2)
        for pid in ids:
            if pid not in self._radius:
                self._radius[pid] = 0.5 * max(ls.person.getLength(pid), ls.person.getWidth(pid))
        self.present = list(ids)
        self.radius_m = np.array([self._radius[p] for p in ids], dtype=float)
        for pid in ids:
            w = self.people.get(pid)
            if w is None:  # a route file's person
                w = self.people[pid] = Walker(pid, t, "", stranger=True)
                w.own_type = ls.person.getTypeID(pid)
            road = ls.person.getRoadID(pid)
            if w.off_s is not None and w.clear_s is None and not road.startswith(":"):
                w.clear_s = t  # across: off the far corner too
                if self.hold and w.go_s is not None:
                    ls.person.setType(pid, w.own_type)
                    junction = self._crossing_of[w.crossing][0]
                    cleared.append((pid, w.crossing, junction))
                continue
            if w.crossing is not None and w.on_s is not None and w.off_s is None:
                if road != w.crossing:
                    w.off_s = t
                elif w.slot_end_s is not None and t > w.slot_end_s:
                    w.overran = True
                continue
            if road in self._crossing_of:
                if w.crossing == road and w.on_s is None:
                    w.on_s = t
                continue
            if w.stranger:
                ask = self._stranger_at_kerb(w, road, t)
                if ask is not None:
                    asks.append(ask)
                continue
            if w.kerb_s is not None or road != w.from_edge:
                continue
            if self.hold:  # waiting at the kerb: its walk there is done
                if ls.person.getRemainingStages(pid) > 2:
                    continue
            else:
                pos = ls.person.getLanePosition(pid)
                if not (pos >= w.kerb_at[0] if w.kerb_at[1] else pos <= w.kerb_at[0]):
                    continue
            # at the kerb of a crossing of ours: a new passage
            w.crossing, w.kerb_s, w.near_m = w.planned, t, w.kerb_near_m
            w.speed_mps = float(ls.person.getMaxSpeed(pid))
            if self.hold:
                asks.append(self._hold(w, t))
        self.asks = asks
        self.cleared = cleared
        return asks

    def _ask(self, w: Walker) -> WalkAsk:
        """``w``'s WALK: from its kerb until off the corner beyond the crossing."""
        junction, _shape, length, _width = self._crossing_of[w.crossing]
        walk = w.near_m + length + w.far_m + CORNER_GROW_M
        return WalkAsk(w.pid, w.crossing, junction, w.kerb_s, walk, w.speed_mps, w.side,
                       w.near_m, w.near_lo_m)  # fmt: skip

    def _hold(self, w: Walker, t: float) -> WalkAsk:
        """``w`` held at the kerb from ``t`` and asked for."""
        w.asked_s = t
        _junction, shape, _length, width = self._crossing_of[w.crossing]
        xy = np.asarray(self.ls.person.getPosition(w.pid), dtype=float)
        w.near_lo_m = min(to_end_edge(xy, shape, width, w.side), w.near_m)
        self._held[w.pid] = w
        return self._ask(w)

    def _stranger_at_kerb(self, w: Walker, road: str, t: float) -> WalkAsk | None:
        """A route file's person on the walking area before a crossing of ours it has not
        asked for yet: a new passage, held where it stands (with ``hold``) and asked for."""
        if not road.startswith(":") or road in self._crossing_of:
            return None
        nxt = self.ls.person.getNextEdge(w.pid)
        if nxt not in self._crossing_of or (w.crossing == nxt and w.clear_s is None):
            return None
        shape = self._crossing_of[nxt][1]
        xy = np.asarray(self.ls.person.getPosition(w.pid))
        d = [float(np.linalg.norm(xy - shape[0])), float(np.linalg.norm(xy - shape[-1]))]
        w.side = int(d[1] < d[0])
        w.crossing, w.kerb_s, w.near_m, w.far_m = nxt, t, d[w.side], CORNER_M
        w.on_s = w.off_s = w.clear_s = w.go_s = w.slot_end_s = None
        w.speed_mps = float(self.ls.person.getMaxSpeed(w.pid))
        if not self.hold:
            return None
        self.ls.person.setSpeed(w.pid, 0.0)
        return self._hold(w, t)

    def again(self, t: float) -> list[WalkAsk]:
        """The held walkers whose WALK has gone unanswered for :data:`ASK_AGAIN_S`: asked
        again (the ICA answers a repeat with the same slot)."""
        out = []
        for w in self._held.values():
            if w.go_s is None and w.asked_s is not None and t - w.asked_s >= ASK_AGAIN_S - 1e-9:
                w.asked_s = t
                out.append(self._ask(w))
        return out

    def waiting_mask(self) -> np.ndarray:
        """Per person of this step (:attr:`present`): held at the kerb."""
        return np.array([p in self._held for p in self.present], dtype=bool)

    def answer(
        self, pid: str, start_s: float, end_s: float, t: float, go_s: float | None = None
    ) -> None:
        """The ICA's slot for ``pid``: let it go at ``start_s`` (now, if that has come), or
        at ``go_s`` (a real-time roadside whose GO came back late)."""
        w = self._held.get(pid)
        if w is None:
            return
        w.go_s, w.slot_end_s = start_s if go_s is None else go_s, end_s
        self.release(t)

    def release(self, t: float) -> None:
        """Let go every held walker whose start has come."""
        for pid in [p for p, w in self._held.items() if w.go_s is not None and w.go_s <= t + 1e-9]:
            w = self._held.pop(pid)
            self.ls.person.setType(pid, GO_TYPE)
            if w.stranger:  # held where it stood: its own speed again
                self.ls.person.setSpeed(pid, -1)
            else:
                self.ls.person.removeStage(pid, 0)  # the wait at the kerb: it walks on

    def summary(self, end_s: float) -> dict:
        """Per-person figures: how many crossed, waited, are still out; waits."""
        people = list(self.people.values())
        waits = [w.wait_s for w in people if w.wait_s is not None]
        crossed = [w for w in people if w.off_s is not None]
        times = [w.off_s - w.on_s for w in crossed if w.on_s is not None]
        at_kerb = [w for w in people if w.kerb_s is not None and w.on_s is None]
        longest = [end_s - w.kerb_s for w in at_kerb]  # those still waiting count too
        return {
            "generated": len(people),
            "crossed": len(crossed),
            "at_kerb_at_end": len(at_kerb),
            "on_crossing_at_end": sum(1 for w in people if w.on_s is not None and w.off_s is None),
            "not_at_a_kerb_yet": sum(1 for w in people if w.kerb_s is None and not w.stranger),
            # a route file's people who never came to a crossing of the junction
            "walked_elsewhere": sum(1 for w in people if w.kerb_s is None and w.stranger),
            "mean_wait_s": float(np.mean(waits)) if waits else None,
            "p95_wait_s": float(np.percentile(waits, 95)) if waits else None,
            "max_wait_s": max([*waits, *longest], default=None),
            # the ICA's part: from its ask to the start it was given (bound: WAIT_BOUND_S)
            "max_ask_to_go_s": max(
                (
                    w.go_s - w.asked_s
                    for w in people
                    if w.go_s is not None and w.asked_s is not None
                ),
                default=None,
            ),
            "mean_crossing_s": float(np.mean(times)) if times else None,
            "overran_slot": sum(1 for w in people if w.overran),
        }

    def rows(self) -> list[dict]:
        """One row per passage for ``persons.csv``."""

        def r(x: float | None) -> float | str:
            return "" if x is None or not math.isfinite(x) else round(x, 2)

        return [
            {
                "person": w.pid, "depart_s": r(w.depart_s), "crossing": w.crossing or w.planned,
                "kerb_s": r(w.kerb_s), "go_s": r(w.go_s), "on_s": r(w.on_s), "off_s": r(w.off_s),
                "wait_s": r(w.wait_s), "speed_mps": r(w.speed_mps),
            }
            for w in self.people.values()
        ]  # fmt: skip
