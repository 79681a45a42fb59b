"""Reactive DICA in the pure core: who is revoked, when an old reservation may go,
the EV ahead of vehicles confirmed before it, holds, and a conflict-free result."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica
from dica.ica.core.ev_event import ReactiveConfig
from dica.ica.core.proposal import propose
from dica.ica.core.reactive import ReactiveDica
from dica.ica.core.request import Confirmation, Reason, Rejection
from dica.ica.core.revocation import DROPPED, EXPIRED, KEPT, Answer
from dica.ica.journal import Journal, records, replay
from dica.sim_gateway.audit import Flown, conflicts

CFG = IcaConfig()
CROSS = "W_in_1", "E_out_1"  # through from the west, crossing the EV's path
EV_ROUTE = "N_in_1", "S_out_1"  # the EV: through from the north


def request(inter, vin, lanes, t, d, v, seq=0):
    route = inter.route(*lanes)
    return propose(route, vin=vin, seq=seq, t0_s=t, dist_to_entry_m=d, speed_mps=v, config=CFG)


def scene(ica: Dica, inter) -> Confirmation:
    """A car from the west is confirmed at t = 0, 30 m out at 8 m/s: it would be in the
    junction when the EV, detected 0.5 s later at 15 m/s, gets there."""
    ica.advance(0.0)
    ica.detect("w1", CROSS[0], 0.0)
    conf = ica.handle(request(inter, "w1", CROSS, 0.0, 30.0, 8.0), 0.0)
    assert isinstance(conf, Confirmation)
    ica.advance(0.5)
    return conf


def detect_ev(ica: Dica, **kw) -> None:
    if isinstance(ica, ReactiveDica):
        ica.detect("ev", EV_ROUTE[0], 0.5, emergency=True, speed_mps=15.0, **kw)
    else:
        ica.detect("ev", EV_ROUTE[0], 0.5)


def ev_request(ica: Dica, inter, seq=0):
    return ica.handle(request(inter, "ev", EV_ROUTE, 0.5, 50.0, 15.0, seq), 0.5)


def start_event(ica: ReactiveDica, inter):
    """The EV asks as head of its lane: its event starts, and the answer is "held"
    while confirmations are being revoked for it."""
    detect_ev(ica)
    first = ev_request(ica, inter)
    assert isinstance(first, Rejection) and first.reason is Reason.HELD
    [r] = ica.take_reorders()
    return r


def flown(inter, confs: list[Confirmation]) -> list[Flown]:
    return [
        Flown(c.vin, inter.route_by_id(c.route_id), 5.0, 1.8, c.tss.t_s, c.tss.x_m, c.tss.y_m,
              c.tss.heading_rad)
        for c in confs
    ]  # fmt: skip


def test_plain_dica_makes_the_ev_wait_for_the_car_confirmed_first(ch45):
    ica = Dica(ch45, CFG)
    w1 = scene(ica, ch45)
    detect_ev(ica)
    ev = ev_request(ica, ch45)
    assert isinstance(ev, Confirmation)
    assert ev.delay_s > 0.3  # the scene is one where the EV loses time
    assert ev.entry_time_s > w1.entry_time_s


def test_the_ev_crosses_first_and_the_car_that_could_stop_goes_after_it(ch45):
    ica = ReactiveDica(ch45, CFG)
    w1_old = scene(ica, ch45)
    r = start_event(ica, ch45)
    assert r.ev == "ev" and r.revoked == ("w1",) and r.order.index("ev") < r.order.index("w1")
    assert r.ev_entry_after_s < r.ev_entry_before_s
    assert ica.pending() == ("w1",)
    assert ica.acknowledge("w1") == []  # the EV is planned first, then the others around it
    ev = ev_request(ica, ch45, seq=1)
    assert isinstance(ev, Confirmation) and ev.delay_s < 1e-3  # at its earliest
    [w1_new] = ica.take_confirmations()
    assert w1_new.vin == "w1" and w1_new.tss.t_s[0] == pytest.approx(0.5)
    assert w1_new.entry_time_s > ev.entry_time_s > w1_old.entry_time_s
    # the new plan starts where the old one had the car when the revocation took effect
    k = round((0.5 - w1_old.tss.t_s[0]) / CFG.step_s)
    assert w1_new.tss.x_m[0] == pytest.approx(w1_old.tss.x_m[k])
    assert conflicts(flown(ch45, [ev, w1_new]), CFG.margin_m) == []
    assert ica.events[0].ev_entry_s == ev.entry_time_s


def test_a_revoked_reservation_holds_until_it_is_acknowledged(ch45):
    ica = ReactiveDica(ch45, CFG)
    scene(ica, ch45)
    start_event(ica, ch45)
    # no acknowledgement yet: the car may still be flying its old plan, so the EV
    # gets exactly what plain DICA would give it, not the car's room
    ev = ev_request(ica, ch45, seq=1)
    plain = Dica(ch45, CFG)
    scene(plain, ch45)
    detect_ev(plain)
    assert isinstance(ev, Confirmation)
    assert ev.entry_time_s == pytest.approx(ev_request(plain, ch45).entry_time_s)
    assert "w1~revoked" in ica.confirmed


def test_others_are_held_until_the_ev_holds_its_plan(ch45):
    ica = ReactiveDica(ch45, CFG)
    scene(ica, ch45)
    r = start_event(ica, ch45)
    for vin in r.revoked:
        ica.acknowledge(vin)
    ica.detect("e1", "E_in_1", 0.5)  # crosses the EV's path
    ica.detect("s1", "S_in_0", 0.5)  # turns right, never near the EV's lane's routes
    held = ica.handle(request(ch45, "e1", ("E_in_1", "W_out_1"), 0.5, 50.0, 10.0), 0.5)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    free = ica.handle(request(ch45, "s1", ("S_in_0", "E_out_0"), 0.5, 50.0, 10.0), 0.5)
    assert isinstance(free, Confirmation)
    assert isinstance(ev_request(ica, ch45, seq=1), Confirmation)
    ica.settle()
    later = ica.handle(request(ch45, "e1", ("E_in_1", "W_out_1"), 0.5, 50.0, 10.0, seq=1), 0.5)
    assert isinstance(later, Confirmation)
    confs = [c.confirmation for c in ica.confirmed.values()]
    assert conflicts(flown(ch45, confs), CFG.margin_m) == []


def test_a_car_that_cannot_stop_keeps_its_confirmation(ch45):
    ica = ReactiveDica(ch45, CFG)
    ica.advance(0.0)
    ica.detect("w1", CROSS[0], 0.0)
    ica.handle(request(ch45, "w1", CROSS, 0.0, 12.0, 15.0), 0.0)  # 15 m/s, 12 m out
    ica.advance(0.05)
    ica.detect("ev", EV_ROUTE[0], 0.05, emergency=True, speed_mps=15.0)
    ev = ica.handle(request(ch45, "ev", EV_ROUTE, 0.05, 50.0, 15.0), 0.05)
    assert isinstance(ev, Confirmation)  # nothing to revoke: confirmed at its first request
    [r] = ica.take_reorders()
    assert r.revoked == () and r.order == ("ev",)


def test_the_event_closes_when_the_ev_has_left(ch45):
    ica = ReactiveDica(ch45, CFG)
    scene(ica, ch45)
    ica.detect("ev2", "E_in_1", 0.5, emergency=True, speed_mps=12.0)
    r = start_event(ica, ch45)
    for vin in r.revoked:
        ica.acknowledge(vin)
    ev = ev_request(ica, ch45, seq=1)
    ica.settle()
    assert ica.event is not None and ica.event.ev == "ev"
    # the second EV waits: its request is held like anyone's that crosses the EV's path
    second = ica.handle(request(ch45, "ev2", ("E_in_1", "W_out_1"), 0.5, 50.0, 12.0), 0.5)
    assert isinstance(second, Confirmation)  # the first EV holds its plan: no hold now
    t = ev.exit_time_s + 1.0
    ica.advance(t)
    assert ica.events[0].closed_s == t and ica.event is None
    assert [e.ev for e in ica.events] == ["ev"]  # the second was confirmed: nothing to do


def test_exhaustive_refusal_keeps_the_present_order(ch45):
    ica = ReactiveDica(ch45, CFG, reactive=ReactiveConfig(solver="exhaustive", exhaustive_limit=1))
    scene(ica, ch45)
    detect_ev(ica)
    assert isinstance(ev_request(ica, ch45), Confirmation)  # nothing revoked: plain DICA
    [r] = ica.take_reorders()
    assert "refused" in r.refused and r.revoked == ()
    assert ica.summary()["refused"] == 1


@pytest.mark.parametrize("solver", ["exact", "ga", "exhaustive"])
def test_every_solver_puts_the_ev_first_here(ch45, solver):
    ica = ReactiveDica(ch45, CFG, reactive=ReactiveConfig(solver=solver, seed=3))
    scene(ica, ch45)
    r = start_event(ica, ch45)
    assert r.order.index("ev") < r.order.index("w1")
    assert np.isfinite(r.solve_s)


def test_at_detection_as_in_the_dissertation(ch45):
    ica = ReactiveDica(ch45, CFG, reactive=ReactiveConfig(start_at="detection"))
    scene(ica, ch45)
    detect_ev(ica)
    [r] = ica.take_reorders()  # decided at the detection, before the EV asks
    assert r.revoked == ("w1",)
    ica.acknowledge("w1")
    ica.settle()  # the EV has not asked: the car ordered behind it gets no plan yet
    assert ica.take_confirmations() == [] and ica.event.unplanned == ["w1"]
    ev = ev_request(ica, ch45)
    assert isinstance(ev, Confirmation) and ev.delay_s < 1e-3


ASK = ReactiveConfig(replan_revoked=False)


def test_over_a_link_the_revoked_car_drops_its_plan_and_asks_after_the_ev(ch45):
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    w1_old = scene(ica, ch45)
    r = start_event(ica, ch45)
    assert r.revoked == ("w1",) and r.seqs == (0,) and r.lane == EV_ROUTE[0]
    assert ica.due_revocations() == [("w1", 0)]
    held = ev_request(ica, ch45, seq=1)  # no answer yet: the EV waits, the room stays taken
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    assert "w1~revoked" in ica.confirmed and ica.due_revocations() == [("w1", 0)]
    assert ica.acknowledge("w1", seq=7) == [] and ica.pending() == ("w1",)  # not that plan
    assert ica.take_answers() == []  # nothing is known of the plan yet: it stays drawn
    assert ica.cancel("w1", 0)  # the vehicle will not fly plan 0: its acknowledgement
    assert ica.pending() == () and ica.due_revocations() == []
    assert ica.take_answers() == [Answer("w1", 0, DROPPED, 0.5)] and ica.take_answers() == []
    assert "w1~revoked" not in ica.confirmed and "w1" not in ica.confirmed
    ev = ev_request(ica, ch45, seq=2)
    assert isinstance(ev, Confirmation) and ev.delay_s < 1e-3
    assert ica.take_confirmations() == []  # the ICA makes it no new plan: it asks again
    k = round((0.5 - w1_old.tss.t_s[0]) / CFG.step_s)
    d = -float(ch45.route(*CROSS).project(np.array([[w1_old.tss.x_m[k], w1_old.tss.y_m[k]]]))[0][0])
    again = ica.handle(request(ch45, "w1", CROSS, 0.5, d, 7.0, seq=3), 0.5)
    assert isinstance(again, Confirmation) and again.entry_time_s > ev.entry_time_s
    assert conflicts(flown(ch45, [ev, again]), CFG.margin_m) == []
    s = ica.summary()
    assert (s["acknowledged"], s["restored"], s["pending"]) == (1, 0, 0)


def test_asking_again_acknowledges_the_revocation_whatever_path_the_ack_took(ch45):
    """Over Zenoh the ACK (a publication) and the vehicle's next REQUEST (a query) may
    reach the ICA in either order: the REQUEST under a higher seq is the proof that the
    revoked plan is not flown, so both orders give the same plan and the same state."""
    w1_old = scene(ReactiveDica(ch45, CFG, reactive=ASK), ch45)  # where w1 is at 0.5 s
    k = round((0.5 - w1_old.tss.t_s[0]) / CFG.step_s)
    xy = np.array([[w1_old.tss.x_m[k], w1_old.tss.y_m[k]]])
    d = -float(ch45.route(*CROSS).project(xy)[0][0])
    plans = []
    for ack_first in (True, False):
        ica = ReactiveDica(ch45, CFG, reactive=ASK)
        scene(ica, ch45)
        start_event(ica, ch45)
        assert ica.pending() == ("w1",)
        # a request under the revoked plan's seq (a late copy of the old one) proves nothing
        ica.handle(request(ch45, "w1", CROSS, 0.5, d, 7.0, seq=0), 0.5)
        assert ica.pending() == ("w1",) and "w1~revoked" in ica.confirmed
        if ack_first:
            ica.acknowledge("w1", 0)
        held = ica.handle(request(ch45, "w1", CROSS, 0.5, d, 7.0, seq=3), 0.5)
        assert isinstance(held, Rejection) and held.reason is Reason.HELD  # the EV first
        assert "w1~revoked" not in ica.confirmed and ica.pending() == ()
        assert ica.acknowledge("w1", 0) == []  # the ACK that comes late changes nothing
        assert [a.outcome for a in ica.take_answers()] == [DROPPED]
        ev = ev_request(ica, ch45, seq=2)
        again = ica.handle(request(ch45, "w1", CROSS, 0.5, d, 7.0, seq=4), 0.5)
        assert isinstance(ev, Confirmation) and isinstance(again, Confirmation)
        plans.append((ev, again))
    (ev1, w1a), (ev2, w1b) = plans
    assert ev1.entry_time_s == ev2.entry_time_s and w1a.entry_time_s == w1b.entry_time_s
    assert np.array_equal(w1a.tss.x_m, w1b.tss.x_m)


def test_a_refused_drop_gives_the_car_its_reservation_back(ch45):
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    w1 = scene(ica, ch45)
    start_event(ica, ch45)
    assert ica.restore("w1", seq=5) == ()  # about another plan: nothing changes
    assert ica.restore("w1", seq=0) == ("w1",)
    assert ica.take_answers() == [Answer("w1", 0, KEPT, 0.5)]
    assert ica.confirmed["w1"].confirmation is w1 and "w1~revoked" not in ica.confirmed
    assert ica.restore("w1", seq=0) == () and ica.due_revocations() == []  # a repeat
    assert not ica.cancel("w1", 5)
    ev = ev_request(ica, ch45, seq=1)  # planned around the car, as plain DICA would
    plain = Dica(ch45, CFG)
    scene(plain, ch45)
    detect_ev(plain)
    assert isinstance(ev, Confirmation)
    assert ev.entry_time_s == pytest.approx(ev_request(plain, ch45).entry_time_s)
    assert ica.summary()["restored"] == 1


def test_an_unanswered_revocation_ends_with_the_old_plan(ch45):
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    w1 = scene(ica, ch45)
    start_event(ica, ch45)
    ica.advance(w1.exit_time_s + 1.0)  # never answered: it flew it (or stopped, unheard)
    assert ica.pending() == () and ica.summary()["expired"] == 1
    assert ica.take_answers() == [Answer("w1", 0, EXPIRED, w1.exit_time_s + 1.0)]
    assert "w1" not in ica._lane_of  # gone from its queue: one still there announces itself


# -- a restarted ICA: the journal keeps what the detector read ---------------------------
def journalled_scene(inter, path, ev_flag: bool = True) -> ReactiveDica:
    """The scene, with every detection and confirmation journalled as the ICA does."""
    ica = ReactiveDica(inter, CFG, reactive=ASK)
    journal = Journal(path, sync=False)
    conf = scene(ica, inter)
    journal.detect("w1", CROSS[0], 0.0, False, 8.0)
    journal.confirm(conf, 5.0, 1.8, CROSS[0])
    detect_ev(ica)
    journal.detect("ev", EV_ROUTE[0], 0.5, ev_flag, 15.0)
    journal.close()
    return ica


def test_a_replayed_journal_keeps_the_ev_flag_and_the_ev_still_goes_first(ch45, tmp_path):
    path = tmp_path / "ica-journal.msgpack"
    before = journalled_scene(ch45, path)
    assert records(path)[0][-1]["ev"] is True
    restarted = ReactiveDica(ch45, CFG, reactive=ASK)
    done = replay(path, restarted)
    assert (done.detects, done.confirmations, done.skipped) == (2, 1, 0)
    restarted.advance(0.5)
    # the EV asks as head of its lane: the restarted ICA reorders exactly as before
    for ica in (before, restarted):
        held = ev_request(ica, ch45)
        assert isinstance(held, Rejection) and held.reason is Reason.HELD
    [r0], [r1] = before.take_reorders(), restarted.take_reorders()
    assert r1.revoked == r0.revoked == ("w1",) and r1.order == r0.order
    assert r1.ev_entry_after_s == pytest.approx(r0.ev_entry_after_s)
    assert restarted._lane_confirmed[CROSS[0]] == ["w1"]  # the lane's order came back too


def test_a_restarted_ica_carries_on_the_revocations_it_awaited(ch45, tmp_path):
    """The ICA revokes the car's plan for the EV and dies before the answer comes.
    Restarted from its journal, it still awaits that answer (the event is journalled):
    the same revocation is due, the room stays taken, the EV's next ask is held within
    the same event, and the answer frees the room so that the EV goes first. Restarted
    from a journal without the event, it knows of no revocation: it would ignore the
    car's answer and decide the event anew."""
    full, bare = tmp_path / "full.msgpack", tmp_path / "bare.msgpack"
    journalled_scene(ch45, full)
    journalled_scene(ch45, bare)
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    replay(full, ica)
    ica.advance(0.5)
    r = start_event(ica, ch45)
    assert r.revoked == ("w1",)
    journal = Journal(full, sync=False)
    journal.reactive(ica.snapshot())  # as the service writes it, before the REVOKE goes out
    journal.close()
    assert records(full)[0][-1]["k"] == "reactive"

    late = 1.0
    restarted = ReactiveDica(ch45, CFG, reactive=ASK)
    done = replay(full, restarted)
    restarted.advance(late)
    assert done.revocations == 1 and restarted.pending() == ("w1",)
    assert restarted.due_revocations() == [("w1", 0)] and "w1~revoked" in restarted.confirmed
    assert restarted.event is not None and restarted.event.reorder.revoked == ("w1",)
    assert restarted.snapshot() == ica.snapshot()
    held = restarted.handle(request(ch45, "ev", EV_ROUTE, late, 42.5, 15.0, seq=1), late)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    assert restarted.take_reorders() == []  # the same event goes on, not a new one
    assert restarted.cancel("w1", 0)  # the answer: the plan is dropped, the room free
    assert restarted.pending() == () and not {"w1", "w1~revoked"} & set(restarted.confirmed)
    ev = restarted.handle(request(ch45, "ev", EV_ROUTE, late, 42.5, 15.0, seq=2), late)
    empty = Dica(ch45, CFG)
    empty.detect("ev", EV_ROUTE[0], 0.5)
    free = empty.handle(request(ch45, "ev", EV_ROUTE, late, 42.5, 15.0, seq=2), late)
    assert isinstance(ev, Confirmation) and ev.entry_time_s == pytest.approx(free.entry_time_s)

    forgot = ReactiveDica(ch45, CFG, reactive=ASK)
    assert replay(bare, forgot).revocations == 0
    forgot.advance(late)
    assert forgot.pending() == () and "w1" in forgot.confirmed  # the answer would be ignored
    forgot.handle(request(ch45, "ev", EV_ROUTE, late, 42.5, 15.0, seq=1), late)
    assert len(forgot.take_reorders()) == 1  # it decides the event again


