"""The observer process: records the run as Rerun space-time visuals.

It only listens: the STATE of every vehicle in the region (``sim/<j>/vehicles``), the
confirmations the ICA publishes (``dica/<j>/confirmed/*``), reactive DICA's
reorderings (``dica/<j>/reorder``), the walkers' slots (``dica/<j>/walks/*``), the
people near the junction (``sim/<j>/people``), the human drivers' greens
(``dica/<j>/greens/*``: each envelope rebuilt from the same limits by the pure core)
and the CLOCK. Human drivers come in the vehicle feed with their signal head's
colour. It is not a lockstep participant, so recording never slows the run; at the
run's end on the clock it drains what is queued, closes the ``.rrd`` and exits. All Rerun calls go
through :class:`sim_gateway.recording.SpaceTimeRecorder`. With ``live_port`` it
also serves the recording over gRPC on 127.0.0.1 while it writes the file, so
``dica view --live`` can watch the run as it happens.

Emergency vehicles are drawn in their colour from the first STATE that flags
them (``ev``). A reordering is marked once, the first time it is heard; a
revoked plan is withdrawn only once the ICA says its vehicle dropped it (a
reordering comes again, whole, each time a revoked plan's fate is known), so
a plan that was kept stays drawn. It is withdrawn at the step at which the
vehicle feed first showed the drop (``refused_seq``), the moment the
vehicle's own observation showed it, not whenever the ICA's clock happened to
be when the ACK came: so the drawing is the same on every run. The wire carries no rejections to the
observer (a REJECT is the reply to the vehicle's query), so the rejections
table holds only the withdrawn plans in a cluster run.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field

import numpy as np

from dica.deploy.transport import Inbox, Item
from dica.ica.core.config import IcaConfig
from dica.ica.core.envelope import DriverLimits, envelope_dtot, green_bounds
from dica.ica.core.intersection import Intersection
from dica.ica.core.walk import WalkSlot
from dica.ica.core.zones import ConflictTables, Shape
from dica.schemas import keys
from dica.schemas.codec import DecodeError, decode
from dica.schemas.messages import (
    DROPPED,
    EXPIRED,
    KEPT,
    Clock,
    Go,
    Lit,
    People,
    Place,
    Reorder,
    Response,
    State,
    VehicleState,
)
from dica.sim_gateway.recording import SpaceTimeRecorder


def listen(inbox: Inbox, on, ended, log: logging.Logger) -> None:
    """An observer's loop: each message to ``on`` until a signal, or ``ended()`` and
    nothing more queued. A bad message, or one the recording cannot draw, is logged
    and dropped."""
    while not inbox.stopping.is_set():
        item = inbox.get(timeout=0.2)
        if item is None:
            if ended():
                break  # the end is announced and nothing more is queued
            continue
        try:
            on(item)
        except DecodeError as e:
            log.warning("dropped a bad %s message: %s", item.what, e)
        except ValueError as e:  # the recorder refuses what it cannot draw
            log.warning("not recorded (%s): %s", item.what, e)


@dataclass(slots=True)
class _Revoked:
    """A revoked plan followed until its fate is drawn."""

    decided_s: float
    shown_s: float | None = None  # first step after the decision whose feed shows the drop
    said: Place | None = None  # the ICA's DROPPED, until the feed shows the drop


@dataclass(slots=True)
class _Step:
    step: int = -1
    t_s: float = 0.0
    vehicles: list[VehicleState] = field(default_factory=list)


class Observer:
    def __init__(
        self,
        session,
        inter: Intersection,
        rrd_path,
        log: logging.Logger,
        name: str = "observer",
        *,
        margin_m: float = 0.25,
        time_pad_s: float = 0.0,
        live_port: int | None = None,
    ) -> None:
        self.inter = inter
        self.log = log
        self.margin_m = margin_m
        self.time_pad_s = time_pad_s
        self.inbox = Inbox()
        self.recorder = SpaceTimeRecorder(inter, rrd_path, margin_m=margin_m, live_port=live_port)
        self.recorder.geometry()
        self.sizes: dict[str, tuple[float, float]] = {}
        self.confirmations = 0
        self.walks = 0  # walkers' slots drawn
        self.greens = 0  # human drivers' greens drawn
        self._humans: set[str] = set()  # human drivers the recorder has been told of
        self._tables: ConflictTables | None = None  # built at the first green
        self.reorders = 0
        self.withdrawn = 0
        self.steps = 0
        self._seq: dict[str, int] = {}  # VIN -> the newest confirmation drawn
        self._emergency: set[str] = set()
        self._marked: set[tuple[str, float]] = set()  # reorderings drawn: (EV, t_s)
        self._answered: set[tuple[str, int]] = set()  # revoked plans whose fate is drawn
        self._revoked: dict[tuple[str, int], _Revoked] = {}  # (VIN, seq) -> what is known
        self._watch: dict[str, list[tuple[int, _Revoked]]] = {}  # drops the feed has not shown
        self.ended = False
        self._cur = _Step()
        j = inter.junction_id
        self._decls = [
            session.declare_subscriber(keys.vehicles(j), self.inbox.sample_cb("state")),
            session.declare_subscriber(keys.confirmed(j), self.inbox.sample_cb("confirmed")),
            session.declare_subscriber(keys.reorder(j), self.inbox.sample_cb("reorder")),
            session.declare_subscriber(keys.clock(j), self.inbox.sample_cb("clock")),
            session.declare_subscriber(keys.walks(j), self.inbox.sample_cb("walk")),
            session.declare_subscriber(keys.people(j), self.inbox.sample_cb("people")),
            session.declare_subscriber(keys.greens(j), self.inbox.sample_cb("green")),
        ]
        # declared last: a gateway waiting for observers starts once all of the above are up
        self._token = session.liveliness().declare_token(keys.observer_alive(j, name))

    def run(self) -> None:
        listen(self.inbox, self._on, lambda: self.ended, self.log)

    def close(self) -> None:
        self._emit()
        for vin in list(self._watch):  # the feed never showed these drops: the ICA's time
            self._settle(vin, math.inf)
        self._token.undeclare()
        for d in self._decls:
            d.undeclare()
        self.recorder.close()

    def _on(self, item: Item) -> None:
        if item.what == "state":
            st = decode(item.payload, State)
            if st.step != self._cur.step:
                self._emit()
                self._cur = _Step(st.step, st.t_s)
            self._cur.vehicles.extend(st.vehicles)
            for v in st.vehicles:
                self.sizes[v.vin] = (v.length_m, v.width_m)
                if v.vin in self._watch:
                    self._feed_shows(v, st.t_s)
                if v.ev and v.vin not in self._emergency:
                    self._emergency.add(v.vin)
                    self.recorder.emergency(v.vin)
                if v.signal and v.vin not in self._humans:
                    self._humans.add(v.vin)
                    self.recorder.human(v.vin)
        elif item.what == "confirmed":
            r = decode(item.payload, Response)
            if r.vin in self._watch:
                self._settle(r.vin, r.seq)  # a dropped plan goes before the next is drawn
            length, width = self.sizes.get(r.vin, (5.0, 1.8))
            self.recorder.confirmed(
                r.vin,
                r.route_id,
                r.t_s,
                r.x_m,
                r.y_m,
                r.heading_rad,
                length,
                width,
                r.entry_time_s,
                r.exit_time_s,
                now_s=float(r.t_s[0]),
                delay_s=r.delay_s,
                rounds=r.iterations,
                margin_m=self.margin_m,
                time_pad_s=self.time_pad_s,
            )
            self.confirmations += 1
            self._seq[r.vin] = max(r.seq, self._seq.get(r.vin, -1))
        elif item.what == "reorder":
            self._on_reorder(decode(item.payload, Reorder))
        elif item.what == "walk":
            go = decode(item.payload, Go)
            slot = WalkSlot(go.person, go.crossing, go.start_s, go.end_s, go.side, go.near_m,
                            go.v_lo, go.v_hi, go.eta_s, go.near_lo_m, go.late_s)  # fmt: skip
            self.recorder.walk(go.given_s, slot)
            self.walks += 1
        elif item.what == "green":
            self._on_green(decode(item.payload, Lit))
        elif item.what == "people":
            seen = decode(item.payload, People)
            xy = np.array([(p.x_m, p.y_m) for p in seen.people], dtype=float).reshape(-1, 2)
            waiting = np.array([p.waiting for p in seen.people], dtype=bool)
            self.recorder.people(seen.t_s, xy, waiting)
        elif item.what == "clock":
            c = decode(item.payload, Clock)
            if c.end:
                self.ended = True

    def _on_green(self, g: Lit) -> None:
        """A human driver's green: each route's envelope, as the ICA built it from the
        same stated limits, to the conflict-point and lane charts."""
        if self._tables is None:
            self._tables = ConflictTables(self.inter, self.margin_m)
        limits = DriverLimits(top_mps=g.top_mps) if g.top_mps > 0.0 else DriverLimits()
        limits = dataclasses.replace(limits, late_s=g.late_s)
        shape = Shape.of(g.length_m, g.width_m)
        step = g.step_s or IcaConfig().step_s  # a sender that left them out: the defaults
        routes = []
        for rid in g.routes:
            r = self.inter.route_by_id(rid)
            if r is None:
                raise ValueError(f"{g.vin}'s green names no route {rid!r} of this junction")
            fast, slow = green_bounds(r, g.length_m, g.green_s, step, limits, g.near_m,
                                      g.speed_mps)  # fmt: skip
            d = envelope_dtot(r, shape, fast, slow, self.margin_m, self._tables.grid(r, shape),
                              True)  # fmt: skip
            routes.append((rid, d, fast, slow))
        self.recorder.envelope(g.asked_s, g.vin, routes, 2.0 * self.time_pad_s)
        self.greens += 1

    def _on_reorder(self, m: Reorder) -> None:
        if (m.ev, m.t_s) not in self._marked:
            self._marked.add((m.ev, m.t_s))
            self.reorders += 1
            self.recorder.reordered(
                m.t_s, m.ev, m.lane, m.solver, [p.vin for p in m.order],
                m.ev_entry_before_s, m.ev_entry_after_s,
                revoked=[p.vin for p in m.order if p.seq >= 0], refused=m.refused,
            )  # fmt: skip
        for p in m.order:
            if p.seq < 0:
                continue
            r = self._revoked.get((p.vin, p.seq))
            if r is None:
                r = self._revoked[(p.vin, p.seq)] = _Revoked(m.t_s)
                self._watch.setdefault(p.vin, []).append((p.seq, r))
            settled = p.plan in (DROPPED, KEPT, EXPIRED)
            if settled and (p.vin, p.seq) not in self._answered:
                self._answered.add((p.vin, p.seq))
                self._on_fate(p, r)

    def _on_fate(self, p: Place, r: _Revoked) -> None:
        """A revoked plan was dropped (withdrawn once the feed shows it), kept, or ended
        unanswered (both stay drawn)."""
        if p.plan == DROPPED:
            r.said = p
            if r.shown_s is not None:
                self._withdraw(p.vin, p.seq, r.shown_s)
            return
        self._unwatch(p.vin, p.seq)
        if p.plan == KEPT:
            self.recorder.kept(p.t_s, p.vin, "kept its plan: it could not stop")
        else:
            self.recorder.kept(p.t_s, p.vin, "no answer before its plan ended")

    def _feed_shows(self, v: VehicleState, t_s: float) -> None:
        """The vehicle feed at ``t_s``: has the actuator dropped a revoked plan?"""
        for seq, r in list(self._watch.get(v.vin, ())):
            if r.shown_s is None and t_s > r.decided_s + 1e-9 and v.refused_seq >= seq:
                r.shown_s = t_s
                if r.said is not None:
                    self._withdraw(v.vin, seq, t_s)

    def _settle(self, vin: str, below_seq: float) -> None:
        """Withdraw at the ICA's time the dropped plans of ``vin`` below ``below_seq``
        whose drop the feed has not shown (a newer plan comes, or the run ends)."""
        for seq, r in list(self._watch.get(vin, ())):
            if seq < below_seq and r.said is not None:
                self._withdraw(vin, seq, r.said.t_s)

    def _withdraw(self, vin: str, seq: int, t_s: float) -> None:
        self._unwatch(vin, seq)
        self.withdrawn += 1
        if self._seq.get(vin, -1) <= seq:
            self.recorder.withdrawn(t_s, vin, "revoked")
        else:  # a newer plan is drawn already: it stays
            self.recorder.rejected(t_s, vin, "revoked")

    def _unwatch(self, vin: str, seq: int) -> None:
        left = [w for w in self._watch.get(vin, ()) if w[0] != seq]
        if left:
            self._watch[vin] = left
        else:
            self._watch.pop(vin, None)

    def _emit(self) -> None:
        cur = self._cur
        if cur.step < 0:
            return
        vs = cur.vehicles
        self.recorder.footprints(
            cur.t_s,
            [v.vin for v in vs],
            np.array([v.x_m for v in vs]),
            np.array([v.y_m for v in vs]),
            np.array([v.angle_deg for v in vs]),
            np.array([v.length_m for v in vs]),
            np.array([v.width_m for v in vs]),
            route_ids=[v.route_id for v in vs],
        )
        if self._humans:  # the heads of the lanes where a human driver stands or goes
            heads = {"red": [], "green": []}
            for v in vs:
                if v.signal in heads and v.head and not v.exited and v.dist_to_entry_m >= 0.0:
                    r = self.inter.route_by_id(v.route_id)
                    if r is not None:
                        heads[v.signal].append(r.points(0.0).reshape(-1)[:2])
            self.recorder.heads(cur.t_s, np.array(heads["red"]).reshape(-1, 2),
                                np.array(heads["green"]).reshape(-1, 2))  # fmt: skip
        self.steps += 1
        self._cur = _Step()
