"""Reactive DICA (chapter 5): an emergency vehicle (EV) crosses as early as it can.

Plain DICA until an EV is detected at the communication region's entry line.
The EV's *event* starts once no unconfirmed vehicle is ahead of it in its
lane (it is next to go: holds begin), and the vehicles are reordered when it
asks as head of its lane (``start_at="head"``). The dissertation does both at
the detection (``start_at="detection"``), but until the EV is next in its lane
it can only follow the queue, and holding everyone else meanwhile cost the
other vehicles more than it gained the EV (see docs/results.md). The EV's
REQUEST that reorders is answered ``held`` if confirmations had to be revoked:
the EV asks again once they are acknowledged (in process, at once).

1. Requests of vehicles that could take the EV's room are held (REJECT
   ``held``) until the EV holds a confirmation: every unconfirmed vehicle
   except those ahead of the EV in its lane and those whose route cannot
   touch any route of the EV's lane. Once the EV holds its reservation DICA
   protects it, so the hold ends there rather than when the EV leaves (the
   dissertation's choice), sparing the others.
2. The **modifiable set**: confirmed vehicles that have not entered and can
   still stop before the entry line at the time a revocation takes effect
   (judged on their confirmed plan, with the planner's 4.5 m/s^2), every
   confirmed vehicle behind them in their lane being modifiable too; plus the
   unconfirmed vehicles ahead of the EV in its lane, and the EV.
3. They are ordered with a solver of :mod:`ica.core.ordering`: the EV's entry
   first, the others' delay second, every lane's order kept. Release times:
   a confirmed vehicle's earliest entry from its state on its plan; for an
   unconfirmed one (its state is not known here) the earliest entry from
   where and how fast it was detected. Vehicles that cannot change any more
   fold into the releases through their separations (:mod:`ica.core.separation`).
4. Every modifiable confirmed vehicle is **revoked**: its reservation stays in
   the confirmed set, set aside, until :meth:`ReactiveDica.acknowledge` says
   the vehicle knows; nobody gets its room before that.
5. Once all have acknowledged, they are **re-confirmed in the order**, each by
   DICA's own conflict search against the whole confirmed set, from its state
   on its old plan at the effective time. If the EV is head of its lane (it is
   about to ask), it is planned first, by its own REQUEST, and the revoked
   vehicles then around its real plan; those ordered ahead of it take any
   room before it that costs it nothing.
6. If the EV has not asked by :meth:`ReactiveDica.settle` (it is behind a
   queue), those ordered ahead of it are re-confirmed, and those behind it get
   no plan: they stop before the line and ask again, held until the EV has
   its plan (a guess at the EV's plan that is early would let them take its
   room, a late one would make them wait for nothing).
7. The event closes when the EV has left the junction; a second EV detected
   meanwhile waits for its own event.

What must happen is handed out as plain data (:class:`Reorder`, and the
confirmations :meth:`ReactiveDica.acknowledge` and
:meth:`ReactiveDica.take_confirmations` return), and so is what became of each
revoked plan (:class:`Answer`: dropped, kept or expired) for whoever shows the
run; carrying it to the vehicles is the caller's business. No I/O here.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica
from dica.ica.core.ev_event import (
    Candidate,
    EvEvent,
    ReactiveConfig,
    Replan,
    event_figures,
    event_log,
    lane_candidates,
)
from dica.ica.core.ev_notice import (
    CLEAR_HEADWAY_S,
    CLEAR_MARGIN_S,
    CLEAR_MOST,
    LEAD_S,
    EvNotice,
    Notices,
    edge_of,
)
from dica.ica.core.intersection import Intersection
from dica.ica.core.ordering import (
    OrderingError,
    Problem,
    evaluate,
    solve,
)
from dica.ica.core.planner import Planner
from dica.ica.core.request import Confirmation, Reason, Rejection, Request, RequestError
from dica.ica.core.revocation import DROPPED, EXPIRED, KEPT, Answer, Reorder
from dica.ica.core.route import Route
from dica.ica.core.separation import SeparationModel
from dica.ica.core.stop_law import predict_stop
from dica.ica.core.zones import ConflictTables, Shape

STOP_SLACK_STEPS, STOP_SLACK_M = 2, 0.5  # room kept beyond the stopping bound
# [s] with revoked vehicles asking again (no re-planning here), one is held this long at most
# for those the order put before it to have their plans
ORDER_WAIT_S = 3.0
REASK_STEPS = 2  # a revoked vehicle's new plan: the REVOKE's step, its answer's, then it asks
_ASIDE = "~revoked"  # suffix of a revoked reservation's key while it awaits acknowledgement


@dataclass(slots=True)
class _Ordered:
    """One ordering of an event's candidates, before anything is revoked."""

    cands: list[Candidate]
    ev_idx: int
    order: tuple[int, ...]
    added: np.ndarray  # [s] per candidate, by the model (0 for one that keeps its plan)
    before: float  # the EV's model entry in the present order
    after: float  # ... and in this one
    refused: str
    bounded: bool  # under a bound on what is added (then those ahead of the EV keep plans)
    prepare_s: float
    solve_s: float

    def kept(self) -> set[int]:
        """Candidates that keep their plans: under a bound, those the order puts ahead of
        the EV (revoked, they would be planned around the EV's real plan, behind it)."""
        if not self.bounded or self.refused:
            return set()
        return set(self.order[: self.order.index(self.ev_idx)])

    def revoked(self) -> list[int]:
        keep = self.kept()
        return [i for i in self.order if self.cands[i].state is not None and i not in keep]