def test_an_answer_journalled_after_the_event_is_not_awaited_again(ch45, tmp_path):
    """The car's answer came (journalled as a cancel of the revoked plan) but the ICA died
    before it journalled the event again: the replay finds the plan gone and awaits
    nothing; the event is carried on, and the EV's next ask is planned first. A second
    copy of the answer changes nothing."""
    path = tmp_path / "j.msgpack"
    journalled_scene(ch45, path)
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    replay(path, ica)
    ica.advance(0.5)
    start_event(ica, ch45)
    journal = Journal(path, sync=False)
    journal.reactive(ica.snapshot())
    journal.cancel("w1", 0)  # the answer, as the service journals it before it acts
    journal.close()
    restarted = ReactiveDica(ch45, CFG, reactive=ASK)
    done = replay(path, restarted)
    restarted.advance(1.0)
    assert done.revocations == 0 and restarted.pending() == ()
    assert not {"w1", "w1~revoked"} & set(restarted.confirmed)
    assert restarted.event is not None and restarted.event.reorder.revoked == ("w1",)
    assert not restarted.cancel("w1", 0)  # the same answer again: nothing to free
    ev = restarted.handle(request(ch45, "ev", EV_ROUTE, 1.0, 42.5, 15.0, seq=1), 1.0)
    assert isinstance(ev, Confirmation) and restarted.take_reorders() == []


