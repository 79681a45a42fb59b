"""The network gate: how much queue the links between signal-free junctions hold, and
how much more may come in.

A network of junctions whose links form cycles can stand still for ever once a
cycle of links is full (every vehicle at a link's head waiting for room on the
next). The gate keeps the queue length inside the network (every vehicle on a
link, and every one confirmed onto a link from outside, at its length plus
:data:`~ica.core.gridlock.QUEUE_GAP_M`) at most the smallest cycle's capacity
(:func:`~ica.core.gridlock.cycle_capacity_m`): the ICAs let a vehicle in from
outside only while it fits (``Observation.network_room_m``), and a route
file's vehicles that would start on a link wait out of SUMO until it does
(:class:`~sim_gateway.insertion.InsertionHold`). Moving between links, a
vehicle neither adds nor takes room, so the bound holds for the whole run.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from dica.ica.core.dica import ROOM_GAP_M, ROOM_SLACK_M
from dica.ica.core.gridlock import (
    QUEUE_GAP_M,
    cycle_capacity_m,
    edge_of,
    full_need_m,
    internal_roads,
    link_capacity_m,
)
from dica.ica.core.intersection import Intersection
from dica.sim_gateway.junction import Car, Junction


class NetworkGate:
    """The network's queue length this step and the room left for one more vehicle."""

    def __init__(
        self, inters: Sequence[Intersection], max_length_m: float, decel_mps2: float
    ) -> None:
        self.links = internal_roads(inters)
        need = full_need_m(inters, max_length_m, decel_mps2, ROOM_GAP_M, ROOM_SLACK_M)
        self.link_capacity_m = link_capacity_m(inters, need)
        self.capacity_m = cycle_capacity_m(inters, self.link_capacity_m)
        self.used_m = 0.0
        self.peak_m = 0.0  # the most queue the network held at once
        self.counted: set[str] = set()  # SUMO ids inside the network this step
        self._length: dict[str, float] = {}
        self._enters: dict[tuple[str, str], bool] = {}  # per (in, out) lane: it enters

    @property
    def closes(self) -> bool:
        """Whether the links form a cycle at all (else the gate never closes)."""
        return math.isfinite(self.capacity_m)

    @property
    def room_m(self) -> float:
        return self.capacity_m - self.used_m

    def entering(self, c: Car) -> bool:
        """Whether ``c``'s crossing takes it into the network from outside."""
        r = c.route
        key = (r.in_lane, r.out_lane)
        enters = self._enters.get(key)
        if enters is None:
            links = self.links
            enters = edge_of(r.out_lane) in links and edge_of(r.in_lane) not in links
            self._enters[key] = enters
        return enters

    def measure(self, ls, junctions: Iterable[Junction]) -> None:
        """Count the queue inside the network: the vehicles on its links, and those
        confirmed onto one that are not on it yet."""
        if not self.closes:
            return
        self.counted = set()
        self.used_m = 0.0
        for e in self.links:
            for x in ls.edge.getLastStepVehicleIDs(e):
                self._count(ls, x)
        for j in junctions:
            self.count_confirmed(ls, j)
        self.peak_m = max(self.peak_m, self.used_m)

    def count_confirmed(self, ls, j: Junction) -> None:
        """Count ``j``'s vehicles confirmed onto a link and not counted yet (after its
        ICA's answers this step, before the next junction's ask)."""
        if not self.closes:
            return
        for c in j.active:
            if c.plan_s is None or c.exited or c.sumo in self.counted:
                continue
            if edge_of(c.route.out_lane) in self.links and c.sumo in j.present:
                self._count(ls, c.sumo)
        self.peak_m = max(self.peak_m, self.used_m)

    def need_m(self, ls, vid: str) -> float:
        """The queue length ``vid`` takes inside the network."""
        n = self._length.get(vid)
        if n is None:
            n = self._length[vid] = ls.vehicle.getLength(vid)
        return n + QUEUE_GAP_M

    def pending_m(self, ls, cars: Iterable[Car]) -> float:
        """The queue length of the vehicles among ``cars`` entering the network and not
        counted yet: any of them may be being let in right now by an ICA whose answer
        has not come."""
        if not self.closes:
            return 0.0
        return sum(
            self.need_m(ls, c.sumo)
            for c in cars
            if c.sumo not in self.counted and not c.exited and self.entering(c)
        )

    def _count(self, ls, vid: str) -> None:
        self.counted.add(vid)
        self.used_m += self.need_m(ls, vid)

    def forget(self, gone: Iterable[str]) -> None:
        for vid in gone:
            self._length.pop(vid, None)
