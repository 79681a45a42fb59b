"""Each vehicle's actuator: the part of a connected vehicle that runs on board whatever
its links do.

A vehicle without a plan it may fly stops short of the junction's entry line
by its own control law; a plan is taken only if it arrives before its start
(a late one is refused, and the next observation says so), and is flown by
position against time, closing the loop on where the vehicle really is; once
out of the junction the vehicle is handed back to SUMO's driver. So a late,
lost or repeated message can cost time but cannot put a vehicle into the
junction without a reservation it can keep.

Who decides the plans (vehicle machines in this process, or vehicle-agent
processes over Zenoh) is not the actuator's business; it only carries them
out, and counts how well they were kept (:class:`Timing`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.stop_law import stop_distance
from dica.sim_gateway.junction import Car, Junction
from dica.sim_gateway.metrics import TripLog
from dica.vehicle_agent.actuation import (
    MODE_CONFIRMED,
    MODE_DEFAULT,
    MODE_HEAD,
    MODE_QUEUED,
    NO_PLAN,
    RELEASE,
    Actuation,
)
from dica.vehicle_agent.control import can_stop_short, entry_time, stop_speed, track_speed

# [m] how far from its plan's first position a vehicle may be when the plan starts; within
# it the position loop catches up in a few steps and the ICA's margin covers the gap
START_TOL_M = 0.1
MIN_GAP_M = 2.5  # [m] SUMO's standstill gap of our vehicle type, also kept short of the line
# [m/s^2] what SUMO is told a vehicle flying its plan could brake at, where SUMO's own
# drivers share its exit lanes (a route file's): it will not brake off its plan, so SUMO
# inserts no vehicle and changes none into a lane just ahead of it, which it would then
# run into; the braking SUMO's checks assume of it is kept this low (see _set_mode)
FLYING_DECEL_MPS2 = 1.0


@dataclass(slots=True)
class Timing:
    """How well the vehicles kept to their plans, as their actuators saw it."""

    accepted: int = 0  # plans taken before their start
    refused: int = 0  # plans never flown: arrived after their start, or found off it
    off_start: int = 0  # of those, found further than START_TOL_M off the plan at its start
    dropped: int = 0  # plans given up on a revocation (reactive DICA)
    kept: int = 0  # plans the vehicle was told to drop but flew on: it could not stop
    # steps a vehicle without a plan braked harder than the plans assume, to stop short of
    # the vehicle ahead (taken over too fast for that braking: see Actuator.stop_speed)
    hard_braking: int = 0
    slack_s: list[float] = field(default_factory=list)  # plan start minus arrival [s]
    adherence_s: list[float] = field(default_factory=list)  # actual minus planned entry [s]
    worst: list[tuple[float, str, float, float]] = field(default_factory=list)

    def entered(self, c: Car, t: float, step_s: float) -> None:
        """``c``'s front has just passed the entry line on its plan: how late against it."""
        actual = t - c.s_m / c.speed_mps if c.speed_mps > 0.1 else t
        planned = entry_time(c.plan_t0_s, step_s, c.plan_s)
        self.adherence_s.append(actual - planned)
        self.worst.append((abs(actual - planned), c.vin, actual, planned))

    def as_dict(self) -> dict:
        def pct(xs: list[float], q: float) -> float | None:
            return float(np.percentile(np.asarray(xs), q)) if xs else None

        adh = [abs(x) for x in self.adherence_s]
        return {
            "plans_accepted": self.accepted,
            "plans_refused": self.refused,
            "plans_refused_off_start": self.off_start,
            "plans_dropped": self.dropped,
            "plans_kept": self.kept,
            "hard_braking_steps": self.hard_braking,
            "plan_slack_p1_s": pct(self.slack_s, 1),
            "plan_slack_median_s": pct(self.slack_s, 50),
            "entry_adherence_p50_s": pct(adh, 50),
            "entry_adherence_p99_s": pct(adh, 99),
            "entry_adherence_max_s": max(adh) if adh else None,
            "entry_adherence_mean_signed_s": (
                float(np.mean(self.adherence_s)) if self.adherence_s else None
            ),
            "entry_adherence_worst": [
                {"vin": vin, "actual_s": round(a, 3), "planned_s": round(p, 3)}
                for _, vin, a, p in sorted(self.worst, reverse=True)[:5]
            ],
        }


