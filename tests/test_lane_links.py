"""A lane with several links onto the same road out: the vehicle SUMO drives takes the
link the ICA planned.

netgenerate's multi-lane grids connect a through lane to two lanes of the road
ahead. A route is a pair of lanes, so the demand draws one of those links; SUMO is
given roads, and left to itself takes a link of its own choosing, over an internal
lane the ICA never reserved for that vehicle, across another's crossing.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import pytest

from dica.ica.netfile import load_intersection
from dica.sim_gateway import embedded
from dica.sim_gateway.runconfig import RunConfig
from tests.user_nets import CITY_MPS, make, tool


@pytest.fixture(scope="module")
def four_lanes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One junction A0, four lanes each way at 50 km/h on 300 m approaches."""
    net = tmp_path_factory.mktemp("lanelinks") / "four4s.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "1", "--grid.attach-length", "300",
          "-L", "4", "-S", str(CITY_MPS), "-o", str(net)])  # fmt: skip
    return net


def _internal_lanes(fcd: Path) -> dict[str, set[str]]:
    """The internal lanes SUMO drove each vehicle over."""
    out: dict[str, set[str]] = defaultdict(set)
    for _, el in ET.iterparse(fcd):
        if el.tag == "vehicle" and el.get("lane", "").startswith(":"):
            out[el.get("id", "")].add(el.get("lane", ""))
        el.clear()
    return out


def test_random_demand_takes_the_link_the_ica_planned(four_lanes, tmp_path):
    inter = load_intersection(four_lanes, "A0")
    # the case at hand: an incoming lane with two links onto one road out
    by_lane_road: dict[tuple[str, str], list[str]] = defaultdict(list)
    for r in inter.routes:
        by_lane_road[r.in_lane, r.out_lane.rsplit("_", 1)[0]].append(r.id)
    twins = {k: v for k, v in by_lane_road.items() if len(v) > 1}
    assert twins
    fcd = tmp_path / "fcd.xml"
    cfg = RunConfig(
        net_path=str(four_lanes), junction_id="A0", volume_per_10min=900.0,
        duration_s=150.0, sumo_args=("--fcd-output", str(fcd), "--fcd-output.attributes",
                                     "lane"),
    )  # fmt: skip
    res = embedded.run(cfg, inter, run_dir=tmp_path)
    assert res.safety["overlaps"] == 0
    assert res.sumo_collisions == 0
    trips = res.trips.trips
    # demand on both links of a lane that has two onto the same road
    taken = {t.route_id for t in trips.values() if t.exited_s is not None}
    assert any(len(taken & set(ids)) > 1 for ids in twins.values())
    # and every vehicle out drove over exactly its planned route's internal lanes
    routes = {r.id: r for r in inter.routes}
    driven = _internal_lanes(fcd)
    out = [v for v, t in trips.items() if t.exited_s is not None]
    assert len(out) > 100
    for v in out:
        assert driven[v] == set(routes[trips[v].route_id].via_lanes), v
