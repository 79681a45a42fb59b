"""A network's trips from SUMO's own records count every vehicle generated: one still in
the net when the run ends (SUMO 1.28 marks its record ``vaporized="end"``) is
generated and not finished, in metrics.json, trips.csv and the summary line alike."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from tests.dica_cli import dica_run
from tests.user_nets import make, tool


@pytest.fixture(scope="module")
def grid2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two by two junctions, 200 m apart, roads of 100 m in from outside."""
    net = tmp_path_factory.mktemp("trips") / "g2.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "2", "--grid.length", "200",
          "--grid.attach-length", "100", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    return net


def test_vehicles_still_in_the_net_at_the_end_count_as_generated_and_unfinished(grid2, tmp_path):
    # no drain: the run ends with the demand, so most of it is still on the road
    out = tmp_path / "run"
    p = dica_run(["network", "--net", grid2, "--duration", "30", "--drain", "0",
                  "--quiet", "--out", out])  # fmt: skip
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "metrics.json").read_text())
    net = m["network"]
    drawn = m["network_run"]["drawn_vehicles"]
    assert net["vehicles"] == drawn > 10
    assert 0 < net["finished"] < drawn
    assert net["in_net_at_end"] > 0
    assert net["unfinished"] == drawn - net["finished"]
    assert net["in_net_at_end"] + net["waiting_to_enter_at_end"] == net["unfinished"]
    assert net["finished_rate"] == pytest.approx(net["finished"] / drawn)
    with (out / "trips.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == drawn - net["waiting_to_enter_at_end"]
    unfinished = [r for r in rows if math.isnan(float(r["arrival_s"]))]
    assert len(unfinished) == net["in_net_at_end"]
    # the summary line says how many did not finish, and where they were
    line = p.stdout.splitlines()[0]
    assert f"{drawn} vehicles, {net['finished']} finished (" in line, line
    assert f"{net['in_net_at_end']} still in the net" in line, line
