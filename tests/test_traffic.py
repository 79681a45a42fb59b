"""Insertion, detection, exit and accounting alone on a real SUMO: every scheduled vehicle
is put in (behind its lane's queue when the entry line is taken), seen into the region
and out of the junction, and accounted for at every moment; one gone missing is found.

No actuator runs: SUMO's own drivers take the vehicles across (priority rules).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import pytest

from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.junction import Junction
from dica.sim_gateway.metrics import TripLog
from dica.sim_gateway.runconfig import RunConfig
from dica.sim_gateway.sumo_io import Reads
from dica.sim_gateway.traffic import EV_VTYPE, VTYPE, Traffic, define_vehicle_types
from tests.sumo_session import open_sumo

LENGTH, WIDTH = 5.0, 1.8


class Rig:
    """One junction's traffic in a real SUMO, stepped as the world steps it."""

    def __init__(self, ls, cfg: RunConfig, inter) -> None:
        self.ls = ls
        ica_cfg = cfg.controller_spec().config
        self.schedule, _, _ = schedule_for(cfg, inter, ica_cfg.step_s)
        define_vehicle_types(ls, ica_cfg, LENGTH, WIDTH, any(v.ev for v in self.schedule))
        self.j = Junction.open(
            ls, inter, self.schedule, signalised=False,
            length_m=LENGTH,
        )  # fmt: skip
        self.log = TripLog()
        self.traffic = Traffic(ls, ica_cfg, LENGTH, self.log)
        self.traffic.register(self.j)
        self.t = 0.0
        self.h = ica_cfg.step_s

    def step(self) -> None:
        ls, j, traffic = self.ls, self.j, self.traffic
        j.forget_gone()
        fresh = traffic.insert_due(j, self.t)
        ls.simulation.step()
        traffic.note_blocked(j, fresh)
        t = self.t = ls.simulation.getTime()
        present = set(ls.vehicle.getIDList())
        for vin in ls.simulation.getDepartedIDList():
            traffic.departed(j, vin, t)
            Reads.subscribe(ls, vin)
        vw = Reads(ls)
        traffic.note_tails(j, vw, present)
        for c in j.active:
            if c.vin not in present:
                continue
            lane = vw.getLaneID(c.vin)
            if math.isnan(c.detected_s) and not traffic.detect(j, c, lane, vw, t):
                continue
            traffic.left_junction(j, vw, c, t)
        j.present = present

    def run(self, until: Callable[[], bool], limit_s: float, each: Callable[[], None]) -> None:
        while not until():
            assert self.t < limit_s, f"stuck: {self.traffic.accounting(self.j, self.t)}"
            self.step()
            each()


