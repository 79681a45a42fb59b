"""The signal baselines' lights on a real SUMO: the program a light is timed to is the one
SUMO runs, and the reactive light gives a waiting emergency vehicle its green early."""

from __future__ import annotations

import itertools
import math

import pytest

from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.junction import Car, Seen
from dica.sim_gateway.light_control import ReactiveLight, setup_signal
from dica.sim_gateway.runconfig import RunConfig
from dica.sim_gateway.scenario import light_net
from dica.sim_gateway.signals import Phase as SignalPhase
from dica.vehicle_agent.machine import Observation
from tests.sumo_session import STEP_S, open_sumo


@pytest.fixture(scope="module")
def static_net(ch45_net, tmp_path_factory):
    net, _ = light_net(
        ch45_net.net_path, ch45_net.junction_id, "static", tmp_path_factory.mktemp("l")
    )
    return net


def _signal(ls, ch45, net, algorithm: str) -> dict:
    cfg = RunConfig(str(net), ch45.junction_id, algorithm=algorithm, volume_per_10min=500)
    _, spec, _ = schedule_for(cfg, ch45, STEP_S)
    return setup_signal(ls, cfg, ch45, spec)


def test_sumo_runs_the_fixed_light_s_program_as_it_was_timed(ch45, static_net):
    """Installed as a program of its own, its phases switch in order at their durations."""
    with open_sumo(static_net) as ls:
        signal = _signal(ls, ch45, static_net, "fixed")
        tls = ch45.junction_id
        assert ls.trafficlight.getProgram(tls) == "dica"
        phases = signal["phases"]
        # the phases are given to the millisecond
        assert signal["cycle_s"] == pytest.approx(sum(d for d, _, _ in phases), abs=0.01)
        switches = [(0.0, ls.trafficlight.getPhase(tls))]  # (from when, which phase)
        while ls.simulation.getTime() < 2 * signal["cycle_s"] - STEP_S / 2:
            ls.simulation.step()
            k = ls.trafficlight.getPhase(tls)
            assert ls.trafficlight.getRedYellowGreenState(tls) == phases[k][1]
            if k != switches[-1][1]:
                switches.append((ls.simulation.getTime(), k))
        n = len(phases)
        assert [k for _, k in switches] == list(range(n)) * 2
        for (a, k), (b, _) in itertools.pairwise(switches):
            assert b - a == pytest.approx(phases[k][0], abs=STEP_S)  # switched at a step


def _seen(ls, car: Car) -> list[Seen]:
    """The EV as the world reports it: waiting in the region on its incoming lane, or past."""
    if car.vin not in ls.vehicle.getIDList():
        return []
    obs = Observation(
        t_s=ls.simulation.getTime(),
        lane=ls.vehicle.getLaneID(car.vin),
        dist_to_entry_m=0.0,
        speed_mps=ls.vehicle.getSpeed(car.vin),
        head=True,
        detected_s=0.0,
        exited=False,
    )
    return [Seen(car, obs)]


def test_the_reactive_light_gives_a_waiting_ev_its_green_then_resumes(ch45, static_net):
    """An EV in front of a red is given green within the clearance (SUMO's driver takes it
    across), not after the rest of the cycle; the program then runs on by itself."""
    with open_sumo(static_net) as ls:
        signal = _signal(ls, ch45, static_net, "reactive-light")
        tls = ch45.junction_id
        program = [SignalPhase(d, st, kind, d, d) for d, st, kind in signal["phases"]]
        light = ReactiveLight(ls, ch45, program)
        links = ls.trafficlight.getControlledLinks(tls)
        state = ls.trafficlight.getRedYellowGreenState(tls)

        def red_now(r) -> bool:
            idx = [
                i for i, g in enumerate(links) if (r.in_lane, r.out_lane) in {ln[:2] for ln in g}
            ]
            return bool(idx) and all(state[i] == "r" for i in idx)

        route = next(r for r in ch45.routes if red_now(r) and r.turn.value == "through")
        edges = route.in_lane.rsplit("_", 1)[0], route.out_lane.rsplit("_", 1)[0]
        ls.route.add("ev", list(edges))
        lane_index = int(route.in_lane.rsplit("_", 1)[1])
        ls.vehicle.add(
            "ev", "ev", departLane=str(lane_index), departSpeed="10",
            departPos=str(ls.lane.getLength(route.in_lane) - 40.0),
        )  # fmt: skip
        car = Car("ev", route, lane_index, 10.0, detected_s=0.0, ev=True)
        crossed_s, crossed_state = math.nan, ""
        while ls.simulation.getTime() < 60.0:
            ls.simulation.step()
            t = ls.simulation.getTime()
            seen = _seen(ls, car)
            if math.isnan(crossed_s) and seen and seen[0].obs.lane != route.in_lane:
                crossed_s, crossed_state = t, ls.trafficlight.getRedYellowGreenState(tls)
            light.step(t, seen)
        assert crossed_s < 20.0  # not after the 127 s cycle's rest
        idx = [
            i
            for i, g in enumerate(links)
            if (route.in_lane, route.out_lane) in {ln[:2] for ln in g}
        ]
        assert all(crossed_state[i] in "Gg" for i in idx)
        assert light.summary()["served"] == 1 and light.ev is None
        assert ls.trafficlight.getNextSwitch(tls) - ls.simulation.getTime() < signal["cycle_s"]
