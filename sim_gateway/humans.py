"""Human drivers at a signal-free junction: the roadside's side of them in SUMO.

A share of the random demand (``--cav-share``) is driven by SUMO's own driver, with
its imperfection, and cannot be sent a plan. Each meets a signal head of its own lane
that only human drivers obey: modelled as a SUMO stop at the line, which the head's
green ends (``resume``). The roadside detects it entering the region as it detects
any vehicle (position, speed, lane: no intent), the ICA is told, and once the driver
stands at the head of its lane the ICA is asked for its green
(:meth:`ica.core.dica.Dica.green`), which reserves every crossing the driver may make.

The audit here trusts none of that: every step it reads the driver's position from
SUMO and counts a driver that passed its line before its green (on red), or whose
front is ahead of its fastest or behind its slowest crossing of the route it really
took (outside its envelope), from the same stated limits
(:class:`ica.core.envelope.DriverLimits`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from dica.ica.core.envelope import (
    ROLL_NEAR_M,
    STOP_SHORT_M,
    DriverLimits,
    bounds_seen,
    green_bounds,
    path_s,
)
from dica.ica.core.trajectory import Trajectory
from dica.sim_gateway.junction import Car, Junction, Seen
from dica.sim_gateway.traffic import HUMAN_VTYPE

HUMAN_COLOR = (150, 150, 150, 255)  # grey: a car the ICA cannot command
# SUMO speed mode of a human driver: its own safe speed, acceleration and braking limits
# and red lights, but not the junction's right of way (its head's green gives it the way)
HUMAN_SPEED_MODE = 0b110111
STOP_S = 1e7  # [s] a stop at the head lasts until the green ends it
TOL_M = 0.05  # [m] the audit's tolerance on a position (SUMO's rounding)
# [s] how often the roadside has the ICA shrink a crossing human's reservations to where
# it is seen, and a waiting one ask again
TIGHTEN_S = 0.5
ROLL_MIN_MPS = 0.5  # [m/s] slower than this it is about to stand, and asks standing


class Desk(Protocol):
    """The ICA as the roadside asks it about human drivers: in the same process
    (:class:`sim_gateway.embedded.LocalDrivers`) or over Zenoh
    (:class:`sim_gateway.gateway.ZenohDrivers`). The same questions in the same order
    either way, so both runs are the same."""

    def spotted(self, car: Car, t: float) -> bool:
        """``car`` entered the communication region (from the detector: no intent).
        False: the ICA did not hear it (it is told again next step)."""

    def green(
        self, car: Car, t: float, near_m: float, again: bool, v_mps: float = 0.0
    ) -> tuple[float, tuple, float] | None:
        """Its green (start, routes, and when the head turns green) standing ``near_m``
        short of its line; ``again``: only a sooner one than it holds; ``v_mps`` above 0:
        rolling towards the line at that speed, a green now or none. None: none given
        (not yet, or not sooner; or, from the real-time gateway, not yet answered: it
        lights or drops each green as its answer comes, ZenohDrivers._answered)."""

    def tighten(
        self, car: Car, t: float, s_m: float, v_mps: float, lane: str
    ) -> tuple[str, ...] | None:
        """Its reservations shrunk to where it is seen: the routes kept, or None."""


def define_human_type(
    ls, limits: DriverLimits, length_m: float, width_m: float, ignore_foes: bool = True
) -> None:
    """SUMO's default driver (Krauss with its imperfection), with the stated limits; at a
    signal-free junction (``ignore_foes``) it ignores the junction's right of way, which
    its head's green gives it; under a light it keeps SUMO's."""
    ls.vehicletype.copy("DEFAULT_VEHTYPE", HUMAN_VTYPE)
    for setter, value in (
        ("setLength", length_m),
        ("setWidth", width_m),
        ("setAccel", limits.accel_mps2),
        ("setDecel", 4.5),
        ("setEmergencyDecel", 9.0),
        ("setImperfection", limits.sigma),
        ("setMaxSpeed", limits.top_mps),
        ("setSpeedFactor", 1.0),  # each driver's own is set on departure
        ("setSpeedDeviation", 0.0),
        ("setColor", HUMAN_COLOR),
    ):
        getattr(ls.vehicletype, setter)(HUMAN_VTYPE, value)
    if ignore_foes:
        ls.vehicletype.setParameter(HUMAN_VTYPE, "junctionModel.jmIgnoreFoeProb", "1")
        ls.vehicletype.setParameter(HUMAN_VTYPE, "junctionModel.jmIgnoreFoeSpeed", "100")


@dataclass(slots=True)
class Driver:
    """One human driver as the roadside knows it."""

    car: Car
    speed_factor: float
    told: bool = False  # the ICA knows it is in the region
    standing_s: float = math.nan  # when it first stood at its head
    green_s: float = math.nan
    head_s: float = math.nan  # when its head turned green: its green, or up to late_s later
    routes: tuple[str, ...] = ()
    resumed: bool = False
    rolled: bool = False  # given its green rolling towards its line
    lane: str = ""  # the lane it was last seen on when its reservations shrank
    tightened_s: float = -math.inf  # when they last shrank to where it was
    asked_s: float = -math.inf  # when it last asked again for a sooner green
    refused_s: float = -math.inf  # when it was last refused a green, standing
    asked_shrunk: int = -1  # the ICA's count of shrunk reservations then
    tightenings: int = 0  # how often its reservations shrank to where it was seen
    sooner: int = 0  # how often it was given a sooner green, asking again
    # the audit: its bounds on the route it took, and what it found
    fast: Trajectory | None = None
    slow: Trajectory | None = None
    on_red: bool = False
    outside_steps: int = 0
    worst_ahead_m: float = 0.0  # how far ahead of its fastest crossing it was, at worst
    worst_behind_m: float = 0.0  # and behind its slowest


@dataclass(slots=True)
class SignalHeads:
    """The human drivers of one junction and their signal heads."""

    ls: object
    junction: Junction
    limits: DriverLimits
    step_s: float
    seed: int
    hold: bool = True  # signal-free: the head holds it (under a light: SUMO's light does)
    drivers: dict[str, Driver] = field(default_factory=dict)
    shrunk: int = 0  # reservations the ICA shrank, or greens it brought sooner
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng([self.seed, 27])

    # -- SUMO ------------------------------------------------------------------------
    def departed(self, c: Car) -> None:
        """``c`` is on the road: its own share of the limit, its lane kept, and a stop
        at its head's line."""
        lim = self.limits
        f = float(np.clip(self.rng.normal(1.0, 0.1), lim.speed_factor_min, lim.speed_factor_max))
        v = self.ls.vehicle
        v.setSpeedFactor(c.sumo, f)
        v.setLaneChangeMode(c.sumo, 0)
        # it keeps its lane and its pace beside the others: past a car standing in the next
        # lane (a turn lane's queue) it neither holds back so as not to pass on the right nor
        # slows to let one change in (SUMO's lane-change model does both, by default, to a
        # driver whose envelope the ICA reserved; both are off the way lanes are kept)
        v.setParameter(c.sumo, "laneChangeModel.lcOvertakeRight", "1")
        v.setParameter(c.sumo, "laneChangeModel.lcCooperativeSpeed", "0")
        self.drivers[c.vin] = Driver(c, f)
        if not self.hold:
            return
        v.setSpeedMode(c.sumo, HUMAN_SPEED_MODE)
        lane_m = self.junction.lane_len_m[c.route.in_lane]
        edge = c.route.in_lane.rsplit("_", 1)[0]
        v.setStop(c.sumo, edge, pos=lane_m - STOP_SHORT_M, laneIndex=c.lane_index,
                  duration=STOP_S)  # fmt: skip

    def as_human(self, sumo_id: str) -> None:
        """A route file's vehicle drawn human as it departs: SUMO's driver with the stated
        limits from the start (its own size kept), so that it comes to the region as a
        human driver would; once there it is adopted (:meth:`departed`)."""
        v = self.ls.vehicle
        size = v.getLength(sumo_id), v.getWidth(sumo_id)
        v.setType(sumo_id, HUMAN_VTYPE)
        v.setLength(sumo_id, size[0])
        v.setWidth(sumo_id, size[1])

    def asking(self, seen: list[Seen], t: float) -> list[Driver]:
        """The drivers standing at the head of their lane, with no green yet."""
        out = []
        for s in seen:
            d = self.drivers.get(s.car.vin)
            if d is None or not math.isnan(d.green_s) or not s.car.head:
                continue
            if self.ls.vehicle.isStopped(s.car.sumo):
                if math.isnan(d.standing_s):
                    d.standing_s = t
                out.append(d)
        return out

    def rolling(self, seen: list[Seen], t: float) -> list[Driver]:
        """The drivers at the head of their lane still rolling towards its line, near it,
        with no green yet, that have not asked for :data:`TIGHTEN_S`: each may be given
        its green now, so that it need not stop."""
        out = []
        for s in seen:
            d = self.drivers.get(s.car.vin)
            c = s.car
            if d is None or not math.isnan(d.green_s) or not c.head:
                continue
            near = -c.s_m
            if not (STOP_SHORT_M < near <= ROLL_NEAR_M and c.speed_mps > ROLL_MIN_MPS):
                continue
            if t < d.asked_s + TIGHTEN_S - 1e-9 or self.ls.vehicle.isStopped(c.sumo):
                continue
            out.append(d)
        return out

    def serve(self, seen: list[Seen], t: float, desk: Desk) -> None:
        """The human drivers of this step: the ICA hears of those new in the region (from
        the roadside's detector, as of any vehicle); those standing at the head of their
        lane ask for their green (its signal head, for them); the reservations of those
        on their green shrink to where they are seen; and whose green has come go."""
        for s in seen:
            d = self.drivers.get(s.car.vin)
            if d is not None and not d.told:
                d.told = desk.spotted(s.car, s.car.detected_s)
        for d in self.asking(seen, t):
            if t < d.refused_s + TIGHTEN_S - 1e-9:
                continue  # refused a moment ago (walkers come first): not every step
            got = desk.green(d.car, t, -d.car.s_m, False)
            if got is not None:
                self.lit(d.car.vin, *got, -d.car.s_m)
            else:
                d.refused_s = t
        for d in self.rolling(seen, t):
            d.asked_s = t
            c = d.car
            got = desk.green(c, t, -c.s_m, False, c.speed_mps)
            if got is not None:
                self.lit(c.vin, *got, -c.s_m, c.speed_mps)
        self._tighten(seen, t, desk)
        self.release(t)

    def _tighten(self, seen: list[Seen], t: float, desk: Desk) -> None:
        """Every :data:`TIGHTEN_S` (and once its turn shows which way it goes) the ICA
        shrinks the reservations of each driver on its green to where it is seen; one
        still standing asks again for a sooner green when anything has shrunk."""
        for s in seen:
            d = self.drivers.get(s.car.vin)
            if d is None or math.isnan(d.green_s) or s.car.exited or math.isnan(s.car.s_m):
                continue
            c = s.car
            if t + 1e-9 < d.green_s:  # standing, its green to come
                if self.shrunk == d.asked_shrunk or t < d.asked_s + TIGHTEN_S - 1e-9:
                    continue
                d.asked_shrunk, d.asked_s = self.shrunk, t
                got = desk.green(c, t, -c.s_m, True)
                if got is not None:
                    self.shrunk += 1
                    self.lit(c.vin, *got, -c.s_m)
                continue
            turned = s.obs.lane != d.lane
            if not turned and t < d.tightened_s + TIGHTEN_S - 1e-9:
                continue
            d.lane, d.tightened_s = s.obs.lane, t
            routes = desk.tighten(c, t, c.s_m, c.speed_mps, s.obs.lane)
            if routes is not None:
                self.shrunk += 1
                self.tightened(c.vin, t, routes, c.s_m, c.speed_mps)

    def lit(
        self,
        vin: str,
        green_s: float,
        routes: tuple[str, ...],
        head_s: float,
        dist_m: float,
        v_mps: float = 0.0,
    ) -> None:
        """The ICA gave ``vin``, standing ``dist_m`` short of its line (or rolling towards
        it at ``v_mps``), its green from ``green_s``; its head turns green at ``head_s``
        (as late as the LIT reached the roadside, at most ``limits.late_s`` after it)."""
        d = self.drivers[vin]
        d.sooner += not math.isnan(d.green_s)
        d.green_s, d.head_s, d.routes = green_s, head_s, routes
        c = d.car
        d.rolled = v_mps > 0.0
        d.fast, d.slow = green_bounds(c.route, c.length_m, green_s, self.step_s, self.limits,
                                      dist_m, v_mps)  # fmt: skip

    def tightened(
        self, vin: str, t: float, routes: tuple[str, ...], s_m: float, v_mps: float
    ) -> None:
        """The ICA shrank ``vin``'s reservations at ``t`` to where it was seen then (front
        ``s_m`` at ``v_mps``), on these routes: the audit holds it to the bounds from
        there (the same stated limits) of the route it takes."""
        d = self.drivers[vin]
        d.tightenings += 1
        c = d.car
        if c.route.id in routes:
            d.fast, d.slow = bounds_seen(c.route, c.length_m, t, s_m, v_mps, self.step_s,
                                         self.limits, d.green_s)  # fmt: skip

    def release(self, t: float) -> None:
        """End the stop of every driver whose head has turned green (one rolling towards
        it: its stop is taken away before it gets there)."""
        v = self.ls.vehicle
        for d in self.drivers.values():
            if not d.resumed and t + 1e-9 >= d.head_s:
                if v.isStopped(d.car.sumo):
                    v.resume(d.car.sumo)
                else:
                    v.replaceStop(d.car.sumo, 0, "")
                d.resumed = True

    # -- the audit -------------------------------------------------------------------
    def audit(self, seen: list[Seen], t: float) -> None:
        """Each driver's front from SUMO against its light and its envelope."""
        for s in seen:
            d = self.drivers.get(s.car.vin)
            c = s.car
            if d is None or c.exited or math.isnan(c.s_m):
                continue
            if math.isnan(d.green_s) or t < d.head_s:  # its head still red
                if c.s_m > TOL_M:
                    d.on_red = True
                if math.isnan(d.green_s) or t < d.green_s:
                    continue
            ahead = c.s_m - path_s(d.fast, t)
            behind = path_s(d.slow, t) - c.s_m
            d.worst_ahead_m = max(d.worst_ahead_m, ahead)
            d.worst_behind_m = max(d.worst_behind_m, behind)
            if ahead > TOL_M or behind > TOL_M:
                d.outside_steps += 1

    def summary(self) -> dict:
        """The human drivers of the run: how many, their wait for the green, the audit."""
        ds = list(self.drivers.values())
        waits = [d.green_s - d.standing_s for d in ds if not math.isnan(d.green_s + d.standing_s)]
        outside = sorted(d.car.vin for d in ds if d.outside_steps)
        return {
            "count": len(ds),
            "given_green": sum(not math.isnan(d.green_s) for d in ds),
            "mean_wait_for_green_s": float(np.mean(waits)) if waits else None,
            "max_wait_for_green_s": float(np.max(waits)) if waits else None,
            "reservations_shrunk": sum(d.tightenings for d in ds),
            "sooner_greens": sum(d.sooner for d in ds),
            "rolling_greens": sum(d.rolled for d in ds),
            "heads_lit_late": sum(d.head_s > d.green_s + 1e-9 for d in ds),
            "most_late_head_s": round(
                max((d.head_s - d.green_s for d in ds if not math.isnan(d.head_s)), default=0.0), 3
            ),
            "entered_on_red": sum(d.on_red for d in ds),
            "outside_envelope": len(outside),
            "outside_envelope_vins": outside[:50],
            "worst_ahead_of_fastest_m": round(max((d.worst_ahead_m for d in ds), default=0.0), 3),
            "worst_behind_slowest_m": round(max((d.worst_behind_m for d in ds), default=0.0), 3),
        }
