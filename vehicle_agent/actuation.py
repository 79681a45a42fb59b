"""What a vehicle's machine tells its actuator, and the SUMO speed modes the actuator
flies it with.

An :class:`Actuation` is in-process: the vehicle's state machine
(:mod:`dica.vehicle_agent.machine`) returns it and the world's actuator carries
it out; over Zenoh it travels as the wire's COMMAND (:mod:`dica.schemas.messages`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MODE_CONFIRMED = 32  # SUMO speed mode while flying a plan: obey the speed, no own checks
MODE_DEFAULT = 31  # SUMO's default checks
# stopping short of the line (vehicle_agent.control): the head of a lane by its own stop law
# alone (SUMO keeps only its acceleration limits), a queued vehicle also by SUMO's
# car-following, but never by SUMO's right-of-way logic at the junction ahead
MODE_HEAD = 6
MODE_QUEUED = 7
RELEASE = -1.0  # a commanded speed of -1 gives the vehicle back to SUMO
BIG = 1e9  # [s] "never" for wake_s
NO_PLAN = -1  # plan sequence number meaning "none"


@dataclass(frozen=True, slots=True, eq=False)
class Actuation:
    """What the actuator is told: a plan to fly by position, and when to wake the vehicle.

    ``s_m`` are route positions [m] (0 at the entry line), one per step from
    ``t0_s``; empty when there is no new plan. ``wake_s`` is when the vehicle
    may next talk to the ICA (DETECT or REQUEST): -BIG at once, BIG never; a
    lockstep gateway uses it to keep the order of ICA contacts across agents.
    """

    vin: str
    seq: int = NO_PLAN
    t0_s: float = math.nan
    s_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wake_s: float = BIG
    # give up every plan up to ``seq`` (revoked) and stop short of the line; the actuator
    # refuses (``kept_seq``) if the vehicle can no longer stop short of it
    drop: bool = False

    @property
    def has_plan(self) -> bool:
        return self.seq != NO_PLAN and len(self.s_m) > 0
