"""The rectangle-overlap test every compiled loop uses, written once.

:func:`ica.core.occupancy.separated`'s separating-axis test on the four edge
normals, for one pair, term for term: the same products and sums in the same
order, so its answer is numpy's bit for bit. It is inlined into each loop
that calls it (numba's ``inline="always"``), so a test costs what the
written-out copies cost.
"""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

EPS_SAT = 1e-9  # [m] as in ica.core.occupancy.separated: touching counts as overlap


class Rect(NamedTuple):
    """An oriented rectangle: centre [m], unit heading, half length and half width [m]."""

    x_m: float
    y_m: float
    hx: float
    hy: float
    half_l_m: float
    half_w_m: float


@njit(inline="always")
def overlaps(a: Rect, b: Rect) -> bool:
    """``not separated(b - a, ...)``: do ``a`` and ``b`` intersect (touching included)?

    With c and s the cosine and sine between the headings, each rectangle's
    half-extent on the other's axes is a sum of |c| and |s| terms; the first
    axis that separates them ends the test.
    """
    ax, ay = a.hx, a.hy
    bx, by = b.hx, b.hy
    dx = b.x_m - a.x_m
    dy = b.y_m - a.y_m
    cs = abs(ax * bx + ay * by)
    sn = abs(ax * by - ay * bx)
    la, wa = a.half_l_m, a.half_w_m
    lb, wb = b.half_l_m, b.half_w_m
    if abs(dx * ax + dy * ay) > la + lb * cs + wb * sn + EPS_SAT:
        return False
    if abs(dy * ax - dx * ay) > wa + lb * sn + wb * cs + EPS_SAT:
        return False
    if abs(dx * bx + dy * by) > lb + la * cs + wa * sn + EPS_SAT:
        return False
    return not abs(dy * bx - dx * by) > wb + la * sn + wa * cs + EPS_SAT
