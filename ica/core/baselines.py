"""Reservation baselines the dissertation compares against, on the same footing.

Each keeps everything of :class:`Dica` (validation, head rule, flyable plans,
checkFV, the lane leader) and changes only what counts as a conflict, so a
comparison isolates how each uses space and time:

* **FIFO**: the junction is one resource, granted in request order: a
  vehicle may touch it only after every vehicle confirmed before it has left.
* **Concurrent** (Kim and Kumar, 2014): vehicles on conflicting routes are
  never inside the junction at the same time; compatible routes may be.
* **Tiles** (FCFS reservations in the manner of AIM, Dresner and Stone): the
  junction is a grid of square tiles; an occupancy reserves every tile its
  footprint touches for its occupancy time interval. Space is quantised to the
  tile size, which is the dissertation's point of comparison with DTOTs. The
  tile test itself is exact (separating axes per tile), and the intervals are
  the same as DICA's, so tiles are never less safe than DTOTs.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.conflict import Conflict
from dica.ica.core.dica import Dica
from dica.ica.core.dtot import Dtot
from dica.ica.core.intersection import Intersection
from dica.ica.core.occupancy import Rects, overlap_matrix


class Fifo(Dica):
    """One vehicle in the junction at a time, in the order requests were confirmed."""

    def conflicts(self, dtot: Dtot) -> list[Conflict]:
        out = [
            Conflict(vin, other.start_s, other.end_s - dtot.start_s)
            for vin, other in self.confirmed_dtots()
            if other.end_s >= dtot.start_s
        ]
        out.sort(key=lambda c: c.first_time_s)
        return out


class Concurrent(Dica):
    """Conflicting routes are never inside the junction together (Kim and Kumar)."""

    def conflicts(self, dtot: Dtot) -> list[Conflict]:
        out = []
        for vin, other in self.confirmed_dtots():
            if other.end_s < dtot.start_s or dtot.end_s < other.start_s:
                continue
            if self.tables.compatible(dtot.route, dtot.shape, other.route, other.shape):
                continue
            out.append(Conflict(vin, other.start_s, other.end_s - dtot.start_s))
        out.sort(key=lambda c: c.first_time_s)
        return out


class Tiles(Dica):
    """FCFS tile reservations: a tile is held by one vehicle at a time."""

    def __init__(
        self, intersection: Intersection, config: IcaConfig | None = None, tile_m: float = 1.0
    ) -> None:
        if not 0.1 <= tile_m <= 10.0:
            raise ValueError("tile size must be between 0.1 and 10 m")
        super().__init__(intersection, config)
        self.tile_m = tile_m
        self._tiles: dict[str, list[np.ndarray]] = {}  # vin -> tile ids per occupancy

    def tiles_of(self, rects: Rects) -> list[np.ndarray]:
        """Tile ids (packed ints) each footprint touches, exactly."""
        corners = rects.corners()
        lo = np.floor(corners.min(axis=1) / self.tile_m).astype(np.int64)
        hi = np.floor(corners.max(axis=1) / self.tile_m).astype(np.int64)
        half = self.tile_m / 2.0
        out = []
        for k in range(len(rects)):
            xs = np.arange(lo[k, 0], hi[k, 0] + 1)
            ys = np.arange(lo[k, 1], hi[k, 1] + 1)
            gx, gy = np.meshgrid(xs, ys, indexing="ij")
            gx, gy = gx.ravel(), gy.ravel()
            cells = Rects(
                np.stack([(gx + 0.5) * self.tile_m, (gy + 0.5) * self.tile_m], -1),
                np.tile([1.0, 0.0], (len(gx), 1)),
                half,
                half,
            )
            hit = overlap_matrix(cells, rects.take(slice(k, k + 1)))[:, 0]
            out.append(gx[hit] * 1_000_003 + gy[hit])
        return out

    def conflicts(self, dtot: Dtot) -> list[Conflict]:
        mine = self.tiles_of(dtot.rects)
        held: dict[int, list[tuple[float, float, str]]] = defaultdict(list)
        for vin, other in self.confirmed_dtots():
            if other.end_s < dtot.start_s or dtot.end_s < other.start_s:
                continue
            tiles = self._tiles.get(vin)
            if tiles is None:
                tiles = self._tiles[vin] = self.tiles_of(other.rects)
            for m, ids in enumerate(tiles):
                for tid in ids.tolist():
                    held[tid].append((other.lb_s[m], other.ub_s[m], vin))
        first: dict[str, float] = {}
        delay: dict[str, float] = {}
        for k, ids in enumerate(mine):
            lb, ub = dtot.lb_s[k], dtot.ub_s[k]
            for tid in ids.tolist():
                for olb, oub, vin in held.get(tid, ()):
                    if olb <= ub and lb <= oub:
                        first[vin] = min(first.get(vin, math.inf), olb)
                        delay[vin] = max(delay.get(vin, -math.inf), oub - lb)
        out = [Conflict(vin, first[vin], delay[vin]) for vin in first]
        out.sort(key=lambda c: c.first_time_s)
        return out

    def _forget(self, vin: str) -> None:
        self._tiles.pop(vin, None)
