"""Offline tables per route (pair): conflict zones and overlap distances.

Routes are fixed for a junction, so the geometry that enhanced DICA needs is
computed once per vehicle shape, on a grid of front positions every ``ds``:

* **conflict zone** of route a against route b: the grid points of a at which
  a footprint on a can touch some footprint on b. Empty means the routes are
  compatible (technique 1) and the zone bounds the occupancies worth testing
  (technique 2).
* **skip distances** along one route (technique 3): how far ahead of (or
  behind) a footprint another footprint on the same route is taken to
  overlap it without a test. The exact tables hold the distance within which
  the two surely overlap (from shrunk footprints), so the nearest clear
  sample, found by the exact test beyond it, gives exactly the exhaustive
  intervals after a handful of tests. The dissertation's tables hold the
  distance beyond which the footprints surely do not overlap (from grown
  footprints): the sample there is the answer, an estimate never narrower
  than the exhaustive interval, found in O(log N).

Grid tables are made safe for any position in between: the footprints used
to build them are longer by ``ds`` and wider by ``pad_m``, so a footprint at any
``s`` lies inside the padded footprint at the nearest grid point. A second,
shrunk footprint (shorter by ``ds``, narrower by ``pad_m``) lies inside every
real footprint near its grid point, so shrunk ones touching proves that the
real ones touch. Between the two, the exact test decides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.intersection import Intersection
from dica.ica.core.kernels.dtot import Grid
from dica.ica.core.occupancy import Rects, footprints, overlap_matrix
from dica.ica.core.route import Route


@dataclass(frozen=True, slots=True)
class Shape:
    """A vehicle's planning size [m], rounded up to 0.1 m so tables can be shared."""

    length_m: float
    width_m: float

    @staticmethod
    def of(length_m: float, width_m: float) -> Shape:
        return Shape(
            float(np.ceil(length_m * 10 - 1e-6) / 10), float(np.ceil(width_m * 10 - 1e-6) / 10)
        )


@dataclass(frozen=True, slots=True, eq=False)
class RouteGrid:
    """A route's grid of front positions and the padded footprints on it."""

    route: Route
    shape: Shape
    s0_m: float
    ds_m: float
    rects: Rects
    inner: Rects  # shrunk footprints: inside the real one at any nearest position
    # skip distances (see the module docstring): a footprint at s is taken to
    # overlap those of the same route with fronts in (s - back_m, s] and
    # [s, s + fwd_m), per nearest grid point of s
    fwd_m: np.ndarray
    back_m: np.ndarray
    route_x: np.ndarray  # the route's vertices, x and y as contiguous arrays
    route_y: np.ndarray
    exact: bool = True  # skip distances of surely overlapping footprints (else surely clear)
    _kernel: dict[float, Grid] = field(
        default_factory=dict, init=False, repr=False, compare=False, hash=False
    )

    def kernel_grid(self, margin_m: float) -> Grid:
        """This grid as the compiled DTOT reads it, for footprints grown by ``margin_m``
        (built once per margin)."""
        g = self._kernel.get(margin_m)
        if g is None:
            shape = self.shape
            g = self._kernel[margin_m] = Grid(
                route_s=self.route.s,
                route_x=self.route_x,
                route_y=self.route_y,
                length_m=shape.length_m,
                s0_m=self.s0_m,
                ds_m=self.ds_m,
                fwd_m=self.fwd_m,
                back_m=self.back_m,
                half_l_m=shape.length_m / 2.0 + margin_m,
                half_w_m=shape.width_m / 2.0 + margin_m,
            )
        return g

    def index(self, s: np.ndarray) -> np.ndarray:
        """Nearest grid index per position (clipped to the grid)."""
        k = np.rint((np.asarray(s) - self.s0_m) / self.ds_m).astype(np.int64)
        return np.minimum(np.maximum(k, 0), len(self.rects) - 1)

    def skip_ahead_m(self, s: np.ndarray) -> np.ndarray:
        """Distance ahead of a footprint at ``s`` within which no test is made."""
        return self.fwd_m[self.index(s)]

    def skip_behind_m(self, s: np.ndarray) -> np.ndarray:
        return self.back_m[self.index(s)]


