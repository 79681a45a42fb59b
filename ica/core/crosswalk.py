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

from dataclasses import dataclass

import numpy as np

from dica.ica.core.occupancy import Rects, footprints, overlap_matrix
from dica.ica.core.route import Route

SPAN_DS_M = 0.1  # [m] front positions sampled this far apart to find a span


@dataclass(frozen=True, slots=True, eq=False)
class Crosswalk:
    """One pedestrian crossing: its id (SUMO's crossing edge), centre line (K, 2) [m],
    width [m] and the roads it crosses."""

    id: str
    shape: np.ndarray
    width_m: float
    crosses: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        shape = np.asarray(self.shape, dtype=float).reshape(-1, 2)
        if len(shape) < 2 or not np.all(np.isfinite(shape)):
            raise ValueError(f"crossing {self.id}: a centre line needs two points or more")
        if not self.width_m > 0.0:
            raise ValueError(f"crossing {self.id}: width must be positive, got {self.width_m}")
        object.__setattr__(self, "shape", shape)

    @property
    def length_m(self) -> float:
        """How far a walker goes across: the centre line's length."""
        return float(np.linalg.norm(np.diff(self.shape, axis=0), axis=1).sum())

    def strips(self, margin_m: float = 0.0) -> list[Rects]:
        """The crossing's area, one rectangle per segment of its centre line (grown by
        ``margin_m`` on every side); segments of no length are left out."""
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
                    n / 2.0 + margin_m,
                    self.width_m / 2.0 + margin_m,
                )
            )
        return out


def span(
    route: Route,
    crosswalk: Crosswalk,
    length_m: float,
    width_m: float,
    margin_m: float = 0.0,
    ds_m: float = SPAN_DS_M,
) -> tuple[float, float] | None:
    """The front positions ``(s_from, s_to)`` on ``route`` over which a vehicle of this
    size (grown by ``margin_m``) touches ``crosswalk``; None if it never does.

    Sampled every ``ds_m`` over the whole route with footprints longer by ``ds_m``,
    and widened by ``ds_m`` at each end, so that the span holds every position where
    the two touch, not only the sampled ones."""
    s = np.arange(route.s_min + length_m, route.s_max + ds_m, ds_m)
    s = s[s <= route.s_max]
    if len(s) == 0:
        return None
    feet = footprints(route, s, length_m, width_m, margin_m + ds_m)
    touch = np.zeros(len(s), dtype=bool)
    for strip in crosswalk.strips():
        touch |= overlap_matrix(feet, strip)[:, 0]
    if not touch.any():
        return None
    hit = s[touch]
    return float(hit[0] - ds_m), float(hit[-1] + ds_m)


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
