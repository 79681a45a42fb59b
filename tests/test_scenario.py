"""The built-in layouts, built with the real netconvert and read back with sumolib."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import sumolib

from dica.sim_gateway.scenario import (
    APPROACH_M,
    DISSERTATION_LAYOUTS,
    OWN_LAYOUTS,
    ROAD_SPEED_MPS,
    Scenario,
    ScenarioError,
    build_scenario,
    default_scenario,
    netconvert_binary,
    repo_root,
    run_netconvert,
)

# (from lane, direction, to lane) per approach, as the layouts are specified.
EXPECTED_MOVES = {
    "ch3": {(0, "r", 0), (0, "s", 0), (1, "s", 0), (1, "l", 0)},
    "ch45": {(0, "r", 0), (0, "s", 0), (1, "s", 1), (2, "l", 1)},
}
TARGET = {  # approach -> direction -> the edge a movement leaves on
    "N": {"r": "W_out", "s": "S_out", "l": "E_out"},
    "E": {"r": "N_out", "s": "W_out", "l": "S_out"},
    "S": {"r": "E_out", "s": "N_out", "l": "W_out"},
    "W": {"r": "S_out", "s": "E_out", "l": "N_out"},
}


@pytest.fixture(scope="module")
def nets(ch3_net: Scenario, ch45_net: Scenario) -> dict[str, Scenario]:
    return {"ch3": ch3_net, "ch45": ch45_net}


def _read(scenario: Scenario) -> sumolib.net.Net:
    return sumolib.net.readNet(str(scenario.net_path), withInternal=True)


def test_netconvert_binary_is_executable() -> None:
    path = Path(netconvert_binary())
    assert path.is_file()
    assert os.access(path, os.X_OK)


@pytest.mark.parametrize("layout", DISSERTATION_LAYOUTS)
def test_layout_builds_with_plain_xml_next_to_net(nets: dict[str, Scenario], layout: str) -> None:
    sc = nets[layout]
    assert sc.layout == layout
    assert sc.junction_id == "C"
    assert sc.net_path.name == f"{layout}.net.xml"
    assert sc.net_path.is_file()
    for kind in ("nod", "edg", "con"):
        assert (sc.net_path.parent / f"{layout}.{kind}.xml").is_file()


@pytest.mark.parametrize("layout", DISSERTATION_LAYOUTS)
def test_junction_and_edges(nets: dict[str, Scenario], layout: str) -> None:
    net = _read(nets[layout])
    node = net.getNode("C")
    assert node.getType() == "priority"
    assert node.getCoord()[:2] == pytest.approx((0.0, 0.0))
    n_in, n_out = {"ch3": (2, 1), "ch45": (3, 2)}[layout]
    for a in "NESW":
        e_in, e_out = net.getEdge(f"{a}_in"), net.getEdge(f"{a}_out")
        assert e_in.getToNode().getID() == "C"
        assert e_out.getFromNode().getID() == "C"
        assert e_in.getLaneNumber() == n_in
        assert e_out.getLaneNumber() == n_out
        for lane in (*e_in.getLanes(), *e_out.getLanes()):
            # netconvert writes 2 decimals: 19.44 m/s.
            assert lane.getSpeed() == pytest.approx(ROAD_SPEED_MPS, abs=0.005)
            assert lane.getWidth() == pytest.approx(3.2)
        # Straight along the axes, far node APPROACH_M from the centre.
        shape = np.asarray(e_in.getLanes()[0].getShape())
        assert np.linalg.norm(shape[0]) == pytest.approx(APPROACH_M, abs=8.1)
        axis = np.abs(shape[-1] - shape[0])
        assert min(axis) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("layout", DISSERTATION_LAYOUTS)
def test_only_the_listed_connections_exist(nets: dict[str, Scenario], layout: str) -> None:
    net = _read(nets[layout])
    for a in "NESW":
        seen = set()
        for lane in net.getEdge(f"{a}_in").getLanes():
            for conn in lane.getOutgoing():
                d = conn.getDirection()
                assert conn.getTo().getID() == TARGET[a][d]
                seen.add((lane.getIndex(), d, conn.getToLane().getIndex()))
        assert seen == EXPECTED_MOVES[layout], a


@pytest.mark.parametrize("layout", OWN_LAYOUTS)
def test_own_layouts_build_with_guessed_movements(tmp_path: Path, layout: str) -> None:
    """The skewed and T junctions: netconvert's movements, long 2-lane arms, a light on demand."""
    from dica.ica.netfile import load_intersection

    sc = build_scenario(layout, tmp_path)
    assert not (tmp_path / f"{layout}.con.xml").exists()
    inter = load_intersection(sc.net_path, sc.junction_id)
    arms = {"skewed": 4, "tee": 3}[layout]
    assert len(inter.in_lanes) == 2 * arms
    assert {r.turn.value for r in inter.routes} >= {"left", "through", "right"}
    net = _read(sc)
    for lane in inter.in_lanes:
        assert net.getLane(lane).getLength() > APPROACH_M - 30.0  # room to queue upstream
    lit = build_scenario(layout, tmp_path, tls="static")
    assert _read(lit).getNode("C").getType() == "traffic_light"


