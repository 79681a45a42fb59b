"""The network seen from above: every junction's area and lanes, the vehicles coloured by
what they are doing, and every junction's confirmed plans as the paths their vehicles
will fly, in one ``.rrd`` of its own.

:class:`TopDrawing` draws; what it is fed comes from SUMO in an embedded run
(:class:`NetworkView`: every vehicle in the net) and from the wire in a cluster
(:class:`sim_gateway.network_observer.NetworkObserver`: the vehicles in the
junctions' regions, which is what the gateway publishes).

The junctions' space-time charts stay in their own recordings (one per junction,
:func:`sim_gateway.network.recording_path`); this one answers where on the
network the traffic and the reservations are. Drawn every ``EVERY_S`` of sim time:
enough to follow the flows across a grid, small beside the junctions' files.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dica.ica.core.intersection import Intersection
from dica.sim_gateway.recording.geometry import (
    FLIP_Y,
    crossing_outlines,
    outlines,
    sumo_heading_rad,
)
from dica.sim_gateway.recording.recorder import finish, free_port
from dica.sim_gateway.recording.style import (
    CROSSING_RGB,
    LANE_EDGE_RGB,
    PERSON_WAITING_RGB,
    PERSON_WALKING_RGB,
    REGION_RGB,
    STATUS_RGBA,
    Status,
    rgba,
)

EVERY_S = 0.5  # [s sim] the view is drawn this often
SUMO_RGBA = rgba((150, 150, 150))  # a vehicle SUMO's driver has (between the regions)


class TopDrawing:
    """The top view's Rerun stream, written to ``path`` as the run goes."""

    def __init__(
        self, inters: Sequence[Intersection], path: Path, live_port: int | None = None
    ) -> None:
        """``live_port``: also serve the view over gRPC on 127.0.0.1 at that port while
        it is written (``dica view --live``)."""
        self.inters = list(inters)
        self.path = Path(path)
        self.rec = rr.RecordingStream("dica network")
        self.rec.set_log_time_enabled(False)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        view = rrb.Spatial2DView(origin="network", name="network: every junction, from above")
        sinks: list = [rr.FileSink(str(self.path))]
        self.live = live_port is not None
        if live_port is not None:
            free_port(live_port)
            sinks.append(rr.GrpcServerSink(bind_ip="127.0.0.1", port=live_port))
        self.rec.set_sinks(*sinks, default_blueprint=rrb.Blueprint(view))

    def geometry(self, lane_shapes: Sequence[np.ndarray]) -> None:
        """Static: the lanes (SUMO's shapes, world frame), each junction's area and name."""
        strips = [np.asarray(x, dtype=float).reshape(-1, 2) * FLIP_Y for x in lane_shapes]
        self.rec.log("network/lanes", rr.LineStrips2D(strips, colors=LANE_EDGE_RGB, radii=0.15),
                     static=True)  # fmt: skip
        areas = [np.vstack([x.region, x.region[:1]]) * FLIP_Y for x in self.inters]
        self.rec.log("network/junctions", rr.LineStrips2D(areas, colors=REGION_RGB, radii=0.3),
                     static=True)  # fmt: skip
        walks = [w for x in self.inters for w in crossing_outlines(x)]
        if walks:
            self.rec.log(
                "network/crossings",
                rr.LineStrips2D(walks, colors=CROSSING_RGB, radii=0.15),
                static=True,
            )
        centres = np.array([np.asarray(x.region).mean(axis=0) for x in self.inters]) * FLIP_Y
        self.rec.log(
            "network/names",
            rr.Points2D(centres, labels=[x.junction_id for x in self.inters], radii=0.1),
            static=True,
        )

    def moment(
        self,
        t_s: float,
        front: np.ndarray,
        angle_deg: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        colours: Sequence,
        paths: Sequence[np.ndarray],
        names: Sequence[str],
    ) -> None:
        """One moment: vehicles by front-bumper centre and SUMO angle, and the plans' paths
        (world frame)."""
        self.rec.set_time("sim_time", duration=t_s)
        if len(front):
            heading = sumo_heading_rad(np.asarray(angle_deg, dtype=float))
            c, s = np.cos(heading), np.sin(heading)
            front = np.asarray(front, dtype=float).reshape(-1, 2)
            cx, cy = front[:, 0] - c * length / 2.0, front[:, 1] - s * length / 2.0
            boxes = outlines(cx, cy, c, s, length / 2.0, width / 2.0)
            # packed 0xRRGGBBAA as uint32: a plain list of four reads as one RGBA colour
            packed = np.asarray(colours, dtype=np.uint32)
            self.rec.log("network/vehicles", rr.LineStrips2D(boxes, colors=packed, radii=0.2))
        else:
            self.rec.log("network/vehicles", rr.Clear(recursive=False))
        if paths:
            self.rec.log(
                "network/plans",
                rr.LineStrips2D(
                    [np.asarray(p, dtype=float) * FLIP_Y for p in paths],
                    colors=STATUS_RGBA[Status.CONFIRMED], radii=0.35, labels=list(names),
                ),
            )  # fmt: skip
        else:
            self.rec.log("network/plans", rr.Clear(recursive=False))

    def people(self, xy: np.ndarray, waiting: np.ndarray) -> None:
        """The people in the net at this moment (SUMO's frame): amber waiting at a kerb
        for its ICA's go, blue walking."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        wait = np.asarray(waiting, dtype=bool).reshape(-1)
        self.rec.log(
            "network/people",
            rr.Points2D(
                (xy * FLIP_Y).astype(np.float32),
                colors=np.where(wait[:, None], PERSON_WAITING_RGB, PERSON_WALKING_RGB).astype(
                    np.uint8
                ),
                radii=0.6,
            ),
        )

    def close(self) -> None:
        finish(self.rec, self.live)


def route_lanes(inters: Sequence[Intersection]) -> list[str]:
    """Every lane the junctions' routes use (in, through, out), sorted."""
    lanes: set[str] = set()
    for x in inters:
        for r in x.routes:
            lanes.update((r.in_lane, r.out_lane, *r.via_lanes))
    return sorted(lanes)


