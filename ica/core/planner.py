"""Longitudinal motion plans a vehicle can really fly.

The dissertation delays a DTOT by shifting its times, which a vehicle that has
to brake or stop cannot follow. Here a later entry time is met by a new plan
from the vehicle's state in the request, built from pieces of constant
acceleration within the vehicle's limits:

* **slow-down family** A(v_m): change speed from v0 to a cruise speed v_m,
  cruise, then accelerate to the entry speed reached exactly at the entry line
  (or brake to the junction's cap when cruising above it). Larger v_m arrives
  earlier; the largest feasible v_m is the time-optimal plan.
* **stop family** B(w): brake to a stop before the entry line, wait ``w``
  seconds, then pull away at full acceleration. With ``run_up`` the vehicle
  stands where that pull-away reaches the crossing cap at the line (or as far
  back as it can still stop), else ``stop_gap_m`` short of the line. With ``hold`` a
  vehicle already standing waits where it stands instead (a platoon's
  follower cannot draw up to the line while its leader stands there).

Inside the junction every plan accelerates at ``accel`` up to the crossing
cap and holds it until the vehicle is fully out. A-plans whose cruise speed
would fall below ``creep_mps`` give way to stopping. Entering at speed
matters under heavy traffic: a vehicle that pulls away from the line occupies
the conflict zones for seconds longer than one that arrives moving.

Positions are arc length along the route with 0 at the entry line, times are
relative to the request (``t = 0`` at the state the vehicle reported).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dica.ica.core.kernels.planner import (
    Approach,
    Plan,
    a_phases,
    bisect_cruise,
    plan_constants_of,
)
from dica.ica.core.limits import Kinematics

_EPS = 1e-9


@dataclass(frozen=True, slots=True, eq=False)
class Profile:
    """Piecewise constant acceleration: segment k starts at ``t_s[k]`` with
    ``s_m[k]``, ``v_mps[k]`` and accelerates at ``a_mps2[k]``. After the last
    segment the vehicle holds its speed."""

    t_s: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    entry_time_s: float
    entry_speed_mps: float

    def position(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.t_s, t, side="right") - 1, 0, len(self.t_s) - 1)
        tau = np.maximum(t - self.t_s[k], 0.0)
        return self.s_m[k] + self.v_mps[k] * tau + 0.5 * self.a_mps2[k] * tau * tau

    def time_at(self, s: float) -> float:
        """First time the front reaches arc length ``s`` (inf if never)."""
        # plain floats: the same IEEE arithmetic as numpy scalars, without their overhead
        ts, ss, vs, accs = (
            self.t_s.tolist(),
            self.s_m.tolist(),
            self.v_mps.tolist(),
            self.a_mps2.tolist(),
        )
        for k in range(len(ts)):
            s0, v0, a = ss[k], vs[k], accs[k]
            end = ts[k + 1] - ts[k] if k + 1 < len(ts) else math.inf
            ds = s - s0
            if ds <= 0.0:
                return float(ts[k])
            if abs(a) < _EPS:
                tau = ds / v0 if v0 > _EPS else math.inf
            else:
                disc = v0 * v0 + 2.0 * a * ds
                tau = math.inf if disc < 0.0 else (math.sqrt(disc) - v0) / a
            if tau <= end + 1e-9:
                return float(ts[k] + tau)
        return math.inf


class _Builder:
    """Accumulates constant-acceleration segments."""

    def __init__(self, s0: float, v0: float) -> None:
        self.t, self.s, self.v = 0.0, s0, v0
        self.segs: list[tuple[float, float, float, float]] = []

    def accel_to(self, v1: float, rate: float) -> None:
        if abs(v1 - self.v) < _EPS:
            return
        a = rate if v1 > self.v else -rate
        dt = (v1 - self.v) / a
        self.segs.append((self.t, self.s, self.v, a))
        self.s += (self.v + v1) / 2.0 * dt
        self.t += dt
        self.v = v1

    def hold(self, dt: float) -> None:
        if dt <= _EPS:
            return
        self.segs.append((self.t, self.s, self.v, 0.0))
        self.s += self.v * dt
        self.t += dt

    def cruise_to(self, s1: float) -> None:
        if s1 - self.s > _EPS and self.v > _EPS:
            self.hold((s1 - self.s) / self.v)

    def profile(self, entry_time: float, entry_speed: float) -> Profile:
        self.segs.append((self.t, self.s, self.v, 0.0))  # hold speed afterwards
        cols = np.array(list(zip(*self.segs, strict=True)), dtype=float)  # contiguous rows
        return Profile(cols[0], cols[1], cols[2], cols[3], entry_time, entry_speed)


def approach_of(
    kin: Kinematics,
    d_m: float,
    v0_mps: float,
    road_mps: float,
    cap_mps: float,
    s_end_m: float,
    hold: bool,
) -> Approach:
    """The approach of a :class:`Planner` with these fields, as the compiled planner
    reads it (a caller that needs no Python planner builds it without one)."""
    return Approach(
        accel_mps2=kin.accel_mps2,
        decel_mps2=kin.decel_mps2,
        v0_mps=v0_mps,
        d_m=d_m,
        road_mps=road_mps,
        cap_mps=cap_mps,
        s_end_m=s_end_m,
        creep_mps=kin.creep_mps,
        stop_gap_m=kin.stop_gap_m,
        run_up=kin.run_up,
        hold=hold,
        cap_sq=cap_mps**2,
        v0_sq=v0_mps**2,
    )


@dataclass(frozen=True, slots=True)
class Planner:
    """Plans for one vehicle: distance ``d_m`` to the entry line, speed ``v0_mps``.

    ``road_mps`` caps the approach, ``cap_mps`` the crossing (turn cap, or a
    front vehicle's exit speed); ``s_end_m`` is where the front is when the
    vehicle is fully out (crossing length plus vehicle length).
    """

    d_m: float
    v0_mps: float
    road_mps: float
    cap_mps: float
    s_end_m: float
    kin: Kinematics = Kinematics()
    # a vehicle standing still waits where it stands, then pulls away, instead of first
    # drawing up to the line (platoons: its leader may still stand between it and the line)
    hold: bool = False
    # what does not depend on the entry time asked for, computed once per planner
    _memo: dict[str, Any] = field(
        default_factory=dict, init=False, repr=False, compare=False, hash=False
    )

    # -- the two families -------------------------------------------------
    def _crossing(self, b: _Builder) -> None:
        """From the entry line: accelerate to the cap, hold until fully out."""
        b.accel_to(max(b.v, self.cap_mps), self.kin.accel_mps2)
        # If accelerating to the cap overshoots s_end we still keep the plan:
        # samples past s_end are never used.
        b.cruise_to(self.s_end_m)

    def _a_phases(self, v_m: float) -> tuple[float, float, float, float] | None:
        """(D1, D3, v_e, T) of A(v_m), or None if it does not fit in d.

        Compiled (:func:`ica.core.kernels.planner.a_phases`, the arithmetic of
        :meth:`_a_phases_reference` in the same order).
        """
        fits, d1, d3, v_e, t = a_phases(tuple(self.approach()), v_m)
        return (d1, d3, v_e, t) if fits else None

    def _a_phases_reference(self, v_m: float) -> tuple[float, float, float, float] | None:
        """:meth:`_a_phases` in Python."""
        a, br, v0, d, cap = (
            self.kin.accel_mps2,
            self.kin.decel_mps2,
            self.v0_mps,
            self.d_m,
            self.cap_mps,
        )
        d1 = (v_m * v_m - v0 * v0) / (2 * a) if v_m >= v0 else (v0 * v0 - v_m * v_m) / (2 * br)
        t1 = abs(v_m - v0) / (a if v_m >= v0 else br)
        if d1 > d + 1e-7:
            return None
        if v_m > cap:
            v_e = cap
            d3 = (v_m * v_m - cap * cap) / (2 * br)
            t3 = (v_m - cap) / br
        else:
            v_e = min(cap, math.sqrt(max(v_m * v_m + 2 * a * (d - d1), 0.0)))
            d3 = (v_e * v_e - v_m * v_m) / (2 * a)
            t3 = (v_e - v_m) / a
        d2 = d - d1 - d3
        if d2 < -1e-7:
            return None
        if d2 > 1e-9 and v_m <= _EPS:
            return None
        t2 = d2 / v_m if d2 > 1e-9 else 0.0
        return d1, d3, v_e, t1 + t2 + t3

    def _v_max(self) -> float:
        """Cruise speed of the time-optimal plan (largest feasible v_m)."""
        a, br, v0, d, cap = (
            self.kin.accel_mps2,
            self.kin.decel_mps2,
            self.v0_mps,
            self.d_m,
            self.cap_mps,
        )
        reach = math.sqrt(v0 * v0 + 2 * a * d)
        if reach <= cap and v0 <= cap:
            return min(reach, self.road_mps)
        peak2 = (d + v0 * v0 / (2 * a) + cap * cap / (2 * br)) / (1 / (2 * a) + 1 / (2 * br))
        return min(self.road_mps, math.sqrt(max(peak2, 0.0)))

    def _v_min_a(self) -> float:
        v_floor = math.sqrt(max(0.0, self.v0_mps**2 - 2 * self.kin.decel_mps2 * self.d_m))
        return max(self.kin.creep_mps, v_floor)

    def _build_a(self, v_m: float) -> Profile | None:
        ph = self._a_phases(v_m)
        if ph is None:
            return None
        _, d3, v_e, t_entry = ph
        rate_up, rate_dn = self.kin.accel_mps2, self.kin.decel_mps2
        b = _Builder(-self.d_m, self.v0_mps)
        b.accel_to(v_m, rate_up if v_m >= self.v0_mps else rate_dn)
        b.cruise_to(-d3)
        b.accel_to(v_e, rate_up if v_e >= v_m else rate_dn)
        b.s = 0.0  # absorb rounding at the entry line
        self._crossing(b)
        return b.profile(t_entry, v_e)

    def _stop_gap(self) -> float:
        """Where the stop family stands: ``stop_gap`` short of the line, or where the
        vehicle stands now if it holds (the family is then: wait, pull away)."""
        if self.hold and self.v0_mps <= 0.0:
            return self.d_m
        gap = self.kin.stop_gap_m
        if self.kin.run_up:
            # back where a pull-away reaches the cap at the line, if it can stop there
            run_up = self.cap_mps**2 / (2 * self.kin.accel_mps2)
            room = self.d_m - self.v0_mps**2 / (2 * self.kin.decel_mps2)
            gap = max(gap, min(run_up, room))
        return min(gap, self.d_m)

    def can_stop(self) -> bool:
        d_stop = self.d_m - self._stop_gap()
        return self.v0_mps**2 <= 2 * self.kin.decel_mps2 * d_stop + 1e-7

    def _b_base(self) -> tuple[_Builder, float]:
        """Time-optimal stop ``stop_gap`` before the line; returns builder and stop time.

        Built once per planner; each call gets its own copy to extend.
        """
        base = self._memo.get("b_base")
        if base is None:
            b, _ = self._b_base_build()
            base = self._memo["b_base"] = (tuple(b.segs), b.t, b.s, b.v)
        segs, t, s, v = base
        b = _Builder(s, v)
        b.segs, b.t = list(segs), t
        return b, t

    def _b_base_build(self) -> tuple[_Builder, float]:
        a, br, v0 = self.kin.accel_mps2, self.kin.decel_mps2, self.v0_mps
        d_stop = self.d_m - self._stop_gap()
        b = _Builder(-self.d_m, v0)
        peak2 = (d_stop + v0 * v0 / (2 * a)) / (1 / (2 * a) + 1 / (2 * br))
        peak = max(v0, min(self.road_mps, math.sqrt(max(peak2, 0.0))))
        b.accel_to(peak, a)
        b.cruise_to(-self._stop_gap() - peak * peak / (2 * br))
        b.accel_to(0.0, br)
        b.s = -self._stop_gap()
        return b, b.t

    def _build_b(self, wait_s: float) -> Profile:
        b, _ = self._b_base()
        b.hold(0.0)
        if wait_s > 0:
            b.segs.append((b.t, b.s, 0.0, 0.0))
            b.t += wait_s
        gap = self._stop_gap()
        a = self.kin.accel_mps2
        v_e = min(self.cap_mps, math.sqrt(2 * a * gap))
        t_entry = b.t + self._pull_away_time(gap)
        self._crossing(b)
        return b.profile(t_entry, v_e)

    def _pull_away_time(self, gap: float) -> float:
        """Time from standstill ``gap`` before the line until the front reaches it."""
        a, cap = self.kin.accel_mps2, self.cap_mps
        if gap <= cap * cap / (2 * a):
            return math.sqrt(2 * gap / a)
        return cap / a + (gap - cap * cap / (2 * a)) / cap

    # -- public ---------------------------------------------------------
    def feasible(self) -> bool:
        """Can the vehicle reach the entry line at or below the crossing cap at all?"""
        return self._a_phases(self._v_max()) is not None

    def fastest(self) -> Profile | None:
        return self._build_a(self._v_max())

    def stop_entry_s(self) -> float:
        """Earliest entry of a plan that stops at the line first (inf if it cannot stop)."""
        if not self.can_stop():
            return math.inf
        _, t_stop = self._b_base()
        return t_stop + self._pull_away_time(self._stop_gap())

    def earliest_entry_s(self) -> float:
        plan = self.plan_constants()
        return plan.hi_entry_s if plan.hi_ok else math.inf

    def _entry_memo(self) -> dict[str, Any]:
        """The time-optimal plan and the slowest slow-down plan, once per planner."""
        m = self._memo
        if "v_hi" not in m:
            v_hi = m["v_hi"] = self._v_max()
            m["hi"] = self._a_phases(v_hi)
            v_lo = m["v_lo"] = self._v_min_a()
            m["lo"] = self._a_phases(v_lo) if v_lo < v_hi else None
        return m

    def approach(self) -> Approach:
        """This vehicle's approach as the compiled planner reads it (once per planner)."""
        m = self._memo
        if "approach" not in m:
            m["approach"] = approach_of(
                self.kin, self.d_m, self.v0_mps, self.road_mps, self.cap_mps, self.s_end_m,
                self.hold,
            )  # fmt: skip
        return m["approach"]

    def plan_constants(self) -> Plan:
        """What :meth:`at_or_after` computes once, for the compiled round loop
        (:func:`ica.core.kernels.resolve.resolve_rounds`): the time-optimal plan's
        cruise speed, whether it fits and its entry time, the same of the slowest
        slow-down plan, the stop plan's earliest entry, the stop-at-the-line base as
        segments and as the builder's (t, s, v). One compiled call
        (:func:`ica.core.kernels.planner.plan_constants_of`), bit for bit
        :meth:`plan_constants_reference`."""
        m = self._memo
        if "constants" not in m:
            m["constants"] = Plan._make(plan_constants_of(tuple(self.approach())))
        return m["constants"]

    def plan_constants_reference(self) -> Plan:
        """:meth:`plan_constants` from the Python planner."""
        m = self._entry_memo()
        hi, lo = m["hi"], m["lo"]
        if "t_b0" not in m:
            m["t_b0"] = self.stop_entry_s()
        t_b0 = m["t_b0"]
        if math.isfinite(t_b0):
            segs, t, s, v = self._memo["b_base"]
            base = np.array(segs, dtype=float).reshape(-1, 4)
            state = np.array([t, s, v], dtype=float)
        else:
            base, state = np.zeros((0, 4)), np.zeros(3)
        kin = self.kin
        return Plan(
            accel_mps2=kin.accel_mps2,
            decel_mps2=kin.decel_mps2,
            v0_mps=self.v0_mps,
            d_m=self.d_m,
            cap_mps=self.cap_mps,
            s_end_m=self.s_end_m,
            v_hi_mps=m["v_hi"],
            hi_ok=hi is not None,
            hi_entry_s=hi[3] if hi is not None else 0.0,
            v_lo_mps=m["v_lo"],
            lo_ok=lo is not None,
            lo_entry_s=lo[3] if lo is not None else 0.0,
            stop_entry_s=t_b0,
            b_segs=base,
            b_state=state,
        )

    def stop_wait_s(self, t_entry_s: float) -> float | None:
        """The wait of the plan :meth:`at_or_after` gives if it is of the stop family,
        else None. Such plans all move alike until ``stop_time_s() + wait``."""
        p = self.plan_constants()
        if not p.hi_ok or t_entry_s <= p.hi_entry_s + 1e-9:
            return None
        if p.lo_ok and t_entry_s <= p.lo_entry_s:
            return None
        return max(0.0, t_entry_s - p.stop_entry_s) if math.isfinite(p.stop_entry_s) else None

    def stop_time_s(self) -> float:
        """When the stop family stands still (relative to the state)."""
        return self._b_base()[1]

    def at_or_after(self, t_entry_s: float) -> Profile | None:
        """The plan entering soonest at or after ``t_entry_s`` (None if none exists).

        Prefers slowing down (higher entry speed) and stops at the line when
        that would mean creeping.
        """
        m = self._entry_memo()
        v_hi, v_lo = m["v_hi"], m["v_lo"]
        hi, lo = m["hi"], m["lo"]
        if hi is None:
            return None
        if t_entry_s <= hi[3] + 1e-9:
            return self._build_a(v_hi)
        if lo is not None and t_entry_s <= lo[3]:
            # T(v_m) decreases with v_m: bisect for the cruise speed that arrives on time
            # (compiled: 60 halvings of [v_lo, v_hi] at most, see bisect_cruise)
            v = bisect_cruise(tuple(self.approach()), v_lo, v_hi, t_entry_s)
            return self._build_a(v)
        if "t_b0" not in m:
            m["t_b0"] = self.stop_entry_s()
        t_b0 = m["t_b0"]
        if not math.isfinite(t_b0):
            return None
        return self._build_b(max(0.0, t_entry_s - t_b0))
