"""DICA and enhanced DICA: confirm a head vehicle's request against the confirmed set.

Algorithm 1 of the dissertation, with one change that a real vehicle needs:
``updateDTOT`` does not shift the requester's times (a vehicle that must
brake or stop cannot fly a shifted DTOT) but asks the planner for a new plan
from the state in the request that enters no earlier than the shifted entry
time. Entry times only grow, every step by at least one sample step, and past
the last confirmed vehicle's exit nothing is left to conflict with, so the loop
ends: the deadlock- and starvation-freedom arguments of chapter 3 carry over,
with the wait of a vehicle bounded by the exit time of the vehicles confirmed
before it. The rounds themselves are :class:`ica.core.search.Search`.

The class keeps the ICA's state: per-lane order of detected vehicles (to tell
head vehicles), the confirmed set and the answers already given (a repeated
request gets the same answer, never a second reservation). It does no I/O.

Over a real link a confirmation can reach its vehicle too late to be flown.
The vehicle then keeps stopping short of the line and asks again under a
higher sequence number, or cancels: either frees the unflown reservation
(until then it only blocks others, which is safe). Since the ICA cannot see
whether a vehicle flew its plan, a vehicle stays in its lane's queue until
its reservation ends, and the queue is ordered by the time each vehicle
crossed the region's entry line, so a vehicle that asks again (or announces
itself again) finds its place at the front. Every occupancy of a confirmed
vehicle can be padded in time by the declared tracking and latency bound
(``IcaConfig.time_pad_s``), the dissertation's remedy for imperfect links.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.conflict import (
    ConfirmedBatch,
    ConfirmedRows,
    Conflict,
    get_cv,
    get_cv_batch,
    pack,
)
from dica.ica.core.crosswalk import passage
from dica.ica.core.dtot import Dtot, build_dtot
from dica.ica.core.envelope import (
    ROLL_DECEL_MPS2,
    ROLL_NEAR_M,
    STOP_SHORT_M,
    DriverLimits,
    bounds_seen,
    envelope_dtot,
    first_reach,
    follow_delay,
    green_bounds,
    path_s,
)
from dica.ica.core.gridlock import QUEUE_GAP_M
from dica.ica.core.handover import Handover
from dica.ica.core.intersection import Intersection
from dica.ica.core.planner import Planner
from dica.ica.core.request import Confirmation, Reason, Rejection, Request, RequestError, Tss
from dica.ica.core.revocation import Answer, Reorder
from dica.ica.core.route import Route
from dica.ica.core.search import Found, Search, plan_entry
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.validate import check_request
from dica.ica.core.walk import (
    CLAIM_S,
    HOLD_AHEAD_S,
    WAIT_BOUND_S,
    Hold,
    WalkSlot,
    Walkways,
    hold,
)
from dica.ica.core.zones import ConflictTables, Shape

LEFT_MEMORY_S = 20.0  # [s] how long exit spacing remembers a vehicle that has left
ROOM_GAP_M = 2.5  # [m] standstill gap behind each vehicle queued on an exit lane (SUMO's)
ROOM_SLACK_M = 7.5  # [m] one car more: a vehicle may change into the lane beyond


@dataclass(frozen=True, slots=True)
class Green:
    """A human driver's green: from ``green_s`` it may take any of ``routes`` (the ids of
    its lane's), between its fastest and slowest crossing (:mod:`ica.core.envelope`),
    all of them reserved; ``keys`` name those reservations in the confirmed set."""

    vin: str
    green_s: float
    asked_s: float
    routes: tuple[str, ...]
    keys: tuple[str, ...]
    rounds: int
    near_m: float = STOP_SHORT_M  # how far short of its line it was when given it
    speed_mps: float = 0.0  # rolling towards its line at this speed (0: standing)


MAX_GREEN_ROUNDS = 10_000  # a green's search moves it later every round; past this, refused


@dataclass(frozen=True, slots=True, eq=False)
class Confirmed:
    vin: str
    dtot: Dtot  # intervals padded by 2 x time_pad_s: conflicts are judged against this
    confirmation: Confirmation
    packed: np.ndarray  # the DTOT's occupancies as rows for the batched getCV (pack)
    out_s: float  # when its rear leaves the junction, and at what speed (the exit rules)
    out_mps: float
    length_m: float  # the vehicle's (the room it takes on its exit lane)

    @classmethod
    def of(cls, vin: str, dtot: Dtot, confirmation: Confirmation, length_m: float) -> Confirmed:
        """Keep what each later request asks of this reservation, worked out once."""
        out_s, out_mps = float(dtot.t_s[-1]), dtot.exit_speed_mps
        return cls(vin, dtot, confirmation, pack(dtot), out_s, out_mps, length_m)


def _no_slower(new: Trajectory, old: Trajectory) -> bool:
    """``new`` is nowhere behind ``old``, nor slower, at ``new``'s samples: a follower
    kept clear of ``old`` as the slowest of a vehicle ahead stays clear of ``new``."""
    t = new.t_s
    ok_s = new.s_m >= np.interp(t, old.t_s, old.s_m) - 1e-6
    if len(new) < 2 or len(old) < 2:
        return bool(ok_s.all())
    v_new = np.diff(new.s_m) / new.step_s
    v_old = np.diff(old.s_m) / old.step_s
    k = np.clip(((t[:-1] - old.t0_s) / old.step_s + 1e-9).astype(int), 0, len(v_old) - 1)
    after = t[:-1] > old.t_s[-1]
    v_ref = np.where(after, v_old[-1], v_old[k])
    return bool(ok_s.all() and (v_new >= v_ref - 1e-6).all())


def padded(dtot: Dtot, pad_s: float) -> Dtot:
    """The DTOT with every occupancy time interval grown by ``pad_s`` on each side.

    If each of two vehicles keeps within ``delta`` seconds of its plan, their
    occupancies can only meet when the intervals grown by ``delta`` overlap;
    growing the stored (confirmed) side by ``2 delta`` tests exactly that.
    """
    if pad_s == 0.0:
        return dtot
    return dataclasses.replace(dtot, lb_s=dtot.lb_s - pad_s, ub_s=dtot.ub_s + pad_s)


class Dica:
    """The intersection control agent's decision core for one junction."""

    # enhanced DICA runs Algorithm 1's rounds compiled; False: the Python loop
    # of Search.rounds, kept as the reference the compiled one is tested against
    compiled_loop = True

    def __init__(
        self,
        intersection: Intersection,
        config: IcaConfig | None = None,
        tables: ConflictTables | None = None,
    ) -> None:
        self.intersection = intersection
        self.config = config or IcaConfig()
        if tables is not None and (
            tables.intersection is not intersection or tables.margin_m != self.config.margin_m
        ):
            raise ValueError("shared conflict tables belong to another junction or margin")
        self.tables = tables or ConflictTables(intersection, self.config.margin_m)
        self.tables.precompute(Shape.of(5.0, 1.8))
        self._confirmed: dict[str, Confirmed] = {}
        # per lane, the detected vehicles in the order they crossed the region's
        # entry line, as (detection time, arrival count, vin); a vehicle leaves its
        # queue only when its reservation ends (the ICA cannot see that it flew it)
        self._lanes: dict[str, list[tuple[float, int, str]]] = {
            lane: [] for lane in intersection.in_lanes
        }
        self._lane_of: dict[str, str] = {}
        self._arrivals = 0
        # the confirmed set's occupancy rows end to end, and as seen from one
        # requester route and shape; any change to the confirmed set bumps the version
        self._rows = ConfirmedRows()
        self._version = 0
        self._batch: tuple[tuple[int, str, Shape], ConfirmedBatch] | None = None
        # with exit spacing: per exit lane, recent vehicles whose reservation has ended
        # (rear out of the junction): (time out, speed out, vin)
        self._left: dict[str, list[tuple[float, float, str]]] = {}
        # per exit lane, the reservations that have ended there in the last LEFT_MEMORY_S
        # (when, and the reservation): a human rolling up may still catch one of them
        self._ended: dict[str, list[tuple[float, Confirmed]]] = {}
        self._exit_cache: tuple[int, dict[str, list[tuple[float, float, str]]]] = (-1, {})
        # the driver beyond the junction, per exit lane's road speed
        self._handovers: dict[float, Handover] = {}
        # reservations ended lately: (rear out [s], exit lane, length, vin), for the room
        self._gone: list[tuple[float, str, float, str]] = []
        # vehicles let into a network of junctions lately: (confirmed [s], length)
        self._entries: list[tuple[float, float]] = []
        # people crossing: the walkers' reservations of the crossings (None: there are
        # none), and per route and shape the crossings it passes (ica.core.crosswalk)
        self.walks = (
            Walkways(intersection.crosswalks, late_s=self.config.green_late_s)
            if intersection.crosswalks
            else None
        )
        self._walk_geometry: dict[
            tuple[str, Shape],
            tuple[list[tuple[str, float, float]], dict[str, tuple[float, float]]],
        ] = {}
        # vehicles refused for holding a crossing too far ahead, since when; and how many
        # went anyway after CLAIM_S
        self._walk_refused: dict[str, float] = {}
        self.walk_claims = 0
        # human drivers: the greens given, by vin; per exit lane, the reservations of a
        # human's envelope there: (key, when it may enter at the soonest, when it is out)
        self.greens: dict[str, Green] = {}
        self.shrunk = 0  # how often a human's reservations shrank (tighten, regreen)
        self.unlit = 0  # greens the roadside dropped, late, and whose reservations went
        # per exit lane, the human reservations onto it: (key, soonest entry, latest exit,
        # fastest crossing)
        self._human_exits: dict[str, list[tuple[str, float, float, Trajectory]]] = {}

    def prepare(self) -> None:
        """Work a controller can do once before it serves, so that no request waits
        for it (DICA's offline tables are built on construction: nothing more)."""

    # -- state -------------------------------------------------------------
    @property
    def confirmed(self) -> dict[str, Confirmed]:
        return dict(self._confirmed)

    def confirmed_dtots(self) -> Iterator[tuple[str, Dtot]]:
        return ((vin, c.dtot) for vin, c in self._confirmed.items())

    def detect(
        self,
        vin: str,
        lane: str,
        t_s: float,
        emergency: bool = False,
        speed_mps: float | None = None,
    ) -> None:
        """A vehicle crossed the communication region's entry line on ``lane``.

        ``emergency`` (an EV, as the region's detector reads it) and ``speed_mps``
        (its speed there, if measured) matter to reactive DICA only."""
        if lane not in self._lanes:
            raise RequestError(
                Reason.UNKNOWN_LANE, f"{lane!r} is not an incoming lane of this junction"
            )
        if vin in self._lane_of:
            if self._lane_of[vin] == lane:
                return  # a repeated detection
            raise RequestError(Reason.BAD_STATE, f"{vin} already detected on {self._lane_of[vin]}")
        if not math.isfinite(t_s):
            raise RequestError(Reason.NOT_FINITE, f"detection time of {vin} is not finite")
        self._arrivals += 1
        bisect.insort(self._lanes[lane], (t_s, self._arrivals, vin))
        self._lane_of[vin] = lane

    def knows(self, vin: str) -> bool:
        """Whether ``vin`` has been detected and is still in its lane's queue."""
        return vin in self._lane_of

    def advance(self, now_s: float) -> list[str]:
        """Move the ICA's clock: forget who has left (their reservation has ended)."""
        gone = [vin for vin, c in self._confirmed.items() if c.dtot.end_s < now_s]
        for vin in gone:  # the room they take counts for requests observed before they left
            c = self._confirmed[vin]
            self._gone.append((c.out_s, c.dtot.route.out_lane, c.length_m, vin))
        if self.walks is not None:
            self.walks.advance(now_s)
            if self._walk_refused:
                self._walk_refused = {
                    v: t for v, t in self._walk_refused.items() if v in self._lane_of
                }
        oldest = now_s - self.config.max_request_age_s - 1.0  # the oldest t_obs still taken
        self._gone = [g for g in self._gone if g[0] > oldest]
        self._entries = [e for e in self._entries if e[0] > oldest]
        if self.config.exit_spacing:
            for vin in gone:
                c = self._confirmed[vin]
                self._left.setdefault(c.dtot.route.out_lane, []).append((c.out_s, c.out_mps, vin))
            for lane, rows in self._left.items():
                self._left[lane] = [r for r in rows if r[0] > now_s - LEFT_MEMORY_S]
        for vin in gone:  # a human's green looks back at them (Dica.green)
            c = self._confirmed[vin]
            self._ended.setdefault(c.dtot.route.out_lane, []).append((c.dtot.end_s, c))
        if self._ended:
            self._ended = {
                lane: kept
                for lane, ended in self._ended.items()
                if (kept := [e for e in ended if e[0] > now_s - LEFT_MEMORY_S])
            }
        for vin in gone:
            self._withdraw(vin)
            self.greens.pop(vin, None)
            lane = self._lane_of.pop(vin, None)
            if lane is not None:
                self._lanes[lane] = [e for e in self._lanes[lane] if e[2] != vin]
        return gone

    def cancel(self, vin: str, seq: int) -> bool:
        """The vehicle will not fly confirmation ``seq``: free its reservation.

        It keeps its place in its lane's queue (it is still there, short of
        the line). False if the ICA holds no such confirmation.
        """
        done = self._confirmed.get(vin)
        if done is None or done.confirmation.seq != seq:
            return False
        self._withdraw(vin)
        return True

    def _withdraw(self, vin: str) -> None:
        if self._human_exits:
            for lane, rows in self._human_exits.items():
                self._human_exits[lane] = [r for r in rows if r[0] != vin]
        del self._confirmed[vin]
        self._rows.remove(vin)
        self._version += 1
        self._forget(vin)

    def _forget(self, vin: str) -> None:
        """A confirmation left the set; controllers with per-vehicle caches extend this."""

    def adopt(
        self, confirmation: Confirmation, length_m: float, width_m: float, in_lane: str
    ) -> None:
        """Take over a confirmation made earlier (a restarted ICA, or a benchmark replay).

        The DTOT is rebuilt from the confirmed TSS with this ICA's own interval
        method, so the state is exactly what this ICA would have stored.
        """
        route = self.intersection.route_by_id(confirmation.route_id)
        if route is None or route.in_lane != in_lane:
            raise RequestError(
                Reason.UNKNOWN_ROUTE, f"route {confirmation.route_id!r} unknown here"
            )
        shape = Shape.of(length_m, width_m)
        tss = confirmation.tss
        s, _ = route.project(np.stack([tss.x_m, tss.y_m], -1))
        traj = Trajectory(float(tss.t_s[0]), self.config.step_s, np.maximum.accumulate(s))
        grid = self.tables.grid(route, shape)
        dtot = build_dtot(
            route, shape, traj, self.config.margin_m, grid, self.config.techniques.estimated_oti
        )
        dtot = padded(dtot, 2.0 * self.config.time_pad_s)
        done = Confirmed.of(confirmation.vin, dtot, confirmation, length_m)
        if confirmation.vin in self._confirmed:  # replaced in place: keep the set's order
            self._confirmed[confirmation.vin] = done
            self._rows = ConfirmedRows()
            for vin, c in self._confirmed.items():
                self._rows.add(vin, c.dtot, c.packed)
        else:
            self._confirmed[confirmation.vin] = done
            self._rows.add(confirmation.vin, dtot, done.packed)
        self._version += 1

    def entries(
        self, skip: frozenset[str] | set[str] = frozenset()
    ) -> list[tuple[Route, float, float]]:
        """Each confirmed plan but those of ``skip``: route, entry time [s], entry speed."""
        return [
            (c.dtot.route, c.confirmation.entry_time_s, c.dtot.trajectory.entry_speed_mps())
            for vin, c in self._confirmed.items()
            if vin not in skip
        ]

    def queue(self, lane: str) -> list[str]:
        """The vehicles detected on ``lane`` whose reservation has not ended, in order."""
        return [e[2] for e in self._lanes[lane]]

    def is_head(self, vin: str, now_s: float) -> bool:
        """Every vehicle ahead of ``vin`` in its lane is confirmed and has begun to
        enter (with platoons: is confirmed; the plan then follows its leader's)."""
        lane = self._lane_of.get(vin)
        if lane is None:
            return False
        platoon = self.config.platoon
        for _, _, ahead in self._lanes[lane]:
            if ahead == vin:
                return True
            c = self._confirmed.get(ahead)
            if c is None:
                return False
            if not platoon and c.confirmation.entry_time_s > now_s:
                return False
        return False

    def _leader(self, vin: str, lane: str) -> Confirmed | None:
        """The nearest confirmed vehicle ahead of ``vin`` in its lane (kept clear of)."""
        leader = None
        for _, _, ahead in self._lanes[lane]:
            if ahead == vin:
                break
            leader = self._confirmed.get(ahead, leader)
        return leader

    # -- revocations: plain DICA never takes a confirmation back ----------------------
    # (reactive DICA, ica/core/reactive.py, overrides these; see ica/core/controller.py)
    replans_revoked = False  # revoked vehicles are re-planned by the ICA at once

    def take_reorders(self) -> list[Reorder]:
        """Reorderings decided since the last call (each once)."""
        return []

    def take_answers(self) -> list[Answer]:
        """What became of revoked confirmations since the last call (each once)."""
        return []

    def take_confirmations(self) -> list[Confirmation]:
        """Confirmations the ICA made of its own accord since the last call."""
        return []

    def due_revocations(self) -> list[tuple[str, int]]:
        """Revocations to send now, as (vin, seq of the plan taken back)."""
        return []

    def pending(self) -> tuple[str, ...]:
        """Revoked vehicles whose answer is awaited."""
        return ()

    def revoked_seq(self, vin: str) -> int | None:
        """The seq of ``vin``'s revoked plan while its answer is awaited, else None."""
        return None

    def acknowledge(self, vin: str, seq: int | None = None) -> list[Confirmation]:
        """``vin`` dropped revoked plan ``seq``; returns confirmations this made."""
        return []

    def restore(self, vin: str, seq: int | None = None) -> tuple[str, ...]:
        """``vin`` could not drop revoked plan ``seq``; returns who got theirs back."""
        return ()

    def settle(self) -> None:
        """End of a step: re-plan what revocations left waiting."""

    def summary(self, events: bool = False) -> dict | None:
        """The controller's own figures for a run's report (None: nothing beyond
        the request statistics); ``events`` adds a log per event."""
        return None

    # -- REQUEST -----------------------------------------------------------
    def handle(self, req: Request, now_s: float) -> Confirmation | Rejection:
        """Answer one REQUEST. Bad input gives a Rejection and changes nothing."""
        try:
            return self._handle(req, now_s)
        except RequestError as e:
            vin = req.vin if isinstance(req.vin, str) else repr(req.vin)
            seq = req.seq if isinstance(req.seq, int) else -1
            return Rejection(vin, seq, e.reason, e.detail)

    def _handle(self, req: Request, now_s: float) -> Confirmation:
        done = self._confirmed.get(req.vin) if isinstance(req.vin, str) else None
        if done is not None:
            if done.confirmation.seq == req.seq:
                return done.confirmation
            if not isinstance(req.seq, int) or req.seq < done.confirmation.seq:
                raise RequestError(
                    Reason.ALREADY_CONFIRMED,
                    f"{req.vin} holds confirmation seq {done.confirmation.seq}",
                )
            # a higher seq: the vehicle did not fly the held one and asks again
            # (it is dropped below, once the new request is known to be valid)
        route, shape, traj = check_request(req, self.intersection, self.config, now_s)
        lane = self._lane_of.get(req.vin)
        if lane is None:
            raise RequestError(
                Reason.NOT_DETECTED, f"{req.vin} was never detected entering the region"
            )
        if lane != req.in_lane:
            raise RequestError(
                Reason.BAD_STATE, f"{req.vin} was detected on {lane}, requests from {req.in_lane}"
            )
        if not self.is_head(req.vin, now_s):
            raise RequestError(Reason.NOT_HEAD, f"{req.vin} is not the head vehicle of {lane}")
        self._check_room(req, route)
        entering = not math.isinf(float(req.network_room_m))
        if entering and done is None:
            self._check_network(req)
        if done is not None:
            self._withdraw(req.vin)

        leader = self._leader(req.vin, lane)
        found = Search(self, req, route, shape, traj, leader).best()
        if self.walks is not None:
            self._check_walk_ahead(req.vin, route, shape, found, now_s)
        conf = self._store(req.vin, req.seq, found, route, shape, req.length_m)
        if entering and done is None:
            self._entries.append((now_s, float(req.length_m)))
        return conf

    def _store(
        self, vin: str, seq: int, found: Found, route: Route, shape: Shape, length_m: float
    ) -> Confirmation:
        """Confirm the plan ``found`` to ``vin`` (its TSS drawn for a vehicle ``length_m``
        long): the answer, and the reservation held with its intervals grown by twice the
        time pad, as :meth:`adopt` rebuilds it."""
        dtot = found.kept_dtot(route, shape, self.config.margin_m)
        entry = dtot.trajectory.entry_time_s()
        conf = Confirmation(
            vin=vin,
            seq=seq,
            route_id=route.id,
            tss=Tss(*dtot.trajectory.tss(route, length_m)),
            entry_time_s=entry,
            exit_time_s=float(dtot.t_s[-1]),
            delay_s=max(0.0, entry - found.earliest),
            iterations=found.iterations,
        )
        stored = padded(dtot, 2.0 * self.config.time_pad_s)
        done = Confirmed.of(vin, stored, conf, length_m)
        self._confirmed[vin] = done
        self._rows.add(vin, stored, done.packed)
        self._version += 1
        return conf

    def _check_room(self, req: Request, route: Route) -> None:
        """Downstream space: confirm a crossing only if its exit lane will have room for the
        vehicle beyond the junction, so that no vehicle ever stands inside it.

        ``req.exit_room_m`` is the room the vehicle observed at ``t_obs_s`` (the space the
        vehicles on the lane would leave were they to queue). Every vehicle confirmed onto
        that lane whose rear was not out yet then takes its length and a standstill gap
        of it; this one needs as much again, one car more (a vehicle may change into the
        lane beyond the junction) and its braking distance at the crossing cap (it flies
        its plan until its rear is out, and SUMO's driver must be able to stop behind the
        queue from there)."""
        room = float(req.exit_room_m)
        if math.isinf(room):
            return  # not measured (the random demand's exit lanes end where vehicles leave)
        t_obs = req.t0_s if math.isnan(req.t_obs_s) else req.t_obs_s
        lane = route.out_lane
        held = [
            (c.out_s, c.length_m)
            for c in self._confirmed.values()
            if c.vin != req.vin and c.dtot.route.out_lane == lane
        ]
        held += [(t, n) for t, out, n, vin in self._gone if out == lane and vin != req.vin]
        taken = sum(n + ROOM_GAP_M for t_out, n in held if t_out > t_obs)
        brake = route.speed_cap_mps**2 / (2.0 * self.config.kinematics.decel_mps2)
        need = taken + req.length_m + ROOM_GAP_M + ROOM_SLACK_M + brake
        if need > room:
            raise RequestError(
                Reason.NO_ROOM,
                f"{route.out_lane} has {room:.1f} m of room, {need:.1f} m needed "
                f"({taken:.1f} m taken by vehicles confirmed onto it)",
            )

    def _check_network(self, req: Request) -> None:
        """The network gate: a vehicle entering a network of junctions from outside is
        confirmed only while the network has room for its queue length
        (:mod:`ica.core.gridlock`), so no cycle of links can ever fill and stand still.

        ``req.network_room_m`` is the room the vehicle observed at ``t_obs_s``; the
        vehicles this ICA has let in since take theirs of it."""
        t_obs = req.t0_s if math.isnan(req.t_obs_s) else req.t_obs_s
        taken = sum(n + QUEUE_GAP_M for t, n in self._entries if t >= t_obs)
        need = taken + float(req.length_m) + QUEUE_GAP_M
        room = float(req.network_room_m)
        if need > room:
            raise RequestError(
                Reason.NO_ROOM,
                f"the network of junctions has {max(room, 0.0):.1f} m of room, {need:.1f} m "
                f"needed ({taken:.1f} m taken by vehicles let in since)",
            )

    # -- people crossing --------------------------------------------------------------
    def _crossing_geometry(
        self, route: Route, shape: Shape
    ) -> tuple[list[tuple[str, float, float]], dict[str, tuple[float, float]]]:
        """:meth:`crossing_spans` and :meth:`crossing_reach`, from one
        :func:`ica.core.crosswalk.passage` per crossing, worked out once."""
        key = (route.id, shape)
        got = self._walk_geometry.get(key)
        if got is None:
            found = []
            for c in self.intersection.crosswalks:
                p = passage(route, c, shape.length_m, shape.width_m, self.config.margin_m)
                if p is not None:
                    found.append((c.id, *p))
            found.sort(key=lambda x: x[1])
            got = ([x[:3] for x in found], {x[0]: x[3:] for x in found})
            self._walk_geometry[key] = got
        return got

    def crossing_spans(self, route: Route, shape: Shape) -> list[tuple[str, float, float]]:
        """The crossings ``route`` passes, with the front positions over which a vehicle
        of ``shape`` (grown by the margin) holds each, in the order it meets them."""
        return self._crossing_geometry(route, shape)[0]

    def crossing_reach(self, route: Route, shape: Shape) -> dict[str, tuple[float, float]]:
        """Per crossing ``route`` passes, the stretch of it a vehicle of ``shape`` (grown
        by the margin) covers there (:func:`ica.core.crosswalk.passage`)."""
        return self._crossing_geometry(route, shape)[1]

    def _holds(self, crossing: str) -> list[Hold]:
        """The confirmed vehicles' holds of ``crossing``: when, and over which stretch."""
        pad = 2.0 * self.config.time_pad_s
        busy: list[Hold] = []
        fasts = {k: f for rows in self._human_exits.values() for k, _, _, f in rows}
        for key, c in self._confirmed.items():
            route, shape = c.dtot.route, c.dtot.shape
            for cid, a, b in self.crossing_spans(route, shape):
                if cid == crossing:
                    t_in, t_out = hold(c.dtot.trajectory, a, b, c.out_mps)
                    if key in fasts:  # a human's envelope: from its fastest touch on
                        t_in = min(t_in, float(first_reach(fasts[key], np.array([a]))[0]))
                    u_lo, u_hi = self.crossing_reach(route, shape)[cid]
                    busy.append((t_in - pad, t_out + pad, u_lo, u_hi))
        return busy

    def walk(
        self,
        person: str,
        crossing: str,
        ready_s: float,
        now_s: float,
        walk_m: float = 0.0,
        speed_mps: float = 0.0,
        side: int = 0,
        near_m: float = 0.0,
        near_lo_m: float = 0.0,
    ) -> WalkSlot:
        """A walker at the kerb of ``crossing`` from ``ready_s``, at most ``near_m`` and
        at least ``near_lo_m`` short of its end ``side`` (its way round the corner, and
        the shortest it may take), ``walk_m`` from being off the corner beyond, walking at
        ``speed_mps`` (0: not stated), asks to cross: the slot it is given, held from then
        on (asked again, the same slot). It goes with a walk phase that has not begun if
        its way is clear from then, else it starts a new phase, no sooner than the
        vehicles' window after the last and clear of every confirmed vehicle
        (:mod:`ica.core.walk`)."""
        if self.walks is None or crossing not in self.walks.crosswalks:
            raise RequestError(Reason.BAD_STATE, f"{crossing!r} is no crossing of this junction")
        if not all(math.isfinite(x) for x in (ready_s, now_s, walk_m, speed_mps)):
            raise RequestError(Reason.NOT_FINITE, f"figures of {person}'s request are not finite")
        if walk_m < 0.0 or speed_mps < 0.0:
            raise RequestError(Reason.BAD_STATE, f"{person}'s walk or speed is negative")
        if side not in (0, 1) or near_m < 0.0 or not 0.0 <= near_lo_m < math.inf:
            raise RequestError(Reason.BAD_STATE, f"{person}'s side or distance is not one")
        held = self.walks.slot_of(person, crossing)
        if held is not None:
            return held
        walks = self.walks
        busy = self._holds(crossing)
        at = max(ready_s, now_s)
        want = walks.slot(person, crossing, at, walk_m, speed_mps, side, near_m, near_lo_m)
        start = walks.joinable(want, at, busy)  # a phase that has not begun: go with it
        if start is None:
            waiting = any(v not in self._confirmed for v in self._lane_of)
            # the window after the phases so far, cut short at the bound on its wait: the
            # vehicles confirmed before it hold its way no later (_check_walk_ahead)
            due = min(walks.next_phase_s_for(waiting), at + WAIT_BOUND_S)
            start = walks.earliest(want, max(at, due), busy)
            # a new phase lasts long enough for anyone at the kerb to join it while it waits
            span = max(want.end_s - want.start_s, walks.phase_s(crossing))
            want = dataclasses.replace(want, end_s=want.start_s + span)
        shift = start - want.start_s
        moved = dataclasses.replace(
            want, start_s=start, end_s=want.end_s + shift, eta_s=want.eta_s + shift
        )
        return walks.reserve(moved)

    def unwalk(self, person: str, crossing: str, start_s: float) -> bool:
        """The roadside kept ``person`` at the kerb of ``crossing``: its GO for ``start_s``
        came later than it may still let a walker go (:attr:`IcaConfig.green_late_s`).
        The walker never stepped off, so its slot goes; it asks again. False if it holds
        no slot of that start there."""
        if self.walks is None or crossing not in self.walks.crosswalks:
            raise RequestError(Reason.BAD_STATE, f"{crossing!r} is no crossing of this junction")
        return self.walks.drop(person, crossing, start_s)

    def walked(self, person: str, crossing: str, t_s: float) -> bool:
        """The roadside saw ``person`` off ``crossing`` and its corners at ``t_s``: its
        slot ends there, so the vehicles and the next walk phase need not wait out its
        slow walk (True if that shortened it)."""
        if self.walks is None or crossing not in self.walks.crosswalks:
            raise RequestError(Reason.BAD_STATE, f"{crossing!r} is no crossing of this junction")
        if not math.isfinite(t_s):
            raise RequestError(Reason.NOT_FINITE, f"the time {person} was across is not finite")
        return self.walks.across(person, crossing, t_s)

    def _check_walk_ahead(
        self, vin: str, route: Route, shape: Shape, found: Found, now_s: float
    ) -> None:
        """Refuse a plan that holds a crossing (padded, and the walkers' gap) later than
        :data:`HOLD_AHEAD_S` from now (walkers asking meanwhile would wait for it), unless
        ``vin`` was first refused for that :data:`CLAIM_S` ago or more: then it may hold
        one up to :data:`WAIT_BOUND_S` ahead, so no vehicle starves and no walker waits
        longer than that bound."""
        late = 0.0
        pad = 2.0 * self.config.time_pad_s + (self.walks.gap_s if self.walks else 0.0)
        for _cid, a, b in self.crossing_spans(route, shape):
            late = max(late, hold(found.traj, a, b, found.out_mps)[1] + pad - now_s)
        self._claim_walk(vin, late, now_s)

    def _claim_walk(self, vin: str, late: float, now_s: float) -> None:
        """Refuse ``vin`` a reservation that holds a crossing ``late`` s from now, past
        :data:`HOLD_AHEAD_S`, unless it has been refused for that :data:`CLAIM_S` or more
        and ``late`` is within :data:`WAIT_BOUND_S` (:meth:`_check_walk_ahead`)."""
        if late <= HOLD_AHEAD_S:
            self._walk_refused.pop(vin, None)
            return
        since = self._walk_refused.setdefault(vin, now_s)
        if now_s - since >= CLAIM_S and late <= WAIT_BOUND_S:
            del self._walk_refused[vin]
            self.walk_claims += 1
            return
        most = HOLD_AHEAD_S if now_s - since < CLAIM_S else WAIT_BOUND_S
        raise RequestError(
            Reason.WALKERS,
            f"it would hold a crossing {late:.1f} s ahead; walkers may be given it first "
            f"(at most {most:.0f} s ahead)",
        )

    # -- human drivers ----------------------------------------------------------------
    def green(
        self,
        vin: str,
        now_s: float,
        length_m: float,
        width_m: float,
        limits: DriverLimits,
        dist_m: float = 0.5,
        v_mps: float = 0.0,
    ) -> Green:
        """A human driver standing at the head of its lane asks (its signal head, for it):
        the earliest green at or after ``now_s`` at which every crossing it may make, on
        every route of its lane, between its fastest and slowest (:mod:`ica.core.envelope`),
        meets no confirmed reservation, and at its fastest it never comes so close behind a
        vehicle confirmed onto an exit lane it may take, at that one's slowest, that it
        would brake inside the junction (:func:`ica.core.envelope.follow_delay`; it would
        fall behind its own envelope). All of them are then reserved, as confirmed
        vehicles are (asked again, the same green). The green is a pure shift of the
        envelope: the driver stands at the line until then.

        A driver still rolling towards its line (``v_mps`` above 0) is given its green
        now or not at all (:func:`ica.core.envelope.bounds_rolling`), and only if at its
        fastest it never comes so close behind the vehicle ahead in its lane, at that
        one's slowest, that it would brake before its rear is out."""
        held = self.greens.get(vin)
        if held is not None:
            return held
        if not all(math.isfinite(x) for x in (now_s, length_m, width_m, dist_m, v_mps)):
            raise RequestError(Reason.NOT_FINITE, f"figures of {vin}'s green are not finite")
        rolling = v_mps > 0.0
        if not 0.0 <= dist_m <= (ROLL_NEAR_M if rolling else 10.0):
            raise RequestError(Reason.BAD_STATE, f"{vin} is {dist_m} m short of its line")
        if v_mps > 70.0:
            raise RequestError(Reason.BAD_STATE, f"{vin} rolls at {v_mps} m/s")
        if rolling and v_mps * v_mps > 2.0 * ROLL_DECEL_MPS2 * dist_m:
            # it may be braking harder than its slowest bound does, to stand at its line
            raise RequestError(Reason.INFEASIBLE, f"{vin} is too fast to be given it rolling")
        if not (0.0 < length_m <= 30.0 and 0.0 < width_m <= 5.0):
            raise RequestError(Reason.BAD_STATE, f"{vin}'s size is not a road vehicle's")
        lane = self._lane_of.get(vin)
        if lane is None:
            raise RequestError(Reason.NOT_DETECTED, f"{vin} was never detected entering the region")
        if vin in self._confirmed:
            raise RequestError(Reason.ALREADY_CONFIRMED, f"{vin} holds a confirmation")
        if not self.is_head(vin, now_s):
            raise RequestError(Reason.NOT_HEAD, f"{vin} is not the head vehicle of {lane}")
        routes = [r for r in self.intersection.routes_from(lane) if r.cars]
        if not routes:
            raise RequestError(Reason.UNKNOWN_ROUTE, f"no route for cars leaves {lane}")
        cfg = self.config
        shape = Shape.of(length_m, width_m)
        pad = 2.0 * cfg.time_pad_s  # a plan may run this late
        g, rounds = now_s, 0
        while True:
            rounds += 1
            built = []
            late, hit, ahead = 0.0, False, -math.inf
            for r in routes:
                fast, slow = green_bounds(r, length_m, g, cfg.step_s, limits, dist_m, v_mps)
                if rolling:
                    late = max(late, self._behind_leader(lane, r, fast, length_m))
                d, fast_in = self._envelope(r, shape, fast, slow)
                built.append((r, slow, d, fast_in, fast))
                for c in self.conflicts(d):  # one that only touches still moves it a step
                    late, hit = max(late, c.delay_s), True
                walk_late, walk_last = self._envelope_walkers(r, shape, fast, slow)
                late, ahead = max(late, walk_late), max(ahead, walk_last)
                fasts = {k: f for k, _, _, f in self._human_exits.get(r.out_lane, ())}
                # never brakes behind one leaving by its exit lane while inside, nor behind
                # one gone out there ahead of it (it might go ahead of one still to come)
                ahead_of = [(k, self._confirmed[k]) for _, _, k in self._exits(r.out_lane)]
                gone_out = [(None, c) for _, c in self._ended.get(r.out_lane, ())]
                for key, c in ahead_of + gone_out:
                    behind = follow_delay(
                        fast, r.cross_length_m, length_m, c.dtot.trajectory.shifted(pad),
                        c.dtot.route.cross_length_m, c.length_m,
                    )  # fmt: skip
                    if (
                        behind > 1e-9
                        and key is not None
                        and self._goes_ahead(fasts.get(key), c, r, slow, length_m)
                    ):
                        continue
                    late = max(late, behind)
            if not hit and late <= 1e-9:
                break
            if rolling:  # it is slowing for its line: now, or it stops and asks there
                raise RequestError(Reason.INFEASIBLE, f"no green for {vin} on the move now")
            if rounds >= MAX_GREEN_ROUNDS:
                raise RequestError(Reason.INFEASIBLE, f"no green for {vin} in {rounds} rounds")
            g += max(late, cfg.step_s)
        if self.walks is not None:  # walkers asking meanwhile wait for it: not too far ahead
            self._claim_walk(vin, ahead - now_s, now_s)
        green = Green(vin, g, now_s, (), (), rounds, dist_m, v_mps)
        return self._reserve(green, built, length_m)

    def _envelope_walkers(
        self, route: Route, shape: Shape, fast: Trajectory, slow: Trajectory
    ) -> tuple[float, float]:
        """A human's envelope on ``route`` against the walkers: how much later it must
        come to keep clear of every walker's slot on the crossings it passes (each held
        from its fastest touch to its slowest leaving, padded), and the latest it holds
        one (with the walkers' gap; -inf: none)."""
        walks = self.walks
        if walks is None:
            return 0.0, -math.inf
        pad = 2.0 * self.config.time_pad_s
        v_out = float(slow.s_m[-1] - slow.s_m[-2]) / slow.step_s if len(slow) > 1 else 0.0
        stretch = self.crossing_reach(route, shape)
        worst, last = 0.0, -math.inf
        for cid, a, b in self.crossing_spans(route, shape):
            t_in = float(first_reach(fast, np.array([a]))[0])
            t_out = hold(slow, a, b, v_out)[1]
            u_lo, u_hi = stretch[cid]
            worst = max(worst, walks.delay(cid, t_in - pad, t_out + pad, u_lo, u_hi))
            last = max(last, t_out + pad + walks.gap_s)
        return worst, last

    def _behind_leader(self, lane: str, route: Route, fast: Trajectory, length_m: float) -> float:
        """How much later a rolling human's fastest crossing of ``route`` would have to
        be so as never to brake behind a vehicle ahead of it from its lane, at that
        one's slowest (each of a human's slow bounds, a plan run late by the time pad),
        both measured from their line: 0 if it never would (it would fall behind its
        own slowest). Its lane is its own: humans keep their lanes."""
        pad = 2.0 * self.config.time_pad_s
        t0, s0 = fast.t0_s, float(fast.s_m[0])
        late = 0.0
        for c in self._confirmed.values():
            if c.dtot.route.in_lane != lane:
                continue
            lead = c.dtot.trajectory.shifted(pad)
            if path_s(lead, t0) <= s0:  # behind it, or level: not a vehicle it follows
                continue
            late = max(late, follow_delay(
                fast, route.cross_length_m, length_m, lead, route.cross_length_m, c.length_m,
            ))  # fmt: skip
        return late

    def relight(
        self,
        vin: str,
        green_s: float,
        asked_s: float,
        length_m: float,
        width_m: float,
        limits: DriverLimits,
        dist_m: float,
        routes: tuple[str, ...],
        v_mps: float = 0.0,
    ) -> Green:
        """A green given before a restart (from the journal): its envelopes on ``routes``
        rebuilt at the same time from the same limits (and the same speed, for one given
        rolling) and reserved as they were, without a check (they were checked when
        given). A later one replaces an earlier."""
        shape = Shape.of(length_m, width_m)
        built = []
        for rid in routes:
            r = self.intersection.route_by_id(rid)
            if r is None:
                raise RequestError(Reason.UNKNOWN_ROUTE, f"{vin}'s green names no route {rid!r}")
            fast, slow = green_bounds(r, length_m, green_s, self.config.step_s, limits, dist_m,
                                      v_mps)  # fmt: skip
            d, fast_in = self._envelope(r, shape, fast, slow)
            built.append((r, slow, d, fast_in, fast))
        held = self.greens.get(vin)
        if held is not None:
            self._unreserve(held)
        green = Green(vin, green_s, asked_s, (), (), 0, dist_m, v_mps)
        return self._reserve(green, built, length_m)

    def _goes_ahead(
        self,
        fast: Trajectory | None,
        c: Confirmed,
        route: Route,
        slow: Trajectory,
        length_m: float,
    ) -> bool:
        """Whether a human's green may put it ahead of reservation ``c`` on their exit
        lane: ``c`` at its fastest (``fast``, another human's fast bound; None: a
        connected vehicle's plan, run early by the time pad) never comes so close behind
        this one at its slowest (``slow`` on ``route``) that it would brake inside the
        junction. A connected vehicle flies its plan until its rear is out, and SUMO's
        driver, to whom it is then handed, starts no faster than SUMO's safe speed
        behind it."""
        from_m = -math.inf
        if fast is None:
            fast, from_m = c.dtot.trajectory.shifted(-2.0 * self.config.time_pad_s), 0.0
        c_cross = c.dtot.route.cross_length_m
        return (
            follow_delay(fast, c_cross, c.length_m, slow, route.cross_length_m, length_m, from_m)
            <= 1e-9
        )

    def _envelope(
        self, route: Route, shape: Shape, fast: Trajectory, slow: Trajectory
    ) -> tuple[Dtot, float]:
        """The envelope's DTOT between ``fast`` and ``slow``, built as this ICA builds
        every DTOT, and the soonest the driver can enter."""
        cfg = self.config
        d = envelope_dtot(
            route, shape, fast, slow, cfg.margin_m, self.tables.grid(route, shape),
            cfg.techniques.estimated_oti,
        )  # fmt: skip
        return d, float(first_reach(fast, np.zeros(1))[0])

    def _reserve(
        self,
        green: Green,
        built: list[tuple[Route, Trajectory, Dtot, float, Trajectory]],
        length_m: float,
    ) -> Green:
        """Store a green's envelopes (route, slow bound, DTOT, soonest entry, fast bound) as
        reservations: ``vin`` names the one out last, ``vin~route`` the others."""
        cfg, vin = self.config, green.vin
        built = sorted(built, key=lambda b: float(b[2].ub_s[-1]))
        keys = []
        for i, (r, slow, d, fast_in, fast) in enumerate(built):
            key = vin if i == len(built) - 1 else f"{vin}~{r.id}"
            conf = Confirmation(
                vin=key,
                seq=0,
                route_id=r.id,
                tss=Tss(*slow.tss(r, length_m)),
                entry_time_s=slow.entry_time_s(),
                exit_time_s=float(d.t_s[-1]),
                delay_s=green.green_s - green.asked_s,
                iterations=green.rounds,
            )
            stored = padded(d, 2.0 * cfg.time_pad_s)
            done = Confirmed.of(key, stored, conf, length_m)
            self._confirmed[key] = done
            self._rows.add(key, stored, done.packed)
            self._human_exits.setdefault(r.out_lane, []).append((key, fast_in, done.out_s, fast))
            keys.append(key)
        self._version += 1
        green = dataclasses.replace(green, routes=tuple(b[0].id for b in built), keys=tuple(keys))
        self.greens[vin] = green
        return green

    def _unreserve(self, green: Green) -> tuple[list[Confirmed], dict[str, list]]:
        """Take a green's reservations out of the confirmed set (to put back with
        :meth:`_restore`)."""
        taken = [self._confirmed.pop(k) for k in green.keys if k in self._confirmed]
        for c in taken:
            self._rows.remove(c.vin)
        keys = set(green.keys)
        exits = {}
        for lane, rows in self._human_exits.items():
            exits[lane] = [r for r in rows if r[0] in keys]
            self._human_exits[lane] = [r for r in rows if r[0] not in keys]
        self.greens.pop(green.vin, None)
        self._version += 1
        return taken, exits

    def _restore(self, green: Green, taken: list[Confirmed], exits: dict[str, list]) -> None:
        for c in taken:
            self._confirmed[c.vin] = c
            self._rows.add(c.vin, c.dtot, c.packed)
        for lane, rows in exits.items():
            self._human_exits.setdefault(lane, []).extend(rows)
        self.greens[green.vin] = green
        self._version += 1

    def regreen(
        self,
        vin: str,
        now_s: float,
        length_m: float,
        width_m: float,
        limits: DriverLimits,
        dist_m: float = 0.5,
    ) -> Green | None:
        """A human driver still standing at its line, its green to come, asks again: the
        reservations it waits for may have shrunk (:meth:`tighten`). The new green if it
        comes sooner (its reservations replace the old), else None (the old stay)."""
        held = self.greens.get(vin)
        if held is None or now_s + 1e-9 >= held.green_s:
            return None
        taken, exits = self._unreserve(held)
        try:
            new = self.green(vin, now_s, length_m, width_m, limits, dist_m)
        except RequestError:
            new = None
        if new is not None and new.green_s < held.green_s - 1e-9:
            self.shrunk += 1
            return new
        if new is not None:
            self._unreserve(new)
        self._restore(held, taken, exits)
        return None

    def unlight(self, vin: str, green_s: float) -> bool:
        """The roadside kept ``vin``'s head red: its green of ``green_s`` came later than
        the roadside may still light it (:attr:`IcaConfig.green_late_s`). The driver never
        moved on it, so its reservations go; it asks again. False if it holds no green
        of that time (one dropped already, or another given since)."""
        held = self.greens.get(vin)
        if held is None or abs(held.green_s - green_s) > 1e-9:
            return False
        self._unreserve(held)
        self.unlit += 1
        return True

    def tighten(
        self,
        vin: str,
        now_s: float,
        s_m: float,
        v_mps: float,
        lane: str,
        limits: DriverLimits,
    ) -> tuple[str, ...] | None:
        """A human driver on its green, seen (by the roadside, as any vehicle) with its
        front at ``s_m`` along its lane's routes at ``v_mps`` on ``lane``: its envelope
        again, from there (:func:`ica.core.envelope.bounds_seen`), on the routes it may
        still take (once on a lane of the junction or beyond, the one it took). The new
        reservations lie within the old if the driver keeps to the stated limits; they
        are taken only if they meet nothing confirmed and keep the exit rules the old
        kept (each enters no sooner and is out no later), else the old stay. The routes
        kept if taken (the roadside audits the driver against the same bounds), else
        None."""
        held = self.greens.get(vin)
        if held is None or now_s < held.green_s or vin not in self._confirmed:
            return None
        if not (math.isfinite(s_m) and math.isfinite(v_mps) and v_mps >= 0.0):
            raise RequestError(Reason.NOT_FINITE, f"{vin} was seen at no finite place")
        routes = [self.intersection.route_by_id(rid) for rid in held.routes]
        routes = [r for r in routes if r is not None]
        took = [r for r in routes if lane == r.out_lane or lane in r.via_lanes]
        if took:
            routes = took
        elif not any(lane == r.in_lane for r in routes):
            return None  # a lane the green knows nothing of: keep what is held
        cfg = self.config
        c0 = self._confirmed[vin]
        length_m, shape = c0.length_m, c0.dtot.shape
        old_in = {k: (fi, out) for rows in self._human_exits.values() for k, fi, out, _ in rows}
        old = {
            self._confirmed[k].dtot.route.id: (*old_in[k], self._confirmed[k].dtot.trajectory)
            for k in held.keys
            if k in self._confirmed and k in old_in
        }
        taken, exits = self._unreserve(held)
        built = []
        ok = True
        for r in routes:
            fast, slow = bounds_seen(r, length_m, now_s, s_m, v_mps, cfg.step_s, limits,
                                     held.green_s)  # fmt: skip
            d, fast_in = self._envelope(r, shape, fast, slow)
            was = old.get(r.id)
            out_s = float(d.t_s[-1])
            if (
                was is None
                or fast_in < was[0] - 1e-9
                or out_s > was[1] + 1e-9
                or not _no_slower(slow, was[2])
                or self.conflicts(d)
            ):
                ok = False
                break
            built.append((r, slow, d, fast_in, fast))
        if not ok:
            self._restore(held, taken, exits)
            return None
        self._reserve(held, built, length_m)
        self.shrunk += 1
        return tuple(b[0].id for b in built)

    def walk_conflict(
        self, route: Route, shape: Shape, traj: Trajectory, exit_mps: float
    ) -> Conflict | None:
        """A plan on ``route`` that would meet a walker on a crossing: the conflict that
        delays it the most (until the walker is past its stretch), or None."""
        walks = self.walks
        if walks is None or not any(walks.slots.values()):
            return None
        pad = 2.0 * self.config.time_pad_s
        worst: Conflict | None = None
        stretch = self.crossing_reach(route, shape)
        for cid, a, b in self.crossing_spans(route, shape):
            t_in, t_out = hold(traj, a, b, exit_mps)
            u_lo, u_hi = stretch[cid]
            d = walks.delay(cid, t_in - pad, t_out + pad, u_lo, u_hi)
            if d > 0.0 and (worst is None or d > worst.delay_s):
                worst = Conflict(f"walkers on {cid}", t_in, d)
        return worst

    def exit_order(
        self,
        route: Route,
        out_s: float,
        out_mps: float,
        traj: Trajectory,
        length_m: float,
    ) -> Conflict | None:
        """checkFV beyond the junction: a plan may not leave by an exit lane ahead of a
        confirmed vehicle that leaves it faster, which would run into it out there
        (nothing checks the road after the junction). The conflict with the one that
        leaves last: delay this plan (its rear out at ``out_s``, at ``out_mps``) until
        it leaves after it. And the plan itself (``traj``, of a vehicle ``length_m``
        long) against the human drivers who may take the exit lane
        (:meth:`_human_order`)."""
        v = out_mps + self.config.speed_tol_mps
        worst: Conflict | None = None
        for t_out, v_out, vin in self._exits(route.out_lane):
            if v_out <= v:
                continue
            need = t_out + self.config.step_s  # its padded reservation's end
            if need > out_s and (worst is None or need - out_s > worst.delay_s):
                worst = Conflict(vin, out_s, need - out_s)
        late = self._human_order(route, traj, length_m, out_s)
        if late is not None and (worst is None or late.delay_s > worst.delay_s):
            worst = late
        return worst

    def _human_order(
        self, route: Route, traj: Trajectory, length_m: float, out_s: float
    ) -> Conflict | None:
        """A plan onto an exit lane a human may take goes ahead of the human, which at
        its fastest then never comes so close behind the plan run late by the time pad
        that it would brake inside the junction, or behind it, the plan run early never,
        from its entry line on, so close behind the human at its slowest: Krauss's
        safe speed either way
        (:func:`ica.core.envelope.follow_delay`), as between two humans. Else the
        conflict that puts it behind the one it would have to follow the latest."""
        rows = self._human_exits.get(route.out_lane, ())
        if not rows:
            return None
        pad = 2.0 * self.config.time_pad_s
        late_plan, early_plan = traj.shifted(pad), traj.shifted(-pad)
        worst: Conflict | None = None
        for key, _fast_in, _slow_out, fast in rows:
            c = self._confirmed.get(key)
            if c is None:
                continue
            cross = c.dtot.route.cross_length_m
            if follow_delay(fast, cross, c.length_m, late_plan, route.cross_length_m,
                            length_m) <= 1e-9:  # fmt: skip
                continue  # ahead of the human: it never brakes behind the plan inside
            d = follow_delay(early_plan, route.cross_length_m, length_m, c.dtot.trajectory,
                             cross, c.length_m, 0.0)  # fmt: skip
            if d > 1e-9 and (worst is None or d > worst.delay_s):
                worst = Conflict(key, out_s, d)
        return worst

    def _exits(self, out_lane: str) -> list[tuple[float, float, str]]:
        """(time out, speed out, vin) of the confirmed vehicles leaving by ``out_lane``,
        worked out once per confirmed set (a request's rounds ask for them each time)."""
        if self._exit_cache[0] != self._version:
            by_lane: dict[str, list[tuple[float, float, str]]] = {}
            for vin, c in self._confirmed.items():
                by_lane.setdefault(c.dtot.route.out_lane, []).append((c.out_s, c.out_mps, vin))
            self._exit_cache = (self._version, by_lane)
        return self._exit_cache[1].get(out_lane, [])

    def exit_spacing(
        self, route: Route, out_s: float, out_mps: float, length: float
    ) -> Conflict | None:
        """The hand-over beyond the junction: a plan that leaves by an exit lane faster
        than a vehicle that leaves it earlier does so late enough that the driver it
        is handed to never brakes behind it (:class:`ica.core.handover.Handover`).
        Each may be ``time_pad_s`` off its plan, so the separation grows by twice
        that. The conflict with the one that needs the latest exit (of a plan whose
        rear leaves at ``out_s``, at ``out_mps``, of a vehicle ``length`` long)."""
        v = out_mps
        tol = self.config.speed_tol_mps
        pad = 2.0 * self.config.time_pad_s
        handover = self.handover(route.exit_mps)
        worst: Conflict | None = None
        for t_out, v_out, vin in self._exits(route.out_lane) + self._left.get(route.out_lane, []):
            if t_out > out_s or v_out >= v - tol:
                continue
            need = t_out + handover.separation_s(v_out, v, length) + pad
            if need > out_s and (worst is None or need - out_s > worst.delay_s):
                worst = Conflict(vin, out_s, need - out_s)
        return worst

    def handover(self, road_mps: float) -> Handover:
        """The road's driver beyond an exit lane of speed limit ``road_mps``."""
        h = self._handovers.get(road_mps)
        if h is None:
            k = self.config.kinematics
            h = self._handovers[road_mps] = Handover(road_mps, k.accel_mps2, k.decel_mps2)
        return h

    def front_cap_mps(self, route: Route) -> float:
        """checkFV: a vehicle may not cross faster than the slowest confirmed
        vehicle leaving by the same exit lane (which covers the same route ahead).

        An exit speed read from a plan's samples that is its route's cap up to
        rounding (1e-9 m/s) does not bind: the plans would differ by rounding alone,
        and exit spacing would plan the request twice for nothing."""
        cap = route.speed_cap_mps
        for _, v_out, _ in self._exits(route.out_lane):
            if v_out < route.speed_cap_mps - 1e-9:
                cap = min(cap, max(v_out, self.config.kinematics.min_cross_mps))
        return cap

    def _compiled_rounds(self) -> bool:
        """Enhanced DICA's rounds run as one compiled call (``Search.rounds``)."""
        tech = self.config.techniques
        return (
            self.compiled_loop
            and tech.reduced_set
            and tech.conflict_zones
            and tech.bisection
            and tech.estimated_oti
            and type(self).conflicts is _BATCHED_GET_CV  # not a baseline's, nor replaced
        )

    def conflicts(self, dtot: Dtot) -> list[Conflict]:
        """getCV: confirmed vehicles in space-time conflict with ``dtot``.

        The one place where the baselines differ: they replace what counts as
        a conflict and keep everything else (validation, flyable plans,
        checkFV, the lane leader).
        """
        tech = self.config.techniques
        if tech.reduced_set and tech.conflict_zones and tech.bisection:
            return get_cv_batch(dtot, self._confirmed_batch(dtot.route, dtot.shape))
        return get_cv(dtot, self.confirmed_dtots(), tech, self.tables)

    def _confirmed_batch(self, route: Route, shape: Shape) -> ConfirmedBatch:
        """The confirmed set as seen from ``route``, picked once per confirmed set."""
        key = (self._version, route.id, shape)
        if self._batch is not None and self._batch[0] == key:
            return self._batch[1]
        batch = ConfirmedBatch.of(route, shape, self._rows.gathered(), self.tables)
        self._batch = (key, batch)
        return batch

    # -- hooks for controllers that revise confirmations (ica/core/reactive.py) ---------
    def _set_aside(self, vin: str, key: str) -> None:
        """Move ``vin``'s reservation to ``key``: it stays in the confirmed set (the
        vehicle may still fly it) while ``vin`` is free for a revised confirmation."""
        c = self._confirmed.pop(vin)
        self._rows.remove(vin)
        self._confirmed[key] = c
        self._rows.add(key, c.dtot, c.packed)
        self._version += 1

    def _restore_aside(self, vin: str, key: str) -> None:
        """Give a reservation set aside under ``key`` back to ``vin`` (undo _set_aside)."""
        c = self._confirmed.pop(key)
        self._rows.remove(key)
        self._confirmed[vin] = c
        self._rows.add(vin, c.dtot, c.packed)
        self._version += 1

    def _drop(self, key: str) -> None:
        """Forget a reservation that will not be flown (a revoked plan, acknowledged)."""
        if self._confirmed.pop(key, None) is not None:
            self._rows.remove(key)
            self._version += 1

    def _confirm_from(
        self,
        vin: str,
        seq: int,
        route: Route,
        shape: Shape,
        t0_s: float,
        dist_to_entry_m: float,
        speed_mps: float,
        not_before_s: float,
        leader_vin: str | None,
    ) -> Confirmation:
        """Confirm ``vin`` anew from a state it will be in (a revised confirmation).

        The same conflict search as a REQUEST's, against the whole confirmed set,
        starting from the plan that enters soonest at or after ``not_before_s``.
        Raises RequestError as a REQUEST would.
        """
        cfg = self.config
        s_end = route.cross_length_m + shape.length_m
        planner = Planner(
            d_m=max(dist_to_entry_m, 0.0),
            v0_mps=speed_mps,
            road_mps=route.road_mps,
            cap_mps=self.front_cap_mps(route),
            s_end_m=s_end,
            kin=cfg.kinematics,
            hold=cfg.platoon,
        )
        traj = plan_entry(planner, t0_s, max(not_before_s - t0_s, 0.0), cfg.step_s, s_end)
        none = np.zeros(0)
        req = Request(
            vin, seq, route.in_lane, route.out_lane, shape.length_m, shape.width_m, t0_s,
            dist_to_entry_m, speed_mps, Tss(none, none, none, none),
        )  # fmt: skip
        leader = self._confirmed.get(leader_vin) if leader_vin is not None else None
        found = Search(self, req, route, shape, traj, leader).best()
        return self._store(vin, seq, found, route, shape, shape.length_m)


_BATCHED_GET_CV = Dica.conflicts  # the getCV the compiled round loop repeats
