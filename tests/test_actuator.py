"""The vehicles' actuator alone on a real SUMO: no plan, it stops short of the line;
a plan taken in time is flown by position; a late one is refused.

The test does the world's observing itself (positions from SUMO each step)
and inserts the vehicles straight into SUMO, so only the actuator drives.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dica.sim_gateway.actuator import MIN_GAP_M, START_TOL_M, Actuator
from dica.sim_gateway.junction import Car, Junction, route_edges
from dica.sim_gateway.metrics import Trip, TripLog
from dica.sim_gateway.runconfig import RunConfig
from dica.sim_gateway.sumo_io import Reads
from dica.sim_gateway.traffic import VTYPE, define_vehicle_types
from dica.vehicle_agent.actuation import (
    MODE_CONFIRMED,
    MODE_DEFAULT,
    MODE_HEAD,
    MODE_QUEUED,
    Actuation,
)
from tests.sumo_session import open_sumo

WEST = "W_in_1", "E_out_1"  # through from the west
LENGTH, WIDTH = 5.0, 1.8


class Rig:
    """One junction in a real SUMO, an actuator, and the observing a world would do."""

    def __init__(self, ls, ch45_net, ch45, predict_s: float = 0.0) -> None:
        cfg = RunConfig(str(ch45_net.net_path), ch45_net.junction_id)
        self.ica_cfg = cfg.controller_spec().config
        self.h = self.ica_cfg.step_s
        self.ls, self.route = ls, ch45.route(*WEST)
        define_vehicle_types(ls, self.ica_cfg, LENGTH, WIDTH, ev=False)
        self.j = Junction.open(ls, ch45, [], signalised=False, length_m=LENGTH)
        self.log = TripLog()
        self.act = Actuator(ls, self.ica_cfg, self.log, predict_s)
        self.t = 0.0

    def insert(self, vin: str, to_line_m: float, speed_mps: float) -> Car:
        """A vehicle on the west approach, its front ``to_line_m`` short of the entry line,
        already in the region (detected)."""
        r = self.route
        c = Car(vin, r, int(r.in_lane.rsplit("_", 1)[1]), speed_mps, detected_s=self.t)
        self.j.cars[vin] = c
        self.j.active.append(c)
        self.log.trips[vin] = Trip(vin, r.id, r.turn.value, self.t)
        self.ls.vehicle.add(
            vin,
            self.j.edge_routes[route_edges(r)],
            typeID=VTYPE,
            departLane=str(c.lane_index),
            departPos=str(self.j.lane_len_m[r.in_lane] - to_line_m),
            departSpeed=str(speed_mps),
        )
        return c

    def step(self, commands: list[Actuation] = ()) -> None:
        """SUMO's step, what the world observes of each car, then the actuator's turn."""
        ls, j = self.ls, self.j
        ls.simulation.step()
        self.t = ls.simulation.getTime()
        present = set(ls.vehicle.getIDList())
        for vin in ls.simulation.getDepartedIDList():
            ls.vehicle.setLaneChangeMode(vin, 0)
        vw = Reads(ls)
        j.order_lanes(vw, present)
        for c in j.active:
            if c.vin not in present:  # not inserted yet
                continue
            lane = vw.getLaneID(c.vin)
            lane_pos = vw.getLanePosition(c.vin)
            c.locate(lane, lane_pos, j.lane_len_m[c.route.in_lane], vw.getDistance(c.vin))
            c.speed_mps = vw.getSpeed(c.vin)
            c.entered = c.entered or lane != c.route.in_lane
            out = vw.getRoadID(c.vin) == route_edges(c.route)[1]
            c.exited = c.exited or (out and lane_pos >= LENGTH)
            c.head = lane == c.route.in_lane and c.ahead is None
        j.present = present
        self.act.apply(j, commands, self.t)


def _plan_from(s0: float, v0: float, h: float, n: int) -> np.ndarray:
    """Route positions every step: from ``v0`` to 10 m/s at 2 m/s^2, then held
    (SUMO's Euler step: s += v_new * h)."""
    s, v, out = s0, v0, [s0]
    for _ in range(n - 1):
        v = min(v + 2.0 * h, 10.0) if v < 10.0 else max(v - 2.0 * h, 10.0)
        s += v * h
        out.append(s)
    return np.array(out)


def test_without_a_plan_a_queue_stops_short_of_the_line_and_a_late_plan_is_refused(ch45_net, ch45):
    """The head by its own stop law (SUMO's right of way off), the one behind also by
    SUMO's car-following, each short of what is ahead; a plan whose start has passed is
    refused, and the head goes on stopping."""
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, ch45_net, ch45)
        kin = rig.ica_cfg.kinematics
        head = rig.insert("head", 50.0, 15.0)
        back = rig.insert("back", 70.0, 15.0)
        late = None
        while rig.t < 25.0:
            cmds = []
            if late is None and rig.t >= 3.0:  # a plan that should have started a second ago
                s = head.s_m + 10.0 * rig.h * np.arange(200)
                late = Actuation("head", seq=4, t0_s=rig.t + rig.h - 1.0, s_m=s)
                cmds.append(late)
            rig.step(cmds)
            assert head.s_m < 0.0 and not back.s_m >= head.s_m - LENGTH  # (NaN: not in yet)
            if rig.t > 0.2:
                assert ls.vehicle.getSpeedMode("head") == MODE_HEAD
                assert ls.vehicle.getSpeedMode("back") == MODE_QUEUED
        assert head.speed_mps == 0.0 and back.speed_mps < 0.01  # SUMO's driver closes up
        assert -kin.stop_gap_m - 0.1 < head.s_m <= -kin.stop_gap_m + 1e-9
        gap = head.s_m - LENGTH - back.s_m
        assert MIN_GAP_M - 1e-9 <= gap < MIN_GAP_M + 0.5
        assert rig.act.obstacles(rig.j) == {"head": math.inf, "back": head.s_m - LENGTH}
        assert head.plan_s is None and head.refused_seq == 4
        timing = rig.act.timing
        assert (timing.refused, timing.accepted) == (1, 0)