def _route_grid(
    route: Route, shape: Shape, margin_m: float, ds_m: float, pad_m: float, exact: bool
) -> RouteGrid:
    s0 = -2.0
    s1 = route.cross_length_m + shape.length_m + 2.0
    s = np.arange(s0, s1 + ds_m / 2, ds_m)
    base = footprints(route, s, shape.length_m, shape.width_m, margin_m)
    rects = Rects(base.centre, base.heading, base.half_length + ds_m / 2, base.half_width + pad_m)
    inner = Rects(
        base.centre,
        base.heading,
        max(base.half_length - ds_m / 2, 0.0),
        max(base.half_width - pad_m, 0.0),
    )
    if exact:
        fwd, back = _sure_overlap_m(inner, ds_m)
    else:
        fwd, back = _sure_clear_m(rects, ds_m)
    x, y = np.ascontiguousarray(route.xy[:, 0]), np.ascontiguousarray(route.xy[:, 1])
    return RouteGrid(route, shape, s0, ds_m, rects, inner, fwd, back, x, y, exact)


SURE_SLACK_M = 0.01  # [m] the shrunk footprints shrink once more, so "surely" survives rounding


def _sure_clear_m(grown: Rects, ds_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Distances ahead and behind beyond which a footprint surely no longer overlaps itself.

    From the grown footprints (each holds the real one at any position nearest
    its grid point): the last grid point ahead that still touches, plus a grid
    step for the position between grid points.
    """
    n = len(grown)
    self_overlap = overlap_matrix(grown, grown)
    idx = np.arange(n)
    ahead = np.where(self_overlap & (idx[None, :] >= idx[:, None]), idx[None, :], -1).max(axis=1)
    behind = np.where(self_overlap & (idx[None, :] <= idx[:, None]), idx[None, :], n).min(axis=1)
    return (ahead - idx + 2) * ds_m, (idx - behind + 2) * ds_m


def _sure_overlap_m(inner: Rects, ds_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Distances ahead and behind within which a footprint surely overlaps itself.

    A real footprint at ``s`` holds the shrunk one of the grid point nearest
    ``s``. If the shrunk footprint at grid point i overlaps those at i - 1, ...,
    i - c (run of c), every real footprint nearest i overlaps every real one
    nearest those points, which covers the fronts from ``s - (c - 1/2) ds`` to
    ``s`` (the half step keeps a rounding of the nearest point off the
    boundary). The first and last grid points also hold the positions beyond
    the grid, so they get, and lend, nothing.
    """
    shrunk = Rects(
        inner.centre,
        inner.heading,
        max(inner.half_length - SURE_SLACK_M, 0.0),
        max(inner.half_width - SURE_SLACK_M, 0.0),
    )
    n = len(shrunk)
    touch = overlap_matrix(shrunk, shrunk)
    fwd, back = np.zeros(n), np.zeros(n)
    for i in range(1, n - 1):
        c = 0
        while i - c - 1 >= 1 and touch[i, i - c - 1]:
            c += 1
        back[i] = max(c - 0.5, 0.0) * ds_m
        c = 0
        while i + c + 1 <= n - 2 and touch[i, i + c + 1]:
            c += 1
        fwd[i] = max(c - 0.5, 0.0) * ds_m
    return fwd, back


APART, MAYBE, TOUCH = 0, 1, 2


@dataclass(eq=False)
class PairStack:
    """Route a's pair tables against other routes, one block of rows per route b.

    Row ``offset[b] + j`` holds the codes of b's grid point j against every
    grid point of a, followed by the first and last grid point of a that are
    not APART (``lo > hi`` when all are). With it, one gather answers pairs
    of a against occupancies of many routes at once. Blocks are only ever
    appended, so an offset stays valid while the stack grows.
    """

    width: int  # grid points of route a
    offset: dict[tuple[str, Shape], int] = field(default_factory=dict)
    codes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))  # flat (rows * width)
    row_lo: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    row_hi: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def append(self, key: tuple[str, Shape], table: np.ndarray) -> int:
        """Add ``table`` (grid a, grid b) as a block; returns its offset."""
        block = np.ascontiguousarray(table.T)  # (grid b, grid a)
        near = block != APART
        lo = np.where(near.any(axis=1), near.argmax(axis=1), self.width)
        hi = np.where(near.any(axis=1), self.width - 1 - near[:, ::-1].argmax(axis=1), -1)
        off = len(self.row_lo)
        self.codes = np.concatenate([self.codes, block.ravel()])
        self.row_lo = np.concatenate([self.row_lo, lo])
        self.row_hi = np.concatenate([self.row_hi, hi])
        self.offset[key] = off
        return off


