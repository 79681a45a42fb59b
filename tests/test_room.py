"""Downstream space: the ICA confirms a crossing only if the exit lane beyond the
junction will have room for the vehicle, counting the vehicles it has confirmed
onto that lane whose rears were not out when the room was observed."""

from __future__ import annotations

import dataclasses
import math

from dica.ica.core.controller import ControllerSpec, build_controller
from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Reason, Rejection
from dica.ica.core.route import Route
from dica.ica.netfile import load_intersection

WEST = "W_in_1", "E_out_1"  # through from the west
EAST_OUT_FROM_SOUTH = "S_in_0", "E_out_0"  # a right turn from the south onto another lane
LEFT_ONTO_THE_SAME = "N_in_2", "E_out_1"  # a left turn from the north onto WEST's exit lane
LENGTH = 5.0


def _need(route: Route, taken: float = 0.0) -> float:
    brake = route.speed_cap_mps**2 / (2.0 * 4.5)
    return taken + LENGTH + ROOM_GAP_M + ROOM_SLACK_M + brake


def _ask(ica, route: Route, vin: str, t: float, room: float, d: float = 40.0, t_obs=None):
    req = propose(
        route, vin=vin, seq=1, t0_s=t, dist_to_entry_m=d, speed_mps=10.0, config=ica.config
    )
    obs = t if t_obs is None else t_obs
    return ica.handle(dataclasses.replace(req, t_obs_s=obs, exit_room_m=room), t)


def _ica(ch45_net):
    inter = load_intersection(ch45_net.net_path, "C")
    return inter, build_controller(ControllerSpec.of("enhanced", 0.25), inter)


def test_no_room_no_confirmation_and_room_enough_confirms(ch45_net):
    inter, ica = _ica(ch45_net)
    route = inter.route(*WEST)
    ica.advance(0.0)
    ica.detect("a", route.in_lane, 0.0)
    short = _ask(ica, route, "a", 0.0, room=_need(route) - 0.1)
    assert isinstance(short, Rejection) and short.reason is Reason.NO_ROOM
    assert not ica.confirmed  # nothing held for it
    ok = _ask(ica, route, "a", 0.0, room=_need(route) + 0.1)
    assert isinstance(ok, Confirmation)


def test_vehicles_confirmed_onto_the_lane_take_their_room_until_they_are_out(ch45_net):
    inter, ica = _ica(ch45_net)
    route = inter.route(*WEST)
    ica.advance(0.0)
    ica.detect("a", route.in_lane, 0.0)
    a = _ask(ica, route, "a", 0.0, room=math.inf)
    assert isinstance(a, Confirmation)
    # b, behind it on the same lane once it has entered, sees the room a has not yet taken
    ica.advance(a.entry_time_s + 0.05)
    ica.detect("b", route.in_lane, 0.05)
    t = a.entry_time_s + 0.05
    b = _ask(ica, route, "b", t, room=_need(route, LENGTH + ROOM_GAP_M) - 0.1, d=30.0)
    assert isinstance(b, Rejection) and b.reason is Reason.NO_ROOM
    b = _ask(ica, route, "b", t, room=_need(route, LENGTH + ROOM_GAP_M) + 0.1, d=30.0)
    assert isinstance(b, Confirmation)
    # a's reservation ends; a room observed before its rear was out does not hold it yet,
    # so a counts; one observed after it holds it, so a is not counted twice
    out = a.exit_time_s + 0.05
    left = inter.route(*LEFT_ONTO_THE_SAME)
    assert left.out_lane == route.out_lane
    ica.detect("c", left.in_lane, out)
    ica.advance(out + 0.5)
    assert "a" not in ica.confirmed
    both = _need(left, 2 * (LENGTH + ROOM_GAP_M))
    early = _ask(ica, left, "c", out + 0.5, room=both - 0.1, d=45.0, t_obs=out - 0.1)
    assert isinstance(early, Rejection) and early.reason is Reason.NO_ROOM
    late = _ask(ica, left, "c", out + 0.5, room=_need(left, LENGTH + ROOM_GAP_M) + 0.1, d=45.0)
    assert not (isinstance(late, Rejection) and late.reason is Reason.NO_ROOM)


def test_another_exit_lane_does_not_count(ch45_net):
    inter, ica = _ica(ch45_net)
    west, south = inter.route(*WEST), inter.route(*EAST_OUT_FROM_SOUTH)
    assert west.out_lane != south.out_lane
    ica.advance(0.0)
    ica.detect("a", west.in_lane, 0.0)
    ica.detect("b", south.in_lane, 0.0)
    assert isinstance(_ask(ica, west, "a", 0.0, room=math.inf), Confirmation)
    b = _ask(ica, south, "b", 0.0, room=_need(south) + 0.1)
    assert not (isinstance(b, Rejection) and b.reason is Reason.NO_ROOM)


def _enter(ica, route: Route, vin: str, t: float, room: float, t_obs=None):
    req = propose(
        route, vin=vin, seq=1, t0_s=t, dist_to_entry_m=40.0, speed_mps=10.0, config=ica.config
    )
    obs = t if t_obs is None else t_obs
    return ica.handle(dataclasses.replace(req, t_obs_s=obs, network_room_m=room), t)


def test_the_network_gate_lets_in_what_fits_and_counts_who_it_let_in_since(ch45_net):
    """A vehicle entering a network of junctions: room for its length and standstill gap
    confirms it, a centimetre less refuses it; one let in after a vehicle observed the
    room takes its share of it, one let in before does not (the roadside counted it)."""
    from dica.ica.core.gridlock import QUEUE_GAP_M

    inter, ica = _ica(ch45_net)
    west, south = inter.route(*WEST), inter.route(*EAST_OUT_FROM_SOUTH)
    need = LENGTH + QUEUE_GAP_M
    ica.advance(0.0)
    ica.detect("a", west.in_lane, 0.0)
    short = _enter(ica, west, "a", 0.0, room=need - 0.01)
    assert isinstance(short, Rejection) and short.reason is Reason.NO_ROOM
    assert "network of junctions" in short.detail
    assert isinstance(_enter(ica, west, "a", 0.0, room=need), Confirmation)
    # b observed the room at 0.0, before a was let in: a takes its share
    ica.detect("b", south.in_lane, 0.0)
    late = _enter(ica, south, "b", 0.0, room=2 * need - 0.01, t_obs=0.0)
    assert isinstance(late, Rejection) and late.reason is Reason.NO_ROOM
    # observed after a was let in, the roadside's room already counts it
    assert isinstance(_enter(ica, south, "b", 0.1, room=need, t_obs=0.1), Confirmation)
