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


def _grid(d: Path, length: int, lanes: int = 1) -> Path:
    net = d / f"g{length}x{lanes}.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", str(length),
          "--grid.attach-length", "100", "-L", str(lanes), "--no-turnarounds", "true",
          "-o", str(net)])  # fmt: skip
    return net


@pytest.mark.parametrize("gate", [[], ["--no-network-gate"]])
def test_a_grid_whose_links_cannot_hold_a_car_beyond_the_junction_is_refused(tmp_path, gate):
    """50 m blocks leave 36 m links: the room rule lets a vehicle onto one only crossing a
    little slower than 50 km/h (its cap lowered to fit), and a link on a cycle must also
    keep room for a car standing at its end, which 36 m cannot; 60 m blocks leave 46 m,
    still short of that (48 m). Refused in one line before the run, with the gate or
    without, naming a link and its need."""
    net = _grid(tmp_path, 50)
    p = dica_run(["network", "--net", net, "--duration", "20", "--quiet",
                  "--out", tmp_path / "run", *gate])  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "is 36 m long, and a link on a cycle of links needs" in p.stderr
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "run" / "metrics.json").exists()
    # 60 m blocks: 46 m links take a vehicle, but not on a cycle with one standing at the end
    p = dica_run(["network", "--net", _grid(tmp_path, 60), "--duration", "20", "--quiet",
                  "--out", tmp_path / "run", *gate])  # fmt: skip
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "the link" in p.stderr and "46 m long" in p.stderr and "needs 48 m" in p.stderr
    assert "--junctions" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "run" / "metrics.json").exists()


def test_a_grid_whose_links_hold_cars_beyond_the_junctions_runs(tmp_path):
    net = _grid(tmp_path, 80)  # 66 m links: about three cars each beyond the room rule's
    p = dica_run(["network", "--net", net, "--duration", "20", "--quiet",
                  "--out", tmp_path / "run"])  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "too short" not in p.stderr


def test_a_junction_the_net_lacks_is_named(grid2, tmp_path):
    p = dica_run(["network", "--net", grid2, "--junctions", "NOPE", "--quiet",
                  "--out", tmp_path / "run"])  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert "junction 'NOPE' not in" in p.stderr and "Traceback" not in p.stderr
