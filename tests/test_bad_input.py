"""Bad requests get a typed rejection and never change the confirmed set."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation, Reason, Rejection, Tss


@pytest.fixture
def ica_and_request(ch45):
    ica = Dica(ch45, IcaConfig())
    route = ch45.routes[1]
    ica.detect("car", route.in_lane, 0.0)
    req = propose(route, vin="car", seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=12.0)
    return ica, req


def tss_with(req, **arrays):
    t = req.tss
    fields = {"t_s": t.t_s, "x_m": t.x_m, "y_m": t.y_m, "heading_rad": t.heading_rad} | arrays
    return dataclasses.replace(req, tss=Tss(**fields))


def nan_at(a, k=5):
    a = a.copy()
    a[k] = np.nan
    return a


def cases(req):
    t = req.tss
    back = t.t_s.copy()
    back[10] = back[9]
    return {
        Reason.BAD_TIME: [
            tss_with(req, t_s=back),
            tss_with(req, t_s=t.t_s * 1.5),
            tss_with(req, t_s=t.t_s + 0.01),
        ],
        Reason.NOT_FINITE: [
            tss_with(req, x_m=nan_at(t.x_m)),
            tss_with(req, heading_rad=nan_at(t.heading_rad)),
            dataclasses.replace(req, speed_mps=float("nan")),
            dataclasses.replace(req, length_m=float("inf")),
        ],
        Reason.BAD_SIZE: [
            dataclasses.replace(req, length_m=0.0),
            dataclasses.replace(req, width_m=-1.8),
        ],
        Reason.TOO_LARGE: [dataclasses.replace(req, length_m=40.0)],
        Reason.UNKNOWN_LANE: [dataclasses.replace(req, in_lane="nowhere_0")],
        Reason.UNKNOWN_ROUTE: [dataclasses.replace(req, out_lane="nowhere_0")],
        Reason.OFF_ROUTE: [
            tss_with(req, x_m=t.x_m + 3.0),
            tss_with(req, heading_rad=t.heading_rad + 1.0),
        ],
        Reason.BAD_STATE: [
            dataclasses.replace(req, dist_to_entry_m=10.0),
            dataclasses.replace(req, dist_to_entry_m=500.0),
            dataclasses.replace(req, speed_mps=-1.0),
            dataclasses.replace(req, vin=""),
            dataclasses.replace(req, seq=-3),
            tss_with(
                req, t_s=t.t_s[:1], x_m=t.x_m[:1], y_m=t.y_m[:1], heading_rad=t.heading_rad[:1]
            ),
            tss_with(
                req, t_s=t.t_s[:20], x_m=t.x_m[:20], y_m=t.y_m[:20], heading_rad=t.heading_rad[:20]
            ),
            tss_with(req, x_m=t.x_m[:-1]),
        ],
        Reason.STALE: [],
    }


def test_every_bad_request_is_rejected_with_its_reason(ica_and_request):
    ica, req = ica_and_request
    for reason, bad in cases(req).items():
        for r in bad:
            out = ica.handle(r, 0.0)
            assert isinstance(out, Rejection), (reason, out)
            assert out.reason == reason, (reason, out.detail)
            assert out.detail
            assert ica.confirmed == {}
    # and the good one still goes through afterwards
    assert isinstance(ica.handle(req, 0.0), Confirmation)


def test_garbage_types_do_not_crash(ica_and_request):
    ica, req = ica_and_request
    for r in [
        dataclasses.replace(req, vin=None),
        dataclasses.replace(req, seq="1"),
        dataclasses.replace(req, length_m="5"),
        tss_with(req, x_m=np.array(["a"] * len(req.tss))),
        tss_with(req, x_m=np.zeros((len(req.tss), 2))),
    ]:
        out = ica.handle(r, 0.0)
        assert isinstance(out, Rejection)
    assert ica.confirmed == {}


def test_stale_and_future_requests(ica_and_request):
    ica, req = ica_and_request
    assert ica.handle(req, 5.0).reason == Reason.STALE
    assert ica.handle(req, -1.0).reason == Reason.BAD_TIME


def test_speeding_tss_is_rejected(ch45):
    ica = Dica(ch45, IcaConfig())
    route = next(r for r in ch45.routes if r.turn.value == "right")
    ica.detect("car", route.in_lane, 0.0)
    fast = propose(ch45.routes[1], vin="x", seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=15.0)
    req = propose(route, vin="car", seq=0, t0_s=0.0, dist_to_entry_m=40.0, speed_mps=15.0)
    # squeeze the same positions into fewer steps: twice the speed
    t = req.tss
    k = np.arange(0, len(t), 2)
    sped = tss_with(
        req, t_s=t.t_s[: len(k)], x_m=t.x_m[k], y_m=t.y_m[k], heading_rad=t.heading_rad[k]
    )
    assert ica.handle(sped, 0.0).reason == Reason.LIMITS
    assert fast.vin == "x"


def test_non_head_undetected_and_repeated_requests(ch45):
    ica = Dica(ch45, IcaConfig())
    route = ch45.routes[1]
    a = propose(route, vin="a", seq=0, t0_s=0.0, dist_to_entry_m=50.0, speed_mps=12.0)
    assert ica.handle(a, 0.0).reason == Reason.NOT_DETECTED
    ica.detect("a", route.in_lane, 0.0)
    ica.detect("b", route.in_lane, 0.0)
    b = propose(route, vin="b", seq=0, t0_s=0.0, dist_to_entry_m=50.0, speed_mps=12.0)
    assert ica.handle(b, 0.0).reason == Reason.NOT_HEAD
    first = ica.handle(a, 0.0)
    assert isinstance(first, Confirmation)
    # the same request again: the same answer, not a second reservation
    assert ica.handle(a, 0.0) is first
    assert len(ica.confirmed) == 1
    # a higher seq: the vehicle did not fly seq 0 and asks again; it replaces it
    again = ica.handle(dataclasses.replace(a, seq=1), 0.0)
    assert isinstance(again, Confirmation) and again.seq == 1
    assert len(ica.confirmed) == 1 and ica.confirmed["a"].confirmation is again
    # an older request (a duplicate arriving late) never takes a reservation back
    assert ica.handle(a, 0.0).reason == Reason.ALREADY_CONFIRMED
    # b is still not head until a has entered
    assert ica.handle(b, 0.0).reason == Reason.NOT_HEAD
    ica.advance(again.entry_time_s)
    b2 = propose(route, vin="b", seq=1, t0_s=again.entry_time_s, dist_to_entry_m=8.0, speed_mps=0.0)
    assert isinstance(ica.handle(b2, again.entry_time_s), Confirmation)


def test_cancel_frees_the_reservation_and_keeps_the_queue(ch45):
    ica = Dica(ch45, IcaConfig())
    route = ch45.routes[1]
    ica.detect("a", route.in_lane, 0.0)
    ica.detect("b", route.in_lane, 0.5)
    a = propose(route, vin="a", seq=0, t0_s=0.0, dist_to_entry_m=50.0, speed_mps=12.0)
    first = ica.handle(a, 0.0)
    assert isinstance(first, Confirmation)
    assert not ica.cancel("a", 7)  # not the held seq: nothing happens
    assert ica.cancel("a", 0) and not ica.confirmed
    # past a's old entry time a is still at the front of its lane: b is not head
    t = first.entry_time_s + 0.5
    ica.advance(t)
    b = propose(route, vin="b", seq=0, t0_s=t, dist_to_entry_m=40.0, speed_mps=10.0)
    assert ica.handle(b, t).reason == Reason.NOT_HEAD
    a2 = propose(route, vin="a", seq=3, t0_s=t, dist_to_entry_m=0.5, speed_mps=0.0)
    assert isinstance(ica.handle(a2, t), Confirmation)


def test_a_vehicle_announcing_itself_again_keeps_its_place(ch45):
    """Lanes are queued by when each vehicle crossed the region's entry line."""
    ica = Dica(ch45, IcaConfig())
    route = ch45.routes[1]
    ica.detect("b", route.in_lane, 2.0)
    ica.detect("a", route.in_lane, 1.0)  # announced later, but crossed earlier
    ica.detect("a", route.in_lane, 1.0)  # and a repeat changes nothing
    assert ica.is_head("a", 3.0) and not ica.is_head("b", 3.0)