def test_an_old_journal_without_the_flag_still_replays(ch45, tmp_path):
    path = tmp_path / "old.msgpack"
    journalled_scene(ch45, path, ev_flag=False)
    recs, _ = records(path)
    with path.open("wb") as f:  # as written before the flag existed: no "ev", no "speed"
        for rec in recs:
            rec.pop("ev", None)
            rec.pop("speed", None)
            f.write(msgpack.packb(rec, use_bin_type=True))
    ica = ReactiveDica(ch45, CFG, reactive=ASK)
    done = replay(path, ica)
    assert (done.detects, done.confirmations, done.skipped) == (2, 1, 0)
    ica.advance(0.5)
    ev = ev_request(ica, ch45)  # a normal vehicle now: planned around the car, no reorder
    assert isinstance(ev, Confirmation) and ica.take_reorders() == []
    plain = Dica(ch45, CFG)
    assert replay(path, plain).detects == 2  # and into plain DICA too


def test_a_revised_confirmation_is_held_with_the_time_pad_like_any_other(ch45):
    """Under a time pad every reservation is judged with its intervals grown by twice
    the pad, as each of two vehicles may be that far off its plan. A confirmation
    revised for an EV is held so too: exactly as a restarted ICA rebuilds it from the
    journal (which pads every confirmation it adopts)."""
    cfg = IcaConfig(time_pad_s=0.2)
    # no bound on what the car may be added: the case needs it revoked
    ica = ReactiveDica(ch45, cfg, reactive=ReactiveConfig(max_added_delay_s=float("inf")))
    scene(ica, ch45)
    start_event(ica, ch45)
    assert ica.acknowledge("w1") == []
    assert isinstance(ev_request(ica, ch45, seq=1), Confirmation)
    [w1] = ica.take_confirmations()
    held = ica.confirmed["w1"].dtot
    rebuilt = Dica(ch45, cfg, tables=ica.tables)
    rebuilt.adopt(w1, 5.0, 1.8, CROSS[0])
    want = rebuilt.confirmed["w1"].dtot
    assert np.array_equal(held.lb_s, want.lb_s) and np.array_equal(held.ub_s, want.ub_s)


