"""Gridlock: how many vehicles a network of signal-free junctions may hold before a
cycle of full links could stand still.

Each ICA confirms a crossing only if the exit road has room for the vehicle
beyond the junction (:meth:`DicaIca._check_room`), so no vehicle ever stands
inside a junction. What that leaves is the network's own deadlock: a cycle of
links, each so full that the vehicle at its head waits for room on the next.
Such a cycle holds more than its capacity (:func:`cycle_capacity_m`, in metres
of queue), every link of it more than its own (:func:`link_capacity_m`). So a
network whose links together never hold more than its smallest cycle's
capacity (the cycle rule), or in which a set of links that every cycle passes
(:func:`feedback_links`) never holds more than each one's capacity (the route
rule), can never stand still (``docs/architecture.md``, "Gridlock").

Pure: the junctions' routes in, numbers out.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Sequence

from dica.ica.core.intersection import Intersection
from dica.ica.core.route import Route

# [m] what one vehicle takes of a standing queue beyond its length: SUMO's standstill gap
# (2.5 m) and a metre of slack for where a driver stops behind the one ahead
QUEUE_GAP_M = 3.5
# [m] how far short of its line the first vehicle of a queue may stand (the actuator
# keeps SUMO's standstill gap to the line, with the same slack)
LINE_GAP_M = 3.5


def edge_of(lane: str) -> str:
    return lane.rsplit("_", 1)[0]


def internal_roads(inters: Iterable[Intersection]) -> frozenset[str]:
    """Roads that leave one of the junctions and come straight into another: the
    network's links (a vehicle on one is inside the network)."""
    inters = list(inters)
    outs = {edge_of(r.out_lane) for x in inters for r in x.routes}
    ins = {edge_of(r.in_lane) for x in inters for r in x.routes}
    return frozenset(outs & ins)


def full_need_m(
    inters: Iterable[Intersection],
    max_length_m: float,
    decel_mps2: float,
    gap_m: float,
    slack_m: float,
) -> dict[str, float]:
    """Per link, the most room a vehicle may be refused with (the downstream-space
    rule's need: its length, the gaps, one car more and its braking distance at the
    crossing's cap): a link with less room than this may hold a waiting vehicle back."""
    need: dict[str, float] = {}
    for x in inters:
        for r in x.routes:
            brake = r.speed_cap_mps**2 / (2.0 * decel_mps2)
            e = edge_of(r.out_lane)
            need[e] = max(need.get(e, 0.0), max_length_m + gap_m + slack_m + brake)
    return need


def exit_lengths_m(routes: Iterable[Route]) -> dict[str, float]:
    """Per exit road of ``routes``, its shortest lane: the room the rule counts on."""
    length: dict[str, float] = {}
    for r in routes:
        e = edge_of(r.out_lane)
        length[e] = min(length.get(e, math.inf), r.out_lane_m)
    return length


def exit_caps(
    routes: Iterable[Route],
    max_length_m: float,
    decel_mps2: float,
    gap_m: float,
    slack_m: float,
    floor_mps: float,
) -> dict[str, float]:
    """Per route onto an exit road too short for the downstream-space rule at the route's
    cap, the crossing cap at which it fits: the road's shortest lane less the longest
    vehicle, its gap and one car more leaves the braking distance, and the cap is the
    speed that brakes in it (a roundabout's 22.3 m ring link: 29 km/h where the ring's
    30 km/h needs 22.7 m). Not below ``floor_mps``: a road shorter than that still is
    (:func:`short_exits`)."""
    routes = list(routes)
    length = exit_lengths_m(routes)
    out: dict[str, float] = {}
    for r in routes:
        brake = length[edge_of(r.out_lane)] - (max_length_m + gap_m + slack_m)
        if r.speed_cap_mps**2 / (2.0 * decel_mps2) <= brake:
            continue
        cap = math.floor(math.sqrt(2.0 * decel_mps2 * max(brake, 0.0)) * 100.0) / 100.0
        if cap >= floor_mps:
            out[r.id] = cap
    return out


def short_exits(
    inter: Intersection, max_length_m: float, decel_mps2: float, gap_m: float, slack_m: float
) -> list[tuple[str, float, float]]:
    """The junction's exit roads shorter than the room the downstream-space rule needs
    to let a vehicle onto them (:func:`full_need_m`): (road, its shortest lane, the
    need). Where the room beyond is measured, no vehicle is ever let onto such a road,
    and those bound for it wait at the line for good."""
    need = full_need_m([inter], max_length_m, decel_mps2, gap_m, slack_m)
    length = exit_lengths_m(inter.routes)
    return sorted((e, m, need[e]) for e, m in length.items() if m < need[e])


