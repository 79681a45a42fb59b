"""An EV's notice from upstream (ica.core.ev_notice): from a lead before its arrival
the junction holds what could take its lanes' room, never what is in them, never a
plan already confirmed, and never longer than its bounds."""

from __future__ import annotations

import dataclasses
import math

import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.ev_notice import (
    CLEAR_HEADWAY_S,
    CLEAR_MARGIN_S,
    CLEAR_MOST,
    GRACE_S,
    MAX_HOLD_S,
    EvNotice,
    edge_of,
)
from dica.ica.core.proposal import propose
from dica.ica.core.reactive import ReactiveDica
from dica.ica.core.request import Confirmation, Reason, Rejection, RequestError

CFG = IcaConfig()
CROSS = "W_in_1", "E_out_1"  # through from the west, across the EV's way
EV_LANES = "N_in_1", "S_out_1"  # the EV's way: through from the north
SAME_ROAD = "N_in_0", "W_out_0"  # beside the EV on its road, turning off it
# [s] how long before the EV's arrival one vehicle waiting in its lanes starts the hold
ONE = CLEAR_MARGIN_S + CLEAR_HEADWAY_S


def ask(ica: ReactiveDica, inter, vin: str, lanes: tuple[str, str], t: float):
    ica.advance(t)
    ica.detect(vin, lanes[0], t)
    route = inter.route(*lanes)
    req = propose(route, vin=vin, seq=0, t0_s=t, dist_to_entry_m=30.0, speed_mps=8.0, config=CFG)
    return ica.handle(req, t)


def queue_up(ica: ReactiveDica, t: float, lane: str = EV_LANES[0]) -> None:
    """A vehicle in the EV's lanes, detected and without a plan yet: a queue to clear."""
    ica.detect("q1", lane, t)


def notice(eta_s: float, ev: str = "ev", sent_s: float = 0.0) -> EvNotice:
    return EvNotice(ev, edge_of(EV_LANES[0]), edge_of(EV_LANES[1]), eta_s, sent_s)


