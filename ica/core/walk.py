"""People crossing: the time each pedestrian crossing is reserved for walkers, and what
a vehicle's plan must keep clear of.

A walker at the kerb asks to cross; the ICA answers with the moment to start,
the first at which the crossing is free of every confirmed vehicle for as long
as a slow walker needs to get across (its length at :data:`WALK_MPS` and
:data:`CLEAR_S` more), and holds the crossing for that time. A vehicle's plan
holds a crossing from its front touching the strip to its rear clearing it
(:func:`ica.core.crosswalk.span`, in time through its trajectory); a plan that
would hold a crossing while a walker has it is delayed until the walker is
across, as a conflict with another vehicle delays it.

So a walker waits at most until the vehicles confirmed before it asked have
cleared the crossing: no vehicle confirmed later can take its time. Walkers
do not conflict with each other. Pure: plans and times in, times out.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

from dica.ica.core.crosswalk import Crosswalk
from dica.ica.core.trajectory import Trajectory

WALK_MPS = 1.0  # [m/s] a slow walker's speed (the 15th percentile is about 1.0-1.1 m/s)
CLEAR_S = 2.0  # [s] beyond the walk itself: stepping off the kerb, and the last step out


@dataclass(frozen=True, slots=True)
class WalkSlot:
    """A crossing reserved for a walker from ``start_s`` to ``end_s``."""

    person: str
    crossing: str
    start_s: float
    end_s: float


def hold(traj: Trajectory, s_from: float, s_to: float, exit_mps: float) -> tuple[float, float]:
    """When a plan holds a crossing it touches over front positions ``[s_from, s_to]``:
    from the last sample before its front reaches ``s_from`` to the first at or after it
    reaches ``s_to``; past the plan's end at ``exit_mps`` (at least 0.1 m/s)."""
    s, t0, h = traj.s_m, traj.t0_s, traj.step_s
    i = int(s.searchsorted(s_from, side="left"))
    t_in = t0 + h * max(i - 1, 0)
    j = int(s.searchsorted(s_to, side="left"))
    if j < len(s):
        t_out = t0 + h * j
    else:  # beyond the plan: the road's driver goes on at least at the exit speed
        t_out = t0 + h * (len(s) - 1) + (s_to - float(s[-1])) / max(exit_mps, 0.1)
    return t_in, t_out


class Walkways:
    """The walkers' reservations of a junction's crossings."""

    def __init__(
        self,
        crosswalks: tuple[Crosswalk, ...],
        walk_mps: float = WALK_MPS,
        clear_s: float = CLEAR_S,
        gap_s: float = 0.5,
    ) -> None:
        if not walk_mps > 0.0:
            raise ValueError(f"walking speed must be positive, got {walk_mps}")
        self.crosswalks = {c.id: c for c in crosswalks}
        self.walk_mps = walk_mps
        self.clear_s = clear_s
        self.gap_s = gap_s  # [s] kept between a vehicle's hold and a walker's, either way
        self.slots: dict[str, list[WalkSlot]] = {c: [] for c in self.crosswalks}

    def walk_s(self, crossing: str) -> float:
        """How long a walker holds ``crossing``."""
        return self.crosswalks[crossing].length_m / self.walk_mps + self.clear_s

    def earliest(self, crossing: str, ready_s: float, busy: list[tuple[float, float]]) -> float:
        """The first start at or after ``ready_s`` at which a walker has ``crossing`` for
        :meth:`walk_s` clear of every vehicle hold in ``busy`` (with :attr:`gap_s` each
        side)."""
        need, gap = self.walk_s(crossing), self.gap_s
        t = ready_s
        for a, b in sorted(busy):
            if b + gap <= t:
                continue
            if t + need + gap <= a:
                break
            t = max(t, b + gap)
        return t

    def slot_of(self, person: str, crossing: str) -> WalkSlot | None:
        """The slot ``person`` holds on ``crossing``, if any (a WALK asked twice gets it
        again, not a second one)."""
        return next((w for w in self.slots.get(crossing, ()) if w.person == person), None)

    def reserve(self, person: str, crossing: str, start_s: float) -> WalkSlot:
        """Hold ``crossing`` for ``person`` from ``start_s`` (the slot it holds already, if
        it has one there)."""
        held = self.slot_of(person, crossing)
        if held is not None:
            return held
        slot = WalkSlot(person, crossing, start_s, start_s + self.walk_s(crossing))
        bisect.insort(self.slots[crossing], slot, key=lambda x: x.start_s)
        return slot

    def delay(self, crossing: str, t_in: float, t_out: float) -> float:
        """How much later a vehicle holding ``crossing`` from ``t_in`` to ``t_out`` must
        come to keep clear of every walker on it (0: it is clear)."""
        gap, worst = self.gap_s, 0.0
        for w in self.slots.get(crossing, ()):
            if w.start_s - gap >= t_out:
                break
            if w.end_s + gap > t_in:
                worst = max(worst, w.end_s + gap - t_in)
        return worst

    def advance(self, now_s: float) -> None:
        """Forget the walkers who are across."""
        for c, slots in self.slots.items():
            if slots and slots[0].end_s < now_s:
                self.slots[c] = [w for w in slots if w.end_s >= now_s]