def test_a_plan_taken_in_time_is_flown_by_position_and_the_vehicle_released_after(ch45_net, ch45):
    """Asked half a second ahead from where the actuator says the braking vehicle will be
    (its intent), the plan starts there, is flown within a millimetre of every
    position (SUMO under speed mode 32), and once out the vehicle is SUMO's again."""
    lead_s = 0.5
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, ch45_net, ch45, predict_s=lead_s)
        c = rig.insert("a", 30.0, 12.0)
        rig.step()
        while c.speed_mps > 11.9:  # until its stop law brakes it for the line
            rig.step()
        fut = rig.act.intents(rig.j, rig.t)["a"]
        assert (fut[1] - fut[0]) - (fut[-1] - fut[-2]) > 1.0 * rig.h  # 1 m/s slower by then
        t0 = rig.t + lead_s
        plan = _plan_from(float(fut[-1]), float(fut[-1] - fut[-2]) / rig.h, rig.h, 300)
        rig.step([Actuation("a", seq=1, t0_s=t0, s_m=plan)])
        assert rig.act.timing.accepted == 1 and c.plan_seq == 1
        errors, modes = {}, set()
        while not c.released:
            assert rig.t < 20.0, "never out of the junction"
            rig.step()
            k = round((rig.t - t0) / rig.h)
            if 0 <= k < len(plan) and not c.exited:
                errors[k] = abs(c.s_m - plan[k])
                modes.add(ls.vehicle.getSpeedMode("a"))
        assert errors[0] <= START_TOL_M
        assert max(e for k, e in errors.items() if k > 0) < 1e-3
        assert len(errors) > 50 and c.entered  # every step from its start until out
        assert modes == {MODE_CONFIRMED}
        assert ls.vehicle.getSpeedMode("a") == MODE_DEFAULT
        assert rig.log.trips["a"].confirmed_s == pytest.approx(t0)
        # taken a step after it was asked for (the rig applies commands after its next step)
        assert rig.act.timing.slack_s == [pytest.approx(lead_s - rig.h)]


def test_a_revoked_plan_not_yet_begun_is_dropped_and_the_vehicle_stops_short(ch45_net, ch45):
    """A drop before the plan's start is always taken: the plan is never flown."""
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, ch45_net, ch45)
        c = rig.insert("a", 50.0, 12.0)
        rig.step()
        t0 = rig.t + 3.0  # the stop law drives it until then
        rig.step([Actuation("a", seq=2, t0_s=t0, s_m=c.s_m + 36.0 + 0.6 * np.arange(300))])
        assert c.plan_seq == 2
        rig.step([Actuation("a", seq=2, drop=True)])
        assert c.plan_s is None and c.refused_seq == 2 and rig.act.timing.dropped == 1
        while rig.t < 20.0:
            rig.step()
            assert c.s_m < 0.0 and not math.isnan(c.s_m)
        assert c.speed_mps == 0.0


def test_a_plan_that_runs_into_the_vehicle_ahead_is_not_flown(ch45_net, ch45):
    """The head flies a plan that stands at the line (a slot far ahead); the one behind
    is handed a plan through where the head stands (made behind a plan of the head's
    that was never flown): at its start it is refused, the vehicle stops behind the head
    and nothing touches; a plan that stays behind the head is flown."""
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, ch45_net, ch45)
        kin = rig.ica_cfg.kinematics
        head = rig.insert("head", kin.stop_gap_m, 0.0)
        back = rig.insert("back", kin.stop_gap_m + LENGTH + MIN_GAP_M, 0.0)
        rig.step()
        rig.step([Actuation("head", seq=1, t0_s=rig.t + 0.5, s_m=np.full(400, head.s_m))])
        t0 = rig.t + 1.0
        rig.step([Actuation("back", seq=2, t0_s=t0, s_m=back.s_m + 3.0 * rig.h * np.arange(200))])
        assert back.plan_seq == 2  # taken: only its start can tell
        while rig.t < t0 + 5.0:
            rig.step()
            assert back.s_m <= head.s_m - LENGTH - 1.0
            assert not ls.simulation.getCollisions()
        assert head.plan_seq == 1 and ls.vehicle.getSpeedMode("head") == MODE_CONFIRMED
        assert back.plan_s is None and back.refused_seq == 2
        assert rig.act.timing.off_start == 1
        t1 = rig.t + 0.5
        creep = back.s_m + np.minimum(1.0 * rig.h * np.arange(200), 1.5)
        rig.step([Actuation("back", seq=3, t0_s=t1, s_m=creep)])
        while rig.t < t1 + 3.0:
            rig.step()
            assert back.s_m <= head.s_m - LENGTH - 0.9
        assert back.plan_seq == 3 and ls.vehicle.getSpeedMode("back") == MODE_CONFIRMED
        assert rig.act.timing.off_start == 1
