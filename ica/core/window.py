"""The requests of a short window, confirmed in the order that delays them least.

First come, first served lets conflicting streams take turns vehicle by
vehicle. With a window the ICA collects the requests of ``window_s`` and
decides them together when it closes: still one by one, each by DICA's own
conflict search against the whole confirmed set (nothing about safety
changes), only in another order: the one of least total delay by the
separation model of :mod:`ica.core.separation`, every lane's order kept,
found by the exact solver of :mod:`ica.core.ordering`. That bounds anyone's
wait: each request is decided when its window closes, behind at most the
other requests of that window, and a window reorders only its own requests,
never a confirmation.

The releases are each request's earliest entry from its own state, and no
earlier than the confirmed plans allow through their separations (entry and
entry speed read off each plan), as reactive DICA folds its fixed vehicles.
No I/O here; the caller collects the window and asks for the order.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from dica.ica.core.dica import Dica
from dica.ica.core.ordering import OrderingError, Problem, solve
from dica.ica.core.planner import Planner
from dica.ica.core.request import Request
from dica.ica.core.route import Route
from dica.ica.core.separation import SeparationModel
from dica.ica.core.zones import Shape


class WindowOrder:
    """Orders one window's requests for a :class:`Dica` (reads its state, never changes it)."""

    def __init__(self, dica: Dica, solver: str = "exact") -> None:
        self.dica = dica
        self.solver = solver
        cfg = dica.config
        self.separations = SeparationModel(
            dica.intersection, dica.tables, Shape.of(5.0, 1.8), cfg.kinematics, cfg.margin_m,
            cfg.step_s, cfg.techniques,
        )  # fmt: skip
        self.windows = 0  # windows with two requests or more (the others need no order)
        self.reordered = 0  # of them, decided in an order other than arrival's
        self.order_s: list[float] = []  # wall time of ordering each of them

    def order(self, reqs: Sequence[Request]) -> list[Request]:
        """``reqs`` (in arrival order) in the order to decide them. Requests the
        model cannot judge (unknown route, not detected) keep their place after
        the others; DICA answers them with its own reason."""
        if len(reqs) < 2:
            return list(reqs)
        dica = self.dica
        rank = {v: i for lane in dica.intersection.in_lanes for i, v in enumerate(dica.queue(lane))}
        known: list[tuple[Request, Route]] = []
        rest: list[Request] = []
        seen: set[str] = set()
        for r in reqs:
            route = (
                dica.intersection.route(r.in_lane, r.out_lane)
                if isinstance(r.in_lane, str) and isinstance(r.out_lane, str)
                else None
            )
            if route is None or r.vin not in rank or r.vin in seen:
                rest.append(r)
            else:
                seen.add(r.vin)
                known.append((r, route))
        if len(known) < 2:
            return [r for r, _ in known] + rest
        t_wall = time.perf_counter()
        self.windows += 1
        # candidates grouped by lane, front first (the ordering keeps index order per lane)
        known.sort(key=lambda x: (x[1].in_lane, rank[x[0].vin]))
        lanes = sorted({route.in_lane for _, route in known})
        release, entry_mps = [], []
        for r, route in known:
            t, v = self._earliest(r, route)
            release.append(t)
            entry_mps.append(v)
        routes = [route for _, route in known]
        fixed = dica.entries()
        release = [
            self.separations.release_after(t, (route,), v, fixed)
            for t, route, v in zip(release, routes, entry_mps, strict=True)
        ]
        # the ordering's first key is an EV's entry; here nobody comes first, so the "EV"
        # is a stand-in in a lane of its own, released before all and separated from none:
        # it goes first at no cost to anyone, and the total delay decides the rest
        n = len(known)
        sep = np.zeros((n + 1, n + 1))
        sep[:n, :n] = self.separations.matrix(routes, entry_mps)
        try:
            problem = Problem(
                np.array([lanes.index(route.in_lane) for route in routes] + [len(lanes)]),
                np.array([*release, min(release) - 1.0]),
                sep,
                n,
            )
            order = [i for i in solve(problem, self.solver).order if i != n]
        except OrderingError:
            return list(reqs)  # the model cannot say: first come, first served
        finally:
            self.order_s.append(time.perf_counter() - t_wall)
        out = [known[i][0] for i in order]
        taken = {id(r) for r in out}
        arrival = [r for r in reqs if id(r) in taken]
        if any(a is not b for a, b in zip(out, arrival, strict=True)):
            self.reordered += 1
        return out + rest

    def _earliest(self, r: Request, route: Route) -> tuple[float, float]:
        """Earliest entry [s] and the speed it enters at, from the request's own state."""
        cfg = self.dica.config
        pl = Planner(
            d_m=max(float(r.dist_to_entry_m), 0.0),
            v0_mps=max(float(r.speed_mps), 0.0),
            road_mps=route.road_mps,
            cap_mps=self.dica.front_cap_mps(route),
            s_end_m=route.cross_length_m + float(r.length_m),
            kin=cfg.kinematics,
            hold=cfg.platoon,
        )
        e = pl.earliest_entry_s()
        fastest = pl.fastest()
        v = fastest.entry_speed_mps if fastest is not None else 0.0
        t = float(r.t0_s) + e if math.isfinite(e) else float(r.t0_s)
        return t, v
