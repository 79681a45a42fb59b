"""A network of junctions over Zenoh: the gateway's side of ``dica gateway --junctions``.

Each junction has its own ICA process on ``dica/<j>/...`` and its own
:class:`~sim_gateway.gateway.ZenohDrivers` on ``sim/<j>/...``; the agents serve
every junction and share one :class:`~sim_gateway.gateway.Fleet`, so a vehicle
keeps its agent from one junction to the next. The routers between them (one per
roadside unit, in a mesh) are Zenoh's business: nothing here forwards anything.

In lockstep the junctions decide in the embedded runner's order, and the network
gate counts what each let in before the next one whose vehicles may enter the
network is asked (as :func:`sim_gateway.network.run_network` does with the ICA
cores in one process); junctions with no such vehicle this step are asked
together with the one before: the run equals the embedded one. In real time every
junction's states go out first and the answers are taken as they come; since no
junction then knows what the others are letting in, each tells its vehicles
entering the network the gate's room less every other vehicle asking to enter
anywhere, room by room (:meth:`~sim_gateway.world.World.pending_network`), and a
route file's insertion onto a guarded link leaves the room of every vehicle whose
answer may still be on its way (:meth:`~sim_gateway.world.World.in_flight_rooms`):
a vehicle holds its room from the moment it may ask, not once its yes arrives.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from dica.sim_gateway.gateway import PREDICT_S, ZenohDrivers
from dica.sim_gateway.junction import Seen
from dica.sim_gateway.runconfig import RunError, RunResult
from dica.sim_gateway.world import World


class Cluster:
    """Every junction's decisions, made by ICA and agent processes over Zenoh."""

    def __init__(
        self,
        drivers: Sequence[ZenohDrivers],
        *,
        peers_timeout_s: float = 60.0,
        checkpoint: Callable[[RunResult, str | None], None] | None = None,
        checkpoint_every_s: float = 30.0,
    ) -> None:
        if not drivers:
            raise RunError("a network needs at least one junction")
        self.drivers = list(drivers)
        self.lockstep = drivers[0].clock == "lockstep"
        self.peers_timeout_s = peers_timeout_s
        self._checkpoint = checkpoint
        self.every_s = checkpoint_every_s
        self.next_s = checkpoint_every_s
        self.ended = False

    @property
    def predict_s(self) -> float:
        """How far ahead each asker is told where its actuator takes it (as the single
        junction's gateway: the agents' lead in real time, the run's lead in lockstep)."""
        return self.drivers[0].cfg.lead_s if self.lockstep else PREDICT_S

    def wait_for_peers(self) -> None:
        """Every junction's ICA, the agents and the observers up, or a RunError."""
        for d in self.drivers:
            d.wait_for_peers(self.peers_timeout_s)

    def decide(self, world: World, each: list[list[Seen]]) -> None:
        """This step's plans from every junction, applied to the world."""
        pairs = list(zip(world.junctions, self.drivers, each, strict=True))
        if self.lockstep:
            # in the embedded order; a junction whose vehicles may enter the network waits
            # for the answers of every such junction before it (the room they leave), the
            # others go out with them: the same decisions, fewer round trips in a row
            asked: list[tuple] = []
            entering = False
            for j, d, seen in pairs:
                enters = world.may_enter_network(seen)
                if enters and entering:
                    self._collect(world, asked)
                    asked, entering = [], False
                world.refresh_network_room(j, seen)
                d.send(world.t, seen)
                asked.append((j, d))
                entering = entering or enters
            self._collect(world, asked)
            return
        world.answers_in_flight = True
        pending = world.pending_network(each)
        for j, d, seen in pairs:
            world.refresh_network_room(j, seen, pending)
            d.send(world.t, seen)
        for j, d, _ in pairs:
            world.apply(d.collect(world.t), j)
            world.counted_confirmed(j)

    @staticmethod
    def _collect(world: World, asked: list[tuple]) -> None:
        for j, d in asked:
            world.apply(d.collect(world.t), j)
            world.counted_confirmed(j)

    def checkpoint(self, world: World, cmd: list[str]) -> None:
        """What the run knows so far, every ``checkpoint_every_s`` of sim time."""
        if self._checkpoint is not None and world.t >= self.next_s:
            self._checkpoint(self._result(world, cmd), f"running: checkpoint at t={world.t:.0f} s")
            self.next_s += self.every_s

    def stopped(self, world: World, cmd: list[str], e: BaseException) -> None:
        """The run stops early: say so in the outputs, and tell the roles."""
        if self._checkpoint is not None and isinstance(e, (RunError, KeyboardInterrupt)):
            why = f"stopped at t={world.t:.2f} s: {e or 'interrupted'}"
            self._checkpoint(self._result(world, cmd), why)
        self._end(world.t)

    def finish(self, world: World, result: RunResult) -> None:
        """The roles' own figures into the result, then the end of the run to them all."""
        self._add_facts(result)
        result.extra["roles"] = {d.junction: d.role_stats() for d in self.drivers}
        self._end(world.t)

    def _end(self, t: float) -> None:
        if not self.ended:
            self.ended = True
            for d in self.drivers:
                d.end(t)

    def _result(self, world: World, cmd: list[str]) -> RunResult:
        res = world.result({}, cmd)
        self._add_facts(res)
        return res

    def _add_facts(self, result: RunResult) -> None:
        facts = {d.junction: d.facts() for d in self.drivers}
        first = next(iter(facts.values()))
        result.extra.update(
            clock=first["clock"],
            speed=first["speed"],
            agents=first["agents"],  # the shared fleet's: every junction says the same
            adoptions=first["adoptions"],
            agent_deaths=max(f["agent_deaths"] for f in facts.values()),
            ica_outages=sum(f["ica_outages"] for f in facts.values()),
        )
        per = result.extra.setdefault("junctions", {})
        for j, f in facts.items():
            per.setdefault(j, {})["cluster"] = f