class Actuator:
    """The on-board control of every vehicle in a junction's region, through SUMO's speeds.

    ``log`` gets each vehicle's first step on a plan (``Trip.confirmed_s``);
    ``predict_s`` is how far ahead :meth:`intents` looks.
    """

    def __init__(
        self, ls, ica_cfg: IcaConfig, log: TripLog, predict_s: float = 0.0, shared: bool = False
    ) -> None:
        self.ls = ls
        self.shared = shared  # SUMO's drivers share the exit lanes (see FLYING_DECEL_MPS2)
        self.ica_cfg = ica_cfg
        self.h = ica_cfg.step_s
        self.log = log
        self.predict_steps = max(round(predict_s / self.h), 0)
        self.timing = Timing()

    def apply(self, j: Junction, commands: Iterable[Actuation], t: float) -> None:
        """Take the drivers' new plans, then drive every vehicle in the region for one step.

        A plan is taken only if it arrives no later than its start (and is
        newer than any plan the vehicle held or refused); a later one could
        not be flown from where the vehicle is, so it is refused, and the
        vehicle goes on stopping short of the line. Commands without a plan
        change nothing here.
        """
        drops = self._take(j, commands, t)
        # the rearmost first: a platoon's follower drops before its leader is asked to
        for c, seq in sorted(drops, key=lambda d: _rank(d[0])):
            self.drop(c, seq, t)
        ahead = self.obstacles(j)
        for c in j.active:
            if c.sumo not in j.present or c.released or math.isnan(c.detected_s) or c.human:
                continue
            if c.plan_s is not None and t >= c.plan_t0_s - 1e-6:
                self._fly(c, t, ahead.get(c.vin, math.inf))
            elif not c.entered:
                self._set_mode(c, MODE_HEAD if self.asks(c) else MODE_QUEUED)
                self.ls.vehicle.setSpeed(c.sumo, self.stop_speed(c, ahead.get(c.vin, math.inf)))

    def _take(self, j: Junction, commands: Iterable[Actuation], t: float) -> list[tuple[Car, int]]:
        """Take the new plans that came in time; return the drops asked for."""
        drops: list[tuple[Car, int]] = []
        for cmd in commands:
            c = j.cars.get(cmd.vin)
            if c is not None and cmd.drop:  # revoked: stop short of the line, if it can
                drops.append((c, cmd.seq))
                continue
            if c is None or c.entered or c.exited:
                continue
            if not cmd.has_plan:
                continue
            if cmd.seq <= max(c.plan_seq, c.refused_seq):
                continue  # a repeat, or older than what the vehicle holds
            if t > cmd.t0_s + 1e-6:
                c.refused_seq = cmd.seq
                self.timing.refused += 1
                continue
            c.plan_seq, c.plan_t0_s, c.plan_s = cmd.seq, cmd.t0_s, np.asarray(cmd.s_m, float)
            self.timing.accepted += 1
            self.timing.slack_s.append(cmd.t0_s - t)
        return drops

    def _fly(self, c: Car, t: float, rear_ahead_m: float) -> None:
        """One step on the plan whose start has come, by position; out of the junction,
        back to SUMO's driver."""
        if abs(t - c.plan_t0_s) < 1e-6 and (
            abs(c.s_m - c.plan_s[0]) > START_TOL_M
            or (c.ahead is not None and not self._clear_behind(c, c.ahead, t))
        ):
            # not where the plan starts (a leader held it back during the lead), or
            # the vehicle ahead is not flying a plan that stays ahead of this one (a
            # leader whose plan was never flown and was made again since, behind
            # this one's): a reservation it cannot keep is not flown; it stops and
            # asks again
            c.refused_seq, c.plan_seq, c.plan_s = c.plan_seq, NO_PLAN, None
            self.timing.off_start += 1
            self.timing.refused += 1
            self.ls.vehicle.setSpeed(c.sumo, self.stop_speed(c, rear_ahead_m))
            return
        if c.exited:
            self._set_mode(c, MODE_DEFAULT)
            self.ls.vehicle.setSpeed(c.sumo, RELEASE)
            if c.adopted_lcm is not None:  # on along its own route, as SUMO drives it
                self.ls.vehicle.setLaneChangeMode(c.sumo, c.adopted_lcm)
            if c.reroute_to is not None:
                way = c.reroute_way
                if way is not None and self.ls.vehicle.getRoadID(c.sumo) == way[0]:
                    self.ls.vehicle.setRoute(c.sumo, list(way))  # the rooms it was let in for
                else:
                    self.ls.vehicle.changeTarget(c.sumo, c.reroute_to)
            c.released = True
            return
        if c.speed_mode != MODE_CONFIRMED:
            self._set_mode(c, MODE_CONFIRMED)
            trip = self.log.trips[c.vin]
            if trip.confirmed_s is None:
                trip.confirmed_s = t
        k = round((t - c.plan_t0_s) / self.h)
        plan = c.plan_s
        if k + 1 < len(plan):
            v = track_speed(float(plan[k + 1]), c.s_m, c.speed_mps, self.h)
        else:  # past the plan's end (the vehicle is out): hold its last speed
            v = float(plan[-1] - plan[-2]) / self.h if len(plan) > 1 else c.speed_mps
        self.ls.vehicle.setSpeed(c.sumo, v)

    def _set_mode(self, c: Car, mode: int) -> None:
        if c.speed_mode != mode:
            self.ls.vehicle.setSpeedMode(c.sumo, mode)
            if self.shared and MODE_CONFIRMED in (mode, c.speed_mode):
                v = self.ls.vehicle
                if mode == MODE_CONFIRMED:
                    c.decel_mps2 = v.getDecel(c.sumo)  # its own, given back once it is out
                    v.setDecel(c.sumo, FLYING_DECEL_MPS2)
                else:
                    v.setDecel(c.sumo, c.decel_mps2)
                # a vehicle's own limits make SUMO give it a type of its own, and with it its
                # type's speed factor again: a route file's type may drive 1.5 x the limit
                # (SUMO's emergency class does), and a connected vehicle keeps the limit
                if v.getSpeedFactor(c.sumo) > 1.0:
                    v.setSpeedFactor(c.sumo, 1.0)
            c.speed_mode = mode

    def _clear_behind(self, c: Car, lead: Car, t: float) -> bool:
        """``c`` may start its plan behind ``lead``: the vehicle ahead on its lane flies
        a plan of its own (it has begun to, or begins now) that stays ahead of ``c``'s
        for as long as both are on the lane."""
        return _flying(lead, t) and _clear_of(lead, c, t, self.h)

    def release(self, c: Car) -> None:
        """Hand ``c`` to SUMO's driver for good (a signalised junction: the light decides)."""
        self.ls.vehicle.setSpeed(c.sumo, RELEASE)

    def may_follow(self, c: Car, speed_mps: float, t: float) -> bool:
        """A platoon's follower may ask: its leader holds a plan (flown, or to be flown
        from its start), it is as far behind that plan as the ICA will ask of it (twice
        the margin behind where the leader was a headway ago), and either it stands (it
        can wait where it is) or the leader's plan goes through without standing short
        of the line (else its own stop law must first stop it behind the leader)."""
        lead, h, cfg = c.ahead, self.h, self.ica_cfg
        if lead is None or lead.plan_s is None:
            return False
        t = max(t, lead.plan_t0_s)  # judged from the leader's start if it is still to come
        k = max(round((t - lead.plan_t0_s) / h), 0)
        behind = round((cfg.headway_s + 2.0 * cfg.time_pad_s) / h)
        lagged = float(lead.plan_s[min(max(k - behind, 0), len(lead.plan_s) - 1)])
        if c.s_m > lagged - c.length_m - 2.0 * cfg.margin_m:
            return False
        if speed_mps <= 0.0:
            return True
        ahead = lead.plan_s[k:]
        ahead = ahead[: int(np.searchsorted(ahead, 0.0)) + 1]
        return bool(np.all(np.diff(ahead) > 1e-6))

    def asks(self, c: Car) -> bool:
        """``c`` may ask for a plan (head of its lane, or following a leader that holds
        one, flown already or still to start): it moves by its stop law alone and never
        speeds up, so where it will be when its plan starts is predictable
        (:meth:`intents`)."""
        if c.human:  # SUMO's driver: its own car-following, never a plan
            return False
        return c.head or (
            self.ica_cfg.platoon and c.ahead is not None and c.ahead.plan_s is not None
        )

    def drop(self, c: Car, seq: int, t: float) -> None:
        """Give up every plan up to ``seq`` (revoked), if the vehicle can still stop.

        A plan not yet begun is always dropped (the stop law drives the vehicle
        until then). One being flown is dropped only if the stop law, from here,
        keeps the front short of the entry line; otherwise the vehicle flies on
        (its reservation is still the ICA's to keep) and ``kept_seq`` says so.
        Either way a plan up to ``seq`` that arrives later is never taken, and a
        repeated drop changes nothing.
        """
        if c.plan_seq == NO_PLAN or c.plan_seq > seq:
            c.refused_seq = max(c.refused_seq, seq)
            return
        kin = self.ica_cfg.kinematics
        flying = t >= c.plan_t0_s - 1e-6
        stoppable = not flying or can_stop_short(
            -c.s_m,
            c.speed_mps,
            gap_m=kin.stop_gap_m,
            h=self.h,
            accel_mps2=kin.accel_mps2,
            decel_mps2=kin.decel_mps2,
        )
        follower = c.behind
        if follower is not None and _flying(follower, t):
            stoppable = False  # a platoon's follower flies behind it: it cannot stop for it
        if c.entered or c.exited or not stoppable:
            if c.kept_seq < c.plan_seq:
                c.kept_seq = c.plan_seq
                self.timing.kept += 1
            return
        c.refused_seq = max(c.refused_seq, seq)
        c.plan_seq, c.plan_s = NO_PLAN, None
        self.timing.dropped += 1

    def obstacles(self, j: Junction) -> dict[str, float]:
        """For each vehicle short of the junction, the rear of the vehicle ahead of it
        on its lane [m, route position] (that vehicle may have begun to enter)."""
        out: dict[str, float] = {}
        for lane, cars in j.short_of_line().items():
            cars.sort(key=lambda c: c.s_m)
            prev = j.last_in.get(lane)
            rear = prev.s_m - prev.length_m if prev is not None and not prev.exited else math.inf
            others = j.strangers.get(lane, ())
            for c in reversed(cars):
                out[c.vin] = min([rear, *(r for f, r in others if f > c.s_m)])
                rear = c.s_m - c.length_m
        return out

    def intents(self, j: Junction, t: float) -> dict[str, np.ndarray]:
        """Where each vehicle short of the junction will be over the next
        ``predict_steps`` steps if no new plan reaches it [route positions, m, now
        first]: on its plan from the plan's start, before that (or without one) by its
        stop law, run step by step as :meth:`apply` runs it against the future of the
        vehicle ahead (for the front one, the last to enter from its lane).

        A vehicle that may ask is told its own (``Observation.intent_m``), so that a
        plan asked for ahead of time starts where it will really be: by the head's law
        alone, one that follows a moving leader would be planned from where it never
        gets, found off its plan's start and refused. A lane's prediction stops at a
        vehicle that SUMO's car-following drives (one that may not ask)."""
        out: dict[str, np.ndarray] = {}
        free = np.full(self.predict_steps + 1, math.inf)
        for lane, cars in j.short_of_line().items():
            cars.sort(key=lambda c: -c.s_m)
            prev = j.last_in.get(lane)
            ahead = free if prev is None or prev.exited else self.future(prev, t, free)
            length = 0.0 if prev is None else prev.length_m
            for c in cars:
                if ahead is None:
                    break
                fut = self.future(c, t, ahead - length)
                if fut is not None:
                    out[c.vin] = fut
                ahead, length = fut, c.length_m
        return out

    def future(self, c: Car, t: float, rear_m: np.ndarray) -> np.ndarray | None:
        """``c``'s positions now and after each of the next steps, behind a vehicle whose
        rear will be at ``rear_m``; None if its own driver is SUMO's car-following."""
        n, h = self.predict_steps, self.h
        kin = self.ica_cfg.kinematics
        plan = c.plan_s
        asks = self.asks(c)
        if plan is None and not asks:
            return None
        k0 = round((t - c.plan_t0_s) / h) if plan is not None else 0
        p = np.empty(n + 1)
        p[0], v = c.s_m, c.speed_mps
        for j in range(n):
            if plan is not None and k0 + j >= 0:  # the plan is flown from its start
                k = k0 + j + 1
                if k < len(plan):
                    p[j + 1] = plan[k]
                else:  # past its end: the last speed held
                    p[j + 1] = p[j] + (plan[-1] - plan[-2] if len(plan) > 1 else v * h)
                continue
            cap = min(c.entry_speed_mps, v) if asks else c.entry_speed_mps
            room = min(-p[j] - kin.stop_gap_m, rear_m[j] - p[j] - MIN_GAP_M)
            v = stop_speed(room, v, cap, h, kin.accel_mps2, kin.decel_mps2)
            p[j + 1] = p[j] + v * h
        return p

    def stop_speed(self, c: Car, rear_ahead_m: float) -> float:
        """The vehicle's own law without a plan to fly: stop short of the entry line,
        and short of the rear of the vehicle ahead as it is now.

        The vehicle ahead only moves forward, so a vehicle that can always stop
        short of where it is now never hits it. The head of a lane (the one that
        asks) moves by this law alone and does not speed up, so what it asks for
        starts where the law predictably takes it; SUMO's car-following, which
        also brakes for slow vehicles far beyond the junction, is off for it.
        Behind the head, SUMO's car-following closes the queue up as drivers do.
        """
        kin = self.ica_cfg.kinematics
        cap = min(c.entry_speed_mps, c.speed_mps) if self.asks(c) else c.entry_speed_mps
        room = min(-c.s_m - kin.stop_gap_m, rear_ahead_m - c.s_m - MIN_GAP_M)
        v = stop_speed(room, c.speed_mps, cap, self.h, kin.accel_mps2, kin.decel_mps2)
        if stop_distance(v, kin.decel_mps2, self.h) > room + 1e-9:
            # taken over faster than the plans' braking can stop behind the vehicle ahead:
            # a route file's type that brakes harder (a motorcycle's 10 m/s^2), driven by
            # SUMO until the region, came up to a queue in it at the road's speed. It brakes
            # as hard as it can rather than run into the queue.
            own = self.ls.vehicle.getDecel(c.sumo)
            if own > kin.decel_mps2:
                v = stop_speed(room, c.speed_mps, cap, self.h, kin.accel_mps2, own)
                self.timing.hard_braking += 1
        return v


