"""People crossing: when each walker has each part of a crossing, and what a vehicle's
plan must keep clear of.

A walker at the kerb asks to cross; the ICA answers with the moment to start. From
then on the walker is somewhere between a slow walk (:data:`WALK_MPS`, or a little
under its own speed if that is slower) and a little over its own pace: over a
stretch ``[u_lo, u_hi]`` of the crossing (metres along it) it may be from the
moment its fast pace brings it there to the moment a slow walk begun
:data:`LAG_S` late has taken it past, and :data:`CLEAR_S` more
(:meth:`WalkSlot.over`). A vehicle's plan touches a crossing over one stretch, the
one its lane runs through (:func:`ica.core.crosswalk.reach`), for as long as its
body is on it (:func:`hold`); the two must not meet. So a walker holds the lane it
is in, not the whole road: a car in the far lane passes while the walker is still
in the near one, as on a real crossing.

Walkers do not conflict with each other, so they cross in phases, all the
junction's crossings together: a walker who asks while a phase has not begun,
and whose walk from its start is clear of the vehicles, joins it. A new phase
begins no sooner than :data:`PHASE_GAP_S` after the last walker of the phases
before is off its way, which leaves every vehicle route a window with all its
crossings free; and no sooner than the vehicles confirmed before the walker
asked are clear of its way (no vehicle confirmed later can take its time). A
new phase begins no later than :data:`WAIT_BOUND_S` after the walker asked, and a
vehicle's plan may hold a crossing at most :data:`HOLD_AHEAD_S` ahead of the moment
it is confirmed (that bound, if it claims its turn), so a walker at the kerb waits
at most :data:`WAIT_BOUND_S` for its start (docs/architecture.md, "People
crossing"). Pure: plans and times in, times out.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass

from dica.ica.core.crosswalk import BODY_M, CORNER_M, Crosswalk
from dica.ica.core.trajectory import Trajectory

WALK_MPS = 1.0  # [m/s] a slow walker's speed (the 15th percentile is about 1.0-1.1 m/s)
FAST_MPS = 2.5  # [m/s] the fastest a walker of no stated speed is taken to go
PACE_UP = 1.1  # a walker of stated speed may go this much faster than it
PACE_DOWN = 0.8  # and this much slower (a crowd, a pause to let someone by)
LAG_S = 3.0  # [s] a walker may step off this late (those ahead of it at the kerb go first)
CLEAR_S = 2.0  # [s] beyond the walk itself: the last step out
KERB_M = 6.0  # [m] a walker at the kerb stands at most this far from the crossing's end
# [s] the vehicles' window between the end of a walk phase and the next: the short one when
# no vehicle waits for a plan as the walker asks, the long one when some do
PHASE_GAP_S = 8.0
BUSY_GAP_S = 35.0
# [s] a vehicle's plan holds no crossing (padded, and the walkers' gap) later than this after
# it is confirmed (unless the vehicle has been refused for it for CLAIM_S: then it may hold
# one up to WAIT_BOUND_S ahead, so it does not starve)
HOLD_AHEAD_S = 25.0
CLAIM_S = 20.0
# [s] a walker is given a start at most this long after the ICA hears it ask: a new walk
# phase begins no later, and no vehicle confirmed before the ask holds its way longer
WAIT_BOUND_S = 90.0

Hold = tuple[float, float, float, float]  # a vehicle on a crossing: t_in, t_out, u_lo, u_hi


@dataclass(frozen=True, slots=True)
class WalkSlot:
    """A walker's reservation of ``crossing``: it starts at ``start_s`` at most
    ``near_m`` and at least ``near_lo_m`` short of the crossing's end ``side`` (0: the
    first point of its centre line as the net draws it, 1: the last), walks at ``v_lo``
    to ``v_hi`` [m/s], and is off the crossing and its corner by ``end_s``. The two
    distances differ because a walker may go round a corner or cut across it: the far
    one says when it may still be on a stretch, the near one when it may be there
    already (0, as the crow flies through anything, if unknown)."""

    person: str
    crossing: str
    start_s: float
    end_s: float
    side: int = 0
    near_m: float = 0.0
    v_lo: float = WALK_MPS
    v_hi: float = FAST_MPS
    eta_s: float = math.inf  # when it is expected off its way at its own pace (<= end_s)
    near_lo_m: float = 0.0  # [m] the shortest way it may take to the crossing's end
    late_s: float = 0.0  # [s] how late after start_s the roadside may still let it go

    def over(
        self, u_lo: float, u_hi: float, length_m: float, clear_s: float
    ) -> tuple[float, float]:
        """When the walker may be on the stretch ``[u_lo, u_hi]`` of the crossing (metres
        from its end 0): from its fastest arrival at the stretch, a body's reach
        (:data:`BODY_M`) early, to its slowest departure (let go :attr:`late_s` late and
        stepping off :data:`LAG_S` after that) a body's reach past it and ``clear_s``
        more, within its slot."""
        a, b = (u_lo, u_hi) if self.side == 0 else (length_m - u_hi, length_m - u_lo)
        t_in = self.start_s + max(a + self.near_lo_m - BODY_M, 0.0) / self.v_hi
        lag = LAG_S + self.late_s
        t_out = self.start_s + lag + max(b + self.near_m + BODY_M, 0.0) / self.v_lo + clear_s
        return min(t_in, self.end_s), min(t_out, self.end_s)


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
        late_s: float = 0.0,
    ) -> None:
        if not walk_mps > 0.0:
            raise ValueError(f"walking speed must be positive, got {walk_mps}")
        self.crosswalks = {c.id: c for c in crosswalks}
        self.walk_mps = walk_mps
        self.clear_s = clear_s
        self.gap_s = gap_s  # [s] kept between a vehicle's hold and a walker's, either way
        # [s] how late after its start the roadside may still let a walker go (the GO's way
        # to it: IcaConfig.green_late_s); a later GO is dropped and the walker asks again
        self.late_s = late_s
        self.slots: dict[str, list[WalkSlot]] = {c: [] for c in self.crosswalks}
        self.phase_gap_s = PHASE_GAP_S
        self._ended = -math.inf  # when the last of the forgotten walkers was off its way

    # -- one walker ------------------------------------------------------------------
    def pace(self, speed_mps: float) -> tuple[float, float]:
        """The slowest and fastest a walker of stated ``speed_mps`` (0: not stated) is
        planned to go."""
        if speed_mps > 0.0:
            slow = min(self.walk_mps, speed_mps * PACE_DOWN)
            return slow, max(speed_mps * PACE_UP, self.walk_mps)
        return self.walk_mps, FAST_MPS

    def walk_s(self, crossing: str, walk_m: float = 0.0, speed_mps: float = 0.0) -> float:
        """How long a walker holds ``crossing``: ``walk_m`` from where it stands until it
        is off the walking area beyond (at least the crossing's length and
        :data:`CORNER_M`), at its slow pace, let go up to :attr:`late_s` late and stepping
        off :data:`LAG_S` after that, and :attr:`clear_s` more."""
        far = max(walk_m, self.crosswalks[crossing].length_m + CORNER_M)
        return self.late_s + LAG_S + far / self.pace(speed_mps)[0] + self.clear_s

    def slot(
        self,
        person: str,
        crossing: str,
        start_s: float,
        walk_m: float = 0.0,
        speed_mps: float = 0.0,
        side: int = 0,
        near_m: float = 0.0,
        near_lo_m: float = 0.0,
    ) -> WalkSlot:
        """The slot of a walker that starts at ``start_s`` (not yet held), at most
        ``near_m`` and at least ``near_lo_m`` from the crossing's end."""
        v_lo, v_hi = self.pace(speed_mps)
        end = start_s + self.walk_s(crossing, walk_m, speed_mps)
        own = speed_mps if speed_mps > 0.0 else self.walk_mps
        far = max(walk_m, self.crosswalks[crossing].length_m + CORNER_M)
        eta = min(start_s + self.late_s + far / own + self.clear_s, end)
        near_lo = min(near_lo_m, near_m)
        return WalkSlot(person, crossing, start_s, end, side, near_m, v_lo, v_hi, eta, near_lo,
                        self.late_s)  # fmt: skip

    def earliest(self, want: WalkSlot, ready_s: float, busy: list[Hold]) -> float:
        """The first start at or after ``ready_s`` at which the walk ``want`` (its start
        moved) meets none of the vehicle holds in ``busy`` (with :attr:`gap_s` each
        side)."""
        banned = sorted(self._banned(want, busy))
        t = ready_s
        for a, b in banned:
            if b <= t:
                continue
            if a >= t:
                break
            t = b
        return t

    def clear_at(self, want: WalkSlot, start_s: float, busy: list[Hold]) -> bool:
        """Whether the walk ``want`` started at ``start_s`` meets none of ``busy``."""
        return all(not (a < start_s < b) for a, b in self._banned(want, busy))

    def _banned(self, want: WalkSlot, busy: list[Hold]) -> list[tuple[float, float]]:
        """The open intervals of starts at which ``want`` meets a hold in ``busy``."""
        length, gap = self.crosswalks[want.crossing].length_m, self.gap_s
        rel = dataclasses.replace(want, start_s=0.0, end_s=want.end_s - want.start_s)
        out = []
        for t_in, t_out, u_lo, u_hi in busy:
            a, b = rel.over(u_lo, u_hi, length, self.clear_s)
            if b > a:
                out.append((t_in - gap - b, t_out + gap - a))
        return out

    # -- phases ----------------------------------------------------------------------
    def phase_s(self, crossing: str) -> float:
        """How long a walk phase on ``crossing`` lasts at least: a slow walk from
        :data:`KERB_M` short of it to its far end."""
        return self.walk_s(crossing, self.crosswalks[crossing].length_m + KERB_M)

    def joinable(self, want: WalkSlot, at_s: float, busy: list[Hold]) -> float | None:
        """The start of a walk phase of the junction that has not begun by ``at_s`` and
        from which the walk ``want`` meets none of ``busy``: a walker there now can go
        with it (None: there is none)."""
        starts = sorted({w.start_s for slots in self.slots.values() for w in slots})
        for start in starts:
            if start >= at_s - 1e-9 and self.clear_at(want, start, busy):
                return start
        return None

    @property
    def last_end(self) -> float:
        """When the last walker of the phases so far is expected off its way: at its own
        pace, or when the roadside saw it across. (The window after it is for the
        vehicles' progress; their safety rests on the slow walk, :meth:`WalkSlot.over`.)"""
        ends = [min(w.eta_s, w.end_s) for slots in self.slots.values() for w in slots]
        return max([self._ended, *ends])

    def across(self, person: str, crossing: str, t_s: float) -> bool:
        """The roadside saw ``person`` off ``crossing`` and its corners at ``t_s``: its slot
        ends there (True), if it holds one that ended later."""
        slots = self.slots.get(crossing, [])
        for i, w in enumerate(slots):
            if w.person == person:
                end = max(t_s, w.start_s)
                if end >= w.end_s:
                    return False
                slots[i] = dataclasses.replace(w, end_s=end, eta_s=min(w.eta_s, end))
                return True
        return False

    def next_phase_s_for(self, vehicles_waiting: bool) -> float:
        """:meth:`next_phase_s`, with the long window (:data:`BUSY_GAP_S`) when vehicles
        wait for plans: the vehicles get the junction for as long as a light's green
        would give them, the walkers the next phase after it."""
        return self.last_end + (BUSY_GAP_S if vehicles_waiting else self.phase_gap_s)

    def next_phase_s(self) -> float:
        """The first moment a new walk phase may begin: :data:`PHASE_GAP_S` after the
        last walker of the phases so far is off its way (the vehicles' window)."""
        return self.last_end + self.phase_gap_s

    # -- the book ----------------------------------------------------------------------
    def drop(self, person: str, crossing: str, start_s: float) -> bool:
        """The roadside never let ``person`` go on its slot of ``crossing`` from
        ``start_s`` (the GO came later than :attr:`late_s` after it): the slot goes (True),
        and the walker may ask again. False if it holds no slot of that start."""
        slots = self.slots.get(crossing, [])
        for i, w in enumerate(slots):
            if w.person == person and abs(w.start_s - start_s) <= 1e-9:
                del slots[i]
                return True
        return False

    def slot_of(self, person: str, crossing: str) -> WalkSlot | None:
        """The slot ``person`` holds on ``crossing``, if any (a WALK asked twice gets it
        again, not a second one)."""
        return next((w for w in self.slots.get(crossing, ()) if w.person == person), None)

    def reserve(self, slot: WalkSlot) -> WalkSlot:
        """Hold ``slot`` (the one its walker holds already on that crossing, if any)."""
        held = self.slot_of(slot.person, slot.crossing)
        if held is not None:
            return held
        bisect.insort(self.slots[slot.crossing], slot, key=lambda x: x.start_s)
        return slot

    def delay(self, crossing: str, t_in: float, t_out: float, u_lo: float, u_hi: float) -> float:
        """How much later a vehicle on the stretch ``[u_lo, u_hi]`` of ``crossing`` from
        ``t_in`` to ``t_out`` must come to keep clear of every walker on it (0: clear)."""
        gap, worst = self.gap_s, 0.0
        length = self.crosswalks[crossing].length_m
        for w in self.slots.get(crossing, ()):
            if w.start_s - gap >= t_out:
                break
            a, b = w.over(u_lo, u_hi, length, self.clear_s)
            if b > a and a - gap < t_out and b + gap > t_in:
                worst = max(worst, b + gap - t_in)
        return worst

    def advance(self, now_s: float) -> None:
        """Forget the walkers who are across."""
        for c, slots in self.slots.items():
            gone = [min(w.eta_s, w.end_s) for w in slots if w.end_s < now_s]
            if gone:
                self._ended = max(self._ended, *gone)
                self.slots[c] = [w for w in slots if w.end_s >= now_s]
