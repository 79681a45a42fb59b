"""One connected vehicle's side of DICA, as a small state machine.

    approaching -> requesting -> confirmed -> crossing -> exited

*approaching*: upstream of the communication region; SUMO's driver drives.
*requesting*: detected at the region's entry line (the vehicle announces
itself with a DETECT). While it has no confirmation it brakes so that its
front stops before the junction's entry line, and when it is head of its lane
it sends a REQUEST (again ``retry_s`` after a rejection, or the next step
after NOT_HEAD). *confirmed*: it flies the confirmed TSS exactly (SUMO speed
mode 32: SUMO's own checks off, so it does not yield inside the junction).
*crossing*: its front has passed the entry line. *exited*: its rear has left
the junction; it is handed back to SUMO's driver.

The machine does no I/O: it reads one observation per step, talks to the ICA
through an :class:`IcaLink` (in-process in the embedded runner, Zenoh queries
in a vehicle-agent process) and returns the setpoint for its actuator. The
same code runs in both, so the two modes make the same decisions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

import numpy as np

from ica.core.config import IcaConfig
from ica.core.proposal import propose
from ica.core.request import Confirmation, Reason, Rejection, Request, RequestError
from ica.core.route import Route

STOP_DECEL_MPS2 = 4.0  # [m/s^2] braking an unconfirmed vehicle plans with (below SUMO's 4.5)
MODE_CONFIRMED = 32  # SUMO speed mode: obey the commanded speed, no own checks
MODE_DEFAULT = 31  # SUMO's default checks
RELEASE = -1.0  # a commanded speed of -1 gives the vehicle back to SUMO
BIG = 1e9  # [s] "never" for wake_s


class Phase(StrEnum):
    APPROACHING = "approaching"
    REQUESTING = "requesting"
    CONFIRMED = "confirmed"
    CROSSING = "crossing"
    EXITED = "exited"


class IcaLink(Protocol):
    """How a vehicle reaches its ICA."""

    def detect(self, vin: str, lane: str, t_s: float) -> Rejection | None: ...

    def request(self, req: Request, now_s: float) -> Confirmation | Rejection: ...


@dataclass(frozen=True, slots=True)
class Observation:
    """What the vehicle knows about itself this step (from its sensors, or the gateway)."""

    t_s: float
    lane: str
    dist_to_entry_m: float  # along the incoming lane, front bumper to entry line
    speed_mps: float
    head: bool  # no vehicle ahead on the incoming lane
    detected_s: float  # when it crossed the region's entry line; NaN before
    exited: bool  # rear out of the junction


@dataclass(frozen=True, slots=True, eq=False)
class Command:
    """Speeds from ``t0_s``, one per step (the last holds); -1 releases to SUMO."""

    vin: str
    t0_s: float
    speeds: np.ndarray
    speed_mode: int = -1  # SUMO speed mode to switch to first; -1 keeps the current
    # when the vehicle may next talk to the ICA (DETECT or REQUEST): -BIG at once,
    # BIG never; lets a lockstep gateway keep the order of ICA contacts across agents
    wake_s: float = BIG


@dataclass(slots=True)
class Vehicle:
    vin: str
    route: Route
    length_m: float
    width_m: float
    max_speed_mps: float  # the speed it entered with and would keep when free
    config: IcaConfig
    retry_s: float = 0.5
    phase: Phase = Phase.APPROACHING
    seq: int = 0
    next_request_s: float = 0.0
    confirmation: Confirmation | None = None
    rejections: dict[str, int] = field(default_factory=dict)
    brake_steps: int = 1  # length of an unconfirmed vehicle's braking profile (see _brake)

    def step(self, obs: Observation, link: IcaLink) -> Command | None:
        """Advance one step; the command for the actuator, or None to keep the last."""
        if self.phase is Phase.APPROACHING:
            if math.isnan(obs.detected_s):
                return None
            rej = link.detect(self.vin, self.route.in_lane, obs.detected_s)
            if rej is not None:
                self._count(rej.reason.value)
                return self._brake(obs, wake_s=-BIG)  # announce again next step; never enter
            self.phase = Phase.REQUESTING
        if self.phase is Phase.REQUESTING:
            if obs.t_s >= self.next_request_s and obs.head:
                command = self._request(obs, link)
                if command is not None:
                    return command
            return self._brake(obs, wake_s=self.next_request_s)
        if obs.exited:
            self.phase = Phase.EXITED
            return Command(self.vin, obs.t_s, np.array([RELEASE]), MODE_DEFAULT)
        if self.phase is Phase.CONFIRMED and obs.lane != self.route.in_lane:
            self.phase = Phase.CROSSING
        return None

    def replace(self, confirmation: Confirmation | None, now_s: float) -> Command:
        """The ICA revoked this vehicle's confirmation (reactive DICA) and, unless
        ``confirmation`` is None, gave it a new one that starts from where its old
        plan has it. Fly the new plan (the old one until the new one starts), or
        without one brake to stop before the line and ask again. In-process
        runners call this; the revocation arrives with the call.
        """
        h = self.config.step_s
        old = self.confirmation
        if confirmation is None:
            self.confirmation = None
            self.phase = Phase.REQUESTING
            self.next_request_s = now_s
            d, v = _on_plan(self.route, old, now_s, h) if old is not None else (0.0, 0.0)
            obs = Observation(now_s, self.route.in_lane, d, v, False, now_s, False)
            cmd = self._brake(obs, wake_s=now_s)
            return Command(self.vin, cmd.t0_s, cmd.speeds, MODE_DEFAULT, now_s)
        self.confirmation = confirmation
        self.phase = Phase.CONFIRMED
        speeds = _speeds(self.route, confirmation, h)
        t0 = float(confirmation.tss.t_s[0])
        if old is not None and t0 > now_s + 1e-9:
            before = _speeds(self.route, old, h)
            k0 = round((now_s - float(old.tss.t_s[0])) / h)
            k1 = round((t0 - float(old.tss.t_s[0])) / h)
            speeds = np.concatenate([before[max(k0, 0) : max(k1, 0)], speeds])
            t0 = now_s
        return Command(self.vin, t0, speeds, MODE_CONFIRMED)

    def _request(self, obs: Observation, link: IcaLink) -> Command | None:
        cfg = self.config
        try:
            req = propose(
                self.route,
                vin=self.vin,
                seq=self.seq,
                t0_s=obs.t_s,
                dist_to_entry_m=max(obs.dist_to_entry_m, 0.0),
                speed_mps=obs.speed_mps,
                length_m=self.length_m,
                width_m=self.width_m,
                config=cfg,
            )
            answer = link.request(req, obs.t_s)
        except RequestError as e:  # cannot even make a plan: stop and ask later
            answer = Rejection(self.vin, self.seq, e.reason, e.detail)
        if not (isinstance(answer, Rejection) and answer.reason is Reason.NO_ANSWER):
            self.seq += 1  # unanswered: ask again under the same number (never two reservations)
        if isinstance(answer, Confirmation):
            self.confirmation = answer
            self.phase = Phase.CONFIRMED
            tss = answer.tss
            s, _ = self.route.project(np.stack([tss.x_m, tss.y_m], -1))
            speeds = np.diff(np.maximum.accumulate(s)) / cfg.step_s
            return Command(self.vin, float(tss.t_s[0]), speeds, MODE_CONFIRMED)
        self._count(answer.reason.value)
        # NOT_HEAD: the lane's order is about to change (the vehicle ahead is entering)
        wait = cfg.step_s / 2 if answer.reason is Reason.NOT_HEAD else self.retry_s
        self.next_request_s = obs.t_s + wait
        return None

    def _brake(self, obs: Observation, wake_s: float) -> Command:
        """Speeds that keep the front short of the entry line (SUMO's discrete stop rule).

        The first is for the coming step; with ``brake_steps`` > 1 the profile
        goes on as if each speed were flown, so an actuator that hears nothing
        new (a late message) keeps braking instead of holding its speed.
        """
        cfg = self.config
        room = max(obs.dist_to_entry_m - cfg.kinematics.stop_gap_m, 0.0)
        b = STOP_DECEL_MPS2
        h = cfg.step_s
        cap = self.max_speed_mps
        speeds = []
        for _ in range(self.brake_steps):
            v_stop = math.sqrt(2 * b * room + (b * h / 2) ** 2) - b * h / 2
            v = max(0.0, min(cap, v_stop, room / h))
            speeds.append(v)
            if v == 0.0:
                break
            room = max(room - v * h, 0.0)
            cap = v
        return Command(self.vin, obs.t_s, np.array(speeds), wake_s=wake_s)

    def _count(self, reason: str) -> None:
        self.rejections[reason] = self.rejections.get(reason, 0) + 1


def _speeds(route: Route, conf: Confirmation, step_s: float) -> np.ndarray:
    """Speed per step of a confirmed TSS, as the actuator flies it."""
    tss = conf.tss
    s, _ = route.project(np.stack([tss.x_m, tss.y_m], -1))
    return np.diff(np.maximum.accumulate(s)) / step_s


def _on_plan(route: Route, conf: Confirmation, t_s: float, step_s: float) -> tuple[float, float]:
    """Distance to the entry line and speed at ``t_s`` on a confirmed plan."""
    tss = conf.tss
    s, _ = route.project(np.stack([tss.x_m, tss.y_m], -1))
    k = min(max(round((t_s - float(tss.t_s[0])) / step_s), 0), len(s) - 1)
    v = (s[k] - s[k - 1]) / step_s if k >= 1 else 0.0
    return float(-s[k]), float(max(v, 0.0))
