"""Reading junctions of real netconvert networks into routes."""

from __future__ import annotations

import itertools
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import shapely
import sumolib

from dica.ica.core.intersection import Intersection
from dica.ica.core.limits import KMH, SpeedCaps, Turn
from dica.ica.core.route import _dedup, classify_turn
from dica.ica.netfile import NetworkError, load_intersection
from dica.sim_gateway.scenario import Scenario, build_scenario

VEHICLE_M = 12.0  # load_intersection's default max_vehicle_length_m
COMM_M = 50.0
ALL = ("ch3", "ch45", "tee", "skewed")


@pytest.fixture(scope="module")
def loaded(
    request: pytest.FixtureRequest,
) -> dict[str, tuple[Intersection, sumolib.net.Net]]:
    """Each intersection with its sumolib net, to compare routes with the raw lanes."""
    out = {}
    for name in ALL:
        inter = request.getfixturevalue(name)
        net_fx = request.getfixturevalue(f"{name}_net")
        path = net_fx.net_path if isinstance(net_fx, Scenario) else net_fx
        out[name] = (inter, sumolib.net.readNet(str(path), withInternal=True))
    return out


def _shape(net: sumolib.net.Net, lane_id: str) -> np.ndarray:
    return np.asarray(net.getLane(lane_id).getShape(), dtype=float)


def _polylen(xy: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())


def _turns_by_edge(inter: Intersection) -> dict[str, Counter]:
    out: dict[str, Counter] = {}
    for r in inter.routes:
        out.setdefault(r.in_lane.rsplit("_", 1)[0], Counter())[r.turn] += 1
    return out


# --- route sets -------------------------------------------------------------


def test_ch3_routes(ch3: Intersection) -> None:
    assert ch3.junction_id == "C"
    assert len(ch3.routes) == 16
    for a in "NESW":
        assert {r.turn for r in ch3.routes_from(f"{a}_in_0")} == {Turn.RIGHT, Turn.THROUGH}
        assert {r.turn for r in ch3.routes_from(f"{a}_in_1")} == {Turn.THROUGH, Turn.LEFT}
        assert {r.out_lane for r in ch3.routes if r.in_lane.startswith(f"{a}_in")} <= {
            f"{b}_out_0" for b in "NESW"
        }
    assert len(ch3.in_lanes) == 8
    assert len(ch3.out_lanes) == 4


def test_ch45_routes(ch45: Intersection) -> None:
    assert len(ch45.routes) == 16
    for counts in _turns_by_edge(ch45).values():
        assert counts == Counter({Turn.LEFT: 1, Turn.THROUGH: 2, Turn.RIGHT: 1})
    for a in "NESW":
        lane0 = {(r.turn, r.out_lane[-1]) for r in ch45.routes_from(f"{a}_in_0")}
        lane1 = {(r.turn, r.out_lane[-1]) for r in ch45.routes_from(f"{a}_in_1")}
        lane2 = {(r.turn, r.out_lane[-1]) for r in ch45.routes_from(f"{a}_in_2")}
        assert lane0 == {(Turn.RIGHT, "0"), (Turn.THROUGH, "0")}
        assert lane1 == {(Turn.THROUGH, "1")}
        assert lane2 == {(Turn.LEFT, "1")}
    assert len(ch45.in_lanes) == 12
    assert len(ch45.out_lanes) == 8


def test_route_ids_and_lookup(ch45: Intersection) -> None:
    r = ch45.route("N_in_2", "E_out_1")
    assert r is not None
    assert r.id == "N_in_2>E_out_1"
    assert ch45.route_by_id(r.id) is r
    assert ch45.route("N_in_2", "S_out_1") is None


def test_tee_and_skewed_routes(tee: Intersection, skewed: Intersection) -> None:
    assert len(tee.routes) == 8
    assert len(skewed.routes) == 16
    for inter in (tee, skewed):
        turns = Counter(r.turn for r in inter.routes)
        assert turns[Turn.LEFT] >= 1
        assert turns[Turn.RIGHT] >= 1
        assert inter.junction_id == "J"
    # The T has no approach from the north.
    assert not any(r.in_lane.startswith("N_") or r.out_lane.startswith("N_") for r in tee.routes)


