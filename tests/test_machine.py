"""The vehicle machine over an asynchronous link: answers come later, or never."""

from __future__ import annotations

import math

from dica.ica.core.config import IcaConfig
from dica.ica.core.request import Reason, Rejection
from dica.vehicle_agent.machine import PENDING, Observation, Phase, Vehicle


class Later:
    """An IcaLink whose every DETECT and REQUEST is answered later (the agent's inbox)."""

    def __init__(self) -> None:
        self.detects: list[str] = []
        self.requests: list[int] = []
        self.cancels: list[int] = []

    def detect(self, vin, lane, t_s):
        self.detects.append(vin)
        return PENDING

    def request(self, req, now_s):
        self.requests.append(req.seq)
        return PENDING

    def cancel(self, vin, seq):
        self.cancels.append(seq)


def obs(t: float, d: float = 30.0, v: float = 10.0) -> Observation:
    return Observation(t, "W_in_1", d, v, True, 0.0, False)


def vehicle(ch45) -> Vehicle:
    return Vehicle("w1", ch45.route("W_in_1", "E_out_1"), 5.0, 1.8, 12.0, IcaConfig())


def test_a_head_asks_without_waiting_for_its_detect_to_be_answered(ch45):
    v, link = vehicle(ch45), Later()
    assert v.step(obs(0.05), link) is None
    assert link.detects == ["w1"] and len(link.requests) == 1
    assert v.phase is Phase.REQUESTING and v.announcing and v.pending
    v.step(obs(0.10), link)
    assert link.detects == ["w1"] and len(link.requests) == 1  # nothing twice while out


def test_a_lost_detect_shows_in_the_request_s_answer_and_is_sent_again(ch45):
    v, link = vehicle(ch45), Later()
    v.step(obs(0.05), link)
    seq = link.requests[-1]
    # the DETECT went unanswered while the REQUEST is out: wait for the REQUEST's answer
    assert v.detected(Rejection("w1", -1, Reason.NO_ANSWER, ""), 1.0) is None
    assert v.phase is Phase.REQUESTING
    # the ICA never got the DETECT: announce again
    cmd = v.answered(Rejection("w1", seq, Reason.NOT_DETECTED, ""), 1.1)
    assert v.phase is Phase.APPROACHING and cmd is not None and cmd.wake_s < 0
    v.step(obs(1.15), link)
    assert link.detects == ["w1", "w1"]


def test_a_detect_refused_with_no_request_out_is_sent_again(ch45):
    v, link = vehicle(ch45), Later()
    v.step(Observation(0.05, "W_in_1", 30.0, 10.0, False, 0.0, False), link)  # not head
    assert link.requests == [] and v.phase is Phase.REQUESTING
    cmd = v.detected(Rejection("w1", -1, Reason.NO_ANSWER, ""), 1.0)
    assert v.phase is Phase.APPROACHING and cmd is not None and cmd.wake_s < 0
    v.step(obs(1.05), link)
    assert link.detects == ["w1", "w1"] and not math.isnan(v.next_request_s)


def test_a_car_held_for_an_emergency_vehicle_asks_again_the_next_step(ch45):
    """What a held car waits for (an answer to a revocation, the EV's plan, those ordered
    before it) comes within a step or two, and it brakes further from what the ICA
    planned for it every step it waits: it asks again a step later, not a retry later."""
    v, link = vehicle(ch45), Later()
    v.step(obs(0.05), link)
    seq = link.requests[-1]
    cmd = v.answered(Rejection("w1", seq, Reason.HELD, "w1 waits: ev was ordered before it"), 0.1)
    assert cmd is not None and 0.1 < cmd.wake_s <= 0.15
    v.step(obs(0.15), link)
    assert len(link.requests) == 2
    cmd = v.answered(Rejection("w1", link.requests[-1], Reason.NO_ROOM, ""), 0.2)
    assert cmd is not None and math.isclose(cmd.wake_s, 0.2 + v.retry_s)  # others: a retry
