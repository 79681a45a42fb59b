"""Ways on for a route file's vehicle sent another way at a junction: never turning back
at a junction an ICA serves.

A vehicle whose lane does not lead where its route goes crosses by a way the junction
serves and is routed on from beyond it. SUMO's router finds the fastest way, and on a
net with turnarounds that way often turns back at the next junction, or at this one
after a round of the block: a U-turn no ICA serves, so the vehicle is sent round
again, and again. Where SUMO's way turns back at a served junction, the vehicle takes
the fastest way that does not (:meth:`Detours.way`), over the net as it is drawn.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Sequence

from dica.ica.netfile import read_net


class Detours:
    """The net's roads, for ways that turn back at none of ``served`` (junction ids)."""

    def __init__(self, net_path: str, served: frozenset[str]) -> None:
        self.net_path = net_path
        self.served = served
        self._net = None
        self._ways: dict[tuple[str, str, str], tuple[str, ...] | None] = {}

    @property
    def net(self):
        if self._net is None:
            self._net = read_net(self.net_path)
        return self._net

    def turns_back(self, edges: Sequence[str]) -> bool:
        """Whether the way ``edges`` turns back at a served junction somewhere."""
        net = self.net
        for a, b in itertools.pairwise(edges):
            ea, eb = net.getEdge(a), net.getEdge(b)
            node = ea.getToNode()
            if (
                node.getID() in self.served
                and eb.getToNode() == ea.getFromNode()
                and (eb.getFromNode() == node)
            ):
                return True
        return False

    def way(self, start: str, dest: str, vclass: str) -> tuple[str, ...] | None:
        """The fastest way (at each road's limit) from road ``start`` to road ``dest`` for
        a vehicle of ``vclass`` that turns back at no served junction (None: none)."""
        key = (start, dest, vclass)
        if key not in self._ways:
            self._ways[key] = self._search(start, dest, vclass)
        return self._ways[key]

    def _search(self, start: str, dest: str, vclass: str) -> tuple[str, ...] | None:
        net = self.net
        if not (net.hasEdge(start) and net.hasEdge(dest)):
            return None
        first = net.getEdge(start)
        queue = [(0.0, 0, first.getID())]
        came: dict[str, str | None] = {first.getID(): None}
        best = {first.getID(): 0.0}
        tie = itertools.count(1)
        while queue:
            cost, _, eid = heapq.heappop(queue)
            if eid == dest:
                out = [eid]
                while came[out[-1]] is not None:
                    out.append(came[out[-1]])
                return tuple(reversed(out))
            if cost > best[eid]:
                continue
            edge = net.getEdge(eid)
            node = edge.getToNode()
            for nxt, conns in edge.getOutgoing().items():
                if nxt.isSpecial() or not nxt.allows(vclass):
                    continue
                if node.getID() in self.served and all(c.getDirection() == "t" for c in conns):
                    continue  # a U-turn the junction does not serve
                c = cost + nxt.getLength() / max(nxt.getSpeed(), 0.1)
                if c < best.get(nxt.getID(), float("inf")):
                    best[nxt.getID()] = c
                    came[nxt.getID()] = eid
                    heapq.heappush(queue, (c, next(tie), nxt.getID()))
        return None
