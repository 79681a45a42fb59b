"""Occupancies: the oriented rectangle a vehicle covers, and overlap tests.

A vehicle's footprint is the rectangle whose front edge is centred on the front
bumper at arc length ``s`` and whose rear edge is centred on the route point at
``s - length``. That is how SUMO draws a vehicle on a curve (heading from rear
to front), so the ICA and the independent collision check agree on shapes.

Rectangles are held as arrays: centre (N, 2), unit heading (N, 2), half
length and half width [m]. The overlap test is the separating-axis theorem,
vectorised over all pairs; touching counts as overlap, so the test errs on
the safe side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dica.ica.core.route import Route


@dataclass(frozen=True, slots=True, eq=False)
class Rects:
    """N oriented rectangles: centre (N, 2), unit heading (N, 2), half extents [m]."""

    centre: np.ndarray
    heading: np.ndarray
    half_length: float
    half_width: float

    def __len__(self) -> int:
        return len(self.centre)

    def take(self, index: np.ndarray | slice) -> Rects:
        return Rects(self.centre[index], self.heading[index], self.half_length, self.half_width)

    def corners(self) -> np.ndarray:
        """Corners (N, 4, 2), counter-clockwise from front-left."""
        u = self.heading * self.half_length
        n = np.stack([-self.heading[:, 1], self.heading[:, 0]], -1) * self.half_width
        c = self.centre
        return np.stack([c + u + n, c - u + n, c - u - n, c + u - n], axis=1)


def footprints(
    route: Route, s_front: np.ndarray, length_m: float, width_m: float, margin_m: float = 0.0
) -> Rects:
    """Footprints of a vehicle whose front bumper is at ``s_front`` on ``route``.

    ``margin_m`` grows the rectangle on every side (tracking error, delay
    bounds, and the safety gap the ICA keeps between vehicles).
    """
    s_front = np.atleast_1d(np.asarray(s_front, dtype=float))
    front = route.points(s_front)
    rear = route.points(s_front - length_m)
    axis = front - rear
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    heading = axis / np.maximum(norm, 1e-12)
    centre = front - heading * (length_m / 2.0)
    return Rects(centre, heading, length_m / 2.0 + margin_m, width_m / 2.0 + margin_m)


def separated(
    dx: np.ndarray,
    dy: np.ndarray,
    ha: np.ndarray,
    hb: np.ndarray,
    la: float | np.ndarray,
    wa: float | np.ndarray,
    lb: float | np.ndarray,
    wb: float | np.ndarray,
) -> np.ndarray:
    """Separating-axis test on the four edge normals, in closed form.

    ``dx, dy`` is centre b minus centre a, ``ha, hb`` the unit headings (..., 2),
    ``la, wa`` and ``lb, wb`` the half length and half width of a and b, all
    broadcast together. With c and s the cosine and sine between the
    headings, each rectangle's half-extent on the other's axes is a sum of
    |c| and |s| terms, so no projections of corners are needed.
    """
    ax, ay, bx, by = ha[..., 0], ha[..., 1], hb[..., 0], hb[..., 1]
    c = np.abs(ax * bx + ay * by)
    s = np.abs(ax * by - ay * bx)
    eps = 1e-9
    sep = np.abs(dx * ax + dy * ay) > la + lb * c + wb * s + eps
    sep |= np.abs(dy * ax - dx * ay) > wa + lb * s + wb * c + eps
    sep |= np.abs(dx * bx + dy * by) > lb + la * c + wa * s + eps
    sep |= np.abs(dy * bx - dx * by) > wb + la * s + wa * c + eps
    return sep


def overlap_matrix(a: Rects, b: Rects) -> np.ndarray:
    """Boolean (len(a), len(b)): which pairs of rectangles intersect (touching included)."""
    dx = b.centre[None, :, 0] - a.centre[:, None, 0]
    dy = b.centre[None, :, 1] - a.centre[:, None, 1]
    return ~separated(
        dx,
        dy,
        a.heading[:, None, :],
        b.heading[None, :, :],
        a.half_length,
        a.half_width,
        b.half_length,
        b.half_width,
    )


def overlap_pairs(a: Rects, ia: np.ndarray, b: Rects, ib: np.ndarray) -> np.ndarray:
    """Overlap of the listed pairs (a[ia[k]], b[ib[k]]), boolean (K,)."""
    d = b.centre[ib] - a.centre[ia]
    return ~separated(
        d[:, 0],
        d[:, 1],
        a.heading[ia],
        b.heading[ib],
        a.half_length,
        a.half_width,
        b.half_length,
        b.half_width,
    )
