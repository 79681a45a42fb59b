"""Session-wide networks: each is built with the real netconvert once per test run."""

from __future__ import annotations

from pathlib import Path

import pytest

from dica.ica.core.intersection import Intersection
from dica.ica.netfile import load_intersection
from dica.sim_gateway.scenario import Scenario, build_scenario
from tests.netfixtures import FIXTURE_JUNCTION_ID, build_fixture_net


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