def test_a_requested_confirmation_is_held_with_the_time_pad_and_no_more(ch45):
    """The request path beside the revision above: held grown by twice the pad on each
    side of the intervals a pad-free ICA holds for the same plan, as a restart
    rebuilds it; and with no pad, exactly those intervals."""
    held = {}
    for pad in (0.0, 0.2):
        cfg = IcaConfig(time_pad_s=pad)
        ica = Dica(ch45, cfg)
        w1 = scene(ica, ch45)
        held[pad] = ica.confirmed["w1"].dtot
        rebuilt = Dica(ch45, cfg, tables=ica.tables)
        rebuilt.adopt(w1, 5.0, 1.8, CROSS[0])
        want = rebuilt.confirmed["w1"].dtot
        assert np.array_equal(held[pad].lb_s, want.lb_s)
        assert np.array_equal(held[pad].ub_s, want.ub_s)
    assert np.array_equal(held[0.2].t_s, held[0.0].t_s)  # the same plan
    assert np.allclose(held[0.2].lb_s, held[0.0].lb_s - 0.4)
    assert np.allclose(held[0.2].ub_s, held[0.0].ub_s + 0.4)


# -- a bound on what reorderings add to a vehicle -------------------------------------
def _bounded(inter, bound: float) -> tuple[ReactiveDica, Confirmation]:
    ica = ReactiveDica(inter, CFG, reactive=ReactiveConfig(max_added_delay_s=bound))
    return ica, scene(ica, inter)


