"""The observer process: records the run as Rerun space-time visuals.

It only listens: the STATE of every vehicle in the region (``sim/<j>/vehicles``), the
confirmations the ICA publishes (``dica/<j>/confirmed/*``) and the CLOCK. It
is not a lockstep participant, so recording never slows the run; at the
run's end on the clock it drains what is queued, closes the ``.rrd`` and
exits. All Rerun calls go through :class:`sim_gateway.recording.SpaceTimeRecorder`.
With ``live_port`` it also serves the recording over gRPC on 127.0.0.1 while
it writes the file, so ``dica view --live`` can watch the run as it happens.

The wire carries no rejections to the observer (a REJECT is the reply to the
vehicle's query), so the rejections table stays empty in a cluster run.
Where a new message or field changes what is drawn: a vehicle's state and
colour are decided in :func:`sim_gateway.recording.vehicle_states`; a
withdrawn plan would call the recorder from :meth:`Observer._on`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ica.core.intersection import Intersection
from schemas import keys
from schemas.codec import DecodeError, decode
from schemas.link import Inbox, Item
from schemas.messages import Clock, Response, State, VehicleState
from sim_gateway.recording import SpaceTimeRecorder


@dataclass(slots=True)
class _Step:
    step: int = -1
    t_s: float = 0.0
    vehicles: list[VehicleState] = field(default_factory=list)


class Observer:
    def __init__(
        self,
        session,
        inter: Intersection,
        rrd_path,
        log: logging.Logger,
        name: str = "observer",
        *,
        margin_m: float = 0.25,
        time_pad_s: float = 0.0,
        live_port: int | None = None,
    ) -> None:
        self.inter = inter
        self.log = log
        self.margin_m = margin_m
        self.time_pad_s = time_pad_s
        self.inbox = Inbox()
        self.recorder = SpaceTimeRecorder(inter, rrd_path, margin_m=margin_m, live_port=live_port)
        self.recorder.geometry()
        self.sizes: dict[str, tuple[float, float]] = {}
        self.confirmations = 0
        self.steps = 0
        self.ended = False
        self._cur = _Step()
        j = inter.junction_id
        self._decls = [
            session.declare_subscriber(keys.vehicles(j), self.inbox.sample_cb("state")),
            session.declare_subscriber(keys.confirmed(j), self.inbox.sample_cb("confirmed")),
            session.declare_subscriber(keys.clock(j), self.inbox.sample_cb("clock")),
        ]
        # declared last: a gateway waiting for observers starts once all of the above are up
        self._token = session.liveliness().declare_token(keys.observer_alive(j, name))

    def run(self) -> None:
        while not self.inbox.stopping.is_set():
            item = self.inbox.get(timeout=0.2)
            if item is None:
                if self.ended:
                    break  # the end is announced and nothing more is queued
                continue
            try:
                self._on(item)
            except DecodeError as e:
                self.log.warning("dropped a bad %s message: %s", item.what, e)
            except ValueError as e:  # the recorder refuses what it cannot draw
                self.log.warning("not recorded (%s): %s", item.what, e)

    def close(self) -> None:
        self._emit()
        self._token.undeclare()
        for d in self._decls:
            d.undeclare()
        self.recorder.close()

    def _on(self, item: Item) -> None:
        if item.what == "state":
            st = decode(item.payload, State)
            if st.step != self._cur.step:
                self._emit()
                self._cur = _Step(st.step, st.t_s)
            self._cur.vehicles.extend(st.vehicles)
            for v in st.vehicles:
                self.sizes[v.vin] = (v.length_m, v.width_m)
        elif item.what == "confirmed":
            r = decode(item.payload, Response)
            length, width = self.sizes.get(r.vin, (5.0, 1.8))
            self.recorder.confirmed(
                r.vin,
                r.route_id,
                r.t_s,
                r.x_m,
                r.y_m,
                r.heading_rad,
                length,
                width,
                r.entry_time_s,
                r.exit_time_s,
                now_s=float(r.t_s[0]),
                delay_s=r.delay_s,
                rounds=r.iterations,
                margin_m=self.margin_m,
                time_pad_s=self.time_pad_s,
            )
            self.confirmations += 1
        elif item.what == "clock":
            c = decode(item.payload, Clock)
            if c.end:
                self.ended = True

    def _emit(self) -> None:
        cur = self._cur
        if cur.step < 0:
            return
        vs = cur.vehicles
        self.recorder.footprints(
            cur.t_s,
            [v.vin for v in vs],
            np.array([v.x_m for v in vs]),
            np.array([v.y_m for v in vs]),
            np.array([v.angle_deg for v in vs]),
            np.array([v.length_m for v in vs]),
            np.array([v.width_m for v in vs]),
            route_ids=[v.route_id for v in vs],
        )
        self.steps += 1
        self._cur = _Step()