def test_skewed_roads_cross_at_60_degrees(skewed: Intersection) -> None:
    a = skewed.route("A_in_0", "B_out_0")
    w = skewed.route("W_in_0", "E_out_0")
    assert a is not None and w is not None
    ha = a.points(-20.0) - a.points(-60.0)
    hw = w.points(-20.0) - w.points(-60.0)
    angle = math.degrees(math.acos(abs(ha @ hw) / np.linalg.norm(ha) / np.linalg.norm(hw)))
    assert angle == pytest.approx(60.0, abs=1.0)


@pytest.mark.parametrize("name", ALL)
def test_turn_class_matches_geometry(loaded: dict, name: str) -> None:
    inter, _ = loaded[name]
    for r in inter.routes:
        xy = r.points(np.array([-2.0, -1.0, r.cross_length_m + 1.0, r.cross_length_m + 2.0]))
        assert classify_turn(xy) == r.turn, r.id


# --- geometry ---------------------------------------------------------------


@pytest.mark.parametrize("name", ALL)
def test_routes_are_continuous_polylines(loaded: dict, name: str) -> None:
    inter, net = loaded[name]
    for r in inter.routes:
        in_shape, out_shape = _shape(net, r.in_lane), _shape(net, r.out_lane)
        assert np.all(np.diff(r.s) > 0), r.id
        # arc length as drawn outside the junction; inside, as SUMO drives its lanes
        step, drawn = np.diff(r.s), np.linalg.norm(np.diff(r.xy, axis=0), axis=1)
        outside = (r.s[1:] <= 1e-9) | (r.s[:-1] >= r.cross_length_m - 1e-9)
        np.testing.assert_allclose(step[outside], drawn[outside])
        sumo = sum(net.getLane(v).getLength() for v in r.via_lanes)
        np.testing.assert_allclose(r.points(0.0), in_shape[-1], atol=1e-6)
        np.testing.assert_allclose(r.points(r.cross_length_m), out_shape[0], atol=1e-6)
        assert r.s_min <= -(COMM_M + VEHICLE_M)
        assert r.s_max >= r.cross_length_m + VEHICLE_M
        # Consecutive lanes join: each piece starts where the previous one ends.
        pieces = [in_shape, *(_shape(net, v) for v in r.via_lanes), out_shape]
        for prev, nxt in itertools.pairwise(pieces):
            assert np.linalg.norm(prev[-1] - nxt[0]) < 0.3, r.id
        # Inside the junction the polyline is exactly the internal lanes, each as long as
        # SUMO drives it.
        inner = np.vstack([in_shape[-1:], *(_shape(net, v) for v in r.via_lanes), out_shape[:1]])
        inside = (r.s >= -1e-9) & (r.s <= r.cross_length_m + 1e-9)
        np.testing.assert_allclose(r.xy[inside], _dedup(inner), atol=1e-9)
        gaps = _polylen(inner) - sum(_polylen(_shape(net, v)) for v in r.via_lanes)
        assert r.cross_length_m == pytest.approx(sumo + gaps, abs=1e-6)


@pytest.mark.parametrize("name", ALL)
def test_polyline_passes_through_every_via_lane(loaded: dict, name: str) -> None:
    inter, net = loaded[name]
    for r in inter.routes:
        assert r.via_lanes, r.id
        s_prev = 0.0
        for v in r.via_lanes:
            s, dist = r.project(_shape(net, v))
            assert np.all(dist < 1e-6), (r.id, v)
            assert np.all(np.diff(s) > 0) and s[0] >= s_prev - 1e-9, (r.id, v)
            s_prev = float(s[-1])
        assert s_prev == pytest.approx(r.cross_length_m, abs=1e-6)


def test_two_lane_via_chains_are_followed(ch45: Intersection, loaded: dict) -> None:
    """On priority junctions SUMO splits yielding left turns at an internal junction."""
    _, net = loaded["ch45"]
    chained = [r for r in ch45.routes if len(r.via_lanes) == 2]
    assert chained, "expected two-part left turns on the priority junction"
    for r in chained:
        assert r.turn == Turn.LEFT
        lengths = [net.getLane(v).getLength() for v in r.via_lanes]
        assert r.cross_length_m == pytest.approx(sum(lengths), abs=0.02)
    # Routes with one via lane: SUMO's lane length (2 decimals) is the shape length.
    for r in ch45.routes:
        if len(r.via_lanes) == 1:
            assert r.cross_length_m == pytest.approx(
                net.getLane(r.via_lanes[0]).getLength(), abs=0.006
            )