def _passed(ica: ReactiveDica, inter) -> tuple[Confirmation, Confirmation]:
    """The EV's event with the car revoked: acknowledged, the EV planned, then the car."""
    r = start_event(ica, inter)
    assert r.order.index("ev") < r.order.index("w1") and r.revoked == ("w1",)
    ica.acknowledge("w1")
    ev = ev_request(ica, inter, seq=1)
    [w1] = ica.take_confirmations()
    assert w1.entry_time_s > ev.entry_time_s
    assert conflicts(flown(inter, [ev, w1]), CFG.margin_m) == []
    return ev, w1


def test_the_ev_goes_first_only_if_the_car_it_passes_stays_within_the_bound(ch45):
    ica, w1_old = _bounded(ch45, float("inf"))
    r = start_event(ica, ch45)
    model = dict(zip(r.order, r.added_s, strict=True))["w1"]
    ica.acknowledge("w1")
    ev_request(ica, ch45, seq=1)
    [w1_new] = ica.take_confirmations()
    cost = w1_new.entry_time_s - w1_old.entry_time_s  # what passing it really costs the car
    assert min(cost, model) > 0.5  # the bound has something to cut
    # a bound under that cost: the car keeps its plan (nothing is revoked) and the EV is
    # planned at once, behind it
    ica, w1 = _bounded(ch45, min(cost, model) - 0.05)
    detect_ev(ica)
    ev = ev_request(ica, ch45)
    [r] = ica.take_reorders()
    assert r.revoked == () and isinstance(ev, Confirmation)
    assert ev.entry_time_s > w1.entry_time_s
    assert ica.confirmed["w1"].confirmation == w1
    assert conflicts(flown(ch45, [ev, w1]), CFG.margin_m) == []
    assert ica.summary()["added_delay_max_s"] == 0.0
    # one over it lets the EV first, and charges the car what its new plan costs it
    ica, _ = _bounded(ch45, max(cost, model) + 0.05)
    _, again = _passed(ica, ch45)
    assert again.entry_time_s == pytest.approx(w1_new.entry_time_s)
    summary = ica.summary()
    assert summary["added_delay_max_s"] == pytest.approx(cost, abs=1e-3)  # (rounded)
    assert summary["replanned_later_max_s"] == pytest.approx(cost, abs=1e-3)
    assert summary["max_added_delay_s"] == pytest.approx(max(cost, model) + 0.05)


