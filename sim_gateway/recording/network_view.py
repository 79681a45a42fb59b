"""The network seen from above: every junction's area and lanes, every vehicle in the net
as SUMO has it, coloured by what it is doing, and every junction's confirmed plans as
the paths their vehicles will fly, in one ``.rrd`` of its own.

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
from dica.sim_gateway.recording.geometry import FLIP_Y, outlines, sumo_heading_rad
from dica.sim_gateway.recording.style import (
    LANE_EDGE_RGB,
    REGION_RGB,
    STATUS_RGBA,
    Status,
    rgba,
)

EVERY_S = 0.5  # [s sim] the view is drawn this often
SUMO_RGBA = rgba((150, 150, 150))  # a vehicle SUMO's driver has (between the regions)


class NetworkView:
    """Writes the network's top view to ``path`` as the run goes."""

    def __init__(self, ls, inters: Sequence[Intersection], path: Path) -> None:
        self.ls = ls
        self.inters = list(inters)
        self.path = Path(path)
        self._next_s = 0.0
        self.rec = rr.RecordingStream("dica network")
        self.rec.set_log_time_enabled(False)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        view = rrb.Spatial2DView(origin="network", name="network: every junction, from above")
        self.rec.set_sinks(rr.FileSink(str(self.path)), default_blueprint=rrb.Blueprint(view))

    def geometry(self) -> None:
        """Static: the lanes the junctions' routes use, each junction's area and name."""
        ls, lanes = self.ls, set()
        for x in self.inters:
            for r in x.routes:
                lanes.update((r.in_lane, r.out_lane, *r.via_lanes))
        strips = [
            np.asarray(ls.lane.getShape(lane), dtype=float) * FLIP_Y for lane in sorted(lanes)
        ]
        self.rec.log("network/lanes", rr.LineStrips2D(strips, colors=LANE_EDGE_RGB, radii=0.15),
                     static=True)  # fmt: skip
        areas = [np.vstack([x.region, x.region[:1]]) * FLIP_Y for x in self.inters]
        self.rec.log("network/junctions", rr.LineStrips2D(areas, colors=REGION_RGB, radii=0.3),
                     static=True)  # fmt: skip
        centres = np.array([np.asarray(x.region).mean(axis=0) for x in self.inters]) * FLIP_Y
        self.rec.log(
            "network/names",
            rr.Points2D(centres, labels=[x.junction_id for x in self.inters], radii=0.1),
            static=True,
        )

    def step(self, t_s: float, junctions: Iterable, drivers: Iterable) -> None:
        """This moment, if one is due: every vehicle in the net, and the plans held."""
        if t_s + 1e-9 < self._next_s:
            return
        self._next_s = t_s + EVERY_S
        ls = self.ls
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
                    paths.append(np.column_stack([conf.tss.x_m, conf.tss.y_m]) * FLIP_Y)
                    names.append(c.vin)
        ids = ls.vehicle.getIDList()
        self.rec.set_time("sim_time", duration=t_s)
        if ids:
            v = ls.vehicle
            front = np.array([v.getPosition(x) for x in ids], dtype=float)
            heading = sumo_heading_rad(np.array([v.getAngle(x) for x in ids]))
            length = np.array([v.getLength(x) for x in ids])
            width = np.array([v.getWidth(x) for x in ids])
            c, s = np.cos(heading), np.sin(heading)
            cx, cy = front[:, 0] - c * length / 2.0, front[:, 1] - s * length / 2.0
            boxes = outlines(cx, cy, c, s, length / 2.0, width / 2.0)
            colours = [STATUS_RGBA[status[x]] if x in status else SUMO_RGBA for x in ids]
            self.rec.log("network/vehicles", rr.LineStrips2D(boxes, colors=colours, radii=0.2))
        else:
            self.rec.log("network/vehicles", rr.Clear(recursive=False))
        if paths:
            self.rec.log(
                "network/plans",
                rr.LineStrips2D(
                    paths, colors=STATUS_RGBA[Status.CONFIRMED], radii=0.35, labels=names
                ),
            )
        else:
            self.rec.log("network/plans", rr.Clear(recursive=False))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