def test_cross_lengths_are_plausible(ch3: Intersection, ch45: Intersection) -> None:
    for inter, width_m in ((ch3, 2 * 3 * 3.2), (ch45, 2 * 5 * 3.2)):
        by_turn = {t: [r.cross_length_m for r in inter.routes if r.turn == t] for t in Turn}
        assert max(by_turn[Turn.RIGHT]) < min(by_turn[Turn.LEFT])
        assert max(by_turn[Turn.RIGHT]) < min(by_turn[Turn.THROUGH])
        # Throughs cross the junction (a bit more when they shift lane), no more.
        assert min(by_turn[Turn.THROUGH]) > 0.8 * width_m
        assert max(by_turn[Turn.THROUGH]) < 1.2 * width_m
        # Symmetric layout: the same movement is equally long from every approach.
        for lengths in by_turn.values():
            assert max(lengths) - min(lengths) < 0.5
    # SUMO's geometry: a left turn is a quarter circle around the junction's
    # inner corner, shorter than crossing the whole 4-lane-plus junction.
    left = [r.cross_length_m for r in ch45.routes if r.turn == Turn.LEFT]
    through = [r.cross_length_m for r in ch45.routes if r.turn == Turn.THROUGH]
    assert max(left) < min(through)


@pytest.mark.parametrize("name", ALL)
def test_speed_caps_per_turn(loaded: dict, name: str) -> None:
    inter, _ = loaded[name]
    expected = {Turn.RIGHT: 25.0 * KMH, Turn.LEFT: 35.0 * KMH, Turn.THROUGH: 65.0 * KMH}
    for r in inter.routes:
        assert r.speed_cap_mps == pytest.approx(expected[r.turn])


def test_custom_caps_and_comm_length(ch45_net: Scenario) -> None:
    caps = SpeedCaps(road_mps=50.0 * KMH, left_mps=20.0 * KMH)
    inter = load_intersection(ch45_net.net_path, "C", comm_length_m=80.0, caps=caps)
    assert inter.comm_length_m == 80.0
    for r in inter.routes:
        assert r.speed_cap_mps == pytest.approx(caps.for_turn(r.turn))
        assert r.s_min <= -(80.0 + VEHICLE_M)


def test_short_approaches_are_extended(tmp_path: Path) -> None:
    """Lanes shorter than the communication region are extended straight upstream."""
    sc = build_scenario("ch3", tmp_path, approach_length_m=40.0)
    inter = load_intersection(sc.net_path, sc.junction_id)
    for r in inter.routes:
        assert r.s_min <= -(COMM_M + VEHICLE_M)
        assert r.s_max >= r.cross_length_m + VEHICLE_M
        assert np.all(np.diff(r.s) > 0)


@pytest.mark.parametrize("name", ALL)
def test_region_is_the_junction_polygon(loaded: dict, name: str) -> None:
    inter, net = loaded[name]
    assert inter.region.ndim == 2 and inter.region.shape[1] == 2
    np.testing.assert_allclose(inter.region, np.asarray(net.getNode(inter.junction_id).getShape()))
    poly = shapely.Polygon(inter.region)
    assert poly.is_valid
    assert poly.contains(shapely.Point(0.0, 0.0))
    for r in inter.routes:
        # Entry and exit lines lie on the junction border; the crossing stays inside.
        for s in (0.0, r.cross_length_m):
            assert poly.exterior.distance(shapely.Point(r.points(s))) < 0.01, r.id
        inside = shapely.LineString(r.points(np.linspace(0.0, r.cross_length_m, 40)))
        assert poly.buffer(0.01).contains(inside), r.id


# --- errors -----------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(NetworkError, match=r"network file not found: .*nothing\.net\.xml"):
        load_intersection(tmp_path / "nothing.net.xml", "C")


def test_unreadable_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<net><edge id='x'")
    with pytest.raises(NetworkError, match="cannot read SUMO network") as info:
        load_intersection(bad, "C")
    assert "\n" not in str(info.value)


def test_unknown_junction_lists_known_ids(ch45_net: Scenario) -> None:
    with pytest.raises(NetworkError, match=r"junction 'X' not in .*known junctions: C, E, N, S, W"):
        load_intersection(ch45_net.net_path, "X")


def test_junction_without_crossing_routes(ch45_net: Scenario) -> None:
    # A far end of an approach: a dead end with no connections (no turnarounds).
    with pytest.raises(NetworkError, match=r"junction 'N' .* has no crossing routes"):
        load_intersection(ch45_net.net_path, "N")
