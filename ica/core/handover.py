"""Handing a vehicle over to the road's driver beyond the junction.

Out of the junction a vehicle is driven again by an ordinary car-following
driver (SUMO's Krauss: reaction time ``tau_s``, standstill gap
``min_gap_m``, braking ``decel_mps2``), which accelerates it freely to the
road speed unless the vehicle ahead makes it brake. A faster vehicle that
leaves by the same exit lane behind a slower one may therefore close in on
it out there, where the ICA no longer checks anything.

checkFV's cap keeps the follower no faster than the leader. The other way,
which the dissertation names (a separation time that depends on both
speeds), is to let the follower leave fast but late enough that its driver
never has to brake: at every moment after its hand-over the gap is at least
the Krauss safe gap, ``min_gap + v_F tau + (v_F^2 - v_L^2) / 2b``, with both
accelerating freely to the road speed. That gap is also what the driver
needs to stop behind the leader if the leader brakes at ``decel_mps2``, so
a hand-over at that separation is one the driver can keep.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from dica.ica.core.kernels.handover import Driver, separation


@dataclass(frozen=True, slots=True)
class Handover:
    """The driver beyond the junction and the free run it gives a vehicle."""

    road_mps: float
    accel_mps2: float = 2.0
    decel_mps2: float = 4.5
    tau_s: float = 1.0
    min_gap_m: float = 2.5
    buffer_m: float = 1.0  # [m] on top of the safe gap: the driver's discrete steps
    step_s: float = 0.05

    def separation_s(self, v_lead_mps: float, v_follow_mps: float, follow_len_m: float) -> float:
        """Least time from the leader's rear leaving the junction to the follower's
        at which the follower, leaving at ``v_follow_mps``, never needs to brake.

        Looked up on a 1 cm/s and 10 cm grid, rounded the safe way (a slower
        leader, a faster and longer follower)."""
        return _separation(
            self,
            math.floor(v_lead_mps * 100.0) / 100.0,
            math.ceil(v_follow_mps * 100.0) / 100.0,
            math.ceil(follow_len_m * 10.0) / 10.0,
        )

    @property
    def driver(self) -> Driver:
        """What the compiled search reads (:func:`ica.core.kernels.handover.separation`)."""
        return Driver(
            road_mps=self.road_mps,
            accel_mps2=self.accel_mps2,
            decel_mps2=self.decel_mps2,
            tau_s=self.tau_s,
            min_gap_m=self.min_gap_m,
            buffer_m=self.buffer_m,
            step_s=self.step_s,
        )

    def _free(self, v0: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance and speed at times ``t`` >= 0 of a free run from ``v0``."""
        v_top = max(self.road_mps, v0)
        t_acc = (v_top - v0) / self.accel_mps2
        ta = np.minimum(t, t_acc)
        x = v0 * ta + 0.5 * self.accel_mps2 * ta * ta + v_top * np.maximum(t - t_acc, 0.0)
        return x, np.minimum(v0 + self.accel_mps2 * t, v_top)

    def gap_ok(self, v_lead: float, v_follow: float, follow_len_m: float, sep_s: float) -> bool:
        """Does a follower released ``sep_s`` after the leader keep the safe gap for good?"""
        horizon = sep_s + (self.road_mps - min(v_lead, v_follow)) / self.accel_mps2 + 1.0
        t = np.arange(0.0, horizon + self.step_s, self.step_s)  # since the follower's release
        x_l, v_l = self._free(v_lead, t + sep_s)
        x_f, v_f = self._free(v_follow, t)
        gap = x_l - x_f - follow_len_m
        need = self.min_gap_m + self.buffer_m + v_f * self.tau_s
        need = need + (v_f * v_f - v_l * v_l) / (2.0 * self.decel_mps2)
        return bool(np.all(gap >= need))


@functools.lru_cache(maxsize=4096)
def _separation(h: Handover, v_lead: float, v_follow: float, follow_len_m: float) -> float:
    # compiled: a miss came to about 0.4 ms in numpy (some 20 gap checks), a request
    # can meet several new speed pairs, and the cache warms only slowly in a real run
    return separation(tuple(h.driver), v_lead, v_follow, follow_len_m)


def clear_separations() -> None:
    """Forget the separations looked up so far (a benchmark's cold start)."""
    _separation.cache_clear()


def separation_reference(h: Handover, v_lead: float, v_follow: float, follow_len_m: float) -> float:
    """The search :func:`ica.core.kernels.handover.separation` compiles, over
    :meth:`Handover.gap_ok` (doubling, then bisection to 0.01 s): the tests hold the
    two equal."""
    lo, hi = 0.0, 1.0
    while not h.gap_ok(v_lead, v_follow, follow_len_m, hi):
        lo, hi = hi, 2.0 * hi
        if hi > 120.0:
            return math.inf
    if h.gap_ok(v_lead, v_follow, follow_len_m, lo):
        return lo
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if h.gap_ok(v_lead, v_follow, follow_len_m, mid) else (mid, hi)
    return hi
