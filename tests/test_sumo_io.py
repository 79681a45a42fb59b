"""What SUMO says, read back: subscribed reads and the safety monitor's feed, on a real SUMO."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from dica.sim_gateway.safety import SafetyMonitor
from dica.sim_gateway.sumo_io import Reads, Watch
from tests.sumo_session import open_sumo

GETTERS = ("getLaneID", "getLanePosition", "getSpeed", "getRoadID", "getDistance")
XY_GETTERS = ("getPosition", "getAngle")


def _add(ls, vin: str, edges: tuple[str, ...], lane: int, pos_m: float, speed_mps: float):
    route = "r_" + "_".join(edges)
    if route not in ls.route.getIDList():
        ls.route.add(route, list(edges))
    ls.vehicle.add(
        vin, route, departLane=str(lane), departPos=str(pos_m), departSpeed=str(speed_mps)
    )


def test_reads_return_what_sumo_says_after_a_subscription(ch45_net):
    """Each getter gives the value SUMO holds for that variable, for a vehicle subscribed
    with and without positions and for one never subscribed (read directly), while the
    vehicles move (lane, road, position and odometer all change: a getter wired to the
    wrong variable differs)."""
    with open_sumo(ch45_net.net_path) as ls:
        _add(ls, "left", ("W_in", "N_out"), 2, 150.0, 12.0)  # turns: its angle changes
        _add(ls, "through", ("S_in", "N_out"), 1, 160.0, 15.0)
        _add(ls, "plain", ("E_in", "W_out"), 1, 140.0, 10.0)
        ls.simulation.step()
        Reads.subscribe(ls, "left", xy=True)
        Reads.subscribe(ls, "through")
        seen_lanes: set[str] = set()
        for _ in range(300):
            ls.simulation.step()
            vw = Reads(ls)
            for vin in ls.vehicle.getIDList():
                getters = GETTERS + (XY_GETTERS if vin == "left" else ())
                for name in getters:
                    assert getattr(vw, name)(vin) == getattr(ls.vehicle, name)(vin), (vin, name)
                seen_lanes.add(vw.getLaneID(vin))
        # what a subscription without positions leaves out is read directly, and equal too
        assert vw.getPosition("through") == ls.vehicle.getPosition("through")
        assert any(lane.startswith(":") for lane in seen_lanes)  # through the junction
        # SUMO delivers exactly what the getters read, in the step's one call
        c = ls.constants
        rows = ls.vehicle.getAllSubscriptionResults()
        wanted = {c.VAR_LANE_ID, c.VAR_LANEPOSITION, c.VAR_SPEED, c.VAR_ROAD_ID, c.VAR_DISTANCE}
        assert set(rows["through"]) == wanted
        assert set(rows["left"]) == wanted | {c.VAR_POSITION, c.VAR_ANGLE}
        assert "plain" not in rows


def _rectangle(ls, vin: str) -> shapely.Polygon:
    """The vehicle's body from SUMO's own getters: the front bumper's centre, the angle
    clockwise from north, its length and width."""
    x, y = ls.vehicle.getPosition(vin)
    a = math.radians(ls.vehicle.getAngle(vin))
    along = np.array([math.sin(a), math.cos(a)])
    across = np.array([along[1], -along[0]])
    half_l, half_w = ls.vehicle.getLength(vin) / 2, ls.vehicle.getWidth(vin) / 2
    centre = np.array([x, y]) - along * half_l
    return shapely.Polygon(
        [
            centre + i * half_l * along + j * half_w * across
            for i, j in ((1, 1), (1, -1), (-1, -1), (-1, 1))
        ]
    )


def test_the_watch_feeds_the_monitor_every_vehicle_near_the_junction_and_no_other(ch45_net, ch45):
    """Vehicles within the radius reach the monitor (their sizes read once), others do
    not; the closest pair it saw is the two standing at the junction's edge, at the gap
    between their bodies as SUMO holds them (positions, angles, lengths and widths)."""
    radius = 40.0
    with open_sumo(ch45_net.net_path) as ls:
        short = ls.lane.getLength("W_in_0") - 1.0
        _add(ls, "near_a", ("W_in", "E_out"), 0, short, 0.0)  # its front 1 m short of it
        _add(ls, "near_b", ("W_out",), 0, 6.0, 0.0)  # leaving: its rear 1 m out of it
        _add(ls, "far", ("E_in", "W_out"), 1, 100.0, 0.0)
        ls.simulation.step()
        for vin in ls.vehicle.getIDList():
            ls.vehicle.setSpeed(vin, 0.0)
        watch = Watch(ch45.junction_id, radius)
        watch.subscribe(ls)
        monitor = SafetyMonitor(ch45.region, watch_margin_m=2.0)
        centre = np.asarray(ls.junction.getPosition(ch45.junction_id))
        for _ in range(3):
            ls.simulation.step()
            watch.feed(ls, monitor, ls.simulation.getTime())
        near = {
            v
            for v in ls.vehicle.getIDList()
            if math.dist(ls.vehicle.getPosition(v), centre) <= radius
        }
        assert near == {"near_a", "near_b"}
        assert set(watch.sizes) == near
        report = monitor.report()
        assert report.steps == 3 and report.overlaps == 0
        assert report.min_gap_pair is not None and set(report.min_gap_pair[1:]) == near
        gap = _rectangle(ls, "near_a").distance(_rectangle(ls, "near_b"))
        assert report.min_gap_m == pytest.approx(gap, abs=1e-6)
