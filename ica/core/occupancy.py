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

from ica.core.route import Route


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


def _radius(h: np.ndarray, hl: float, hw: float, axis: np.ndarray) -> np.ndarray:
    """Half-extent of rectangles with heading ``h`` projected on ``axis`` (broadcast)."""
    dot_u = np.abs(h[..., 0] * axis[..., 0] + h[..., 1] * axis[..., 1])
    dot_n = np.abs(-h[..., 1] * axis[..., 0] + h[..., 0] * axis[..., 1])
    return hl * dot_u + hw * dot_n


def overlap_matrix(a: Rects, b: Rects) -> np.ndarray:
    """Boolean (len(a), len(b)): which pairs of rectangles intersect (touching included)."""
    ca = a.centre[:, None, :]
    cb = b.centre[None, :, :]
    ha = a.heading[:, None, :]
    hb = b.heading[None, :, :]
    d = cb - ca
    result = np.ones((len(a), len(b)), dtype=bool)
    na = np.stack([-ha[..., 1], ha[..., 0]], -1)
    nb = np.stack([-hb[..., 1], hb[..., 0]], -1)
    for axis in (ha, na, hb, nb):
        dist = np.abs(d[..., 0] * axis[..., 0] + d[..., 1] * axis[..., 1])
        reach = _radius(ha, a.half_length, a.half_width, axis) + _radius(
            hb, b.half_length, b.half_width, axis
        )
        result &= dist <= reach + 1e-9
    return result


def overlap_pairs(a: Rects, ia: np.ndarray, b: Rects, ib: np.ndarray) -> np.ndarray:
    """Overlap of the listed pairs (a[ia[k]], b[ib[k]]), boolean (K,)."""
    ca, cb = a.centre[ia], b.centre[ib]
    ha, hb = a.heading[ia], b.heading[ib]
    d = cb - ca
    result = np.ones(len(ia), dtype=bool)
    na = np.stack([-ha[:, 1], ha[:, 0]], -1)
    nb = np.stack([-hb[:, 1], hb[:, 0]], -1)
    for axis in (ha, na, hb, nb):
        dist = np.abs(np.einsum("ij,ij->i", d, axis))
        reach = _radius(ha, a.half_length, a.half_width, axis) + _radius(
            hb, b.half_length, b.half_width, axis
        )
        result &= dist <= reach + 1e-9
    return result
