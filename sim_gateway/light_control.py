"""The signal baselines' lights in SUMO: their programs installed, and the reactive light's
pre-emption for emergency vehicles switched phase by phase.

The timing itself (clearances, the cycle model, the pre-emption's plan) is
worked out without SUMO in :mod:`sim_gateway.signals`; this module reads the
junction's light and links from SUMO, hands them over, and sets what comes
back. Under a light the world's actuator stays out of the way: SUMO's drivers
obey the light.
"""

from __future__ import annotations

import math

from dica.ica.core.intersection import Intersection
from dica.sim_gateway.demand import DemandSpec, expected_lane_flows
from dica.sim_gateway.junction import Seen
from dica.sim_gateway.runconfig import RunConfig, RunError
from dica.sim_gateway.signals import (
    HOLD,
    Preemption,
    SignalLink,
    phases_of,
    reactive_phases,
    retime,
    with_clearance,
)
from dica.sim_gateway.signals import Phase as SignalPhase


def setup_signal(ls, cfg: RunConfig, inter: Intersection, spec: DemandSpec | None) -> dict:
    """Clearance from the formulas on the junction's program; for the fixed light,
    greens from the cycle model on top (:mod:`sim_gateway.signals`), for the random
    demand's expected flows (``spec``; with a route file, None: the program's own)."""
    tls = light_of(ls, inter)
    logic = current_logic(ls, tls)
    links = signal_links(ls, tls)
    phases = phases_of(
        [p.duration for p in logic.phases],
        [p.state for p in logic.phases],
        [p.minDur for p in logic.phases],
        [p.maxDur for p in logic.phases],
    )
    phases = with_clearance(phases, links, cfg.length_m)
    out: dict = {"type": cfg.algorithm}
    if cfg.algorithm == "fixed" and spec is None:  # a route file: no expected flows
        out["greens"] = "the net's own"
    elif cfg.algorithm == "fixed":
        lanes = [ln.in_lane if ln is not None else "" for ln in links]
        phases, timing = retime(phases, lanes, expected_lane_flows(inter, spec))
        out |= {"cycle_s": timing.cycle_s, "flow_ratio_sum": timing.flow_ratio_sum}
    elif cfg.algorithm == "reactive-light":
        phases = reactive_phases(phases)
        out["cycle_s"] = sum(p.duration_s for p in phases)
    make = ls.trafficlight.Phase
    logic.phases = tuple(make(p.duration_s, p.state, p.min_s, p.max_s) for p in phases)
    # a program of its own: replacing the running actuated one in place crashed SUMO 1.28
    logic.programID = "dica"
    logic.currentPhaseIndex = 0
    if cfg.algorithm in ("fixed", "reactive-light"):
        logic.type = ls.constants.TRAFFICLIGHT_TYPE_STATIC
    ls.trafficlight.setProgramLogic(tls, logic)
    ls.trafficlight.setProgram(tls, logic.programID)
    out["phases"] = [(round(p.duration_s, 3), p.state, p.kind) for p in phases]
    return out


def light_of(ls, inter: Intersection) -> str:
    """The id of the light over the junction: its own id, or (a joined cluster's, or one
    light over several junctions) the light that controls its incoming lanes."""
    lights = ls.trafficlight.getIDList()
    if inter.junction_id in lights:
        return inter.junction_id
    ours = set(inter.in_lanes)
    for tls in lights:
        if ours & set(ls.trafficlight.getControlledLanes(tls)):
            return tls
    raise RunError(f"junction {inter.junction_id} has no traffic light in the signalised net")


def current_logic(ls, tls: str):
    program = ls.trafficlight.getProgram(tls)
    logics = ls.trafficlight.getAllProgramLogics(tls)
    return next((lg for lg in logics if lg.programID == program), logics[0])