def test_approach_length_is_configurable(tmp_path: Path) -> None:
    sc = build_scenario("ch3", tmp_path, approach_length_m=120.0)
    lane = _read(sc).getEdge("W_in").getLanes()[0]
    assert lane.getShape()[0][0] == pytest.approx(-120.0)


def test_unknown_layout(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"unknown layout 'ch9'.*ch3, ch45, skewed, tee"):
        build_scenario("ch9", tmp_path)
    with pytest.raises(ScenarioError, match="unknown layout"):
        default_scenario("nope", cache_dir=tmp_path)
    assert not list(tmp_path.iterdir())


def test_netconvert_failure_reports_stderr(tmp_path: Path) -> None:
    nodes = tmp_path / "bad.nod.xml"
    edges = tmp_path / "bad.edg.xml"
    nodes.write_text('<nodes><node id="a" x="0" y="0"/></nodes>\n')
    edges.write_text('<edges><edge id="e" from="a" to="missing_node"/></edges>\n')
    with pytest.raises(ScenarioError) as info:
        run_netconvert(nodes, edges, tmp_path / "bad.net.xml")
    msg = str(info.value)
    assert "netconvert failed" in msg
    assert "missing_node" in msg
    assert "\n" not in msg


def test_default_scenario_is_idempotent(tmp_path: Path) -> None:
    first = default_scenario("ch3", cache_dir=tmp_path)
    assert first.net_path == tmp_path / "ch3" / "ch3.net.xml"
    mtime = first.net_path.stat().st_mtime_ns
    second = default_scenario("ch3", cache_dir=tmp_path)
    assert second == first
    assert second.net_path.stat().st_mtime_ns == mtime
    # No temp build directories are left behind.
    assert sorted(p.name for p in (tmp_path / "ch3").iterdir()) == [
        "ch3.con.xml",
        "ch3.edg.xml",
        "ch3.net.xml",
        "ch3.nod.xml",
    ]


def test_default_scenario_rebuilds_when_inputs_changed(tmp_path: Path) -> None:
    sc = default_scenario("ch45", cache_dir=tmp_path)
    con = sc.net_path.parent / "ch45.con.xml"
    original = con.read_text()
    con.write_text(original.replace('fromLane="2"', 'fromLane="1"'))
    os.utime(sc.net_path, ns=(0, 0))
    again = default_scenario("ch45", cache_dir=tmp_path)
    assert again.net_path.stat().st_mtime_ns != 0
    assert con.read_text() == original


def test_default_scenario_concurrent_callers(tmp_path: Path) -> None:
    with ThreadPoolExecutor(max_workers=3) as pool:
        results = list(pool.map(lambda _: default_scenario("ch45", cache_dir=tmp_path), range(3)))
    assert len({r.net_path for r in results}) == 1
    net = _read(results[0])
    assert net.getNode("C").getType() == "priority"
    assert not [p for p in (tmp_path / "ch45").iterdir() if p.name.startswith(".")]


def test_default_cache_lives_under_repo_build() -> None:
    assert repo_root() == Path(__file__).resolve().parent.parent
    assert (repo_root() / "sim_gateway" / "scenario.py").is_file()