def test_insertion_puts_every_scheduled_vehicle_in_and_accounting_finds_each_one(ch45_net, ch45):
    """A heavy west approach: some find the entry line taken and join the queue behind;
    all get in, are detected as they pass the line (unqueued ones when scheduled), and
    leave; at every step each vehicle due is in exactly one place; one removed from SUMO
    inside the region is counted lost, and only it."""
    cfg = RunConfig(
        str(ch45_net.net_path), ch45_net.junction_id, volume_per_10min=1500, seed=4,
        approach_weights=(("W_in", 8.0),), until_left=50,
    )  # fmt: skip
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, cfg, ch45)
        j, n = rig.j, len(rig.schedule)
        removed: list[str] = []
        placed: dict[str, float] = {}  # lane position a step after insertion
        out: set[str] = set()

        def check() -> None:
            for vin in ls.simulation.getDepartedIDList():
                placed[vin] = ls.vehicle.getLanePosition(vin)
            for c in j.active:  # detected once, and as soon as, its front is in the region
                if c.vin in j.present and ls.vehicle.getLaneID(c.vin) == c.route.in_lane:
                    d = j.lane_len_m[c.route.in_lane] - ls.vehicle.getLanePosition(c.vin)
                    assert math.isnan(c.detected_s) == (d > ch45.comm_length_m), c.vin
            for c in j.cars.values():
                if c.exited and c.vin not in out:  # the rear's exit, within the step it was seen
                    out.add(c.vin)
                    assert rig.t - rig.h < rig.log.trips[c.vin].exited_s <= rig.t
            due = sum(v.arrival_s <= rig.t for v in rig.schedule)
            a = rig.traffic.accounting(j, rig.t)
            assert a["generated"] == due
            assert a["crossed"] + a["in_region"] + a["not_yet_in_region"] + a["lost"] == due
            assert a["lost"] == len(removed)
            assert a["crossed"] == j.crossed
            in_region = [
                c for c in j.active if c.vin in j.present and c.detected_s <= rig.t and not c.exited
            ]
            if not removed and rig.t > 20.0 and in_region:
                ls.vehicle.unsubscribe(in_region[0].vin)
                ls.vehicle.remove(in_region[0].vin)  # gone from SUMO before leaving
                removed.append(in_region[0].vin)

        rig.run(lambda: bool(removed) and j.crossed == n - 1, 600.0, check)
        assert rig.traffic.accounting(j, rig.t) == {
            "generated": n, "crossed": n - 1, "in_region": 0, "not_yet_in_region": 0, "lost": 1,
        }  # fmt: skip
        trips = rig.log.trips
        # on the road a step after it was put in, unless SUMO found no room at the line
        queued = [v for v in rig.schedule if trips[v.vin].inserted_s > v.arrival_s + 1.5 * rig.h]
        assert len(queued) >= 3  # the entry line was taken: they joined the queue
        entry = {lane: n - ch45.comm_length_m for lane, n in j.lane_len_m.items()}
        # most were on the road a step later behind the queue's tail, not left in SUMO's
        # waiting list until the line is free (or put at the line again, the tail gone)
        behind = [v for v in queued if placed[v.vin] < entry[v.route.in_lane] - LENGTH]
        assert len(behind) >= len(queued) / 2
        for v in behind:
            assert trips[v.vin].inserted_s <= v.arrival_s + 2.5 * rig.h
        for v in rig.schedule:
            trip = trips[v.vin]
            assert trip.inserted_s >= v.arrival_s - 1e-9
            assert trip.entered_s >= trip.inserted_s - 0.1
            if v not in queued:  # in at the line, at its speed: detected when scheduled
                assert trip.entered_s == pytest.approx(v.arrival_s, abs=0.06)
                assert trip.free_flow_s == pytest.approx(trip.free_flow_scheduled_s, rel=1e-3)
            if v.vin not in removed:
                assert trip.exited_s > trip.entered_s
                assert j.cars[v.vin].exited


def test_an_ev_candidate_is_an_ev_only_while_no_other_ev_is_in_the_region(ch45_net, ch45):
    cfg = RunConfig(
        str(ch45_net.net_path), ch45_net.junction_id, volume_per_10min=600, seed=8,
        ev_prob=1.0, until_left=30,
    )  # fmt: skip
    with open_sumo(ch45_net.net_path) as ls:
        rig = Rig(ls, cfg, ch45)
        types: dict[str, str] = {}

        def note_types() -> None:
            for vin in ls.simulation.getDepartedIDList():
                types[vin] = ls.vehicle.getTypeID(vin)

        rig.run(lambda: rig.j.crossed == len(rig.schedule), 600.0, note_types)
        trips = rig.log.trips
        evs = [v.vin for v in rig.schedule if trips[v.vin].ev]
        others = [v.vin for v in rig.schedule if not trips[v.vin].ev]
        assert len(evs) >= 2 and others
        assert {types[vin] for vin in evs} == {EV_VTYPE}
        assert {types[vin] for vin in others} == {VTYPE}
        spans = sorted((trips[vin].depart_s, trips[vin].exited_s) for vin in evs)
        for (_, out), (due, _) in itertools.pairwise(spans):
            assert due >= out  # the next EV came after the one before had left
        for vin in others:  # each candidate turned down had an EV in the region
            due = trips[vin].depart_s
            # (the exit is interpolated back into the step it was seen in)
            assert any(start <= due <= out + 0.05 for start, out in spans)