def signal_links(ls, tls: str) -> list[SignalLink | None]:
    """Per signal index: the incoming lane, its speed limit, and the way through
    the junction (the chain of internal lanes to the outgoing lane)."""
    out: list[SignalLink | None] = []
    for group in ls.trafficlight.getControlledLinks(tls):
        if not group:
            out.append(None)
            continue
        in_lane, out_lane, via = group[0]
        v_in = ls.lane.getMaxSpeed(in_lane)
        length, v_min = 0.0, v_in
        for _ in range(16):  # SUMO chains a handful of internal lanes at most
            if not via.startswith(":"):
                break
            length += ls.lane.getLength(via)
            v_min = min(v_min, ls.lane.getMaxSpeed(via))
            via = next((lk[4] for lk in ls.lane.getLinks(via) if lk[0] == out_lane), "")
        out.append(SignalLink(in_lane, v_in, length, v_min))
    return out


class ReactiveLight:
    """Pre-emption for one emergency vehicle at a time (:class:`sim_gateway.signals.Preemption`).

    The first EV seen in the region gets its movements green as soon as the
    program's clearances allow; the green is held until its front has passed
    the stop line, then the program resumes where it stands.
    """

    _FOREVER_S = 1e6

    def __init__(self, ls, inter: Intersection, phases: list[SignalPhase]) -> None:
        self.ls = ls
        self.tls = light_of(ls, inter)
        self.program = Preemption(phases)
        self.program_id = ls.trafficlight.getProgram(self.tls)
        self.links = ls.trafficlight.getControlledLinks(self.tls)
        self.ev: str | None = None
        self.steps: list[tuple[int | str, float | None]] = []
        self.step_end_s = math.inf
        self.served = 0
        self.kinds: dict[str, int] = {"extend": 0, "return": 0, "cut": 0}

    def _ev_links(self, s: Seen) -> list[int]:
        r = s.car.route
        return [
            i
            for i, group in enumerate(self.links)
            if any(ln[0] == r.in_lane and ln[1] == r.out_lane for ln in group)
        ]

    def step(self, t: float, seen: list[Seen]) -> None:
        tl = self.ls.trafficlight
        if self.ev is None:
            for s in seen:
                waiting = s.obs.lane == s.car.route.in_lane and not math.isnan(s.obs.detected_s)
                if s.car.ev and waiting:
                    links = self._ev_links(s)
                    if not links:
                        continue
                    phase = tl.getPhase(self.tls)
                    remaining = tl.getNextSwitch(self.tls) - t
                    self.steps = self.program.steps(phase, remaining, links)
                    kind = "cut" if len(self.steps) > 1 else (
                        "extend" if self.steps[0][0] == phase else "return"
                    )  # fmt: skip
                    self.kinds[kind] += 1
                    self.ev = s.car.vin
                    self._begin(t, first=True)
                    break
            return
        ev = next((s for s in seen if s.car.vin == self.ev), None)
        entered = ev is None or ev.obs.lane != ev.car.route.in_lane or ev.obs.exited
        k, duration = self.steps[0]
        if duration is HOLD:
            if entered:
                self._resume(t, k)
            return
        if t >= self.step_end_s - 1e-6:
            self.steps.pop(0)
            self._begin(t, first=False)

    def _begin(self, t: float, first: bool) -> None:
        tl = self.ls.trafficlight
        k, duration = self.steps[0]
        if isinstance(k, str):  # a transition of the cut: a state of its own
            tl.setRedYellowGreenState(self.tls, k)
        elif not (first and tl.getPhase(self.tls) == k):
            if tl.getProgram(self.tls) != self.program_id:
                tl.setProgram(self.tls, self.program_id)
            tl.setPhase(self.tls, k)
        # SUMO must not move on by itself: every switch is ours until the EV has entered
        tl.setPhaseDuration(self.tls, self._FOREVER_S)
        self.step_end_s = math.inf if duration is HOLD else t + duration

    def _resume(self, t: float, k: int) -> None:
        tl = self.ls.trafficlight
        spent = tl.getSpentDuration(self.tls)
        tl.setPhaseDuration(self.tls, max(self.program.durations[k] - spent, 0.05))
        self.ev = None
        self.steps = []
        self.served += 1

    def summary(self) -> dict:
        return {"served": self.served, **self.kinds}