@dataclass(eq=False)
class ConflictTables:
    """Lazily built, cached offline tables for one intersection and safety margin."""

    intersection: Intersection
    margin_m: float
    ds_m: float = 0.25
    pad_m: float = 0.1
    exact_oti: bool = True  # skip distances for exact intervals; False: the dissertation's
    _grids: dict[tuple[str, Shape], RouteGrid] = field(default_factory=dict)
    _pairs: dict[tuple[str, Shape, str, Shape], np.ndarray] = field(default_factory=dict)
    _zones: dict[tuple[str, Shape, str, Shape], np.ndarray] = field(default_factory=dict)
    _compatible: dict[tuple[str, Shape, str, Shape], bool] = field(default_factory=dict)
    _stacks: dict[tuple[str, Shape], PairStack] = field(default_factory=dict)
    _rows_of: dict[tuple[str, Shape], dict[tuple[str, float, float], int]] = field(
        default_factory=dict
    )

    def grid(self, route: Route, shape: Shape) -> RouteGrid:
        key = (route.id, shape)
        g = self._grids.get(key)
        if g is None:
            g = _route_grid(route, shape, self.margin_m, self.ds_m, self.pad_m, self.exact_oti)
            self._grids[key] = g
        return g

    def pairs(self, ra: Route, sa: Shape, rb: Route, sb: Shape) -> np.ndarray:
        """int8 (grid a, grid b): APART, MAYBE or TOUCH for footprints nearest those points.

        APART and TOUCH settle a pair exactly; only MAYBE needs the exact test.
        """
        key = (ra.id, sa, rb.id, sb)
        m = self._pairs.get(key)
        if m is None:
            ga, gb = self.grid(ra, sa), self.grid(rb, sb)
            maybe = _overlap_bbox_filtered(ga.rects, gb.rects)
            m = maybe.astype(np.int8)
            if maybe.any():
                rows, cols = np.nonzero(maybe.any(axis=1))[0], np.nonzero(maybe.any(axis=0))[0]
                sure = overlap_matrix(ga.inner.take(rows), gb.inner.take(cols))
                m[np.ix_(rows, cols)] += sure.astype(np.int8)
            self._pairs[key] = m
            self._pairs[(rb.id, sb, ra.id, sa)] = m.T
            self._zones[key] = maybe.any(axis=1)
            self._zones[(rb.id, sb, ra.id, sa)] = maybe.any(axis=0)
        return m

    def zone(self, ra: Route, sa: Shape, rb: Route, sb: Shape) -> np.ndarray:
        """Boolean mask over route a's grid: where a can touch route b."""
        z = self._zones.get((ra.id, sa, rb.id, sb))
        if z is None:
            self.pairs(ra, sa, rb, sb)
            z = self._zones[(ra.id, sa, rb.id, sb)]
        return z

    def compatible(self, ra: Route, sa: Shape, rb: Route, sb: Shape) -> bool:
        key = (ra.id, sa, rb.id, sb)
        c = self._compatible.get(key)
        if c is None:
            c = not self.zone(ra, sa, rb, sb).any()
            self._compatible[key] = c
        return c

    def stack(self, ra: Route, sa: Shape) -> PairStack:
        """Every pair table of route a, transposed and stacked (see :class:`PairStack`)."""
        key = (ra.id, sa)
        st = self._stacks.get(key)
        if st is None:
            st = PairStack(len(self.grid(ra, sa).rects))
            self._stacks[key] = st
        return st

    def stack_offset(self, ra: Route, sa: Shape, rb: Route, sb: Shape) -> int:
        """Row of grid point 0 of route b in route a's :class:`PairStack`."""
        st = self.stack(ra, sa)
        off = st.offset.get((rb.id, sb))
        if off is None:
            off = st.append((rb.id, sb), self.pairs(ra, sa, rb, sb))
        return off

    def rows_of(self, ra: Route, sa: Shape) -> dict[tuple[str, float, float], int]:
        """Route a's rows by (route b's id, length, width): route b's block in route a's
        :class:`PairStack`, -1 where the two are compatible. Filled by the caller as
        it meets route b (``ConfirmedBatch.of``, once per request), kept for good."""
        return self._rows_of.setdefault((ra.id, sa), {})

    def precompute(self, shape: Shape) -> None:
        """Build every table for one shape now (the offline step, done at start-up)."""
        routes = self.intersection.routes
        for i, ra in enumerate(routes):
            for rb in routes[i:]:
                self.zone(ra, shape, rb, shape)
        for ra in routes:
            for rb in routes:
                if not self.compatible(ra, shape, rb, shape):
                    self.stack_offset(ra, shape, rb, shape)


def _overlap_bbox_filtered(a: Rects, b: Rects) -> np.ndarray:
    """overlap_matrix, skipping the work when the two sweeps' boxes are apart."""
    ra = a.half_length + a.half_width
    rb = b.half_length + b.half_width
    lo_a, hi_a = a.centre.min(0) - ra, a.centre.max(0) + ra
    lo_b, hi_b = b.centre.min(0) - rb, b.centre.max(0) + rb
    if np.any(hi_a < lo_b) or np.any(hi_b < lo_a):
        return np.zeros((len(a), len(b)), dtype=bool)
    return overlap_matrix(a, b)
