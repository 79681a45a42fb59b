"""The gateway process: SUMO's side of the cluster, keyed to Zenoh.

The only process that imports libsumo. It steps the same world as the
embedded runner (:mod:`sim_gateway.world`), publishes the sim CLOCK on
``sim/<j>/clock`` and each agent's vehicles' states on ``sim/<j>/state/<agent>``
(the first STATE naming a vehicle hands it to that agent), and applies the
COMMANDs agents send on ``sim/<j>/command/<agent>``.

Two clocks:

* ``lockstep``: each step waits until every agent that got a STATE has
  answered it, in waves that keep the ICA's order of contacts (see
  :meth:`ZenohDrivers._waves`). Deterministic, the same decisions as the
  embedded runner, and as fast as the slowest participant.
* ``realtime``: steps are paced to the wall clock times ``--speed``; whatever
  commands have arrived are applied, late ones at the next step. A confirmed
  vehicle's command holds its whole speed profile, so it is flown on time.

Agents announce themselves with liveliness tokens; a token that disappears
mid-run (a killed process) stops the run with an error naming the agent.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter

import numpy as np

from schemas import keys
from schemas.codec import DecodeError, decode, encode, now_ns
from schemas.link import Inbox, Item, publisher
from schemas.messages import Clock, Command, State, VehicleState
from sim_gateway.embedded import ica_config, schedule_for
from sim_gateway.runconfig import RunConfig, RunError, RunResult
from sim_gateway.world import Seen, World
from vehicle_agent.machine import BIG, MODE_CONFIRMED
from vehicle_agent.machine import Command as Actuation

CLOCKS = ("lockstep", "realtime")


class ZenohDrivers:
    """The vehicles' decisions, made by agent processes reached over Zenoh."""

    def __init__(
        self,
        session,
        junction: str,
        cfg: RunConfig,
        *,
        agents: int,
        observers: int = 0,
        per_agent: int = 0,
        clock: str = "lockstep",
        speed: float = 1.0,
        step_timeout_s: float = 30.0,
        log: logging.Logger,
    ) -> None:
        if clock not in CLOCKS:
            raise RunError(f"unknown clock {clock!r}: use lockstep or realtime")
        if agents < 1:
            raise RunError("at least one vehicle agent is needed")
        self.session = session
        self.junction = junction
        self.cfg = cfg
        self.n_agents = agents
        self.n_observers = observers
        self.observers: set[str] = set()
        self.per_agent = per_agent
        self.clock = clock
        self.speed = speed
        self.step_timeout_s = step_timeout_s
        self.log = log
        self.inbox = Inbox()
        self.alive: set[str] = set()
        self.ica_alive = False
        self.owner: dict[str, str] = {}
        self.load: Counter[str] = Counter()
        self.hosted: Counter[str] = Counter()
        self.late_commands = 0
        self.multi_wave_steps = 0
        self.known: set[str] = set()  # vehicles their agent has seen (it has DETECTed them)
        self.wake: dict[str, float] = {}  # per vehicle: when it may next talk to the ICA
        self.dropped_setpoints = 0
        self.wait_s: list[float] = []
        self._pending: tuple[int, int, set[str], list[Actuation]] = (0, 0, set(), [])
        self.step_s = ica_config(cfg).step_s
        self._k = 0
        self._t0_wall = 0.0
        j = junction
        self._clock_pub = publisher(session, keys.clock(j))
        self._vehicles_pub = publisher(session, keys.vehicles(j))
        self.told_entered: set[str] = set()
        self._state_pubs: dict[str, object] = {}
        lv = session.liveliness()
        self._decls = [
            session.declare_subscriber(keys.command(j), self.inbox.sample_cb("command")),
            lv.declare_subscriber(
                keys.agent_alive(j), self.inbox.liveliness_cb("agent"), history=True
            ),
            lv.declare_subscriber(keys.ica_alive(j), self.inbox.liveliness_cb("ica"), history=True),
            lv.declare_subscriber(
                keys.observer_alive(j), self.inbox.liveliness_cb("observer"), history=True
            ),
        ]

    # -- start and end ---------------------------------------------------------
    def wait_for_peers(self, timeout_s: float) -> None:
        """Block until the ICA, every agent and every observer are up (liveliness), or fail."""
        deadline = time.monotonic() + timeout_s
        while (
            len(self.alive) < self.n_agents
            or not self.ica_alive
            or len(self.observers) < self.n_observers
        ):
            if self.inbox.stopping.is_set():
                raise RunError("stopped while waiting for the ICA and the agents")
            if time.monotonic() > deadline:
                raise RunError(
                    f"after {timeout_s:.0f} s: ICA {'up' if self.ica_alive else 'not up'}, "
                    f"{len(self.alive)} of {self.n_agents} vehicle agents and "
                    f"{len(self.observers)} of {self.n_observers} observers up"
                )
            item = self.inbox.get(timeout=0.1)
            if item is not None:
                self._note(item)
        self.log.info("ICA and %d agents up: %s", len(self.alive), ", ".join(sorted(self.alive)))
        self._t0_wall = time.monotonic()

    def end(self, t: float) -> None:
        self._clock_pub.put(encode(Clock(self._k, t, self.clock, True, now_ns())))

    def close(self) -> None:
        self._clock_pub.undeclare()
        self._vehicles_pub.undeclare()
        for p in self._state_pubs.values():
            p.undeclare()
        for d in self._decls:
            d.undeclare()

    # -- one step ----------------------------------------------------------------
    def send(self, t: float, seen: list[Seen]) -> None:
        """Publish this step's CLOCK and STATEs; in lockstep, every wave but the
        last is also answered here. :meth:`collect` gets the last answers."""
        out: list[Actuation] = []
        while (item := self.inbox.get(timeout=0)) is not None:
            self._take(item, None, out)  # liveliness news, and realtime's late commands
        if not self.ica_alive:
            raise RunError(f"the ICA is gone (t={t:.2f} s)")
        self._k += 1
        k = self._k
        self._clock_pub.put(encode(Clock(k, t, self.clock, False, now_ns())))
        stamp = now_ns()
        if self._vehicles_pub.matching_status.matching:  # an observer listens
            everyone = tuple(_vehicle_state(s, self.cfg) for s in seen)
            self._vehicles_pub.put(encode(State("", k, 0, t, everyone, stamp)))
        # a vehicle flying its confirmed plan needs its agent again only when it
        # enters the junction (crossing) and when it has left (hand back to SUMO)
        feed = [s for s in seen if self._needs_agent(s)]
        waves = self._waves(t, feed) if self.clock == "lockstep" else [self._batches(feed)]
        for part, batches in enumerate(waves):
            if part > 0:
                self._wait_commands(k, part - 1, set(waves[part - 1]), out, t)
            for agent, vehicles in batches.items():
                pub = self._state_pubs.get(agent)
                if pub is None:
                    pub = self._state_pubs[agent] = publisher(
                        self.session, keys.state(self.junction, agent)
                    )
                pub.put(encode(State(agent, k, part, t, tuple(vehicles), stamp)))
        if len(waves) > 1:
            self.multi_wave_steps += 1
        for s in feed:
            self.known.add(s.car.vin)
            if s.obs.exited:
                self.load[self.owner[s.car.vin]] -= 1
                self.known.discard(s.car.vin)
                self.wake.pop(s.car.vin, None)
                self.told_entered.discard(s.car.vin)
        self._pending = (k, len(waves) - 1, set(waves[-1]), out)

    def collect(self, t: float) -> list[Actuation]:
        """The commands to apply before the next step (lockstep: waits for them)."""
        k, part, expected, out = self._pending
        if self.clock == "lockstep":
            self._wait_commands(k, part, expected, out, t)
        else:
            self._drain(k, out, t)
            pace = self._t0_wall + k * self.step_s / self.speed - time.monotonic()
            if pace > 0:
                time.sleep(pace)
        return out

    def _needs_agent(self, s: Seen) -> bool:
        c = s.car
        if c.speed_mode != MODE_CONFIRMED or s.obs.exited:
            return True
        if c.entered and c.vin not in self.told_entered:
            self.told_entered.add(c.vin)
            return True
        return False

    def _batches(self, seen: list[Seen]) -> dict[str, list[VehicleState]]:
        batches: dict[str, list[VehicleState]] = {}
        for s in seen:
            agent = self.owner.get(s.car.vin) or self._assign(s.car.vin)
            batches.setdefault(agent, []).append(_vehicle_state(s, self.cfg))
        return batches

    def _waves(self, t: float, seen: list[Seen]) -> list[dict[str, list[VehicleState]]]:
        """This step's STATEs, in waves that keep the order of ICA contacts across agents.

        A vehicle talks to the ICA this step if it is new to its agent (it
        will DETECT) or its agent said it may (``wake_s``) and it is head of
        its lane. When such vehicles belong to more than one agent, the step
        is split: each run of consecutive contacts (in the world's order, the
        embedded runner's order) of one agent is a wave, and a wave is sent
        only after the previous one is answered. The ICA then sees DETECTs
        and REQUESTs in exactly the embedded runner's order, whatever the
        number of agents: lockstep runs are deterministic and equal to it.
        """
        runs: list[tuple[str, list[Seen]]] = []
        quiet: list[Seen] = []
        for s in seen:
            agent = self.owner.get(s.car.vin) or self._assign(s.car.vin)
            wake = self.wake.get(s.car.vin, -BIG)
            contact = s.car.vin not in self.known or (t >= wake and (s.obs.head or wake <= -BIG))
            if not contact:
                quiet.append(s)
            elif runs and runs[-1][0] == agent:
                runs[-1][1].append(s)
            else:
                runs.append((agent, [s]))
        if len(runs) <= 1:
            return [self._batches(seen)]
        waves: list[dict[str, list[VehicleState]]] = [
            {agent: [_vehicle_state(s, self.cfg) for s in run]} for agent, run in runs
        ]
        for s in quiet:  # no ICA contact: order does not matter, send them first
            waves[0].setdefault(self.owner[s.car.vin], []).append(_vehicle_state(s, self.cfg))
        return waves

    def _assign(self, vin: str) -> str:
        free = [
            a for a in sorted(self.alive) if not self.per_agent or self.load[a] < self.per_agent
        ]
        if not free:
            raise RunError(
                f"no vehicle agent has room for {vin}: {len(self.alive)} agents x "
                f"{self.per_agent} vehicles are all in use; start more agents or raise --per-agent"
            )
        agent = min(free, key=lambda a: (self.load[a], a))
        self.owner[vin] = agent
        self.load[agent] += 1
        self.hosted[agent] += 1
        return agent

    def _wait_commands(
        self, k: int, part: int, expected: set[str], out: list[Actuation], t: float
    ) -> None:
        start = time.perf_counter()
        deadline = time.monotonic() + self.step_timeout_s
        while expected:
            dead = expected - self.alive
            if dead:
                raise RunError(f"vehicle agent {', '.join(sorted(dead))} died at t={t:.2f} s")
            if self.inbox.stopping.is_set():
                raise RunError(f"stopped by a signal at t={t:.2f} s")
            item = self.inbox.get(timeout=min(0.5, max(deadline - time.monotonic(), 0.01)))
            if item is None:
                if time.monotonic() > deadline:
                    raise RunError(
                        f"no command for step {k} (t={t:.2f} s) from "
                        f"{', '.join(sorted(expected))} within {self.step_timeout_s:.0f} s"
                    )
                continue
            answered = self._take(item, (k, part), out)
            if answered is not None:
                expected.discard(answered)
        self.wait_s.append(time.perf_counter() - start)

    def _drain(self, k: int, out: list[Actuation], t: float) -> None:
        while (item := self.inbox.get(timeout=0)) is not None:
            self._take(item, (k, 0), out)
        gone = set(self.owner.values()) - self.alive
        if gone & {a for a, n in self.load.items() if n > 0}:
            raise RunError(f"vehicle agent {', '.join(sorted(gone))} died at t={t:.2f} s")

    def _take(self, item: Item, wanted: tuple[int, int] | None, out: list[Actuation]) -> str | None:
        """Handle one inbox item; the agent, if it was its command for (step, part) ``wanted``."""
        if item.what != "command":
            self._note(item)
            return None
        try:
            cmd = decode(item.payload, Command)
        except DecodeError as e:
            self.log.warning("dropped a bad command on %s: %s", item.key, e)
            return None
        on_time = wanted is not None and (cmd.step, cmd.part) == wanted
        if not on_time:
            self.late_commands += 1
        for sp in cmd.setpoints:
            if self.owner.get(sp.vin) != cmd.agent:
                self.dropped_setpoints += 1  # not this agent's vehicle
                continue
            self.wake[sp.vin] = sp.wake_s
            out.append(Actuation(sp.vin, sp.t0_s, sp.speeds, sp.speed_mode, sp.wake_s))
        return cmd.agent if on_time else None

    def _note(self, item: Item) -> None:
        name = item.key.rsplit("/", 1)[-1]
        up = item.payload == b"+"
        if item.what == "agent":
            if up:
                self.alive.add(name)
            else:
                self.alive.discard(name)
                self.log.error("vehicle agent %s is gone", name)
        elif item.what == "observer":
            (self.observers.add if up else self.observers.discard)(name)
        elif item.what == "ica":
            self.ica_alive = up
            if not up:
                self.log.error("the ICA is gone")

    def facts(self) -> dict:
        w = np.array(self.wait_s) if self.wait_s else np.full(1, math.nan)
        return {
            "clock": self.clock,
            "speed": self.speed if self.clock == "realtime" else None,
            "agents": dict(sorted(self.hosted.items())),
            "late_commands": self.late_commands,
            "multi_wave_steps": self.multi_wave_steps,
            "dropped_setpoints": self.dropped_setpoints,
            "step_wait_median_ms": float(np.median(w) * 1e3),
            "step_wait_p99_ms": float(np.percentile(w, 99) * 1e3),
        }


