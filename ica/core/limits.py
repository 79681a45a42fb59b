"""The limits a plan keeps: the vehicles' kinematics and the junction's speed caps.

Plain data with no numerics, so that settings and command lines can name them
without loading the compiled core.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

KMH = 1.0 / 3.6  # [m/s per km/h]


class Turn(StrEnum):
    LEFT = "left"
    THROUGH = "through"
    RIGHT = "right"


@dataclass(frozen=True, slots=True)
class SpeedCaps:
    """Speed limits [m/s]: the road's, and the comfortable caps inside the junction.

    Defaults are the dissertation's: 70 km/h road, 25 / 35 / 65 km/h for right,
    left and through movements.
    """

    road_mps: float = 70.0 * KMH
    left_mps: float = 35.0 * KMH
    through_mps: float = 65.0 * KMH
    right_mps: float = 25.0 * KMH

    def for_turn(self, turn: Turn) -> float:
        cap = {Turn.LEFT: self.left_mps, Turn.THROUGH: self.through_mps, Turn.RIGHT: self.right_mps}
        return min(cap[turn], self.road_mps)


@dataclass(frozen=True, slots=True)
class Kinematics:
    """Vehicle limits used for planning [m/s^2, m/s, m]: the dissertation's
    accelerations, and how a vehicle that must wait approaches the line.

    With ``run_up`` (the default) it enters at speed: a slow-down plan may cruise
    as slowly as ``creep_mps``, and the stop family stands where pulling away
    reaches the crossing cap at the line (as far back as the vehicle can still
    stop), so the vehicle crosses quickly and frees the conflict zones early.
    :meth:`at_the_line` is the earlier rule: slow to no less than 2 m/s, else stop
    ``stop_gap_m`` short of the line and pull away from there.
    ``min_cross_mps`` is the slowest crossing cap checkFV imposes behind a slow
    vehicle.
    """

    accel_mps2: float = 2.0
    decel_mps2: float = 4.5
    creep_mps: float = 0.5
    stop_gap_m: float = 0.5
    run_up: bool = True
    min_cross_mps: float = 2.0

    @classmethod
    def at_the_line(cls) -> Kinematics:
        """Slow to 2 m/s at least, else stop at the line (``--no-run-up``)."""
        return cls(creep_mps=2.0, run_up=False)
