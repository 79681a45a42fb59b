"""Session-wide networks (each built with the real netconvert once per test run), and
the tiers every test belongs to.

Tiers, chosen with ``-m`` (the README lists the invocations):

* ``core``: the decision core, the wire, the command line and their inputs (nets
  built with netconvert); no simulation runs, no Zenoh.
* ``sumo``: simulations in SUMO (embedded runs, the lights, recordings).
* ``cluster``: processes and sessions over a real Zenoh on loopback.
* ``timing``: the real-time cluster under link faults and killed processes.

A test file has a tier (:data:`TIERS`); a test in it that runs more than its file's
tier says so with its own marker.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from dica.ica.core.intersection import Intersection
from dica.ica.netfile import load_intersection
from dica.sim_gateway.scenario import Scenario, build_scenario
from tests.netfixtures import FIXTURE_JUNCTION_ID, build_fixture_net

TIERS = ("core", "sumo", "cluster", "timing")
FILE_TIER = {
    "test_rdica_sumo.py": "sumo",
    "test_recording.py": "sumo",
    "test_run_sumo.py": "sumo",
    "test_actuator.py": "sumo",
    "test_light_control.py": "sumo",
    "test_sumo_io.py": "sumo",
    "test_traffic.py": "sumo",
    "test_user_nets.py": "sumo",
    "test_network.py": "sumo",
    "test_gridlock.py": "sumo",
    "test_network_runs.py": "sumo",
    "test_signals.py": "sumo",
    "test_walkers.py": "sumo",
    "test_network_ev.py": "sumo",
    "test_attack.py": "cluster",
    "test_cluster.py": "cluster",
    "test_handlers.py": "cluster",
    "test_secure.py": "cluster",
    "test_network_cluster.py": "cluster",
    "test_network_secure.py": "cluster",
    "test_network_observer.py": "cluster",
    "test_timing.py": "timing",
}  # every other test file: core


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Give each test its file's tier unless it has a tier of its own."""
    for item in items:
        if not any(item.get_closest_marker(t) for t in TIERS):
            item.add_marker(getattr(pytest.mark, FILE_TIER.get(item.path.name, "core")))


@pytest.fixture(scope="session")
def ch3_net(tmp_path_factory: pytest.TempPathFactory) -> Scenario:
    return build_scenario("ch3", tmp_path_factory.mktemp("ch3"))


@pytest.fixture(scope="session")
def ch45_net(tmp_path_factory: pytest.TempPathFactory) -> Scenario:
    return build_scenario("ch45", tmp_path_factory.mktemp("ch45"))


@pytest.fixture(scope="session")
def tee_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_fixture_net("tee", tmp_path_factory.mktemp("tee"))


@pytest.fixture(scope="session")
def skewed_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_fixture_net("skewed", tmp_path_factory.mktemp("skewed"))


@pytest.fixture(scope="session")
def ch3(ch3_net: Scenario) -> Intersection:
    return load_intersection(ch3_net.net_path, ch3_net.junction_id)


@pytest.fixture(scope="session")
def ch45(ch45_net: Scenario) -> Intersection:
    return load_intersection(ch45_net.net_path, ch45_net.junction_id)


@pytest.fixture(scope="session")
def tee(tee_net: Path) -> Intersection:
    return load_intersection(tee_net, FIXTURE_JUNCTION_ID)


@pytest.fixture(scope="session")
def skewed(skewed_net: Path) -> Intersection:
    return load_intersection(skewed_net, FIXTURE_JUNCTION_ID)