class NetworkView:
    """The embedded run's top view: every vehicle in the net as SUMO has it."""

    def __init__(self, ls, inters: Sequence[Intersection], path: Path) -> None:
        self.ls = ls
        self.draw = TopDrawing(inters, path)
        self._next_s = 0.0

    def geometry(self) -> None:
        lanes = route_lanes(self.draw.inters)
        self.draw.geometry([self.ls.lane.getShape(lane) for lane in lanes])

    def step(self, t_s: float, junctions: Iterable, drivers: Iterable, walkers=None) -> None:
        """This moment, if one is due: every vehicle in the net, the plans held, and the
        people (``walkers``: :class:`sim_gateway.walkers.Walkers`, if any)."""
        if t_s + 1e-9 < self._next_s:
            return
        self._next_s = t_s + EVERY_S
        status: dict[str, int] = {}
        paths, names = [], []
        for j, d in zip(junctions, drivers, strict=False):
            for c in j.active:
                if c.sumo not in j.present or c.exited:
                    continue
                if c.ev:
                    status[c.sumo] = Status.EMERGENCY
                elif c.entered:
                    status[c.sumo] = Status.CROSSING
                elif c.plan_s is not None:
                    status[c.sumo] = Status.CONFIRMED
                else:
                    status[c.sumo] = Status.REQUESTING
                v = d.vehicles.get(c.vin) if d is not None else None
                conf = v.confirmation if v is not None else None
                if conf is not None and c.plan_s is not None:
                    paths.append(np.column_stack([conf.tss.x_m, conf.tss.y_m]))
                    names.append(c.vin)
        v = self.ls.vehicle
        ids = v.getIDList()
        self.draw.moment(
            t_s,
            np.array([v.getPosition(x) for x in ids], dtype=float).reshape(-1, 2),
            np.array([v.getAngle(x) for x in ids], dtype=float),
            np.array([v.getLength(x) for x in ids], dtype=float),
            np.array([v.getWidth(x) for x in ids], dtype=float),
            [STATUS_RGBA[status[x]] if x in status else SUMO_RGBA for x in ids],
            paths,
            names,
        )
        if walkers is not None:
            self.draw.people(walkers.xy, walkers.waiting_mask())

    def close(self) -> None:
        self.draw.close()
