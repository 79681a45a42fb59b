"""Traffic-light baselines: re-timing a fixed-cycle program to the demand.

The optimised fixed-cycle light of the dissertation uses the exponential
cycle-length model C0 = 1.5 L e^(1.8 Y) (Cheng et al.), with 4 s of lost
time per phase (L = 4 s x phases) and 3 s of yellow. Y is the sum over the
green phases of each phase's critical flow ratio: the largest demand over
saturation flow among the lanes the phase serves with priority ('G').
The effective green C0 - L is shared in proportion to those ratios.

The phase plan itself is the one netconvert builds for the junction, so the
same code re-times any signalised SUMO junction, not just ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LOST_PER_PHASE_S = 4.0
YELLOW_S = 3.0
SATURATION_VEH_H = 1800.0  # per lane
MIN_GREEN_S = 5.0


@dataclass(frozen=True, slots=True)
class Timing:
    cycle_s: float
    flow_ratio_sum: float
    greens_s: tuple[float, ...]


def cycle_length_s(lost_s: float, y: float) -> float:
    """C0 = 1.5 L e^(1.8 Y)."""
    return 1.5 * lost_s * math.exp(1.8 * y)


def retime(
    states: list[str],
    link_lanes: list[str],
    lane_flow_veh_h: dict[str, float],
) -> tuple[list[float], Timing]:
    """Durations for each phase state of a program.

    ``states`` are the phase strings of the program, ``link_lanes[i]`` the
    incoming lane of signal link i. Green phases (no 'y') get their share of
    the effective green plus the difference between lost time and yellow;
    yellow phases get ``YELLOW_S``; anything else (all red) keeps 1 s.
    """
    greens = [k for k, s in enumerate(states) if "y" not in s.lower() and ("G" in s or "g" in s)]
    ratios = []
    for k in greens:
        lanes = {link_lanes[i] for i, c in enumerate(states[k]) if c == "G"}
        ratios.append(
            max((lane_flow_veh_h.get(ln, 0.0) / SATURATION_VEH_H for ln in lanes), default=0.0)
        )
    y = sum(ratios)
    lost = LOST_PER_PHASE_S * len(greens)
    if y >= 0.95:
        y = 0.95  # oversaturated: the model's cycle would explode; cap it
    cycle = cycle_length_s(lost, y)
    durations = []
    green_s = []
    for k, s in enumerate(states):
        if k in greens:
            share = ratios[greens.index(k)] / y if y > 0 else 1.0 / len(greens)
            g = max(MIN_GREEN_S, (cycle - lost) * share + (LOST_PER_PHASE_S - YELLOW_S))
            durations.append(g)
            green_s.append(g)
        elif "y" in s.lower():
            durations.append(YELLOW_S)
        else:
            durations.append(1.0)
    return durations, Timing(sum(durations), y, tuple(green_s))


# -- the reactive light (chapter 5): a fixed program with EV pre-emption ----------------
REACTIVE_GREEN_S = 31.0  # the dissertation's SUMO default program, as a through lane sees it
REACTIVE_YELLOW_S = 13.0
REACTIVE_RED_S = 83.0
REACTIVE_MIN_GREEN_S = 5.0
HOLD = None  # a step that lasts until the emergency vehicle has entered the junction


def _is_yellow(state: str) -> bool:
    return "y" in state.lower()


def _is_green(state: str) -> bool:
    return not _is_yellow(state) and ("G" in state or "g" in state)


def reactive_durations(states: list[str]) -> list[float]:
    """Durations of a phase plan that give the main movements 31 s of green, 13 s of
    yellow and 83 s of red, as in the dissertation.

    The main greens (the phases with the most priority links) get 31 s, every
    yellow 13 s, all-red phases keep 1 s, and the other greens (protected
    turns) share what is left of the 127 s cycle, at least 5 s each.
    """
    greens = [k for k, s in enumerate(states) if _is_green(s)]
    if not greens:
        raise ValueError("the signal program has no green phase")
    most = max(states[k].count("G") for k in greens)
    main = [k for k in greens if states[k].count("G") == most]
    minor = [k for k in greens if k not in main]
    yellows = [k for k, s in enumerate(states) if _is_yellow(s)]
    red = [k for k in range(len(states)) if k not in greens and k not in yellows]
    cycle = REACTIVE_GREEN_S + REACTIVE_YELLOW_S + REACTIVE_RED_S
    left = cycle - REACTIVE_GREEN_S * len(main) - REACTIVE_YELLOW_S * len(yellows) - len(red)
    minor_s = max(REACTIVE_MIN_GREEN_S, left / len(minor)) if minor else 0.0
    out = []
    for k in range(len(states)):
        if k in main:
            out.append(REACTIVE_GREEN_S)
        elif k in minor:
            out.append(minor_s)
        elif k in yellows:
            out.append(REACTIVE_YELLOW_S)
        else:
            out.append(1.0)
    return out


class Preemption:
    """What the light does for an emergency vehicle (EV) whose movements are ``links``.

    :meth:`steps` answers, from the phase running now, the phases to run in
    turn, each with its duration or :data:`HOLD` (until the EV has entered):

    * the EV's movements are green: **extend** the green;
    * they are yellow after their green: **return** to that green;
    * otherwise **cut** the running green to its own yellow (a yellow or
      all-red already running finishes), run the all-red phases that follow
      it in the program with their full durations, then green the EV's lanes.

    Yellow and all-red clearances are never shortened, so a cut is as safe as
    the program's own phase change.
    """

    def __init__(self, states: list[str], durations: list[float]) -> None:
        if len(states) != len(durations) or not states:
            raise ValueError("one duration per phase state is needed")
        self.states = list(states)
        self.durations = list(durations)

    def _green_for(self, phase: int, links: list[int]) -> bool:
        s = self.states[phase]
        return _is_green(s) and all(s[i] in "Gg" for i in links)

    def target(self, links: list[int]) -> int:
        """The phase that gives the EV's movements priority green ('G'), else any green."""
        for strict in (True, False):
            for k, s in enumerate(self.states):
                if _is_green(s) and all(s[i] == "G" if strict else s[i] in "Gg" for i in links):
                    return k
        raise ValueError(f"no phase gives links {links} green")

    def steps(
        self, phase: int, remaining_s: float, links: list[int]
    ) -> list[tuple[int, float | None]]:
        n = len(self.states)
        if self._green_for(phase, links):
            return [(phase, HOLD)]
        prev = (phase - 1) % n
        if _is_yellow(self.states[phase]) and self._green_for(prev, links):
            return [(prev, HOLD)]
        out: list[tuple[int, float | None]] = []
        k = phase
        if _is_green(self.states[k]):
            k = (k + 1) % n
            if not _is_yellow(self.states[k]):
                raise ValueError(f"green phase {phase} is not followed by a yellow")
            out.append((k, self.durations[k]))
        else:
            out.append((k, max(remaining_s, 0.0)))
        k = (k + 1) % n
        while not _is_green(self.states[k]) and not _is_yellow(self.states[k]):
            out.append((k, self.durations[k]))  # all-red clearance
            k = (k + 1) % n
        out.append((self.target(links), HOLD))
        return out