class _Optimist(ReactiveDica):
    """An ordering model that thinks the EV's lane costs nobody anything when it goes
    first, and that anyone going before it holds it up for 3 s."""

    def _sep(self, a, a_mps, b, b_mps) -> float:
        return 0.0 if a[0].in_lane == EV_ROUTE[0] else 3.0


def test_a_bound_holds_on_the_real_plans_whatever_the_ordering_model_says(ch45):
    """The order is carried out on a copy before anything is revoked: a car whose real new
    plan would break the bound keeps its plan, though the model saw no cost to it."""
    ica = _Optimist(ch45, CFG)
    w1_old = scene(ica, ch45)
    _, w1_new = _passed(ica, ch45)
    real = w1_new.entry_time_s - w1_old.entry_time_s
    assert real > 0.5
    ica = _Optimist(ch45, CFG, reactive=ReactiveConfig(max_added_delay_s=real - 0.1))
    w1 = scene(ica, ch45)
    detect_ev(ica)
    assert isinstance(ev_request(ica, ch45), Confirmation)
    [r] = ica.take_reorders()
    assert r.order == ("ev",)  # ordered again with the car kept out of it
    assert r.revoked == () and ica.confirmed["w1"].confirmation == w1
    assert ica.summary()["bound_trials"] == 1
    # with room for what it really costs, the car is passed as the model wanted
    ica = _Optimist(ch45, CFG, reactive=ReactiveConfig(max_added_delay_s=real + 0.1))
    scene(ica, ch45)
    _passed(ica, ch45)
    assert ica.summary()["bound_trials"] == 1


