"""An emergency vehicle's notice to a junction ahead on its route: it is coming, by
this approach to that exit, at the earliest then.

Reactive DICA reorders when an EV reaches the junction's own region, 50 m out. By
then a queue in the EV's lane may reach back past the region, and the EV stops
behind it whatever the reordering does. A notice lets the junction clear the
EV's approach before it arrives, as a pre-empting light turns green ahead of the
ambulance, but only for as long as the queue there needs: while ``n`` vehicles
detected in the EV's lanes wait for their plans, from ``CLEAR_MARGIN_S + n *
CLEAR_HEADWAY_S`` (at most :data:`LEAD_S`) before the EV's earliest arrival at the
entry line, the ICA holds (REJECT ``held``) the new requests of vehicles whose way
through the junction could take the room of the EV's lanes, so the vehicles of
those lanes (those ahead of it included) are planned through at once and the EV
finds them flowing. With nothing waiting there, nobody is held. Plans already
confirmed are kept: a notice never takes back a confirmation, so safety is DICA's
own.

A notice holds until the EV holds a confirmation at the junction, or until
:data:`GRACE_S` past the arrival it gave unless a newer notice moves that on, and
never longer than :data:`MAX_HOLD_S` in all for one EV at one junction: an EV
stuck upstream cannot starve the junction's other approaches. Notices are sent
again every few seconds while the EV drives on, so a restarted ICA, or one that
lost a message, is told again. Pure: plain data in, a verdict out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LEAD_S = 10.0  # [s] the hold begins at most this long before the EV's earliest arrival
# [s] what clearing a queue takes: each vehicle waiting in the EV's lanes this long (a queue's
# discharge headway at the line), and this much more; the hold begins that long ahead
CLEAR_HEADWAY_S = 2.0
CLEAR_MARGIN_S = 2.0
# a longer queue than this in the EV's lanes is not cleared ahead (holding the traffic across
# as long as it takes cost a grid near saturation more than it gained the EVs)
CLEAR_MOST = 3
GRACE_S = 10.0  # [s] a notice not renewed ends this long after the arrival it gave
MAX_HOLD_S = 20.0  # [s] the longest one EV's notices may hold a junction, in all
HORIZON_S = 60.0  # [s] notices are sent for junctions the EV may reach within this


@dataclass(frozen=True, slots=True)
class EvNotice:
    """EV ``ev`` will come in by ``in_edge`` and leave by ``out_edge``, its front at
    the entry line at ``eta_s`` at the earliest (free flow from where it is)."""

    ev: str
    in_edge: str
    out_edge: str
    eta_s: float
    sent_s: float


@dataclass(slots=True)
class Notice:
    """One EV's notice as a junction keeps it: the lanes it may come by (their
    vehicles are never held for it) and when its hold begins and ends."""

    ev: str
    lanes: frozenset[str]
    eta_s: float
    first_hold_s: float  # when its hold first began (inf: not yet)
    sent_s: float = -math.inf  # when the notice kept was sent (a late older one is stale)

    def holding(self, now_s: float) -> bool:
        if now_s < self.eta_s - LEAD_S or now_s > self.eta_s + GRACE_S:
            return False
        return now_s <= min(self.first_hold_s, now_s) + MAX_HOLD_S


def edge_of(lane: str) -> str:
    """A SUMO lane's edge: its id less the ``_<index>`` it ends with."""
    return lane.rsplit("_", 1)[0]


class Notices:
    """The EV notices a junction holds to: renewed by newer ones, ended once the EV is
    served (confirmed here) or its time is up."""

    def __init__(self) -> None:
        self._by_ev: dict[str, Notice] = {}
        self._served: dict[str, float] = {}  # EVs confirmed here, and when
        self._first: dict[str, float] = {}  # EVs whose notices ended: when their hold began
        self.received = 0
        self.held = 0  # requests held for a notice

    def __bool__(self) -> bool:
        return bool(self._by_ev)

    def take(self, lanes: frozenset[str], notice: EvNotice, now_s: float) -> bool:
        """Keep ``notice`` (its EV may come by ``lanes``); False if it is stale: its EV
        is served here already, or a newer notice of it is held."""
        self.received += 1
        if notice.ev in self._served:
            return False
        old = self._by_ev.get(notice.ev)
        if old is not None and notice.sent_s < old.sent_s:
            return False  # overtaken on its way by a newer one
        if old is not None and old.lanes == lanes and notice.eta_s == old.eta_s:
            return True
        first = old.first_hold_s if old is not None else self._first.get(notice.ev, math.inf)
        n = self._by_ev[notice.ev] = Notice(notice.ev, lanes, notice.eta_s, first, notice.sent_s)
        if n.holding(now_s):
            n.first_hold_s = min(first, now_s)
        return True

    def __contains__(self, ev: object) -> bool:
        """Whether a notice of EV ``ev`` is kept."""
        return ev in self._by_ev

    def served(self, ev: str, now_s: float) -> None:
        """``ev`` holds a confirmation here: its notices are done (a late one is stale)."""
        if self._by_ev.pop(ev, None) is not None:
            self._served[ev] = now_s

    def advance(self, now_s: float) -> None:
        """Note when each hold begins; forget notices whose time is up, and served EVs
        long gone (a late notice of one cannot come that much later)."""
        for ev, n in list(self._by_ev.items()):
            if n.holding(now_s):
                n.first_hold_s = min(n.first_hold_s, now_s)
            elif now_s > n.eta_s + GRACE_S or now_s > n.first_hold_s + MAX_HOLD_S:
                del self._by_ev[ev]
                if math.isfinite(n.first_hold_s):  # a renewed notice holds no longer
                    self._first[ev] = n.first_hold_s
        forget = HORIZON_S + GRACE_S + MAX_HOLD_S
        if self._served:
            self._served = {v: t for v, t in self._served.items() if now_s - t < forget}
        if self._first:
            self._first = {v: t for v, t in self._first.items() if now_s - t < forget}

    def holding(self, now_s: float) -> list[Notice]:
        """The notices that hold now, earliest arrival first."""
        return sorted((n for n in self._by_ev.values() if n.holding(now_s)), key=lambda n: n.eta_s)

    def snapshot(self) -> dict:
        return {
            "notices": [
                [n.ev, sorted(n.lanes), n.eta_s, _finite(n.first_hold_s), _finite(n.sent_s)]
                for n in self._by_ev.values()
            ],
            "served": dict(self._served),
            "first": dict(self._first),
        }

    def restore(self, snap: dict) -> None:
        self._by_ev = {
            str(ev): Notice(
                str(ev), frozenset(lanes), float(eta), math.inf if first is None else first,
                -math.inf if sent is None else sent,
            )
            for ev, lanes, eta, first, sent in snap.get("notices", [])
        }  # fmt: skip
        self._served = {str(v): float(t) for v, t in snap.get("served", {}).items()}
        self._first = {str(v): float(t) for v, t in snap.get("first", {}).items()}


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