def test_plans_must_start_between_observation_and_lead_and_not_before_now(ch45):
    ica = Dica(ch45, IcaConfig(max_lead_s=2.0))
    route = ch45.routes[1]
    ica.detect("a", route.in_lane, 0.0)

    def ask(t_obs: float, t0: float, now: float):
        req = propose(route, vin="a", seq=0, t0_s=t0, dist_to_entry_m=45.0, speed_mps=12.0)
        return ica.handle(dataclasses.replace(req, t_obs_s=t_obs), now)

    assert ask(1.0, 3.5, 1.2).reason == Reason.BAD_TIME  # beyond the 2 s lead
    assert ask(1.0, 0.5, 1.2).reason == Reason.BAD_TIME  # starts before it was observed
    assert ask(1.0, 1.5, 1.6).reason == Reason.STALE  # the plan began before now
    assert ask(0.0, 1.5, 1.2).reason == Reason.STALE  # observed over 1 s ago
    assert ask(2.0, 2.5, 1.2).reason == Reason.BAD_TIME  # observed in the future
    assert isinstance(ask(1.0, 2.0, 1.2), Confirmation)


def test_detection_on_unknown_lane_is_typed(ch45):
    ica = Dica(ch45, IcaConfig())
    with pytest.raises(Exception) as e:
        ica.detect("a", "nowhere_0", 0.0)
    assert getattr(e.value, "reason", None) == Reason.UNKNOWN_LANE
