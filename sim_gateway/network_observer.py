"""The cluster's top view of a network: one observer process that listens to every
junction and writes ``network.rrd``, as the embedded run's
:class:`~sim_gateway.recording.network_view.NetworkView` does from SUMO.

It hears what the gateway publishes, the vehicles in each junction's region
(``sim/<j>/vehicles``), and what the ICAs confirm (``dica/<j>/confirmed/*``),
so it draws those vehicles, coloured by what they are doing, and the paths of
the plans they hold; a vehicle between two regions, driven by SUMO's driver,
is not on the wire and not drawn. Like the junctions' observers it is no
lockstep participant and stops at the run's end on the clock. With
``live_port`` it also serves the view on 127.0.0.1 as it writes it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dica.deploy.transport import Inbox, Item
from dica.ica.core.intersection import Intersection
from dica.schemas import keys
from dica.schemas.codec import decode
from dica.schemas.messages import Clock, Response, State, VehicleState
from dica.sim_gateway.observer import listen
from dica.sim_gateway.recording.network_view import EVERY_S, SUMO_RGBA, TopDrawing
from dica.sim_gateway.recording.style import STATUS_RGBA, Status


def status_of(v: VehicleState, inter: Intersection) -> Status | None:
    """How a vehicle in ``inter``'s region is drawn (None: it has left the junction)."""
    if v.exited:
        return None
    if v.ev:
        return Status.EMERGENCY
    route = inter.route_by_id(v.route_id)
    if route is not None and (v.lane != route.in_lane or v.dist_to_entry_m <= 0.0):
        return Status.CROSSING
    return Status.CONFIRMED if v.plan_seq >= 0 else Status.REQUESTING


class NetworkObserver:
    """Writes the top view of the junctions ``inters`` to ``rrd_path`` from the wire."""

    def __init__(
        self,
        session,
        inters: Sequence[Intersection],
        lane_shapes: Sequence[np.ndarray],
        rrd_path: Path,
        log: logging.Logger,
        name: str = "network",
        live_port: int | None = None,
    ) -> None:
        self.inters = {x.junction_id: x for x in inters}
        self.log = log
        self.inbox = Inbox()
        self.draw = TopDrawing(inters, rrd_path, live_port)
        self.draw.geometry(lane_shapes)
        self.ended = False
        self.steps = 0  # moments drawn
        self.confirmations = 0
        self._step = -1
        self._t_s = 0.0
        self._next_s = 0.0
        # per junction: the step its vehicles were last published at, and those vehicles
        # by VIN (a message heard twice draws each once)
        self._seen: dict[str, tuple[int, dict[str, VehicleState]]] = {}
        # per junction and vehicle: the newest confirmed plan's seq and path
        self._plans: dict[tuple[str, str], tuple[int, np.ndarray]] = {}
        self._decls = []
        for j in self.inters:
            self._decls += [
                session.declare_subscriber(keys.vehicles(j), self.inbox.sample_cb(f"state {j}")),
                session.declare_subscriber(
                    keys.confirmed(j), self.inbox.sample_cb(f"confirmed {j}")
                ),
                session.declare_subscriber(keys.clock(j), self.inbox.sample_cb(f"clock {j}")),
            ]
        # declared last: the gateway sends every step's vehicles while an observer is up
        self._tokens = [
            session.liveliness().declare_token(keys.observer_alive(j, name)) for j in self.inters
        ]

    def run(self) -> None:
        listen(self.inbox, self._on, lambda: self.ended, self.log)

    def close(self) -> None:
        self._emit()
        for t in self._tokens:
            t.undeclare()
        for d in self._decls:
            d.undeclare()
        self.draw.close()

    def _on(self, item: Item) -> None:
        what, j = item.what.split(" ", 1)
        if what == "state":
            st = decode(item.payload, State)
            if st.step > self._step:
                self._emit()
                self._step, self._t_s = st.step, st.t_s
            step, vs = self._seen.get(j, (-1, {}))
            if st.step < step:
                return  # late: this junction has been heard at a later step
            if step != st.step:
                step, vs = st.step, {}
                self._seen[j] = (step, vs)
            vs.update((v.vin, v) for v in st.vehicles)
        elif what == "confirmed":
            r = decode(item.payload, Response)
            seq, _ = self._plans.get((j, r.vin), (-1, None))
            if r.seq >= seq:
                self._plans[(j, r.vin)] = (r.seq, np.column_stack([r.x_m, r.y_m]))
            self.confirmations += 1
        elif what == "clock" and decode(item.payload, Clock).end:
            self.ended = True

    def _emit(self) -> None:
        """Draw the moment of the newest step, if one is due: every junction that
        published its vehicles at that step."""
        if self._step < 0 or self._t_s + 1e-9 < self._next_s:
            return
        self._next_s = self._t_s + EVERY_S
        vs, colours, paths, names = [], [], [], []
        for j, (step, seen) in self._seen.items():
            if step != self._step:
                continue
            inter = self.inters[j]
            for v in seen.values():
                st = status_of(v, inter)
                vs.append(v)
                colours.append(SUMO_RGBA if st is None else STATUS_RGBA[st])
                plan = self._plans.get((j, v.vin))
                if st is not None and plan is not None and 0 <= v.plan_seq <= plan[0]:
                    paths.append(plan[1])
                    names.append(v.vin)
        self.draw.moment(
            self._t_s,
            np.array([(v.x_m, v.y_m) for v in vs], dtype=float).reshape(-1, 2),
            np.array([v.angle_deg for v in vs], dtype=float),
            np.array([v.length_m for v in vs], dtype=float),
            np.array([v.width_m for v in vs], dtype=float),
            colours,
            paths,
            names,
        )
        self.steps += 1
        # plans of vehicles no junction names any more are done with
        here = {(j, vin) for j, (_, seen) in self._seen.items() for vin in seen}
        for k in [k for k in self._plans if k not in here]:
            del self._plans[k]