def test_what_a_vehicle_was_added_counts_against_later_reorderings_and_a_restart(ch45):
    ica, w1_old = _bounded(ch45, 10.0)
    _, w1_new = _passed(ica, ch45)  # (10 s is more than both the model's cost and the real)
    cost = w1_new.entry_time_s - w1_old.entry_time_s
    assert ica.snapshot()["added"] == {"w1": pytest.approx(cost)}
    again = ReactiveDica(ch45, CFG, reactive=ReactiveConfig(max_added_delay_s=10.0))
    again.restore_snapshot(ica.snapshot())
    assert again.snapshot()["added"] == ica.snapshot()["added"]
    # a vehicle that has used its bound up is passed by no later EV
    spent = ReactiveDica(ch45, CFG, reactive=ReactiveConfig(max_added_delay_s=10.0))
    scene(spent, ch45)
    spent.restore_snapshot(spent.snapshot() | {"added": {"w1": 10.0}})
    detect_ev(spent)
    assert isinstance(ev_request(spent, ch45), Confirmation)  # nothing to revoke: planned
    [r] = spent.take_reorders()
    assert r.order.index("w1") < r.order.index("ev") and r.revoked == ()


def test_the_bound_must_not_be_negative():
    with pytest.raises(ValueError, match="max_added_delay_s"):
        ReactiveConfig(max_added_delay_s=-1.0)
    with pytest.raises(ValueError, match="max_added_delay_s"):
        ReactiveConfig(max_added_delay_s=float("nan"))


def test_a_zero_bound_is_a_bound_no_car_is_passed_at_any_cost(ch45):
    """0, the least value allowed, is taken as it is (not as "none"): the car keeps its
    plan and the EV is planned behind it at once."""
    ica, w1 = _bounded(ch45, 0.0)
    detect_ev(ica)
    ev = ev_request(ica, ch45)
    [r] = ica.take_reorders()
    assert r.revoked == () and isinstance(ev, Confirmation)
    assert ev.entry_time_s > w1.entry_time_s
    assert ica.summary()["max_added_delay_s"] == 0.0