def link_capacity_m(inters: Sequence[Intersection], need_m: dict[str, float]) -> dict[str, float]:
    """Per link, the least queue (vehicle lengths plus :data:`QUEUE_GAP_M` each) that can
    leave it with less room than ``need_m``: its shortest lane, less the need and
    where the first vehicle stands short of the line (never below zero)."""
    length = link_length_m(inters)
    return {e: max(0.0, m - need_m.get(e, 0.0) - LINE_GAP_M) for e, m in length.items()}


def link_length_m(inters: Sequence[Intersection]) -> dict[str, float]:
    """Per link, its shortest lane (as the junctions' routes measure it)."""
    links = internal_roads(inters)
    length: dict[str, float] = {}
    for x in inters:
        for r in x.routes:
            for lane, m in ((r.in_lane, r.in_lane_m), (r.out_lane, r.out_lane_m)):
                e = edge_of(lane)
                if e in links and math.isfinite(m):
                    length[e] = min(length.get(e, math.inf), m)
    return length


def on_cycles(arcs: dict[str, set[str]]) -> frozenset[str]:
    """The links some cycle of links passes through (a vehicle can drive round from it
    back onto it)."""
    found = set()
    for start in arcs:
        seen, todo = set(), list(arcs[start])
        while todo:
            e = todo.pop()
            if e == start:
                found.add(start)
                break
            if e not in seen:
                seen.add(e)
                todo.extend(arcs.get(e, ()))
    return frozenset(found)


def cycle_capacity_m(inters: Sequence[Intersection], capacity_m: dict[str, float]) -> float:
    """The least total capacity over the cycles of links a vehicle can drive round
    (link to link by one of the junctions' routes); inf if the links form no cycle.

    A set of vehicles that wait for each other for ever waits round such a cycle,
    every link of it full, so it holds at least this much queue."""
    arcs = link_arcs(inters, capacity_m)
    best = math.inf
    for start in sorted(arcs):  # Dijkstra from each link back to itself
        dist = {start: capacity_m[start]}
        heap = [(capacity_m[start], start)]
        while heap:
            d, e = heapq.heappop(heap)
            if d > dist.get(e, math.inf) or d >= best:
                continue
            for f in arcs.get(e, ()):
                if f == start:
                    best = min(best, d)
                    continue
                nd = d + capacity_m[f]
                if nd < dist.get(f, math.inf):
                    dist[f] = nd
                    heapq.heappush(heap, (nd, f))
    return best


def link_arcs(inters: Iterable[Intersection], links: Iterable[str]) -> dict[str, set[str]]:
    """Per link, the links a vehicle can drive onto next (by one of the junctions' routes)."""
    links = set(links)
    arcs: dict[str, set[str]] = {e: set() for e in links}
    for x in inters:
        for r in x.routes:
            a, b = edge_of(r.in_lane), edge_of(r.out_lane)
            if a in links and b in links:
                arcs[a].add(b)
    return arcs


def feedback_links(arcs: dict[str, set[str]], capacity_m: dict[str, float]) -> frozenset[str]:
    """Links that every cycle of links passes through (a feedback vertex set): if none of
    these ever fills, no cycle of full links can form. Greedy: drop links on no cycle
    (nothing comes in, or nothing goes on), then take the link on the most paths through
    (in times out), the larger capacity first, until no cycle is left."""
    succ = {e: set(f) for e, f in arcs.items()}
    pred: dict[str, set[str]] = {e: set() for e in succ}
    for e, fs in succ.items():
        for f in fs:
            pred.setdefault(f, set()).add(e)
            succ.setdefault(f, set())
    chosen: set[str] = set()

    def drop(e: str) -> None:
        for f in succ.pop(e):
            pred[f].discard(e)
        for f in pred.pop(e):
            succ[f].discard(e)

    while succ:
        bare = [e for e in succ if not succ[e] or not pred[e]]
        if bare:
            for e in bare:
                if e in succ:
                    drop(e)
            continue
        loops = sorted(e for e in succ if e in succ[e])  # a link onto itself: a cycle alone
        pick = (
            loops[0]
            if loops
            else max(
                sorted(succ), key=lambda e: (len(pred[e]) * len(succ[e]), capacity_m.get(e, 0.0))
            )
        )
        chosen.add(pick)
        drop(pick)
    return frozenset(chosen)