class ReactiveDica(Dica):
    """DICA that lets one emergency vehicle at a time cross first."""

    def __init__(
        self,
        intersection: Intersection,
        config: IcaConfig | None = None,
        tables: ConflictTables | None = None,
        reactive: ReactiveConfig | None = None,
    ) -> None:
        super().__init__(intersection, config, tables)
        self.reactive = reactive or ReactiveConfig()
        self._shape = Shape.of(5.0, 1.8)
        cfg = self.config
        self.separations = SeparationModel(
            intersection, self.tables, self._shape, cfg.kinematics, cfg.margin_m, cfg.step_s,
            cfg.techniques,
        )  # fmt: skip
        self._now = -math.inf
        self._detected: dict[str, tuple[int, float, float | None]] = {}  # number, t, speed
        self._detections = 0  # detections so far: a vehicle's number says who came first
        self._lane_confirmed: dict[str, list[str]] = {ln: [] for ln in intersection.in_lanes}
        self._event: EvEvent | None = None
        self._waiting_evs: list[tuple[str, str, float]] = []
        self._pending: dict[str, str] = {}  # revoked vin -> key of its set-aside reservation
        self._revoked_seq: dict[str, int] = {}  # revoked vin -> the seq of the plan revoked
        self._revoked_at: dict[str, float] = {}  # revoked vin -> when it was decided [s]
        self._lane_revoked: dict[str, list[str]] = {}  # per lane, revoked vins front to back
        self._added: dict[str, float] = {}  # vin -> delay reorderings added to it so far [s]
        self.added_peak_s = 0.0  # the most any vehicle was added, over the run [s]
        self._revoked_entry: dict[str, float] = {}  # revoked vin -> its revoked plan's entry
        self.replanned_later_s = 0.0  # the most a revoked vehicle's new entry came later [s]
        self.trials = 0  # orders carried out on a copy to check the bound on the real plans
        self.acknowledged = 0  # revocations the vehicle confirmed (its plan dropped)
        self.restored = 0  # reservations given back: the vehicle could no longer stop
        self.expired = 0  # set-aside reservations that ended unanswered
        self._before: list[Replan] = []  # re-confirmations ahead of the EV, awaiting acks
        self._after: list[Replan] = []  # re-confirmations behind the EV
        self._late: list[Confirmation] = []  # re-confirmations made outside acknowledge()
        self._outbox: list[Reorder] = []
        self._answers: list[Answer] = []
        self.events: list[EvEvent] = []
        # EVs on their way from upstream (ica.core.ev_notice): their lanes are cleared early
        self.notices = Notices()
        self._notice_routes: dict[frozenset[str], tuple[Route, ...]] = {}
        self._notice_lanes: dict[tuple[str, str], frozenset[str]] = {}  # by (in, out) edge
        self._no_room: set[str] = set()  # last refused for room beyond the junction
        # revoked vehicles to ask again (``replan_revoked`` off), in the order the solver put
        # them, and since when each was held for those before it
        self._re_ask: list[str] = []
        self._order_since: dict[str, float] = {}

    def prepare(self) -> None:
        """Measure every separation the EV ordering can ask for (see
        :meth:`SeparationModel.precompute`): a reorder then only looks them up."""
        self.separations.precompute()

    # -- what the caller sees -------------------------------------------------------
    @property
    def event(self) -> EvEvent | None:
        return self._event

    @property
    def replans_revoked(self) -> bool:  # type: ignore[override]
        return self.reactive.replan_revoked

    def take_reorders(self) -> list[Reorder]:
        """Decisions made since the last call (each once)."""
        out, self._outbox = self._outbox, []
        return out

    def take_answers(self) -> list[Answer]:
        """What became of revoked confirmations since the last call (each once)."""
        out, self._answers = self._answers, []
        return out

    def _answered(self, vin: str, outcome: str) -> None:
        t = self._now if math.isfinite(self._now) else self._revoked_at.get(vin, 0.0)
        self._answers.append(Answer(vin, self._revoked_seq.get(vin, -1), outcome, t))

    def pending(self) -> tuple[str, ...]:
        """Revoked vehicles whose acknowledgement is not known yet."""
        return tuple(self._pending)

    def revoked_seq(self, vin: str) -> int | None:
        """The seq of ``vin``'s revoked plan while its answer is awaited, else None."""
        return self._revoked_seq[vin] if vin in self._pending else None

    def awaiting(self) -> tuple[str, ...]:
        """Revoked vehicles with no new confirmation yet (acknowledged or not)."""
        return tuple(self._pending) + tuple(r.vin for r in self._before + self._after)

    def due_revocations(self) -> list[tuple[str, int]]:
        """The revocations to send now, as (vin, seq of the plan revoked).

        Every pending revocation is due at once, each lane's rearmost first. With
        ``replan_revoked`` off a revoked vehicle drops its plan and stops short of
        the line, which its follower's plan did not expect; the actuator therefore
        drops a plan only while no follower flies behind it (drops of one step
        go rearmost first), and a vehicle is modifiable only if every confirmed one
        behind it is (:meth:`_classify`). A REVOKE that reaches a leader before its
        follower's is answered "kept" (see :meth:`restore`): safe, never a
        collision. Sending them together (rather than each once the one behind has
        dropped) also keeps a lockstep cluster's decisions independent of when an
        acknowledgement happens to arrive.
        The answer is the same until something is acknowledged or restored, so a
        caller may send it again (a lost REVOKE) as often as it likes.
        """
        if self.reactive.replan_revoked:
            return [(vin, self._revoked_seq[vin]) for vin in self._pending]
        out = []
        for vins in self._lane_revoked.values():
            out += [(v, self._revoked_seq[v]) for v in reversed(vins) if v in self._pending]
        return out

    def cancel(self, vin: str, seq: int) -> bool:
        """A CANCEL of a revoked plan is its acknowledgement: the vehicle will not fly it."""
        if vin in self._pending and self._revoked_seq.get(vin) == seq:
            self.acknowledge(vin)
            return True
        return super().cancel(vin, seq)

    def restore(self, vin: str, seq: int | None = None) -> tuple[str, ...]:
        """``vin`` could not drop revoked plan ``seq`` (it can no longer stop short of
        the line): its set-aside reservation is its own again, and so are those of the
        revoked vehicles ahead of it in its lane, which were not told yet (their
        follower flies on behind them, so they must too). Returns who got theirs back.
        """
        if vin not in self._pending or (seq is not None and self._revoked_seq.get(vin) != seq):
            return ()
        lane = self._lane_of.get(vin)
        order = self._lane_revoked.get(lane, [vin]) if lane is not None else [vin]
        ahead = order[: order.index(vin) + 1] if vin in order else [vin]
        back = []
        for v in ahead:
            key = self._pending.pop(v, None)
            if key is None:
                continue
            if v in self._confirmed:  # it asked again, so it did drop that plan
                self._drop(key)
                self._answered(v, DROPPED)
                continue
            self._restore_aside(v, key)
            self._done_re_asking(v)  # it flies its plan: it will not ask again
            self._revoked_entry.pop(v, None)  # it flies its plan: nothing was added
            self.restored += 1
            self._answered(v, KEPT)
            back.append(v)
        return tuple(back)

    def acknowledge(self, vin: str, seq: int | None = None) -> list[Confirmation]:
        """``vin`` knows its confirmation was revoked: its old reservation goes
        (``seq``, if given, must be the revoked plan's; an answer about another is
        ignored). With ``replan_revoked`` off the vehicle has dropped that plan.

        When the last vehicle of a reorder has acknowledged, the revoked
        vehicles ordered ahead of the EV are re-confirmed in the order and
        their new confirmations returned, unless the EV is head of its lane:
        then everyone revoked is re-confirmed when the EV is (around its real
        plan), or at :meth:`settle` (see :meth:`take_confirmations`).
        """
        if seq is not None and (vin not in self._pending or self._revoked_seq.get(vin) != seq):
            return []
        key = self._pending.pop(vin, None)
        if key is not None:
            self._drop(key)
            self.acknowledged += 1
            self._answered(vin, DROPPED)
            if not self.reactive.replan_revoked:
                # it stops short of the line and asks again like any head of its lane
                if vin not in self._confirmed:  # (not confirmed anew meanwhile)
                    if self._event is not None:
                        self._event.unplanned.append(vin)
                    self._forget_confirmed(vin)
                return []
        if self._pending:
            return []
        ev = self._event
        if ev is not None and ev.ev_confirmed_s is None and self.queue(ev.lane)[:1] == [ev.ev]:
            return []  # the EV is head of its lane and about to ask: it is planned first
        replans, self._before = self._before, []
        return self._replan(replans)

    def settle(self) -> None:
        """The EV has not asked: its plan is not known. Those ordered ahead of it are
        re-confirmed now; those behind it get no new plan (a guess at the EV's that
        is early lets them take its room, a late one makes them wait for nothing):
        they stop before the line and ask again, held until the EV has its plan.
        Call it once the acknowledgements are in and the EV has had its chance to
        ask (the embedded runner: at the end of each step)."""
        if self._pending:
            return
        if self._before:
            replans, self._before = self._before, []
            self._late += self._replan(replans)
        if not self._after:
            return
        replans, self._after = self._after, []
        for r in replans:
            if r.vin not in self._confirmed and self._event is not None:
                self._event.unplanned.append(r.vin)
                self._forget_confirmed(r.vin)

    def take_confirmations(self) -> list[Confirmation]:
        """Re-confirmations made since the last call outside :meth:`acknowledge`."""
        out, self._late = self._late, []
        return out

    def _replan(self, replans: list[Replan]) -> list[Confirmation]:
        """Re-confirm revoked vehicles in order; those without a plan are left to ask."""
        out = []
        ev = self._event
        stopped: set[str] = set()  # lanes where a vehicle got no new plan: it stops there
        for r in replans:
            if r.vin in self._confirmed:
                continue  # it asked and was confirmed meanwhile
            leader = self._leader_of(r.vin, r.route.in_lane)
            try:
                if r.route.in_lane in stopped:
                    # those behind it (after it in the order, which keeps each lane's) stop
                    # too: planned past it as if it were gone, they would run into it
                    raise RequestError(Reason.NOT_HEAD, "a vehicle ahead stops")
                conf = self._confirm_from(
                    r.vin, r.seq, r.route, r.shape, r.t0_s, r.dist_m, r.speed_mps,
                    -math.inf, leader,
                )  # fmt: skip
            except RequestError:
                if ev is not None:
                    ev.failed.append(r.vin)
                self._forget_confirmed(r.vin)
                stopped.add(r.route.in_lane)
                continue
            out.append(conf)
            self._measure(conf)
        if ev is not None:
            ev.confirmations.extend(out)
        return out

    def _measure(self, conf: Confirmation) -> None:
        """How much later than its revoked plan a revoked vehicle's new plan enters: what
        the reordering added to it, charged against its bound."""
        old = self._revoked_entry.pop(conf.vin, None)
        if old is not None:
            self.replanned_later_s = max(self.replanned_later_s, conf.entry_time_s - old)
            self._charge(conf.vin, conf.entry_time_s - old)

    def _charge(self, vin: str, added_s: float) -> None:
        if added_s > 0.0:
            total = self._added.get(vin, 0.0) + added_s
            self._added[vin] = total
            self.added_peak_s = max(self.added_peak_s, total)

    def summary(self, events: bool = False) -> dict:
        """Per-run figures of the events (counts, solver time, the EV's entries) and of
        the revocations' answers; with ``events`` also a log line per event."""
        out = event_figures(self.reactive.solver, self.events) | {
            "acknowledged": self.acknowledged,
            "restored": self.restored,
            "expired": self.expired,
            "pending": len(self._pending),
            # when the oldest revocation still unanswered was decided [sim s]
            "pending_since_s": min((self._revoked_at[v] for v in self._pending), default=None),
            # the bound on what reorderings add to a vehicle, and the most any was added
            "max_added_delay_s": _finite(self.reactive.max_added_delay_s),
            "added_delay_max_s": round(self.added_peak_s, 3),
            # measured on the plans: the most a revoked vehicle's new plan entered later
            "replanned_later_max_s": round(self.replanned_later_s, 3),
            "bound_trials": self.trials,
            # EVs' notices from upstream: received, and requests held for them
            "notices": self.notices.received,
            "notice_held": self.notices.held,
        }
        if events:
            out["events_log"] = [event_log(e) for e in self.events]
        return out

    # -- crash survival ----------------------------------------------------------------
    def snapshot(self) -> dict:
        """What a restarted ICA needs, beyond its confirmations, to carry on the event it
        was in: the EV's event and its reordering, the EVs waiting, the revocations still
        unanswered (each by the seq of the plan revoked) and the re-confirmations still
        to come, as plain data for the journal (:meth:`restore_snapshot`)."""
        ev = self._event
        return {
            "event": None if ev is None else {
                "ev": ev.ev, "lane": ev.lane, "detected": ev.detected_s,
                "started": ev.started_s, "confirmed": ev.ev_confirmed_s,
                "entry": ev.ev_entry_s, "unplanned": list(ev.unplanned),
                "failed": list(ev.failed),
                "reorder": None if ev.reorder is None else asdict(ev.reorder),
            },
            "waiting": [list(w) for w in self._waiting_evs],
            "pending": [[v, self._revoked_seq[v], self._revoked_at.get(v, 0.0)]
                        for v in self._pending],
            "lanes": {ln: list(vs) for ln, vs in self._lane_revoked.items() if vs},
            "before": [_replan_row(r) for r in self._before],
            "after": [_replan_row(r) for r in self._after],
            "answers": [self.acknowledged, self.restored, self.expired],
            "added": dict(self._added),
            "revoked_entry": dict(self._revoked_entry),
            "notices": self.notices.snapshot(),
            "re_ask": list(self._re_ask),
            "order_since": dict(self._order_since),
        }  # fmt: skip

    def restore_snapshot(self, snap: dict) -> None:
        """Carry on from :meth:`snapshot` after the journal's confirmations were replayed:
        each revoked plan still held under its seq is set aside again and awaits its
        answer (one answered before the crash was journalled as a cancel and is gone);
        the event, the EVs waiting and the re-confirmations to come are as they were."""
        ev = snap.get("event")
        self._event = None
        if ev is not None:
            r = ev.get("reorder")
            reorder = None
            if r is not None:
                reorder = Reorder(**{
                    k: tuple(v) if isinstance(v, list) else v for k, v in r.items()
                })  # fmt: skip
            self._event = EvEvent(
                str(ev["ev"]), str(ev["lane"]), float(ev["detected"]), float(ev["started"]),
                reorder, [], list(ev["failed"]), list(ev["unplanned"]), ev["confirmed"],
                ev["entry"],
            )  # fmt: skip
            self.events = [e for e in self.events if e.ev != self._event.ev] + [self._event]
        self._waiting_evs = [(str(v), str(ln), float(t)) for v, ln, t in snap["waiting"]]
        for vin, seq, at in snap["pending"]:
            c = self._confirmed.get(vin)
            if c is None or c.confirmation.seq != seq or vin in self._pending:
                continue
            key = vin + _ASIDE
            self._set_aside(vin, key)
            self._pending[vin] = key
            self._revoked_seq[vin] = int(seq)
            self._revoked_at[vin] = float(at)
        self._lane_revoked = {
            ln: [v for v in vs if v in self._pending] for ln, vs in snap["lanes"].items()
        }
        self._before = [r for r in map(self._replan_of, snap["before"]) if r is not None]
        self._after = [r for r in map(self._replan_of, snap["after"]) if r is not None]
        self.acknowledged, self.restored, self.expired = (int(x) for x in snap["answers"])
        self._added = {str(v): float(a) for v, a in snap.get("added", {}).items()}
        self._revoked_entry = {str(v): float(t) for v, t in snap.get("revoked_entry", {}).items()}
        self.notices.restore(snap.get("notices", {}))
        self._re_ask = [str(v) for v in snap.get("re_ask", [])]
        self._order_since = {str(v): float(t) for v, t in snap.get("order_since", {}).items()}

    def _replan_of(self, row: list) -> Replan | None:
        vin, seq, rid, length, width, t0, dist, speed = row
        route = self.intersection.route_by_id(rid)
        if route is None:
            return None
        return Replan(vin, int(seq), route, Shape.of(length, width), t0, dist, speed)

    # -- DICA's entry points ------------------------------------------------------------
    def detect(
        self,
        vin: str,
        lane: str,
        t_s: float,
        emergency: bool = False,
        speed_mps: float | None = None,
    ) -> None:
        """A vehicle crossed the region's entry line; ``emergency`` marks an EV (the
        detector reads it), ``speed_mps`` is its speed there if measured."""
        super().detect(vin, lane, t_s)
        if vin not in self._detected:
            self._detected[vin] = (self._detections, t_s, speed_mps)
            self._detections += 1
            if emergency:
                self._waiting_evs.append((vin, lane, t_s))
                if self._event is None and self.reactive.start_at == "detection":
                    self._next_event(max(self._now, t_s))

    def adopt(
        self, confirmation: Confirmation, length_m: float, width_m: float, in_lane: str
    ) -> None:
        """DICA's adoption (a restarted ICA's replay), with the lane's order of
        confirmations kept as :meth:`handle` keeps it: a replay leaves the same state."""
        known = confirmation.vin in self._confirmed
        super().adopt(confirmation, length_m, width_m, in_lane)
        if not known:
            self._lane_confirmed[in_lane].append(confirmation.vin)

    def advance(self, now_s: float) -> list[str]:
        self._now = now_s
        gone = super().advance(now_s)
        self.notices.advance(now_s)
        for key in gone:
            if key.endswith(_ASIDE):
                vin = key[: -len(_ASIDE)]
                if self._pending.get(vin) == key:  # its old plan is over: nothing to wait for
                    del self._pending[vin]
                    self.expired += 1
                    self._answered(vin, EXPIRED)
                    if vin not in self._confirmed:
                        self._done_re_asking(vin)
                        # flown, or dropped with the answer lost: either way it leaves its
                        # lane's queue (one still short of the line is told NOT_DETECTED
                        # when it asks, and announces itself again in its place)
                        lane = self._lane_of.pop(vin, None)
                        if lane is not None:
                            self._lanes[lane] = [e for e in self._lanes[lane] if e[2] != vin]
                        self._forget_confirmed(vin)
                continue
            self._detected.pop(key, None)
            self._no_room.discard(key)
            self._done_re_asking(key)
            self._added.pop(key, None)
            self._revoked_entry.pop(key, None)
            for lst in self._lane_confirmed.values():
                if key in lst:
                    lst.remove(key)
        ev = self._event
        if ev is not None and ev.ev in gone:
            ev.closed_s = now_s
            self._event = None
        if self._event is None:
            if self.reactive.start_at == "detection":
                self._next_event(now_s)
            else:
                self._next_hold(now_s)
        return gone

    def _handle(self, req: Request, now_s: float) -> Confirmation:
        well_typed = all(isinstance(x, str) for x in (req.vin, req.in_lane, req.out_lane))
        if (
            well_typed
            and req.vin in self._pending
            and isinstance(req.seq, int)
            and req.seq > self._revoked_seq[req.vin]
        ):
            # asking again under a higher seq proves the vehicle does not fly the revoked
            # plan (as a CANCEL of it would): its ACK may still be on its way by another
            # path, and the request must not be planned around its own old reservation
            self.acknowledge(req.vin, self._revoked_seq[req.vin])
        ev = self._event
        if (
            well_typed
            and req.vin not in self._confirmed
            and (ev is None or (ev.ev == req.vin and ev.reorder is None))
            and any(w[0] == req.vin for w in self._waiting_evs) == (ev is None)
            and self.is_head(req.vin, now_s)
        ):
            # an EV asks as head of its lane: the vehicles are reordered for it now
            if ev is None:
                self._next_event(now_s, first=req.vin, reorder=False)
            self._reorder(self._event, now_s, req)
            if self._pending:
                raise RequestError(
                    Reason.HELD,
                    f"{req.vin}: confirmations are being revoked for it; ask again once "
                    "they are acknowledged",
                )
        ev = self._event
        if (
            not self.reactive.replan_revoked
            and ev is not None
            and req.vin == ev.ev
            and ev.ev_confirmed_s is None
            and self._pending
        ):
            raise RequestError(
                Reason.HELD,
                f"{req.vin}: {len(self._pending)} revoked confirmations await their answers",
            )
        if (
            ev is not None
            and ev.ev_confirmed_s is None
            and well_typed
            and req.vin not in self._confirmed  # a repeated request gets its answer again
            and self._held(req, ev)
        ):
            raise RequestError(
                Reason.HELD, f"{req.vin} waits: emergency vehicle {ev.ev} crosses first"
            )
        if self._re_ask and well_typed and req.vin not in self._confirmed:
            first = self._ordered_before(req.vin, now_s)
            if first is not None:
                raise RequestError(Reason.HELD, f"{req.vin} waits: {first} was ordered before it")
        if self.notices and well_typed and req.vin not in self._confirmed:
            coming = self._notice_held(req, now_s)
            if coming is not None:
                self.notices.held += 1
                raise RequestError(
                    Reason.HELD, f"{req.vin} waits: emergency vehicle {coming} is on its way"
                )
        known = req.vin in self._confirmed if well_typed else True
        conf = super()._handle(req, now_s)
        if not known:
            self._lane_confirmed[req.in_lane].append(req.vin)
            self._measure(conf)
            self.notices.served(req.vin, now_s)
            self._done_re_asking(req.vin)
        if ev is not None and req.vin == ev.ev and ev.ev_confirmed_s is None:
            ev.ev_confirmed_s = now_s
            ev.ev_entry_s = conf.entry_time_s
            waiting = self._before + self._after
            if waiting and not self._pending and abs(now_s - waiting[0].t0_s) < 1e-6:
                # the revoked vehicles, in the order, around the EV's real plan, from the
                # states they had at the effective time (no time has passed in between)
                self._before, self._after = [], []
                self._late += self._replan(waiting)
        return conf

    # -- EVs on their way -----------------------------------------------------------
    def ev_coming(self, notice: EvNotice, now_s: float) -> bool:
        """EV ``notice.ev`` is on its way here (:mod:`ica.core.ev_notice`): from a lead
        before its arrival, vehicles that could take its lanes' room are held. False if
        the notice is stale (the EV is confirmed here already); a notice of a way this
        junction does not have is refused."""
        if not (isinstance(notice.ev, str) and math.isfinite(notice.eta_s)):
            raise RequestError(Reason.BAD_STATE, "an EV notice needs an id and a finite arrival")
        way = (notice.in_edge, notice.out_edge)
        lanes = self._notice_lanes.get(way)  # an EV is told again every 2 s of its way here
        if lanes is None:
            lanes = frozenset(
                r.in_lane
                for r in self.intersection.routes
                if edge_of(r.in_lane) == notice.in_edge and edge_of(r.out_lane) == notice.out_edge
            )
            if lanes:  # (a way this junction lacks is not kept: any text may be asked)
                self._notice_lanes[way] = lanes
        if not lanes:
            raise RequestError(
                Reason.UNKNOWN_ROUTE,
                f"no way from {notice.in_edge} to {notice.out_edge} through "
                f"{self.intersection.junction_id}",
            )
        if notice.ev in self._confirmed:
            self.notices.served(notice.ev, now_s)
            return False
        return self.notices.take(lanes, notice, now_s)

    def _notice_held(self, req: Request, now_s: float) -> str | None:
        """The EV on its way that ``req`` must wait for (None: none): its way here could
        take the room of a way from the EV's lanes, and it is not in one of them."""
        if req.vin in self.notices or any(w[0] == req.vin for w in self._waiting_evs):
            return None  # an EV itself is never held for another's notice
        route = self.intersection.route(req.in_lane, req.out_lane)
        if route is None:
            return None  # let DICA reject it with its own reason
        sh = Shape.of(req.length_m, req.width_m) if _sized(req) else self._shape
        for n in self.notices.holding(now_s):
            if req.in_lane in n.lanes:
                continue  # in the EV's lanes: it clears them
            waiting = self._waiting_in(n.lanes)
            lead = min(LEAD_S, CLEAR_MARGIN_S + waiting * CLEAR_HEADWAY_S)
            if not 0 < waiting <= CLEAR_MOST or now_s < n.eta_s - lead:
                continue  # nothing to clear away (or too much), or not yet
            theirs = self._notice_routes.get(n.lanes)
            if theirs is None:
                theirs = tuple(r for r in self.intersection.routes if r.in_lane in n.lanes)
                self._notice_routes[n.lanes] = theirs
            if not all(self.tables.compatible(route, sh, r, self._shape) for r in theirs):
                return n.ev
        return None

    def _ordered_before(self, vin: str, now_s: float) -> str | None:
        """A revoked vehicle asking again waits for its event's EV and for those the order
        put before it to have their plans, ORDER_WAIT_S at most: the bound was checked on
        a copy that planned them so (the EV first, then the revoked in the order, with
        every revocation answered). Asking in their own order, or before the EV, they were
        planned around revoked plans not yet dropped and charged up to 6 s over a 2 s
        bound. The first it waits for, or None."""
        if vin not in self._re_ask:
            return None
        ahead = self._re_ask[: self._re_ask.index(vin)]
        first = next((v for v in ahead if v not in self._confirmed and v in self._lane_of), None)
        ev = self._event
        if (
            ev is not None
            and ev.ev_confirmed_s is None
            and ev.reorder is not None
            and vin in ev.reorder.revoked
            and ev.ev in self._lane_of
        ):
            first = ev.ev
        if first is None:
            return None
        since = self._order_since.setdefault(vin, now_s)
        return first if now_s - since <= ORDER_WAIT_S else None

    def _done_re_asking(self, vin: str) -> None:
        if vin in self._re_ask:
            self._re_ask.remove(vin)
        self._order_since.pop(vin, None)

    def _waiting_in(self, lanes: frozenset[str]) -> int:
        """The most vehicles detected in one of ``lanes`` that wait for their plans (the
        queue the EV would meet; 0: its lanes flow). A lane whose first vehicle waiting
        was last refused for room beyond the junction counts none: holding the traffic
        across would not move it."""
        most = 0
        for lane in lanes:
            waiting = [v for v in self.queue(lane) if v not in self._confirmed]
            if waiting and waiting[0] not in self._no_room:
                most = max(most, len(waiting))
        return most

    def handle(self, req: Request, now_s: float) -> Confirmation | Rejection:
        """DICA's answer, noting who waits for room beyond the junction (:meth:`_waiting_in`
        does not clear a lane for an EV whose first vehicle waits for that)."""
        got = super().handle(req, now_s)
        if isinstance(got, Rejection) and got.reason is Reason.NO_ROOM:
            self._no_room.add(got.vin)
        elif self._no_room:
            self._no_room.discard(req.vin)
        return got

    # -- the event ----------------------------------------------------------------------
    def _held(self, req: Request, ev: EvEvent) -> bool:
        vin = req.vin
        if vin == ev.ev:
            return False
        if req.in_lane == ev.lane:
            mine = self._detected.get(vin)
            theirs = self._detected.get(ev.ev)
            if mine is not None and theirs is not None and mine[0] < theirs[0]:
                return False  # ahead of the EV in its lane: it must go first anyway
        route = self.intersection.route(req.in_lane, req.out_lane)
        if route is None:
            return False  # an unknown route: let DICA reject it with its own reason
        sh = Shape.of(req.length_m, req.width_m) if _sized(req) else self._shape
        return not all(
            self.tables.compatible(route, sh, r, self._shape)
            for r in self.intersection.routes_from(ev.lane)
        )

    def _next_hold(self, now_s: float) -> None:
        """Start holding for the first EV waiting once no unconfirmed vehicle is ahead
        of it in its lane: it is next to go, and its request will reorder."""
        while self._waiting_evs and self._event is None:
            vin, lane, _ = self._waiting_evs[0]
            if vin in self._confirmed or vin not in self._lane_of:
                self._waiting_evs.pop(0)
                continue
            queue = self.queue(lane)
            if any(v not in self._confirmed for v in queue[: queue.index(vin)]):
                return
            self._next_event(now_s, reorder=False)

    def _next_event(self, now_s: float, first: str | None = None, reorder: bool = True) -> None:
        """Start the event of the next EV waiting (of ``first``, if given)."""
        if first is not None:
            i = next(i for i, w in enumerate(self._waiting_evs) if w[0] == first)
            self._waiting_evs.insert(0, self._waiting_evs.pop(i))
        while self._waiting_evs and self._event is None:
            vin, lane, t_det = self._waiting_evs.pop(0)
            if vin in self._confirmed or vin not in self._lane_of:
                continue  # already confirmed (or gone): nothing left to reorder for it
            self._event = EvEvent(vin, lane, t_det, now_s)
            self.events.append(self._event)
            if reorder:
                self._reorder(self._event, now_s)

    def _reorder(self, ev: EvEvent, now_s: float, req: Request | None = None) -> None:
        t_prep = time.perf_counter()
        t_eff = now_s + self.reactive.revoke_latency_s
        fixed, modifiable = self._classify(t_eff)
        classify_s = time.perf_counter() - t_prep
        o = self._ordered(ev, t_eff, fixed, modifiable)
        prepare_s, solve_s = classify_s + o.prepare_s, o.solve_s
        bounded = math.isfinite(self.reactive.max_added_delay_s)
        trials = 0
        while bounded and req is not None and not o.refused and o.revoked():
            # the ordering model's separations are those of lone vehicles: the real re-plans
            # (DICA's search around the EV's real plan) may come out later. Carry the order
            # out on a copy; whoever would end past its bound keeps its plan, with everyone
            # ahead of it in its lane, and the rest is ordered again
            trials += 1
            t_trial = time.perf_counter()
            over = self._over_bound(req, now_s, o)
            prepare_s += time.perf_counter() - t_trial
            if not over:
                break
            kept = self._with_those_ahead(over, {vin for vin, _ in modifiable})
            modifiable = [m for m in modifiable if m[0] not in kept]
            fixed = self.entries(skip={vin for vin, _ in modifiable})
            o = self._ordered(ev, t_eff, fixed, modifiable)
            prepare_s += o.prepare_s
            solve_s += o.solve_s
        cands, order, added = o.cands, o.order, o.added
        revoked: list[str] = []
        if not o.refused:
            ev_pos = order.index(o.ev_idx)
            keep = o.kept()
            for i, c in enumerate(cands):
                if c.state is None:  # not revoked: its plan is yet to come, the model's say
                    self._charge(c.vin, float(added[i]))
            replan = self.reactive.replan_revoked
            for pos, i in enumerate(order):
                c = cands[i]
                if c.state is None or i in keep:
                    continue
                if replan:
                    (self._after if pos > ev_pos else self._before).append(c.state)
                self._revoked_seq[c.vin] = self._confirmed[c.vin].confirmation.seq
                self._revoked_entry[c.vin] = self._confirmed[c.vin].confirmation.entry_time_s
                self._revoked_at[c.vin] = now_s
                key = c.vin + _ASIDE
                self._set_aside(c.vin, key)
                self._pending[c.vin] = key
                revoked.append(c.vin)
            if not replan:
                self._re_ask = [v for v in self._re_ask if v in self._lane_of] + revoked
            for vin in revoked:  # front to back in each lane, by detection
                lane = self._lane_of[vin]
                lst = [v for v in self._lane_revoked.get(lane, []) if v in self._pending]
                self._lane_revoked[lane] = sorted(
                    {*lst, vin}, key=lambda v: self._detected.get(v, (0,))[0]
                )
        self.trials += trials
        ev.reorder = Reorder(
            t_s=now_s,
            effective_s=t_eff,
            ev=ev.ev,
            solver=self.reactive.solver,
            order=tuple(cands[i].vin for i in order),
            revoked=tuple(revoked),
            ev_entry_before_s=o.before,
            ev_entry_after_s=o.after,
            solve_s=solve_s,
            prepare_s=prepare_s,
            refused=o.refused,
            lane=ev.lane,
            seqs=tuple(self._revoked_seq[vin] for vin in revoked),
            added_s=tuple(round(float(added[i]), 6) for i in order),
        )
        self._outbox.append(ev.reorder)

    def _ordered(
        self,
        ev: EvEvent,
        t_eff: float,
        fixed: list[tuple[Route, float, float]],
        modifiable: list[tuple[str, Replan]],
    ) -> _Ordered:
        """The candidates and the solver's order for them (the present one if refused)."""
        t_prep = time.perf_counter()
        cands = [self._confirmed_candidate(vin, st) for vin, st in modifiable]
        cands += self._lane_candidates(ev, t_eff)
        n = len(cands)
        ev_idx = next(i for i, c in enumerate(cands) if c.vin == ev.ev)
        lanes = sorted({c.lane for c in cands})
        sep = np.zeros((n, n))
        for j, cj in enumerate(cands):
            for k, ck in enumerate(cands):
                if j != k:
                    sep[j, k] = self._sep(cj.routes, cj.entry_mps, ck.routes, ck.entry_mps)
        release = np.array([self._release(c, fixed) for c in cands])
        # the present order: confirmed vehicles by their confirmed entries, then the EV's lane
        present = sorted(
            (i for i in range(n) if cands[i].state is not None),
            key=lambda i: (self._confirmed[cands[i].vin].confirmation.entry_time_s, i),
        ) + [i for i in range(n) if cands[i].state is None]
        t0 = time.perf_counter()
        refused = ""
        before = after = math.nan
        added = np.zeros(n)
        bounded = False
        try:
            lane_idx = np.array([lanes.index(c.lane) for c in cands])
            problem = Problem(lane_idx, release, sep, ev_idx)
            e_present, before, _ = evaluate(problem, present)
            bound = self.reactive.max_added_delay_s
            if math.isfinite(bound):
                # nobody may enter later than in the present order by more than what is
                # left of its bound after the reorderings it met before
                spare = np.array([max(0.0, bound - self._added.get(c.vin, 0.0)) for c in cands])
                deadline = e_present + spare
                deadline[ev_idx] = math.inf
                problem = Problem(lane_idx, release, sep, ev_idx, deadline)
                bounded = True
            sol = solve(
                problem,
                self.reactive.solver,
                seed=hash((self.reactive.seed, len(self.events))) & 0x7FFFFFFF,
                ga_params=self.reactive.ga,
                limit=self.reactive.exhaustive_limit,
            )
            order, after = sol.order, sol.ev_entry_s
            added = np.maximum(sol.entry_s - e_present, 0.0)
            added[ev_idx] = 0.0
        except OrderingError as e:
            refused = str(e)
            order, after = tuple(present), before
        o = _Ordered(
            cands, ev_idx, tuple(order), added, before, after, refused, bounded,
            t0 - t_prep, time.perf_counter() - t0,
        )  # fmt: skip
        for i in o.kept():  # it keeps its plan: nothing is added to it
            if cands[i].state is not None:
                added[i] = 0.0
        return o

    def _with_those_ahead(self, vins: set[str], modifiable: set[str]) -> set[str]:
        """``vins`` and every modifiable vehicle ahead of one of them in its lane: a vehicle
        that keeps its plan must not find its leader's plan gone."""
        out = set(vins)
        for vin in vins:
            lane = self._lane_of.get(vin)
            queue = self.queue(lane) if lane is not None else []
            if vin in queue:
                out |= {v for v in queue[: queue.index(vin)] if v in modifiable}
        return out

    def _over_bound(self, req: Request, now_s: float, o: _Ordered) -> set[str]:
        """Carry ``o`` out on a copy of this ICA, as it would go with every revocation
        acknowledged: the EV planned by its REQUEST, then the revoked vehicles in the
        order around its real plan. Returns the revoked vehicles whose new plan would
        enter later than their revoked one by more than what is left of their bound (or
        that would get no plan at all).

        With ``replan_revoked`` off the revoked vehicles drop their plans and ask again
        themselves, each once those before it have theirs: from REASK_STEPS steps on,
        all in one step or each a step after the one before (their requests in one step
        go in any order). A plan is found among slots, so a start a step off can land in
        another: the order must keep every bound at both ends."""
        revoked = [o.cands[i] for i in o.revoked()]
        old = {c.vin: self._confirmed[c.vin].confirmation.entry_time_s for c in revoked}
        states = [c.state for c in revoked]
        if self.reactive.replan_revoked:
            cases = [states]
        else:
            cases = [
                [self._re_asked(st, REASK_STEPS) for st in states],
                [self._re_asked(st, REASK_STEPS + i) for i, st in enumerate(states)],
            ]
            if len(states) < 2:
                cases = cases[:1]
        bound = self.reactive.max_added_delay_s
        base = copy.deepcopy(self, self._shared())
        for c in revoked:
            base._drop(c.vin)
        base._event = None
        try:
            Dica._handle(base, req, now_s)
        except RequestError:
            return set()  # the EV is not planned now: nothing to measure against
        over: set[str] = set()
        for k, case in enumerate(cases):  # the EV's plan made once, each case on a copy
            trial = base if k == len(cases) - 1 else copy.deepcopy(base, self._shared())
            new = {conf.vin: conf.entry_time_s for conf in trial._replan(case)}
            over |= {
                vin
                for vin, t in old.items()
                if vin not in new or new[vin] - t > bound - self._added.get(vin, 0.0) + 1e-9
            }
        return over

    def _re_asked(self, st: Replan, steps: int) -> Replan:
        """``st`` ``steps`` steps on, the plan dropped: where the vehicle's stop law takes it
        (a vehicle that may ask does not speed up), from which its new plan starts."""
        kin, h = self.config.kinematics, self.config.step_s
        d, v = predict_stop(
            st.dist_m, st.speed_mps, steps, gap_m=kin.stop_gap_m, cap_mps=st.speed_mps, h=h,
            accel_mps2=kin.accel_mps2, decel_mps2=kin.decel_mps2,
        )  # fmt: skip
        # on the clock's millisecond grid, as the vehicle's own REQUEST will be: the search
        # can tell a plan starting on the grid from one a rounding error off it
        return replace(st, t0_s=round(st.t0_s + steps * h, 6), dist_m=d, speed_mps=v)

    def _shared(self) -> dict[int, object]:
        """What a trial copy shares with this ICA instead of copying (read-only)."""
        return {id(x): x for x in (self.intersection, self.tables, self.separations, self.config,
                                   self.reactive, self._shape)}  # fmt: skip

    def _classify(self, t_eff: float) -> tuple[list[tuple[Route, float, float]], list]:
        """Confirmed reservations split into fixed ones (route, entry, entry speed) and
        modifiable vehicles (vin, state at ``t_eff``), lane by lane from the back."""
        modifiable: list[tuple[str, Replan]] = []
        for queue in map(self.queue, self._lanes):
            confirmed = [v for v in queue if v in self._confirmed]
            ok = True
            for vin in reversed(confirmed):  # a vehicle can change only if those behind can
                st = self._state_at(vin, t_eff) if ok else None
                if st is None:
                    ok = False
                else:
                    modifiable.append((vin, st))
        fixed = self.entries(skip={vin for vin, _ in modifiable})
        modifiable.sort(key=lambda m: (m[1].route.in_lane, self._detected.get(m[0], (0,))[0]))
        return fixed, modifiable

    def _state_at(self, vin: str, t_eff: float) -> Replan | None:
        """The state of a confirmed vehicle at ``t_eff`` on its plan, if it can still stop."""
        c = self._confirmed[vin]
        traj = c.dtot.trajectory
        k = round((t_eff - traj.t0_s) / traj.step_s)
        if k < 0 or k >= len(traj) - 1:
            return None
        s = float(traj.s_m[k])
        if s >= 0.0:
            return None
        if k >= 1:
            v = float(traj.s_m[k] - traj.s_m[k - 1]) / traj.step_s
        else:
            v = float(traj.s_m[1] - traj.s_m[0]) / traj.step_s
        st = Replan(
            # re-confirmed under the next seq: a plan the actuator takes over the old one
            vin, c.confirmation.seq + 1, c.dtot.route, c.dtot.shape, traj.t0_s + k * traj.step_s,
            -s, v,
        )  # fmt: skip
        # the actuator's discrete stop law, run from where the vehicle really is (within
        # its tracking error), needs a little more room than the continuous bound: a
        # revocation it could not carry out would leave a plan flown that nobody holds
        slack = STOP_SLACK_STEPS * v * traj.step_s + STOP_SLACK_M
        if not self._planner(replace(st, dist_m=st.dist_m - slack)).can_stop():
            return None
        return st

    def _planner(self, st: Replan) -> Planner:
        cfg = self.config
        return Planner(
            d_m=st.dist_m,
            v0_mps=st.speed_mps,
            road_mps=st.route.road_mps,
            cap_mps=self.front_cap_mps(st.route),
            s_end_m=st.route.cross_length_m + st.shape.length_m,
            kin=cfg.kinematics,
            hold=cfg.platoon,
        )

    def _confirmed_candidate(self, vin: str, st: Replan) -> Candidate:
        pl = self._planner(st)
        fastest = pl.fastest()
        entry_mps = fastest.entry_speed_mps if fastest is not None else 0.0
        release = st.t0_s + pl.earliest_entry_s()
        return Candidate(vin, st.route.in_lane, (st.route,), release, entry_mps, st)

    def _lane_candidates(self, ev: EvEvent, t_eff: float) -> list[Candidate]:
        queue = self.queue(ev.lane)
        return lane_candidates(
            ev, t_eff, queue, [v in self._confirmed for v in queue], self._detected,
            self.intersection, self.config, self._shape, self.separations,
        )  # fmt: skip

    def _sep(self, a: tuple[Route, ...], a_mps: float, b: tuple[Route, ...], b_mps: float) -> float:
        """The largest separation over the routes each vehicle may take."""
        return max(self.separations.separation_s(ra, a_mps, rb, b_mps) for ra in a for rb in b)

    def _release(self, c: Candidate, fixed: list[tuple[Route, float, float]]) -> float:
        """Earliest entry, and no earlier than the fixed reservations allow."""
        return self.separations.release_after(c.release_s, c.routes, c.entry_mps, fixed)

    def _leader_of(self, vin: str, lane: str) -> str | None:
        """The vehicle confirmed from ``vin``'s lane just before it (still confirmed)."""
        lst = self._lane_confirmed[lane]
        if vin not in lst:
            return None
        i = lst.index(vin)
        for lead in reversed(lst[:i]):
            if lead in self._confirmed:
                return lead
        return None

    def _forget_confirmed(self, vin: str) -> None:
        """A revoked vehicle left without a plan: it will ask again like any other."""
        for lst in self._lane_confirmed.values():
            if vin in lst:
                lst.remove(vin)


def _replan_row(r: Replan) -> list:
    return [r.vin, r.seq, r.route.id, r.shape.length_m, r.shape.width_m, r.t0_s, r.dist_m,
            r.speed_mps]  # fmt: skip


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _sized(req: Request) -> bool:
    return (
        isinstance(req.length_m, (int, float))
        and isinstance(req.width_m, (int, float))
        and 0 < req.length_m < 50
        and 0 < req.width_m < 10
    )
