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