def _clear_of(lead: Car, c: Car, t: float, h: float) -> bool:
    """Whether ``c``'s plan, from ``t`` on, keeps its front behind the rear of ``lead``
    as ``lead``'s plan has it, while that rear is on their common incoming lane (short
    of the entry line; beyond it their routes may part, and the ICA's reservations
    keep them apart). Both plans are route positions [m] per step of ``h``."""
    assert c.plan_s is not None and lead.plan_s is not None
    k_c = max(round((t - c.plan_t0_s) / h), 0)
    k_l = max(round((t - lead.plan_t0_s) / h), 0)
    n = min(len(c.plan_s) - k_c, len(lead.plan_s) - k_l)
    if n <= 0:
        return True
    rear = lead.plan_s[k_l : k_l + n] - lead.length_m
    on_lane = rear < 0.0
    return bool(np.all(c.plan_s[k_c : k_c + n][on_lane] <= rear[on_lane] + 1e-6))


def _flying(c: Car, t: float) -> bool:
    """The actuator flies a plan for ``c`` now (its start has come)."""
    return c.plan_s is not None and t >= c.plan_t0_s - 1e-6


def _rank(c: Car) -> float:
    """Position along the route for ordering drops, rearmost first."""
    return c.s_m if not math.isnan(c.s_m) else -math.inf
