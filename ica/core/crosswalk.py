"""Pedestrian crossings as the ICA sees them: strips people walk across the routes.

A crossing is where a walker and a vehicle can meet, so for the ICA it is a
conflict zone like the ones between routes: a vehicle on a route occupies a
crossing while its footprint touches the crossing's strip, and that happens
over one span of front positions ``s`` (:func:`span`). With a vehicle's DTOT
(the time at each ``s``) the span becomes the time the vehicle holds the
crossing, which a walker's reservation must keep clear of.

SUMO draws a crossing as a centre line (two points or more) and a width, just
before the vehicles' entry line on an arm or just past their exit line; its
strip is a rectangle per segment of the centre line. Pure: shapes in, spans out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.occupancy import Rects, footprints, overlap_matrix
from dica.ica.core.route import Route

SPAN_DS_M = 0.1  # [m] front positions sampled this far apart to find a span
# Where people are, beyond the painted strip: a body reaches over its edges, and at each
# end the walking area's corner, where a turning vehicle's body sweeps too (SUMO draws
# walkers there on their way to and from the crossing, up to a metre or so off its shape).
BODY_M = 0.5  # [m] across, each side
CORNER_M = 2.5  # [m] along, each end
CORNER_GROW_M = 1.5  # [m] a walking area's bounding rectangle grown by this each side
REACH_M = 12.0  # [m] the farthest into a corner a vehicle's stretch of a crossing goes


@dataclass(frozen=True, slots=True, eq=False)
class Crosswalk:
    """One pedestrian crossing: its id (SUMO's crossing edge), centre line (K, 2) [m],
    width [m], the roads it crosses, and the walking areas its ends open onto (polygons
    (M, 2) [m]: the corners walkers go through to and from it)."""

    id: str
    shape: np.ndarray
    width_m: float
    crosses: tuple[str, ...] = ()
    corners: tuple[np.ndarray, ...] = ()
    _length_m: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        shape = np.asarray(self.shape, dtype=float).reshape(-1, 2)
        if len(shape) < 2 or not np.all(np.isfinite(shape)):
            raise ValueError(f"crossing {self.id}: a centre line needs two points or more")
        if not self.width_m > 0.0:
            raise ValueError(f"crossing {self.id}: width must be positive, got {self.width_m}")
        object.__setattr__(self, "shape", shape)
        length = float(np.linalg.norm(np.diff(shape, axis=0), axis=1).sum())
        object.__setattr__(self, "_length_m", length)

    @property
    def length_m(self) -> float:
        """How far a walker goes across: the centre line's length (asked for each walker
        a vehicle may meet, so worked out once)."""
        return self._length_m

    def strips(self, margin_m: float = 0.0, along_m: float | None = None) -> list[Rects]:
        """The crossing's area, one rectangle per segment of its centre line (grown by
        ``margin_m`` on every side, or ``along_m`` at the ends if given); segments of no
        length are left out."""
        along = margin_m if along_m is None else along_m
        out = []
        for a, b in zip(self.shape[:-1], self.shape[1:], strict=True):
            d = b - a
            n = float(np.hypot(*d))
            if n < 1e-9:
                continue
            out.append(
                Rects(
                    ((a + b) / 2.0)[None, :],
                    (d / n)[None, :],
                    n / 2.0 + along,
                    self.width_m / 2.0 + margin_m,
                )
            )
        return out

    def corner_boxes(self, grow_m: float = CORNER_GROW_M) -> list[Rects]:
        """Each walking area at its ends as its least bounding rectangle, grown by
        ``grow_m`` on every side."""
        out = []
        for poly in self.corners:
            c, u, half = _bounding_rectangle(np.asarray(poly, dtype=float))
            out.append(Rects(c[None, :], u[None, :], half[0] + grow_m, half[1] + grow_m))
        return out


def _bounding_rectangle(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The least-area rectangle holding ``poly``'s points (one side along an edge of
    their hull): centre, unit direction of its first side, half sizes."""
    pts = poly
    best = None
    for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True):
        d = b - a
        n = float(np.hypot(*d))
        if n < 1e-9:
            continue
        u = d / n
        v = np.array([-u[1], u[0]])
        pu, pv = pts @ u, pts @ v
        area = (pu.max() - pu.min()) * (pv.max() - pv.min())
        if best is None or area < best[0]:
            mid = u * (pu.max() + pu.min()) / 2.0 + v * (pv.max() + pv.min()) / 2.0
            best = (area, mid, u, np.array([(pu.max() - pu.min()) / 2, (pv.max() - pv.min()) / 2]))
    if best is None:
        raise ValueError("a walking area needs points apart")
    return best[1], best[2], best[3]


