"""Traffic-light baselines: clearance times that are safe on any net, and the
dissertation's fixed-cycle re-timing on top.

Clearance (the usual traffic-engineering formulas, per link losing right of
way; the longest link of a phase decides):

* yellow = reaction time + v / (2 x comfortable deceleration), v the approach
  lane's speed limit: a vehicle too close to stop at that deceleration when
  the yellow starts reaches the stop line before it ends;
* all-red = (way through the junction + vehicle length) / v, v the slowest
  speed limit on that way (turns are driven slower than the approach): a
  vehicle that crossed the stop line at the end of the yellow is out of the
  junction before a conflicting link turns green.

Neither is ever shorter than the net's own program. netconvert's programs
have no all-red phase, so one is inserted after each yellow (the yellow's
state with its 'y' links red; links that stay green through the change stay
green).

The optimised fixed-cycle light of the dissertation then uses the
exponential cycle-length model C0 = 1.5 L e^(1.8 Y) (Cheng et al.). Y is the
sum over the green phases of each phase's critical flow ratio: the largest
demand over saturation flow among the lanes the phase serves with priority
('G'). L is the lost time, 4 s per green phase as in the dissertation, or
that phase's clearance (yellow plus all-red) where longer. The effective
green C0 - L is shared in proportion to the ratios.

The phase plan itself is the one netconvert builds for the junction, so the
same code times any signalised SUMO junction, not just ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

LOST_PER_PHASE_S = 4.0  # [s] the dissertation's lost time per green phase
SATURATION_VEH_H = 1800.0  # per lane
MIN_GREEN_S = 5.0
REACTION_S = 1.0  # [s] perception-reaction time of the yellow formula
COMFORT_DECEL_MPS2 = 3.0  # [m/s^2] comfortable deceleration of the yellow formula

GREEN, YELLOW, ALL_RED = "green", "yellow", "all-red"


@dataclass(frozen=True, slots=True)
class SignalLink:
    """One controlled link: the lane it leaves and its way through the junction."""

    in_lane: str
    approach_speed_mps: float  # speed limit of the incoming lane
    crossing_m: float  # length of the internal lanes from stop line to exit [m]
    crossing_speed_mps: float  # slowest speed limit on the approach and that way


@dataclass(frozen=True, slots=True)
class Phase:
    """One phase of a program; ``min_s``/``max_s`` matter to actuated lights only."""

    duration_s: float
    state: str
    kind: str  # GREEN, YELLOW or ALL_RED
    min_s: float
    max_s: float


@dataclass(frozen=True, slots=True)
class Timing:
    cycle_s: float
    flow_ratio_sum: float
    greens_s: tuple[float, ...]


def cycle_length_s(lost_s: float, y: float) -> float:
    """C0 = 1.5 L e^(1.8 Y)."""
    return 1.5 * lost_s * math.exp(1.8 * y)


def yellow_time_s(approach_speed_mps: float) -> float:
    """Reaction time + v / (2 x comfortable deceleration)."""
    return REACTION_S + approach_speed_mps / (2.0 * COMFORT_DECEL_MPS2)


def all_red_time_s(crossing_m: float, vehicle_length_m: float, speed_mps: float) -> float:
    """(Way through the junction + vehicle length) / v."""
    return (crossing_m + vehicle_length_m) / max(speed_mps, 0.1)


def phases_of(durations_s: list[float], states: list[str], mins_s=None, maxs_s=None) -> list[Phase]:
    """A net's program as phases: yellow where a link shows 'y', all-red where a
    phase right after a yellow only holds red what the yellow ended, else green."""
    n = len(states)
    mins_s = list(durations_s) if mins_s is None else mins_s
    maxs_s = list(durations_s) if maxs_s is None else maxs_s
    out = []
    for k, st in enumerate(states):
        before = states[k - 1] if n > 1 else ""
        if "y" in st.lower():
            kind = YELLOW
        elif "y" in before.lower() and _only_clears(st, before):
            kind = ALL_RED
        else:
            kind = GREEN
        out.append(Phase(durations_s[k], st, kind, mins_s[k], maxs_s[k]))
    return out


def _only_clears(state: str, yellow: str) -> bool:
    """Every link red, or green as it was through the yellow."""
    return all(c in "rR" or (y in "Gg" and c == y) for c, y in zip(state, yellow, strict=True))


def with_clearance(
    phases: list[Phase], links: list[SignalLink | None], vehicle_length_m: float
) -> list[Phase]:
    """The program with every yellow and all-red at least as long as the formulas ask.

    ``links[i]`` describes signal index i (None where no lane is controlled).
    A yellow not followed by an all-red phase gets one inserted after it.
    """
    need_red: dict[int, float] = {}
    out: list[Phase] = []
    n = len(phases)
    for k, ph in enumerate(phases):
        if ph.kind == ALL_RED and k - 1 in need_red:
            d = max(ph.duration_s, need_red[k - 1])
            out.append(replace(ph, duration_s=d, min_s=d, max_s=d))
            continue
        if ph.kind == ALL_RED and k == 0 and phases[-1].kind == YELLOW:
            continue  # lengthened below, once the last yellow is seen
        if ph.kind != YELLOW:
            out.append(ph)
            continue
        ending = [links[i] for i, c in enumerate(ph.state) if c in "yY" and links[i] is not None]
        y = max([ph.duration_s] + [yellow_time_s(ln.approach_speed_mps) for ln in ending])
        out.append(replace(ph, duration_s=y, min_s=y, max_s=y))
        red = max(
            [0.0]
            + [
                all_red_time_s(ln.crossing_m, vehicle_length_m, ln.crossing_speed_mps)
                for ln in ending
            ]
        )
        need_red[k] = red
        nxt = phases[(k + 1) % n]
        if nxt.kind != ALL_RED and red > 0.0:
            state = "".join("r" if c in "yY" else c for c in ph.state)
            out.append(Phase(red, state, ALL_RED, red, red))
    if n > 1 and phases[0].kind == ALL_RED and phases[-1].kind == YELLOW:
        d = max(phases[0].duration_s, need_red[n - 1])
        out.insert(0, replace(phases[0], duration_s=d, min_s=d, max_s=d))
    return out


def retime(
    phases: list[Phase], link_lanes: list[str], lane_flow_veh_h: dict[str, float]
) -> tuple[list[Phase], Timing]:
    """The fixed-cycle program: green durations from the cycle model, clearances kept.

    ``link_lanes[i]`` is the incoming lane of signal link i. A green phase's
    lost time is ``LOST_PER_PHASE_S`` or the clearance phases after it, where
    longer; its displayed green is its share of the effective green plus the
    part of its lost time the clearance does not take.
    """
    greens = [k for k, ph in enumerate(phases) if ph.kind == GREEN]
    if not greens:
        raise ValueError("the signal program has no green phase")
    ratios, lost = [], []
    for k in greens:
        lanes = {link_lanes[i] for i, c in enumerate(phases[k].state) if c == "G"}
        ratios.append(
            max((lane_flow_veh_h.get(ln, 0.0) / SATURATION_VEH_H for ln in lanes), default=0.0)
        )
        clear = 0.0
        j = (k + 1) % len(phases)
        while phases[j].kind != GREEN and j != k:
            clear += phases[j].duration_s
            j = (j + 1) % len(phases)
        lost.append((max(LOST_PER_PHASE_S, clear), clear))
    y = sum(ratios)
    lost_s = sum(total for total, _ in lost)
    if y >= 0.95:
        y = 0.95  # oversaturated: the model's cycle would explode; cap it
    cycle = cycle_length_s(lost_s, y)
    out = list(phases)
    green_s = []
    for q, k in enumerate(greens):
        share = ratios[q] / y if y > 0 else 1.0 / len(greens)
        total, clear = lost[q]
        g = max(MIN_GREEN_S, (cycle - lost_s) * share + (total - clear))
        out[k] = replace(phases[k], duration_s=g, min_s=g, max_s=g)
        green_s.append(g)
    return out, Timing(sum(ph.duration_s for ph in out), y, tuple(green_s))


# -- the reactive light (chapter 5): a fixed program with EV pre-emption ----------------
REACTIVE_GREEN_S = 31.0  # the dissertation's SUMO default program, as a through lane sees it
REACTIVE_YELLOW_S = 13.0
REACTIVE_RED_S = 83.0
REACTIVE_MIN_GREEN_S = 5.0
HOLD = None  # a step that lasts until the emergency vehicle has entered the junction


def reactive_phases(phases: list[Phase]) -> list[Phase]:
    """The program (with its safe clearance) timed as the dissertation's reactive light:
    the main movements get 31 s of green, and a yellow 13 s where its own is shorter.

    The main greens (the phases with the most priority links) get 31 s, the
    other greens (protected turns) share what is left of the 127 s cycle, at
    least 5 s each; all-reds keep their clearance.
    """
    greens = [k for k, ph in enumerate(phases) if ph.kind == GREEN]
    if not greens:
        raise ValueError("the signal program has no green phase")
    most = max(phases[k].state.count("G") for k in greens)
    main = [k for k in greens if phases[k].state.count("G") == most]
    minor = [k for k in greens if k not in main]
    out = []
    for k, ph in enumerate(phases):
        d = ph.duration_s
        if ph.kind == YELLOW:
            d = max(d, REACTIVE_YELLOW_S)
        elif k in main:
            d = REACTIVE_GREEN_S
        out.append(replace(ph, duration_s=d, min_s=d, max_s=d))
    cycle = REACTIVE_GREEN_S + REACTIVE_YELLOW_S + REACTIVE_RED_S
    left = cycle - sum(ph.duration_s for k, ph in enumerate(out) if k not in minor)
    minor_s = max(REACTIVE_MIN_GREEN_S, left / len(minor)) if minor else 0.0
    return [
        replace(ph, duration_s=minor_s, min_s=minor_s, max_s=minor_s) if k in minor else ph
        for k, ph in enumerate(out)
    ]


class Preemption:
    """What the light does for an emergency vehicle (EV) whose movements are ``links``.

    :meth:`steps` answers, from the phase running now, what to show in turn,
    each a program phase (its index) or a transition state of its own (a
    signal string), with its duration or :data:`HOLD` (until the EV has
    entered):

    * the EV's movements are green: **extend** the green;
    * they are yellow after their green: **return** to that green;
    * otherwise **cut** to the EV's green: every movement green now and not
      green in the EV's phase turns yellow for the program's full yellow (those
      yellow already finish theirs), then all of them are red for the program's
      longest all-red, and only then the EV's phase starts. Movements green in
      both stay green throughout (they are compatible with the EV's phase).

    The program's own phases in between are not run: a yellow of the program
    keeps green what its *next* green keeps, which need not be the EV's phase's,
    so jumping from it to the EV's phase could turn a green red with no yellow.
    Clearances are never shortened, so a cut is as safe as a phase change.
    """

    def __init__(self, phases: list[Phase]) -> None:
        if not phases:
            raise ValueError("the program has no phase")
        self.states = [ph.state for ph in phases]
        self.durations = [ph.duration_s for ph in phases]
        self.kinds = [ph.kind for ph in phases]
        yellows = [ph.duration_s for ph in phases if ph.kind == YELLOW]
        reds = [ph.duration_s for ph in phases if ph.kind == ALL_RED]
        self.yellow_s = max(yellows, default=REACTIVE_YELLOW_S)
        self.all_red_s = max(reds, default=0.0)

    def _green_for(self, phase: int, links: list[int]) -> bool:
        s = self.states[phase]
        return self.kinds[phase] == GREEN and all(s[i] in "Gg" for i in links)

    def target(self, links: list[int]) -> int:
        """The phase that gives the EV's movements priority green ('G'), else any green."""
        for strict in (True, False):
            for k, s in enumerate(self.states):
                green = self.kinds[k] == GREEN
                if green and all(s[i] == "G" if strict else s[i] in "Gg" for i in links):
                    return k
        raise ValueError(f"no phase gives links {links} green")

    def steps(
        self, phase: int, remaining_s: float, links: list[int]
    ) -> list[tuple[int | str, float | None]]:
        n = len(self.states)
        if self._green_for(phase, links):
            return [(phase, HOLD)]
        prev = (phase - 1) % n
        if self.kinds[phase] == YELLOW and self._green_for(prev, links):
            return [(prev, HOLD)]
        tgt = self.target(links)
        now, then = self.states[phase], self.states[tgt]
        keep = [a in "Gg" and b in "Gg" for a, b in zip(now, then, strict=True)]
        stops = any(a in "Gg" and not k for a, k in zip(now, keep, strict=True))
        out: list[tuple[int | str, float | None]] = []
        if stops or any(a in "yY" for a in now):
            yellow = "".join(
                a if k else ("y" if a in "GgyY" else "r") for a, k in zip(now, keep, strict=True)
            )
            out.append((yellow, self.yellow_s if stops else max(remaining_s, 0.0)))
        red = "".join(a if k else "r" for a, k in zip(now, keep, strict=True))
        cleared = self.kinds[phase] == ALL_RED and not stops and red == now
        out.append((red, max(remaining_s, 0.0) if cleared else self.all_red_s))
        out.append((tgt, HOLD))
        return [(k, d) for k, d in out if d is HOLD or d > 0.0]
