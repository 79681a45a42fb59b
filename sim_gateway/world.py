"""The SUMO side of a run, shared by the embedded runner and the cluster gateway.

The world steps SUMO and composes three jobs around it: reading what SUMO
says (:mod:`sim_gateway.sumo_io`), the traffic's insertion, detection and
accounting (:mod:`sim_gateway.traffic`), and each vehicle's actuator
(:mod:`sim_gateway.actuator`), the on-board part of a connected vehicle that
stops it short of the junction unless it holds a plan it can still fly. Each
step it inserts who is due, observes every vehicle in the region for its
driver, applies the drivers' commands, and feeds the independent safety
monitor and the trip log. Who decides the commands (vehicle machines in this
process, or vehicle-agent processes over Zenoh) is not its business, so both
modes measure and check with exactly this code.

What it keeps of a junction lives in a :class:`~sim_gateway.junction.Junction`;
the world holds one, or several along a route file's net (each under its own
ICA, :mod:`sim_gateway.network`): a vehicle is one junction's from its region
until its rear is out, then SUMO's driver's until the next junction's region.

Nothing here trusts the ICA for safety: every step the monitor rebuilds
rectangles from SUMO's own positions, and SUMO's junction collision detection
gives a second opinion.
"""

from __future__ import annotations

import bisect
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from dica.ica.core.config import IcaConfig
from dica.ica.core.envelope import human_limits
from dica.ica.core.intersection import Intersection
from dica.sim_gateway.actuator import Actuator
from dica.sim_gateway.demand import Arrival
from dica.sim_gateway.detour import Detours
from dica.sim_gateway.humans import SignalHeads, define_human_type
from dica.sim_gateway.insertion import InsertionHold
from dica.sim_gateway.junction import Car, Junction, Seen
from dica.sim_gateway.lights_off import switch_off
from dica.sim_gateway.metrics import TripLog, summarize
from dica.sim_gateway.network_gate import NetworkGate
from dica.sim_gateway.route_file import (
    MAX_LENGTH_M,
    check_arrivals,
    check_link_room,
    check_stops_and_starts,
    check_types,
    loaded_size,
    note_moved_lines,
    read_route_file,
)
from dica.sim_gateway.runconfig import RunConfig, RunError, RunResult
from dica.sim_gateway.safety import PersonCheck, merge_reports
from dica.sim_gateway.sumo_io import People, Reads
from dica.sim_gateway.traffic import Traffic, define_vehicle_types
from dica.sim_gateway.walkers import Walkers, check_sidewalks, draw_legs, kerbs
from dica.vehicle_agent.actuation import MODE_CONFIRMED, Actuation
from dica.vehicle_agent.machine import Observation


