"""The intersection as the ICA sees it: its routes, region and lanes."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from dica.ica.core.crosswalk import Crosswalk
from dica.ica.core.route import Route
from dica.ica.core.waiting import sweeping


@dataclass(frozen=True, slots=True, eq=False)
class Intersection:
    """Routes through one junction, its area polygon and its approaches.

    ``comm_length_m`` is the length of the communication region: its entry
    line lies that far upstream of every entry line (50 m in the dissertation).
    ``region`` (K, 2) is the junction's area polygon as SUMO draws it.
    ``crosswalks`` are its pedestrian crossings (none where the net has none).
    """

    junction_id: str
    routes: tuple[Route, ...]
    region: np.ndarray
    comm_length_m: float = 50.0
    crosswalks: tuple[Crosswalk, ...] = ()
    _by_lanes: Mapping[tuple[str, str], Route] = field(init=False, repr=False)
    _by_id: Mapping[str, Route] = field(init=False, repr=False)
    _in_lanes: tuple[str, ...] = field(init=False, repr=False)
    _out_lanes: tuple[str, ...] = field(init=False, repr=False)
    _sweeping: dict[tuple[float, ...], frozenset[str]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        by_lanes = {(r.in_lane, r.out_lane): r for r in self.routes}
        if len(by_lanes) != len(self.routes):
            raise ValueError("two routes join the same incoming and outgoing lane")
        object.__setattr__(self, "_by_lanes", by_lanes)
        object.__setattr__(self, "_by_id", {r.id: r for r in self.routes})
        object.__setattr__(self, "_in_lanes", tuple(sorted({r.in_lane for r in self.routes})))
        object.__setattr__(self, "_out_lanes", tuple(sorted({r.out_lane for r in self.routes})))
        object.__setattr__(self, "_sweeping", {})

    @property
    def in_lanes(self) -> tuple[str, ...]:
        return self._in_lanes

    @property
    def out_lanes(self) -> tuple[str, ...]:
        return self._out_lanes

    def sweeping(
        self, length_m: float, width_m: float, gap_m: float, decel_mps2: float
    ) -> frozenset[str]:
        """The routes on which a vehicle this size would sweep over the place one waits,
        ``gap_m`` short of another lane's line or behind it, or over the last of a queue
        on another exit lane (none: the lines as placed and the room rule keep them
        clear; see :mod:`ica.core.waiting`). Worked out once per size."""
        key = (length_m, width_m, gap_m, decel_mps2)
        if key not in self._sweeping:
            self._sweeping[key] = sweeping(self.routes, length_m, width_m, gap_m, decel_mps2)
        return self._sweeping[key]

    def route(self, in_lane: str, out_lane: str) -> Route | None:
        return self._by_lanes.get((in_lane, out_lane))

    def route_by_id(self, route_id: str) -> Route | None:
        return self._by_id.get(route_id)

    def routes_from(self, in_lane: str) -> tuple[Route, ...]:
        return tuple(r for r in self.routes if r.in_lane == in_lane)
