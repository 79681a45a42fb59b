"""Emergency vehicles' notices to the junctions ahead of them (:mod:`ica.core.ev_notice`),
worked out from SUMO's own state as an EV's on-board unit would from its route and
position.

Every :data:`PERIOD_S` each emergency vehicle in the net tells each signal-free
junction its route still passes, within :data:`~ica.core.ev_notice.HORIZON_S` of
free flow, by which way it will cross and when its front may reach the entry
line at the earliest: free flow from where it is, at its own speed factor and no
faster than its type allows, with nothing of the junctions' own lengths counted
(an earlier arrival only starts the hold sooner). A junction it is crossing or has
crossed is told nothing more.
"""

from __future__ import annotations

from collections.abc import Sequence

from dica.ica.core.ev_notice import HORIZON_S, EvNotice, edge_of
from dica.ica.core.intersection import Intersection

PERIOD_S = 2.0  # [s] how often each EV's notices are sent again


class EvCorridor:
    """The notices each EV in the net sends, for ``inters``' junctions."""

    def __init__(self, ls, inters: Sequence[Intersection], step_s: float) -> None:
        self.ls = ls
        self._way: dict[tuple[str, str], str] = {}
        for x in inters:
            for r in x.routes:
                self._way[(edge_of(r.in_lane), edge_of(r.out_lane))] = x.junction_id
        self._every = max(1, round(PERIOD_S / step_s))
        self._step = 0
        self._class: dict[str, bool] = {}  # vehicle -> whether an EV (read once)
        self._edge: dict[str, tuple[float, float]] = {}  # edge -> (length, speed limit)

    def due(self) -> bool:
        """Whether this step's notices are due (call once a step)."""
        self._step += 1
        return (self._step - 1) % self._every == 0

    def notices(self, t_s: float) -> list[tuple[str, EvNotice]]:
        """This step's notices, as (junction, notice), EVs by id."""
        v = self.ls.vehicle
        present = v.getIDList()
        known = self._class
        for vid in present:
            if vid not in known:
                known[vid] = v.getVehicleClass(vid) == "emergency"
        if len(known) > 2 * len(present) + 64:
            keep = set(present)
            self._class = known = {k: e for k, e in known.items() if k in keep}
        out = []
        for vid in sorted(x for x in present if known[x]):
            out += self._ahead(vid, t_s)
        return out

    def _ahead(self, vid: str, t_s: float) -> list[tuple[str, EvNotice]]:
        v = self.ls.vehicle
        route = v.getRoute(vid)
        idx = v.getRouteIndex(vid)
        if idx < 0 or idx >= len(route):
            return []
        inside = v.getRoadID(vid).startswith(":")  # crossing the junction after route[idx]
        top = min(v.getMaxSpeed(vid), 1e9)
        factor = v.getSpeedFactor(vid)
        ahead_s = 0.0
        out = []
        for k in range(idx, len(route) - 1):
            length, limit = self._edge_of(route[k])
            speed = max(min(limit * factor, top), 0.1)
            if k == idx:
                length = 0.0 if inside else max(length - v.getLanePosition(vid), 0.0)
            ahead_s += length / speed
            if ahead_s > HORIZON_S:
                break
            junction = self._way.get((route[k], route[k + 1]))
            if junction is not None and not (k == idx and inside):
                out.append((junction, EvNotice(vid, route[k], route[k + 1], t_s + ahead_s, t_s)))
        return out

    def _edge_of(self, edge: str) -> tuple[float, float]:
        got = self._edge.get(edge)
        if got is None:
            lanes = [f"{edge}_{i}" for i in range(self.ls.edge.getLaneNumber(edge))]
            # the fastest lane's limit (a sidewalk's or a bus lane's may be lower)
            got = (
                self.ls.lane.getLength(lanes[0]),
                max(self.ls.lane.getMaxSpeed(x) for x in lanes),
            )
            self._edge[edge] = got
        return got