class World:
    """SUMO through libsumo, for one junction and one vehicle schedule, or for several
    junctions of a route file's net (``more``: the others' intersections)."""

    def __init__(
        self,
        ls,
        cfg: RunConfig,
        inter: Intersection,
        ica_cfg: IcaConfig,
        schedule: list[Arrival],
        horizon: float,
        *,
        signalised: bool = False,
        want_xy: bool = False,
        predict_s: float = 0.0,
        more: tuple[Intersection, ...] = (),
    ) -> None:
        self.ls = ls
        self.cfg = cfg
        self.ica_cfg = ica_cfg
        self.h = ica_cfg.step_s
        self.horizon = horizon
        self.want_xy = want_xy
        self.log = TripLog()
        self.t = 0.0
        self.sumo_collisions = 0  # SUMO's reports on the junction's own lanes
        self.sumo_collisions_elsewhere = 0
        # the first of SUMO's reports in full (who, where, what kind): a count alone
        # does not say where to look
        self.sumo_collision_log: list[dict] = []
        self._last_sample = -1.0
        self._taken: set[str] = set()  # inserted this step and taken back out (insertion)
        self._t_wall = time.perf_counter()
        # a route file's insertions wait while a vehicle is about to leave a junction onto
        # their road (sim_gateway/insertion.py)
        self.hold: InsertionHold | None = None
        # a route file's net of several junctions: how much queue its links may hold
        self.gate: NetworkGate | None = None
        self.gate_holds = 0  # steps a vehicle at a region's head waited for the gate's room
        # whether the ICAs' answers may arrive steps after their vehicles asked (the
        # real-time cluster): then an insertion onto a guarded link leaves their room
        self.answers_in_flight = False
        rf = None
        if cfg.routes_path:
            rf = read_route_file(Path(cfg.routes_path))
            check_types(ls, rf, ica_cfg.kinematics)
            check_arrivals(ls, rf, (inter, *more))
            size = loaded_size(ls, rf)
            longest = size[0]
            if not signalised:
                # stops and starts where the plans would run into them; links that cannot
                # hold a vehicle beyond the junction; then, nothing refused, what to know
                check_stops_and_starts(ls, rf, (inter, *more), longest, ica_cfg.kinematics)
                check_link_room((inter, *more), longest, ica_cfg.kinematics.decel_mps2)
                for line in note_moved_lines(rf, (inter, *more), size, ica_cfg.kinematics):
                    print(f"note: {line}", file=sys.stderr)
            if not signalised and cfg.network_gate:  # lights hold no vehicle for room
                self.gate = NetworkGate(
                    (inter, *more), longest, ica_cfg.kinematics.decel_mps2, cfg.network_gate_rule
                )
            self.hold = InsertionHold(ls, rf, self.gate)
        define_vehicle_types(ls, ica_cfg, cfg.length_m, cfg.width_m, any(v.ev for v in schedule))
        # human drivers (--cav-share below 1): SUMO's own, each with a signal head at its line
        self.heads: SignalHeads | None = None
        self.human_seen: list[Seen] = []  # this step's, apart from the connected vehicles
        # (a route file's share of them is drawn as each departs: Traffic.draws_human)
        humans = any(v.human for v in schedule) or (cfg.routes_path and cfg.cav_share < 1.0)
        if humans:
            limits = human_limits(ica_cfg.caps.road_mps, ica_cfg.green_late_s)
            define_human_type(ls, limits, cfg.length_m, cfg.width_m, ignore_foes=not signalised)
        self.junctions = [
            Junction.open(
                ls,
                x,
                schedule if x is inter else [],
                signalised=signalised,
                length_m=cfg.length_m,
                max_length_m=MAX_LENGTH_M if cfg.routes_path else None,
            )
            for x in (inter, *more)
        ]
        self.junction = self.junctions[0]
        if humans:
            self.heads = SignalHeads(ls, self.junction, limits, self.h, cfg.seed, not signalised)
        self.traffic = Traffic(ls, ica_cfg, cfg.length_m, self.log)
        if cfg.routes_path:
            self.traffic.human_share, self.traffic.seed = 1.0 - cfg.cav_share, cfg.seed
        if cfg.routes_path and not signalised:  # none of them serves a U-turn
            served = frozenset(j.inter.junction_id for j in self.junctions)
            self.traffic.detours = Detours(cfg.net_path, served)
        self.traffic.register(self.junction)
        self._arrivals = [v.arrival_s for v in schedule]
        # people on foot (--peds): put in, held at the kerb under an ICA, measured
        self.walkers: Walkers | None = None
        self.sumo_person_collisions = 0  # SUMO's vehicle-person reports at the junctions
        self.sumo_person_collisions_elsewhere = 0  # at junctions SUMO drives, on their roads
        people = rf.people if rf is not None else 0
        if not signalised and (self.heads is not None or cfg.peds_per_h > 0 or people):
            # SUMO's drivers and walkers obey a light the net gives the junction: off
            ids = [j.inter.junction_id for j in self.junctions]
            for line in switch_off(ls, ids):
                print(f"note: {line}", file=sys.stderr)
        if people and len(self.junctions) > 1:
            raise RunError(
                f"route file {cfg.routes_path} has {people} people on foot: several junctions "
                "serve walkers not yet; give one --junction, or leave them out"
            )
        if cfg.peds_per_h > 0 or people:
            if not signalised:
                size = loaded_size(ls, rf) if rf is not None else (cfg.length_m, cfg.width_m)
                for j in self.junctions:
                    check_sidewalks(Path(cfg.net_path), j.inter, *size)
            self.walkers = self._walkers(signalised, schedule)
        # how far ahead [s] each vehicle that may ask is told where its own control law will
        # take it (Observation.intent_m): as far as its agents plan ahead (their lead)
        self.actuator = Actuator(ls, ica_cfg, self.log, predict_s, shared=bool(cfg.routes_path))

    def _walkers(self, signalised: bool, schedule: list[Arrival]) -> Walkers:
        ends: dict = {}
        for j in self.junctions:
            j.person_check = PersonCheck(j.inter.region)
            if not self.cfg.peds_per_h:
                continue  # a route file's people only: they walk their own ways
            if not j.inter.crosswalks:
                raise RunError(
                    f"--peds: junction {j.inter.junction_id} has no pedestrian crossings (a "
                    "net with sidewalks and crossings has them, e.g. --layout ch45-walk)"
                )
            ends.update(kerbs(self.ls, j.inter))
        if self.cfg.peds_per_h and not any(a and b for a, b in ends.values()):
            raise RunError("--peds: no crossing has a sidewalk at both ends to walk from and to")
        until = self.horizon if math.isfinite(self.horizon) else max(self._arrivals, default=0.0)
        legs = draw_legs(ends, self.cfg.peds_per_h, until, self.cfg.seed)
        return Walkers(self.ls, tuple(j.inter for j in self.junctions), legs, hold=not signalised)

    # the world's totals: over its junctions
    @property
    def crossed(self) -> int:
        return sum(j.crossed for j in self.junctions)

    @property
    def waiting(self) -> int:
        return sum(j.waiting for j in self.junctions)

    @property
    def unconfirmed_entries(self) -> list[str]:
        return [vin for j in self.junctions for vin in j.unconfirmed_entries]

    # -- one step ------------------------------------------------------------
    def step(self) -> list[Seen]:
        """Insert who is due, step SUMO, and observe every vehicle in the region."""
        return self.step_each()[0]

    def step_each(self) -> list[list[Seen]]:
        """:meth:`step` for every junction: what each junction's region holds."""
        ls, first = self.ls, self.junction
        for j in self.junctions:
            j.forget_gone()
        fresh = self.traffic.insert_due(first, self.t)
        # what answers in flight may take: nothing counted changes until the next measure
        in_flight = self.in_flight_rooms() if self.hold is not None else {}
        if self.hold is not None:
            self.hold.before_step(self.junctions, in_flight)
        try:
            ls.simulation.step()
        except ls.FatalTraCIError as e:  # SUMO cannot go on (a route file's clash it meets)
            raise RunError(f"SUMO stopped at {self.t:g} s: {' '.join(str(e).split())}") from None
        departed = ls.simulation.getDepartedIDList()
        taken = self.hold.after_step(departed, in_flight) if self.hold else set()
        self._taken = taken
        self.traffic.note_blocked(first, fresh)
        t = self.t = ls.simulation.getTime()
        people = self.walkers.people if self.walkers is not None else {}
        for hit in ls.simulation.getCollisions():
            if len(self.sumo_collision_log) < 50:
                self.sumo_collision_log.append(
                    {
                        "t": round(t, 2), "collider": hit.collider, "victim": hit.victim,
                        "type": hit.type, "lane": hit.lane, "pos": round(hit.pos, 1),
                        "collider_mps": round(hit.colliderSpeed, 2),
                        "victim_mps": round(hit.victimSpeed, 2),
                        "collider_state": self._state_of(hit.collider),
                        "victim_state": self._state_of(hit.victim),
                    }
                )  # fmt: skip
            if hit.victim in people or hit.collider in people:
                if any(j.covers(hit.lane) or j.borders(hit.lane) for j in self.junctions):
                    self.sumo_person_collisions += 1
                else:  # a junction the net's own control runs, or a road away from ours
                    self.sumo_person_collisions_elsewhere += 1
            elif any(j.covers(hit.lane) for j in self.junctions):
                self.sumo_collisions += 1
            else:  # a route file's net beyond the junctions, driven by SUMO alone
                self.sumo_collisions_elsewhere += 1
        if self.walkers is not None:
            self.walkers.step(t)
        present = set(ls.vehicle.getIDList())
        for vin in departed:
            if vin in taken:
                continue
            if self.traffic.departed(first, vin, t):
                Reads.subscribe(ls, vin, self.want_xy)
                if self.heads is not None and first.cars[vin].human:
                    self.heads.departed(first.cars[vin])
            elif self.heads is not None and self.traffic.draws_human(vin):
                self.heads.as_human(vin)
        if self.cfg.routes_path:
            # a vehicle is one junction's at a time: the next takes it once the last let go
            held = {c.sumo for j in self.junctions for c in j.active if not c.exited}
            for j in self.junctions:
                for c in self.traffic.adopt(j, t, held):
                    Reads.subscribe(ls, c.sumo, self.want_xy)
                    held.add(c.sumo)
                    if c.human and self.heads is not None:
                        self.heads.departed(c)
            for j in self.junctions:  # beyond a junction its vehicles go on, and may queue
                j.measure_room()
                j.note_strangers(ls)
            if self.gate is not None:
                self.gate.forget(ls.simulation.getArrivedIDList())
                self.gate.measure(ls, self.junctions)
        vw = Reads(ls)
        each = [self._look(j, vw, present, t) for j in self.junctions]
        if self.heads is not None:  # the human drivers apart: no machine drives them
            self.human_seen = [s for s in each[0] if s.car.human]
            each[0] = [s for s in each[0] if not s.car.human]
            for s in self.human_seen:  # a route file's, sent another way: on to where it goes
                c = s.car
                if c.exited and c.reroute_to is not None and not c.released:
                    ls.vehicle.changeTarget(c.sumo, c.reroute_to)
                    c.released = True
            if self.heads.hold:
                self.heads.audit(self.human_seen, t)
        if self.actuator.predict_steps:
            for j, seen in zip(self.junctions, each, strict=True):
                self._tell_intents(j, seen, t)
        return each

    def _look(self, j: Junction, vw: Reads, present: set[str], t: float) -> list[Seen]:
        """Every vehicle in ``j``'s region, as its driver observes it this step."""
        self.traffic.note_tails(j, vw, present)
        j.order_lanes(vw, present)
        j.waiting = 0
        seen = []
        for c in j.active:
            s = self._see(j, c, vw, t) if c.sumo in present else None
            if s is not None:
                seen.append(s)
        if self.want_xy:
            for s in seen:
                s.xy = vw.getPosition(s.car.sumo)
                s.angle_deg = vw.getAngle(s.car.sumo)
        j.present = present
        return seen

    def _tell_intents(self, j: Junction, seen: list[Seen], t: float) -> None:
        """Tell each vehicle that may ask and holds no plan where its actuator will take
        it over the next steps (:meth:`Actuator.intents`)."""
        intents = self.actuator.intents(j, t)
        for s in seen:
            fut = intents.get(s.car.vin)
            if fut is not None and s.obs.may_ask and s.car.plan_s is None:
                s.obs = replace(s.obs, intent_m=tuple(fut[1:].tolist()))

    def _see(self, j: Junction, c: Car, vw: Reads, t: float) -> Seen | None:
        """``c`` as its driver observes it this step; None while it is short of the region."""
        lane = vw.getLaneID(c.sumo)
        on_approach = lane == c.route.in_lane
        if math.isnan(c.detected_s):
            if not self.traffic.detect(j, c, lane, vw, t):
                return None
            if j.signalised:  # in the region SUMO's driver drives as it likes
                self.actuator.release(c)
        speed = vw.getSpeed(c.sumo)
        odo = vw.getDistance(c.sumo)
        lane_pos = vw.getLanePosition(c.sumo) if on_approach else math.nan
        c.locate(lane, lane_pos, j.lane_len_m[c.route.in_lane], odo)
        d = j.lane_len_m[c.route.in_lane] - vw.getLanePosition(c.sumo)
        # past a line moved back (Route.line_back_m) a vehicle is in the junction, though
        # SUMO still has it on its incoming lane
        on_approach = on_approach and (d >= 0.0 or c.route.line_back_m == 0.0)
        c.speed_mps = speed
        if not c.entered and not on_approach:
            self._entered(j, c, t)
        self.traffic.note_speed(j, c, speed)
        self.traffic.left_junction(j, vw, c, t)
        # behind a vehicle that is not the junction's, a vehicle neither asks nor follows
        clear = not (j.strangers and j.stranger_ahead(c))
        c.head = on_approach and c.ahead is None and clear
        follows = (
            self.ica_cfg.platoon
            and c.plan_s is None  # one that holds a plan does not ask
            and on_approach
            and clear
            and self.actuator.may_follow(c, speed, t)
        )
        obs = Observation(
            t_s=t,
            lane=lane,
            dist_to_entry_m=d if on_approach else -1.0,
            speed_mps=speed,
            head=c.head,
            detected_s=c.detected_s,
            exited=c.exited,
            plan_seq=c.plan_seq,
            refused_seq=c.refused_seq,
            kept_seq=c.kept_seq,
            follows=follows,
            exit_room_m=j.room_of(self.ls, c.route.out_lane) if on_approach else math.inf,
            network_room_m=self.network_room(c),
        )
        return Seen(c, obs)

    def _state_of(self, sumo_id: str) -> list[dict]:
        """Each junction's record of a vehicle SUMO reports in a collision: what the
        roadside had it doing, with its plan's positions about now (for the collision
        log, never for a decision)."""
        out = []
        for j in self.junctions:
            for c in j.cars.values():
                if c.sumo != sumo_id:
                    continue
                plan_now = None
                if c.plan_s is not None:
                    k = round((self.t - c.plan_t0_s) / self.h)
                    plan_now = [round(float(x), 2) for x in c.plan_s[max(k - 2, 0) : k + 3]]
                out.append(
                    {
                        "junction": j.inter.junction_id, "vin": c.vin, "mode": c.speed_mode,
                        "head": c.head, "ahead": c.ahead.vin if c.ahead else None,
                        "entered": c.entered, "exited": c.exited, "s_m": _finite(c.s_m),
                        "seq": c.plan_seq, "refused": c.refused_seq, "kept": c.kept_seq,
                        "plan_t0_s": _finite(c.plan_t0_s), "plan_now": plan_now,
                    }
                )  # fmt: skip
        return out

    def network_room(self, c: Car) -> float:
        """The room the network gate has left for ``c`` (inf: its crossing does not take
        it into a network of junctions whose links form a cycle)."""
        g = self.gate
        if g is None or not g.closes or not g.takes(self.ls, c):
            return math.inf
        return g.room_for(self.ls, c)

    def refresh_network_room(
        self, j: Junction, seen: list[Seen], pending: Mapping[str, float] | None = None
    ) -> None:
        """Before ``j``'s vehicles ask: tell the ones entering the network what room the
        junctions that answered before it this step have left, less ``pending`` (per
        room, what ICAs answering at the same time may be letting in,
        :meth:`pending_network`; a vehicle's own length is not held against it)."""
        g = self.gate
        if g is None or not g.closes:
            return
        for s in seen:
            if g.takes(self.ls, s.car):
                room = g.room_besides(self.ls, s.car, pending or {})
                s.obs = replace(s.obs, network_room_m=room)
                if s.obs.may_ask and s.car.plan_s is None and room < g.need_m(self.ls, s.car.sumo):
                    self.gate_holds += 1  # it may ask, and will be told no_room

    def may_enter_network(self, seen: Sequence[Seen]) -> bool:
        """Whether any of these vehicles' crossings takes it into a network the gate
        guards (its junction's answers may change the room the next one is told)."""
        g = self.gate
        return g is not None and g.closes and any(g.takes(self.ls, s.car) for s in seen)

    def pending_network(self, each: Sequence[Sequence[Seen]]) -> dict[str, float]:
        """Per room of the gate, the queue length of every vehicle now asking to enter the
        network and not let in yet, at every junction: where the junctions' ICAs answer
        at the same time (the real-time cluster), each tells its vehicles the room less
        all of these, so that together they cannot let in more than the gate holds."""
        g = self.gate
        if g is None or not g.closes:
            return {}
        return g.pending_rooms(self.ls, (s.car for seen in each for s in seen))

    def in_flight_rooms(self) -> dict[str, float]:
        """Per room of the gate, what vehicles whose answer may still be travelling could
        take of it: every vehicle at any junction entering the network and not let in
        yet (only where answers travel while the world steps on: ``answers_in_flight``).
        A route file's insertion onto a guarded link waits for room less these."""
        g = self.gate
        if not self.answers_in_flight or g is None or not g.closes:
            return {}
        return g.pending_rooms(self.ls, (c for j in self.junctions for c in j.active))

    def counted_confirmed(self, j: Junction) -> None:
        """After ``j``'s ICA answered: the vehicles it let into the network take room."""
        if self.gate is not None:
            self.gate.count_confirmed(self.ls, j)

    def _entered(self, j: Junction, c: Car, t: float) -> None:
        """``c``'s front has just passed the entry line: it must be flying its plan."""
        c.entered = True
        j.last_in[c.route.in_lane] = c
        if c.human:
            return  # its own light and envelope say whether it may (the audit checks)
        if not j.signalised and c.speed_mode != MODE_CONFIRMED:
            j.unconfirmed_entries.append(c.vin)  # never: the vehicles must stop
        elif c.plan_s is not None:
            self.actuator.timing.entered(c, t, self.h)

    def apply(self, commands: Iterable[Actuation], j: Junction | None = None) -> None:
        """Carry out the drivers' commands and drive every vehicle in the region (of
        ``j``, by default the first junction) for one step (:meth:`Actuator.apply`)."""
        self.actuator.apply(j or self.junction, commands, self.t)

    def end_step(self, progress: Callable[[float, int, int], None] | None = None) -> None:
        """Check and log this step. Needs nothing from the drivers, so the cluster
        gateway runs it while the agents are deciding."""
        w = self.walkers
        for j in self.junctions:
            people = None if w is None else People(j.person_check, w.present, w.xy, w.radius_m)
            j.watch.feed(self.ls, j.monitor, self.t, self._taken, people)
        if self.t - self._last_sample >= 1.0 - 1e-9:
            generated = (
                sum(len(j.cars) for j in self.junctions)
                if self.cfg.routes_path
                else bisect.bisect_right(self._arrivals, self.t + 1e-9)
            )
            self.log.sample(self.t, self.waiting, self.crossed, generated)
            self._last_sample = self.t
        if progress is not None:
            progress(self.t, self.waiting, self.crossed)

    def emptied(self, after_s: float | None) -> bool:
        """Whether ``after_s`` is past and every vehicle has left (none in SUMO, none
        due, none held out of it)."""
        if after_s is None or self.t < after_s:
            return False
        held = self.hold.held if self.hold is not None else ()
        return not held and self.ls.simulation.getMinExpectedNumber() == 0

    def waiting_to_enter(self) -> int:
        """Vehicles due that SUMO has not inserted yet (or the hold keeps out)."""
        return len(self.waiting_ids())

    def waiting_ids(self) -> set[str]:
        """The ids of :meth:`waiting_to_enter`'s vehicles."""
        held = {h.vid for h in self.hold.held} if self.hold is not None else set()
        return set(self.ls.simulation.getPendingVehicles()) | held

    def done(self) -> bool:
        scheduled = len(self.junction.schedule)
        if self.cfg.until_left:
            if self.crossed >= scheduled:
                return True
            if self.t > 20.0 * scheduled + 600.0:
                raise RunError(
                    f"{scheduled - self.crossed} vehicles never left (stopped at t={self.t:.0f} s)"
                )
            return False
        return self.t >= self.horizon - 1e-9

    def result(self, requests: dict, cmd: list[str]) -> RunResult:
        end = self.t if self.cfg.until_left else self.horizon
        reports = [j.monitor.report() for j in self.junctions]
        accounted = [self.traffic.accounting(j, end) for j in self.junctions]
        extra = {
            "unconfirmed_entries": len(self.unconfirmed_entries),
            "stood_inside": sum(len(j.stood_inside) for j in self.junctions),
            "timing": self.actuator.timing.as_dict(),
            "accounted": {k: sum(a[k] for a in accounted) for k in accounted[0]},
        }
        if self.sumo_collision_log:
            extra["sumo_collision_log"] = self.sumo_collision_log
        if self.hold is not None:
            extra["rerouted"] = self.traffic.rerouted
            extra["ended_short"] = self.traffic.ended_short
            extra["insertions_held"] = self.hold.holds
            extra["insertions_not_held"] = self.hold.unheld
            extra["sumo_collisions_elsewhere"] = self.sumo_collisions_elsewhere
            extra["longest_standstill_s"] = self.log.longest_standstill_s()
        if self.gate is not None and self.gate.closes:
            g = self.gate
            extra["network_gate"] = {
                "rule": g.rule,
                "capacity_m": round(g.capacity_m, 1),
                "least_link_capacity_m": round(min(g.link_capacity_m.values()), 1),
                "guarded_links": len(g.guarded),
                "peak_m": round(g.peak_m, 1),
                "peak_share": round(g.peak_share, 3),
                "links": len(g.links),
                # vehicle-seconds that vehicles free to ask spent refused room by the gate
                "vehicle_s_held": round(self.gate_holds * self.h, 1),
            }
        if self.heads is not None:
            extra["humans"] = self.heads.summary()
            if self.cfg.routes_path:  # drawn human, but seen too fast to stop at a head
                extra["humans"]["kept_connected_too_fast"] = self.traffic.humans_too_fast
        persons = None
        if self.walkers is not None:
            checks = [j.person_check.report() for j in self.junctions]
            closest = min(checks, key=lambda r: r.min_gap_m)
            extra["walkers"] = {
                **self.walkers.summary(end),
                "per_hour_per_crossing": self.cfg.peds_per_h,
                "person_hits": sum(r.hits for r in checks),
                "person_hit_pairs": sorted(p for r in checks for p in r.hit_pairs)[:100],
                "min_person_gap_m": closest.as_dict()["min_gap_m"],
                "min_person_gap_pair": closest.as_dict()["min_gap_pair"],
                "sumo_person_collisions": self.sumo_person_collisions,
                "sumo_person_collisions_elsewhere": self.sumo_person_collisions_elsewhere,
            }
            persons = self.walkers.rows()
        if len(self.junctions) > 1:
            extra["junctions"] = {
                j.inter.junction_id: {
                    "crossed": j.crossed,
                    "overlaps": r.overlaps,
                    "min_gap_m": r.as_dict()["min_gap_m"],
                    "unconfirmed_entries": len(j.unconfirmed_entries),
                    "stood_inside": len(j.stood_inside),
                    "accounted": a,
                }
                for j, r, a in zip(self.junctions, reports, accounted, strict=True)
            }
        return RunResult(
            metrics=summarize(self.log, end),
            trips=self.log,
            safety=merge_reports(reports).as_dict(),
            requests=requests,
            sumo_collisions=self.sumo_collisions,
            sim_time_s=self.t,
            begin_s=self.cfg.begin_s,
            wall_s=time.perf_counter() - self._t_wall,
            sumo_command=cmd,
            extra=extra,
            persons=persons,
        )


def _finite(x: float) -> float | None:
    """``x`` rounded for a JSON log, or None when it is not a number (no NaN in JSON)."""
    return round(x, 2) if math.isfinite(x) else None
