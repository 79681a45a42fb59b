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


class PreemptedLight:
    """One light's pre-emption for one emergency vehicle at a time
    (:class:`sim_gateway.signals.Preemption`): given the EV's links, its movements go
    green as soon as the program's clearances allow; the green is held until the EV
    has passed the stop line, then the program resumes where it stands."""

    _FOREVER_S = 1e6

    def __init__(self, ls, tls: str, phases: list[SignalPhase]) -> None:
        self.ls = ls
        self.tls = tls
        self.program = Preemption(phases)
        self.program_id = ls.trafficlight.getProgram(tls)
        self.ev: str | None = None
        self.steps: list[tuple[int | str, float | None]] = []
        self.step_end_s = math.inf
        self.served = 0
        self.kinds: dict[str, int] = {"extend": 0, "return": 0, "cut": 0}

    def start(self, t: float, ev: str, links: list[int]) -> None:
        """Serve ``ev``, whose movements are the signal indices ``links``."""
        tl = self.ls.trafficlight
        phase = tl.getPhase(self.tls)
        remaining = tl.getNextSwitch(self.tls) - t
        self.steps = self.program.steps(phase, remaining, links)
        kind = "cut" if len(self.steps) > 1 else (
            "extend" if self.steps[0][0] == phase else "return"
        )  # fmt: skip
        self.kinds[kind] += 1
        self.ev = ev
        self._begin(t, first=True)

    def step(self, t: float, passed: bool) -> None:
        """One step while serving: ``passed`` once the EV's front is past the stop line."""
        k, duration = self.steps[0]
        if duration is HOLD:
            if passed:
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


class ReactiveLight:
    """The reactive light's pre-emption (:class:`PreemptedLight`): the first EV seen
    waiting in the region is served, one at a time."""

    def __init__(self, ls, inter: Intersection, phases: list[SignalPhase]) -> None:
        self.light = PreemptedLight(ls, light_of(ls, inter), phases)
        self.links = ls.trafficlight.getControlledLinks(self.light.tls)

    @property
    def ev(self) -> str | None:
        return self.light.ev

    def _ev_links(self, s: Seen) -> list[int]:
        r = s.car.route
        return [
            i
            for i, group in enumerate(self.links)
            if any(ln[0] == r.in_lane and ln[1] == r.out_lane for ln in group)
        ]

    def step(self, t: float, seen: list[Seen]) -> None:
        light = self.light
        if light.ev is None:
            for s in seen:
                waiting = s.obs.lane == s.car.route.in_lane and not math.isnan(s.obs.detected_s)
                if s.car.ev and waiting:
                    links = self._ev_links(s)
                    if links:
                        light.start(t, s.car.vin, links)
                        break
            return
        ev = next((s for s in seen if s.car.vin == light.ev), None)
        entered = ev is None or ev.obs.lane != ev.car.route.in_lane or ev.obs.exited
        light.step(t, entered)

    def summary(self) -> dict:
        return self.light.summary()


PREEMPT_LEAD_S = 20.0  # [s] a light is pre-empted when an EV is this far from it


class CorridorPreemption:
    """Emergency-vehicle pre-emption at every light of a network, as deployed systems
    do it: a light is pre-empted for an EV once the EV is :data:`PREEMPT_LEAD_S` from
    its stop line at its road's speed (its distance along its route, as SUMO gives the
    lights ahead of it, over the speed it may drive there), whatever the traffic
    between; its movement is served (:class:`PreemptedLight`) until the EV is past
    the line, then the next EV waiting for that light, in the order they came within
    reach. Each light keeps the program it runs (fixed-time, with its clearances)."""

    def __init__(self, ls, tls_ids: list[str], lead_s: float = PREEMPT_LEAD_S) -> None:
        self.ls = ls
        self.lead_s = lead_s
        self.lights: dict[str, PreemptedLight] = {}
        for tls in tls_ids:
            logic = current_logic(ls, tls)
            phases = phases_of(
                [p.duration for p in logic.phases],
                [p.state for p in logic.phases],
                [p.minDur for p in logic.phases],
                [p.maxDur for p in logic.phases],
            )
            self.lights[tls] = PreemptedLight(ls, tls, phases)
        self.evs: list[str] = []  # in SUMO, in the order they departed
        self.queue: dict[str, list[tuple[str, int]]] = {t: [] for t in self.lights}
        self.calls = 0  # EVs that came within reach of a light
        self.unservable = 0  # calls for a movement no phase of the light's program serves

    def step(self, t: float) -> None:
        """Before SUMO's step: note the EVs that departed and left, call each light the
        EVs have come within reach of, and switch every light that serves one."""
        ls = self.ls
        for vin in ls.simulation.getDepartedIDList():
            if ls.vehicle.getVehicleClass(vin) == "emergency":
                self.evs.append(vin)
        gone = set(ls.simulation.getArrivedIDList())
        self.evs = [v for v in self.evs if v not in gone]
        ahead: dict[str, set[str]] = {t: set() for t in self.lights}  # EVs short of its line
        for ev in self.evs:
            upcoming = ls.vehicle.getNextTLS(ev)
            reach = self.lead_s * max(ls.vehicle.getAllowedSpeed(ev), 1.0)
            for tls, link, dist, _state in upcoming:
                if tls not in self.lights:
                    continue
                ahead[tls].add(ev)
                queued = self.queue[tls]
                waits = self.lights[tls].ev == ev or any(e == ev for e, _ in queued)
                if dist <= reach and not waits:
                    queued.append((ev, link))
                    self.calls += 1
                break  # the next light on its way only: the one after is called later
        for tls, light in self.lights.items():
            queued = self.queue[tls]
            if light.ev is not None:
                light.step(t, passed=light.ev not in ahead[tls])
            if light.ev is None:
                # an EV that left the light's approach before its turn needs it no more
                queued[:] = [(e, k) for e, k in queued if e in ahead[tls]]
                while queued and light.ev is None:
                    ev, link = queued.pop(0)
                    try:
                        light.start(t, ev, [link])
                    except ValueError:  # no phase of the program ever gives it green
                        self.unservable += 1

    def summary(self) -> dict:
        lights = [x.summary() for x in self.lights.values()]
        out = {k: sum(x[k] for x in lights) for k in ("served", "extend", "return", "cut")}
        return {"lead_s": self.lead_s, "calls": self.calls, "unservable": self.unservable, **out}
