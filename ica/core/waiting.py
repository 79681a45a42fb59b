"""Waiting places: how far back of a lane's line its vehicles must wait.

A vehicle waits ``stop_gap_m`` short of its lane's entry line, outside the
junction and so outside every reservation. A long, wide vehicle turning from
another lane on a tight corner swings its body over that place (its rear cuts
the corner while its front is already turned). Where it does, the lane's line
is moved back (:meth:`Route.moved_back`) until nothing swept reaches a vehicle
waiting behind it: the stretch in between becomes part of the junction, so the
reservations cover whoever passes over it and nobody waits on it.

The exit side needs no moved line: the downstream-space rule confirms a crossing
onto an exit lane only with room for the vehicle to stop beyond the junction from
the route's speed cap (``DicaIca._check_room``), so the last vehicle of a queue
there stands at least that braking distance past the exit line. A crossing that
would sweep deeper than that over another route's exit lane is refused
(:func:`exit_sweeps`); on every net tried, a 12 m vehicle sweeps at most 4 m and
the least braking distance is 5.4 m.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np

from dica.ica.core.occupancy import Rects, footprints, overlap_matrix
from dica.ica.core.route import Route

STEP_M = 0.5  # [m] how finely the lines move back (and where a waiting front is tried)


def line_backs(
    routes: tuple[Route, ...], length_m: float, width_m: float, gap_m: float
) -> dict[str, float]:
    """Per incoming lane, how far [m] its line must move back so that a vehicle
    ``length_m`` x ``width_m`` standing ``gap_m`` short of it, or anywhere behind,
    touches none of the same size crossing from another lane (from its front at that
    lane's line until its rear is out). Only lanes that need it are listed."""
    backs: dict[str, float] = {}
    for lane, _, deepest in entry_sweeps(routes, length_m, width_m, gap_m):
        backs[lane] = max(backs.get(lane, 0.0), (deepest + 1) * STEP_M)
    return backs


def sweeping(
    routes: tuple[Route, ...], length_m: float, width_m: float, gap_m: float, decel_mps2: float
) -> frozenset[str]:
    """The routes on which a vehicle ``length_m`` x ``width_m`` would sweep over a place
    where one of its size waits, ``gap_m`` short of another lane's line or behind it, or
    stands at the end of a queue on another route's exit lane (:func:`exit_sweeps`):
    the ICA confirms no such crossing (the lines as placed were meant for smaller ones)."""
    entry = {r for _, r, _ in entry_sweeps(routes, length_m, width_m, gap_m)}
    return frozenset(entry | {r for _, r, _ in exit_sweeps(routes, length_m, width_m, decel_mps2)})


def exit_clearance_m(routes: tuple[Route, ...], decel_mps2: float) -> dict[str, float]:
    """Per exit lane, how far past its exit line the last vehicle of a queue on it stands
    at least: the downstream-space rule lets a vehicle onto it only with room to stop
    from its route's speed cap beyond the junction, so the least such braking distance."""
    out: dict[str, float] = {}
    for r in routes:
        brake = r.speed_cap_mps**2 / (2.0 * decel_mps2)
        out[r.out_lane] = min(out.get(r.out_lane, math.inf), brake)
    return out


def exit_sweeps(
    routes: tuple[Route, ...], length_m: float, width_m: float, decel_mps2: float
) -> list[tuple[str, str, float]]:
    """(exit lane, sweeping route, clearance [m]) where a vehicle ``length_m`` x
    ``width_m`` crossing on the route reaches over one of its size standing on another
    route's exit lane with its rear the clearance (:func:`exit_clearance_m`) past the
    exit line, or further on: a long vehicle turning on a tight corner cuts across the
    first metres of the lane beside its own."""
    clear = exit_clearance_m(routes, decel_mps2)
    reach = _reach(routes, length_m)

    def standing(lane: str, r: Route) -> Rects:
        rears = r.cross_length_m + clear[lane] + np.arange(0.0, reach, STEP_M)
        return _beyond(r, rears, length_m, width_m)

    touched = _touching(routes, length_m, width_m, "out_lane", standing)
    return [(lane, other, clear[lane]) for lane, other, _ in touched]


def entry_sweeps(
    routes: tuple[Route, ...], length_m: float, width_m: float, gap_m: float
) -> list[tuple[str, str, int]]:
    """(waiting lane, sweeping route, how deep the touch reaches: the index of the
    furthest waiting front touched, fronts ``STEP_M`` apart from ``gap_m`` back)."""
    fronts = -gap_m - np.arange(0.0, _reach(routes, length_m), STEP_M)

    def standing(_: str, r: Route) -> Rects:
        return footprints(r, fronts, length_m, width_m)

    touched = _touching(routes, length_m, width_m, "in_lane", standing)
    return [(lane, other, int(np.flatnonzero(hit).max())) for lane, other, hit in touched]


def _reach(routes: tuple[Route, ...], length_m: float) -> float:
    """How far from a line a standing vehicle is tried: past anything a crossing sweeps."""
    return max(r.cross_length_m for r in routes) + 3.0 * length_m + 10.0


def _touching(
    routes: tuple[Route, ...],
    length_m: float,
    width_m: float,
    side: str,
    standing: Callable[[str, Route], Rects],
) -> Iterator[tuple[str, str, np.ndarray]]:
    """For each lane on ``side`` of the routes (``in_lane`` or ``out_lane``), the
    ``standing`` footprints of a vehicle on it, and each route from (or onto) another
    lane whose crossing touches some of them: (lane, that route, which are touched)."""
    moving = {r.id: _crossing(r, length_m, width_m) for r in routes}
    by_lane = {getattr(r, side): r for r in routes}
    for lane, r in by_lane.items():
        still = standing(lane, r)
        lo, hi = _box(still.corners().reshape(-1, 2))
        for other in routes:
            if getattr(other, side) == lane:
                continue
            m = moving[other.id]
            mlo, mhi = _box(m.corners().reshape(-1, 2))
            if np.any(mhi < lo) or np.any(hi < mlo):
                continue
            hit = overlap_matrix(m, still).any(axis=0)
            if hit.any():
                yield lane, other.id, hit


def sidewalk_sweeps(
    routes: tuple[Route, ...],
    sidewalks: tuple[tuple[str, Rects], ...],
    length_m: float,
    width_m: float,
) -> list[tuple[str, str]]:
    """(route, sidewalk lane) where a vehicle ``length_m`` x ``width_m`` crossing on the
    route (from its front at the line until its rear is out) reaches over a lane only
    people use: a long vehicle turning on a tight corner cuts it. No reservation covers
    people walking there, so they may be touched."""
    out = []
    for r in routes:
        m = _crossing(r, length_m, width_m)
        lanes = {lane for lane, walk in sidewalks if overlap_matrix(m, walk).any()}
        out += [(r.id, lane) for lane in sorted(lanes)]
    return out


def _crossing(r: Route, length_m: float, width_m: float) -> Rects:
    """A vehicle's footprints on ``r`` every 0.25 m, from its front at the line until its
    rear is out."""
    return footprints(r, np.arange(0.0, r.cross_length_m + length_m + 0.25, 0.25), length_m,
                      width_m)  # fmt: skip


def _beyond(r: Route, rear_m: np.ndarray, length_m: float, width_m: float) -> Rects:
    """Footprints of a vehicle whose rear is at ``rear_m`` on ``r``, the route carried on
    straight past its last point (it reaches only a little beyond the exit line)."""
    end = r.s[-1]
    d = r.xy[-1] - r.xy[-2]
    u = d / max(float(np.hypot(*d)), 1e-12)

    def at(s: np.ndarray) -> np.ndarray:
        return r.points(np.minimum(s, end)) + np.maximum(s - end, 0.0)[:, None] * u

    rear, front = at(rear_m), at(rear_m + length_m)
    axis = front - rear
    heading = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    return Rects((front + rear) / 2.0, heading, length_m / 2.0, width_m / 2.0)


def _box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)