def _vehicle_state(s: Seen, cfg: RunConfig) -> VehicleState:
    c, o = s.car, s.obs
    return VehicleState(
        vin=c.vin,
        route_id=c.route.id,
        lane=o.lane,
        dist_to_entry_m=float(o.dist_to_entry_m),
        speed_mps=float(o.speed_mps),
        x_m=float(s.xy[0]),
        y_m=float(s.xy[1]),
        angle_deg=float(s.angle_deg),
        length_m=cfg.length_m,
        width_m=cfg.width_m,
        max_speed_mps=float(c.entry_speed_mps),
        head=o.head,
        detected_s=float(o.detected_s),
        exited=o.exited,
    )


def run_gateway(
    session,
    cfg: RunConfig,
    inter,
    drivers: ZenohDrivers,
    *,
    peers_timeout_s: float = 60.0,
    progress=None,
) -> RunResult:
    """Run the world with the agents' decisions; the same result as an embedded run."""
    from sim_gateway.world import import_libsumo, start_sumo

    ls = import_libsumo()
    ica_cfg = ica_config(cfg)
    schedule, _spec, horizon = schedule_for(cfg, inter, ica_cfg.step_s)
    drivers.wait_for_peers(peers_timeout_s)
    cmd = start_sumo(ls, cfg, ica_cfg.step_s)
    try:
        world = World(ls, cfg, inter, ica_cfg, schedule, horizon, want_xy=True)
        try:
            while True:
                seen = world.step()
                drivers.send(world.t, seen)
                world.end_step(progress)  # while the agents decide
                world.apply(drivers.collect(world.t))
                if world.done():
                    break
        finally:
            drivers.end(world.t)
        result = world.result({}, cmd)
        result.extra.update(drivers.facts())
        return result
    finally:
        ls.close()