def _where(inter, conf: Confirmation, lanes, t: float) -> float:
    """How far short of its line a vehicle flying ``conf`` is at ``t``."""
    k = round((t - conf.tss.t_s[0]) / CFG.step_s)
    xy = np.array([[conf.tss.x_m[k], conf.tss.y_m[k]]])
    return -float(inter.route(*lanes).project(xy)[0][0])


EAST = "E_in_1", "W_out_1"  # through from the east, across the EV's way too


def two_revoked_over_a_link(inter):
    """Two cars across the EV's way (w1 from the west, e1 from the east), confirmed, then
    revoked for the EV by an ICA that lets revoked cars ask again (the cluster's way):
    the ICA, the reorder, and each car's plan and lanes."""
    ica = ReactiveDica(inter, CFG, reactive=ReactiveConfig(replan_revoked=False))
    w1 = scene(ica, inter)
    ica.detect("e1", EAST[0], 0.0)
    e1 = ica.handle(request(inter, "e1", EAST, 0.0, 30.0, 8.0), 0.0)
    assert isinstance(e1, Confirmation)
    r = start_event(ica, inter)
    assert set(r.revoked) == {"w1", "e1"}
    return ica, r, {"w1": (w1, CROSS), "e1": (e1, EAST)}


@pytest.mark.parametrize("first_asks", [True, False])
def test_revoked_cars_asking_again_go_in_the_order_they_were_given(ch45, first_asks):
    """Two cars across the EV's way, revoked for it over a link: whichever asks again
    first, the one the order put second waits for the first to have its plan (for
    ORDER_WAIT_S at most, should the first never ask), as the bound was checked."""
    from dica.ica.core.reactive import ORDER_WAIT_S

    ica, r, plans = two_revoked_over_a_link(ch45)
    for vin, seq in ica.due_revocations():
        ica.cancel(vin, seq)
    assert isinstance(ev_request(ica, ch45, seq=1), Confirmation)
    first, second = r.revoked  # in the solver's order
    t = 0.5

    def again(vin: str, t: float, seq: int):
        conf, lanes = plans[vin]
        ica.advance(t)
        return ica.handle(request(ch45, vin, lanes, t, _where(ch45, conf, lanes, 0.5), 6.0,
                                  seq=seq), t)  # fmt: skip

    held = again(second, t, 3)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    assert f"{first} was ordered before it" in held.detail
    if first_asks:
        assert isinstance(again(first, t, 3), Confirmation)
        assert isinstance(again(second, t, 4), Confirmation)
    else:  # the first never asks: the second goes once it has waited long enough
        still = again(second, t + ORDER_WAIT_S - 0.5, 4)
        assert isinstance(still, Rejection) and "ordered before" in still.detail
        assert isinstance(again(second, t + ORDER_WAIT_S + 0.5, 5), Confirmation)


def test_a_revoked_car_asking_again_before_the_ev_has_its_plan_waits_for_it(ch45):
    """Over a link the bound is checked on a copy that plans the EV first and the revoked
    cars around it: a revoked car that asks again while the EV is still held waits for the
    EV's plan, whether or not its way crosses the EV's (asking first, one that does not
    was planned around revoked plans not yet dropped and came out seconds later than the
    copy said), and the EV, once planned, frees it."""
    ica, r, plans = two_revoked_over_a_link(ch45)
    first = r.revoked[0]
    assert ica._ordered_before(first, 0.5) == r.ev  # the rule itself, whatever the route
    for vin, seq in ica.due_revocations():
        ica.cancel(vin, seq)
    conf, lanes = plans[first]
    ica.advance(0.55)
    d = _where(ch45, conf, lanes, 0.55)
    held = ica.handle(request(ch45, first, lanes, 0.55, d, 6.0, seq=3), 0.55)
    assert isinstance(held, Rejection) and held.reason is Reason.HELD
    assert isinstance(ev_request(ica, ch45, seq=1), Confirmation)
    assert ica._ordered_before(first, 0.6) is None
    ica.advance(0.6)
    d = _where(ch45, conf, lanes, 0.6)
    again = ica.handle(request(ch45, first, lanes, 0.6, d, 6.0, seq=4), 0.6)
    assert isinstance(again, Confirmation)