def test_a_crossing_vehicle_is_held_only_as_long_before_the_ev_as_the_queue_needs(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    assert ica.ev_coming(notice(eta_s=30.0), 0.0)
    queue_up(ica, 0.0)
    early = ask(ica, ch45, "w1", CROSS, 30.0 - ONE - 1.0)
    assert isinstance(early, Confirmation)  # before the lead: as plain DICA
    held = ask(ica, ch45, "w2", CROSS, 30.0 - ONE + 0.5)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    assert "ev" in held.detail
    assert ica.summary()["notice_held"] == 1


def test_nobody_is_held_while_nothing_waits_in_the_evs_lanes(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.ev_coming(notice(eta_s=12.0), 0.0)
    assert isinstance(ask(ica, ch45, "w1", CROSS, 5.0), Confirmation)  # its lanes flow
    queue_up(ica, 5.5)
    assert isinstance(ask(ica, ch45, "w2", ("W_in_0", "E_out_0"), 12.0 - ONE + 0.5), Rejection)


def test_the_evs_own_road_is_never_held_and_the_ev_ends_the_hold(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.ev_coming(notice(eta_s=12.0), 0.0)
    ahead = ask(ica, ch45, "n1", SAME_ROAD, 5.0)  # ahead of the EV on its road
    assert isinstance(ahead, Confirmation)
    queue_up(ica, 5.2, SAME_ROAD[0])
    assert isinstance(ask(ica, ch45, "w1", CROSS, 12.0 - ONE + 0.5), Rejection)
    ica.advance(9.0)
    ica.detect("ev", EV_LANES[0], 9.0, emergency=True, speed_mps=12.0)
    route = ch45.route(*EV_LANES)
    req = propose(route, vin="ev", seq=0, t0_s=9.0, dist_to_entry_m=50.0, speed_mps=12.0,
                  config=CFG)  # fmt: skip
    assert isinstance(ica.handle(req, 9.0), Confirmation)
    assert "ev" not in ica.notices
    # once the EV holds its plan, the crossing vehicle is planned around it (DICA's own)
    ica.advance(9.5)
    again = propose(ch45.route(*CROSS), vin="w1", seq=1, t0_s=9.5, dist_to_entry_m=30.0,
                    speed_mps=8.0, config=CFG)  # fmt: skip
    w1 = ica.handle(again, 9.5)
    assert isinstance(w1, Confirmation)
    # a late notice of the EV served here is stale
    assert not ica.ev_coming(notice(eta_s=12.0, sent_s=9.0), 9.5)


def test_a_notice_not_renewed_ends_and_none_holds_past_its_bound(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.ev_coming(notice(eta_s=20.0), 0.0)
    queue_up(ica, 0.0)
    gone = 20.0 + GRACE_S + 0.5  # the EV never came, and no newer notice said so
    assert isinstance(ask(ica, ch45, "w1", CROSS, gone), Confirmation)

    ica = ReactiveDica(ch45, CFG)
    queue_up(ica, 0.0)
    ica.detect("w", CROSS[0], 0.0)
    route = ch45.route(*CROSS)
    held_until = -math.inf
    # an EV stuck upstream that keeps saying it is 3 s away: the car across its way asks
    # every half second
    for k in range(200):
        t = k * 0.5
        ica.advance(t)
        ica.ev_coming(notice(eta_s=t + 3.0, sent_s=t), t)
        req = propose(route, vin="w", seq=0, t0_s=t, dist_to_entry_m=30.0, speed_mps=8.0,
                      config=CFG)  # fmt: skip
        got = ica.handle(req, t)
        if isinstance(got, Confirmation):
            break
        assert got.reason is Reason.HELD
        held_until = t
    assert isinstance(got, Confirmation)
    assert MAX_HOLD_S - 1.0 <= held_until <= MAX_HOLD_S


def test_a_notice_of_a_way_the_junction_has_not_is_refused(ch45):
    """Refused every time it comes, before and after a way the junction has was taken
    (each way's lanes are kept once worked out), and so is a known road in paired with
    a road out it does not lead to."""
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    nowhere = EvNotice("ev", "nowhere", "S_out", 10.0, 0.0)
    wrong_out = EvNotice("ev", edge_of(EV_LANES[0]), "nowhere", 10.0, 0.0)
    for _ in range(2):
        for bad in (nowhere, wrong_out):
            with pytest.raises(RequestError) as e:
                ica.ev_coming(bad, 0.0)
            assert e.value.reason is Reason.UNKNOWN_ROUTE
        assert ica.ev_coming(notice(eta_s=30.0), 0.0)
    with pytest.raises(RequestError):
        ica.ev_coming(notice(eta_s=math.nan), 0.0)


def test_a_restarted_ica_keeps_its_notices(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.ev_coming(notice(eta_s=15.0), 0.0)
    again = ReactiveDica(ch45, CFG)
    again.restore_snapshot(ica.snapshot())
    queue_up(again, 0.0)
    held = ask(again, ch45, "w1", CROSS, 15.0 - ONE + 1.0)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD


def test_a_queue_holding_nobody_back_or_too_long_to_clear_holds_nobody(ch45):
    """The EV's lane's first vehicle waits for room beyond the junction (holding the
    traffic across would not move it), or more wait there than a short hold clears."""
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.ev_coming(notice(eta_s=12.0), 0.0)
    ica.detect("q1", EV_LANES[0], 0.0)
    route = ch45.route(*EV_LANES)
    req = propose(route, vin="q1", seq=0, t0_s=0.0, dist_to_entry_m=30.0, speed_mps=8.0,
                  config=CFG)  # fmt: skip
    full = ica.handle(dataclasses.replace(req, exit_room_m=1.0), 0.0)
    assert isinstance(full, Rejection) and full.reason is Reason.NO_ROOM
    assert isinstance(ask(ica, ch45, "w1", CROSS, 12.0 - ONE + 0.5), Confirmation)

    for waiting, held in ((CLEAR_MOST, True), (CLEAR_MOST + 1, False)):
        ica = ReactiveDica(ch45, CFG)
        ica.advance(0.0)
        ica.ev_coming(notice(eta_s=20.0), 0.0)
        for k in range(waiting):
            ica.detect(f"q{k}", EV_LANES[0], 0.0)
        got = ask(ica, ch45, "w1", CROSS, 19.0)
        assert isinstance(got, Rejection) == held, waiting


def test_a_notice_late_or_twice_changes_nothing(ch45):
    """Over a link a notice may come twice, or after a newer one: the newest sent holds."""
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    queue_up(ica, 0.0)
    assert ica.ev_coming(notice(eta_s=30.0, sent_s=2.0), 2.0)
    assert ica.ev_coming(notice(eta_s=30.0, sent_s=2.0), 2.0)  # twice: the same
    assert not ica.ev_coming(notice(eta_s=12.0, sent_s=0.0), 2.0)  # sent before: stale
    # the EV is still 30 s away by the newest word: nobody is held yet
    assert isinstance(ask(ica, ch45, "w1", CROSS, 12.0 - ONE + 0.5), Confirmation)
    again = ReactiveDica(ch45, CFG)  # a restarted ICA knows which was newest too
    again.restore_snapshot(ica.snapshot())
    assert not again.ev_coming(notice(eta_s=12.0, sent_s=0.0), 2.5)