def _touching(
    route: Route,
    crosswalk: Crosswalk,
    length_m: float,
    width_m: float,
    margin_m: float,
    ds_m: float,
) -> tuple[np.ndarray, Rects, np.ndarray] | None:
    """Front positions sampled every ``ds_m`` over the route, the footprints there
    (longer by ``ds_m``), and which of them touch where walkers on ``crosswalk`` may be."""
    s = np.arange(route.s_min + length_m, route.s_max + ds_m, ds_m)
    s = s[s <= route.s_max]
    if len(s) == 0:
        return None
    feet = footprints(route, s, length_m, width_m, margin_m + ds_m)
    touch = np.zeros(len(s), dtype=bool)
    for strip in crosswalk.strips(BODY_M, CORNER_M) + crosswalk.corner_boxes():
        touch |= overlap_matrix(feet, strip)[:, 0]
    return s, feet, touch


def passage(
    route: Route,
    crosswalk: Crosswalk,
    length_m: float,
    width_m: float,
    margin_m: float = 0.0,
    ds_m: float = SPAN_DS_M,
) -> tuple[float, float, float, float] | None:
    """Where a vehicle of this size (grown by ``margin_m``) on ``route`` meets where
    walkers on ``crosswalk`` may be (its strip, :data:`BODY_M` wider each side and
    :data:`CORNER_M` longer each end, and the walking areas at its ends): the front
    positions ``(s_from, s_to)`` over which it touches, and the stretch ``(u_lo, u_hi)``
    of the crossing its body covers then (metres from the crossing's first end along the
    line to its last, negative or past its length in the corners; a bent crossing is
    covered whole). None if it never touches.

    Sampled every ``ds_m`` over the whole route with footprints longer by ``ds_m``,
    and the span widened by ``ds_m`` at each end, so that it holds every position where
    the two touch, not only the sampled ones."""
    got = _touching(route, crosswalk, length_m, width_m, margin_m, ds_m)
    if got is None or not got[2].any():
        return None
    s, feet, touch = got
    hit = s[touch]
    ends = crosswalk.shape[[0, -1]]
    chord = ends[1] - ends[0]
    n = float(np.hypot(*chord))
    length = crosswalk.length_m
    if n < 1e-9 or n < length - 1e-6:  # not straight: the whole of it
        lo, hi = -REACH_M, length + REACH_M
    else:
        u = (feet.take(touch).corners() - ends[0]) @ (chord / n)
        lo = float(np.clip(u.min(), -REACH_M, length + REACH_M))
        hi = float(np.clip(u.max(), -REACH_M, length + REACH_M))
    return float(hit[0] - ds_m), float(hit[-1] + ds_m), lo, hi


def span(
    route: Route,
    crosswalk: Crosswalk,
    length_m: float,
    width_m: float,
    margin_m: float = 0.0,
    ds_m: float = SPAN_DS_M,
) -> tuple[float, float] | None:
    """The front positions of :func:`passage`: ``(s_from, s_to)``, or None."""
    got = passage(route, crosswalk, length_m, width_m, margin_m, ds_m)
    return None if got is None else got[:2]


def spans(
    routes: tuple[Route, ...],
    crosswalks: tuple[Crosswalk, ...],
    length_m: float,
    width_m: float,
    margin_m: float = 0.0,
) -> dict[str, list[tuple[str, float, float]]]:
    """Per route id, the crossings it passes over: ``(crossing id, s_from, s_to)`` in
    the order the route meets them."""
    out: dict[str, list[tuple[str, float, float]]] = {}
    for r in routes:
        found = []
        for c in crosswalks:
            sp = span(r, c, length_m, width_m, margin_m)
            if sp is not None:
                found.append((c.id, *sp))
        out[r.id] = sorted(found, key=lambda x: x[1])
    return out
