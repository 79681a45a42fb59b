"""Real SUMO runs through the `dica run` command: zero collisions, metrics, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
KEYS = {
    "generated",
    "crossed",
    "throughput",
    "mean_trip_time_s",
    "std_trip_time_s",
    "max_trip_time_s",
    "stopped_rate",
    "crawled_rate",
    "effective_mean_trip_time_s",
    "mean_delay_s",
    "mean_system_time_s",
    "mean_system_delay_s",
    "not_in_region_at_end",
    "collisions",
    "min_gap_m",
}


def dica(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return dica_run(
        [*DICA, *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    ("layout", "algorithm", "volume"),
    [
        ("ch45", "enhanced", 500),
        ("ch45", "basic", 300),
        ("ch3", "enhanced", 300),
        ("ch45", "fifo", 300),
        ("ch45", "concurrent", 300),
        ("ch45", "tiles", 300),
        ("ch45", "fixed", 500),
        ("ch3", "actuated", 300),
    ],
)
def test_run_is_collision_free_and_writes_metrics(tmp_path, layout, algorithm, volume):
    out = tmp_path / "run"
    p = dica(
        "run",
        "--layout",
        layout,
        "--algorithm",
        algorithm,
        "--volume",
        str(volume),
        "--duration",
        "150",
        "--seed",
        "21",
        "--out",
        str(out),
        "--quiet",
    )
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m.keys() >= KEYS
    assert m["collisions"] == 0
    assert m["sumo_collisions"] == 0
    assert m["unconfirmed_entries"] == 0
    if algorithm not in ("fixed", "actuated"):  # SUMO's own car following under lights
        assert m["min_gap_m"] > 2 * 0.25 - 1e-6  # never closer than the ICA's two margins
    # in 150 s a light runs one or two cycles of about 90 s (safe clearance is long)
    least = {"fifo": 0.2, "fixed": 0.5, "actuated": 0.5}.get(algorithm, 0.7)
    assert m["crossed"] > least * m["generated"] > 0
    assert m["mean_trip_time_s"] > 0
    assert m["crawled_rate"] >= m["stopped_rate"]  # a stop is below walking pace too
    # platoons: a follower may be told to ask again (too close for the headway, or it
    # must first stop behind its leader); nothing else is ever refused here
    assert set(m["requests"]["rejections"]) <= {"follow"}
    if algorithm == "fixed":
        signal = json.loads((out / "config.json").read_text())["signal"]
        assert signal["type"] == "fixed"
        assert 16.0 < signal["cycle_s"] < 200.0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["run"]["algorithm"] == algorithm
    assert (out / "vehicles.csv").read_text().count("\n") > m["generated"]
    assert (out / "timeseries.csv").exists()


def test_the_whole_delay_counts_the_queue_before_the_region(tmp_path):
    """A light's queue spills back past the 50 m region: the vehicles join it on
    the road upstream, and the time counted from the scheduled arrival sees the
    wait that the dissertation's trip time (from the region's entry) does not."""
    import csv

    out = tmp_path / "run"
    p = dica(*("run", "--algorithm", "fixed", "--volume", "900", "--duration", "150"),
             *("--seed", "12", "--out", str(out), "--quiet"))  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    with (out / "vehicles.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    entered = [r for r in rows if r["entered_s"]]
    waited = [r for r in entered if float(r["entered_s"]) > float(r["depart_s"]) + 5.0]
    assert len(waited) > 5  # joined the queue before the region and waited there
    crossed = [r for r in entered if r["exited_s"]]
    for r in crossed:
        assert float(r["entered_s"]) >= float(r["depart_s"]) - 0.1  # never entered early
        assert float(r["system_time_s"]) >= float(r["trip_time_s"]) - 0.1
    assert m["mean_system_delay_s"] > m["mean_delay_s"]
    assert m["not_in_region_at_end"] > 10  # still queued upstream at the end


def test_until_left_runs_until_every_vehicle_has_left(tmp_path):
    out = tmp_path / "run"
    p = dica(
        "run",
        "--until-left",
        "60",
        "--volume",
        "500",
        "--out",
        str(out),
        "--quiet",
        "--sumo-args",
        f"--tripinfo-output {tmp_path / 'trips.xml'}",
    )
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["generated"] == 60
    assert m["crossed"] == 60
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert (tmp_path / "trips.xml").exists()  # SUMO options pass through verbatim


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--net", "/no/such.net.xml", "--junction", "C"], "not found"),
        (["--junction", "ZZ", "--net", "{net}"], "not in"),
        (["--volume", "0"], "--volume must be between 1 and 2000"),
        (["--volume", "99999"], "--volume must be between 1 and 2000"),
        (["--algorithm", "magic"], "unknown algorithm"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, ch45_net, args, needle):
    args = [a.replace("{net}", str(ch45_net.net_path)) for a in args]
    p = dica("run", "--duration", "5", "--out", str(tmp_path / "o"), "--quiet", *args)
    assert p.returncode == 2
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dica") and needle in err[0], p.stderr
    assert "Traceback" not in p.stderr


def test_experiment_grid_resumes_and_report_draws(tmp_path):
    grid = tmp_path / "grid"
    args = [
        "experiment",
        "--algorithms",
        "enhanced,fixed",
        "--volumes",
        "300,900",
        "--ramps",
        "100-600",
        "--seeds",
        "12",
        "--duration",
        "40",
        "--jobs",
        "2",
        "--out",
        str(grid),
        "--quiet",
    ]
    p = dica(*args)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "6 to run" in p.stdout
    assert (grid / "ch45" / "fixed" / "r100-600" / "s12" / "metrics.json").is_file()
    again = dica(*args)
    assert "6 already done, 0 to run" in again.stdout
    # the same cells with another duration would mix two grids' runs: refused
    other = dica(*[("50" if a == "40" else a) for a in args])
    assert other.returncode == 2 and "was run with other settings" in other.stderr
    r = dica("report", str(grid))
    assert r.returncode == 0, r.stderr
    md = (grid / "report" / "report.md").read_text()
    assert "| enhanced | 300 |" in md and "| fixed | 300 |" in md
    assert "## Saturation" in md and "| ch45 | enhanced |" in md
    assert "## ch45 (to 600)" in md
    pngs = list((grid / "report").glob("*.png"))
    assert len(pngs) == 4 and all(p.stat().st_size > 10_000 for p in pngs)
    bad = dica("report", str(tmp_path / "nothing"))
    assert bad.returncode == 2 and "no such directory" in bad.stderr


def test_rising_volume_keeps_arriving_until_the_end(tmp_path):
    out = tmp_path / "rise"
    p = dica(
        "run",
        "--volume",
        "100",
        "--volume-end",
        "500",
        "--duration",
        "240",
        "--ramp",
        "240",
        "--out",
        str(out),
        "--quiet",
    )
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "metrics.json").read_text())
    # expected arrivals: the mean of 100 and 500 per 10 min over 4 minutes = 120
    assert 85 < m["generated"] < 160
    with (out / "vehicles.csv").open() as fh:
        departs = sorted(float(line.split(",")[3]) for line in list(fh)[1:])
    assert departs[-1] > 225  # still arriving at the end
    first, last = sum(d < 120 for d in departs), sum(d >= 120 for d in departs)
    assert last > 1.5 * first  # and faster in the second half


def test_run_records_every_confirmation_and_footprint(tmp_path):
    import csv
    import itertools

    from rerun.chunk import RrdReader

    from dica.sim_gateway.recording import TOP_EVERY

    out = tmp_path / "run"
    p = dica(*("run", "--volume", "500", "--duration", "40", "--seed", "21"),
             *("--out", str(out), "--quiet", "--record"))  # fmt: skip
    assert p.returncode == 0, p.stderr
    with (out / "vehicles.csv").open() as fh:
        confirmed = {r["vin"] for r in csv.DictReader(fh) if r["confirmed_s"]}
    drawn, steps = set(), set()
    for chunk in RrdReader(out / "spacetime.rrd").stream():
        path = str(chunk.entity_path)
        batch = chunk.to_record_batch()
        if path == "/tables/confirmed" and "TextLog:text" in batch.schema.names:
            drawn.update(row[0].split()[0] for row in batch.column("TextLog:text").to_pylist())
        if path == "/junction/vehicles" and "sim_time" in batch.schema.names:
            steps.update(batch.column("sim_time").cast("int64").to_pylist())
    assert drawn == confirmed and len(confirmed) > 10
    # the top view on every TOP_EVERY-th step from the first confirmation to the end
    gaps = {round((b - a) / 1e9, 6) for a, b in itertools.pairwise(sorted(steps))}
    assert gaps == {0.05 * TOP_EVERY} and max(steps) / 1e9 > 40 - 0.05 * TOP_EVERY


UNCHECKED = """
from dica.sim_gateway.demand import schedule_for
from dica.sim_gateway.runconfig import RunConfig
from dica.sim_gateway.scenario import default_scenario
from dica.sim_gateway.sumo_io import import_libsumo, start_sumo
from dica.sim_gateway.world import World
from dica.ica.netfile import load_intersection

sc = default_scenario("ch45")
inter = load_intersection(sc.net_path, sc.junction_id)
cfg = RunConfig(str(sc.net_path), sc.junction_id, volume_per_10min=300, duration_s=60)
ica_cfg = cfg.controller_spec().config
schedule, _, horizon = schedule_for(cfg, inter, ica_cfg.step_s)
ls = import_libsumo()
start_sumo(ls, cfg, ica_cfg.step_s)
world = World(ls, cfg, inter, ica_cfg, schedule, horizon)
while True:
    world.step()  # nobody commands: vehicles drive in unconfirmed
    world.end_step()
    if world.done():
        break
print(len(world.unconfirmed_entries))
"""


def test_unconfirmed_entries_are_counted(tmp_path):
    """The check the runs assert zero on does see vehicles that enter unconfirmed."""
    p = subprocess.run(
        [sys.executable, "-c", UNCHECKED], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert p.returncode == 0, p.stderr
    assert int(p.stdout.split()[-1]) > 10


def test_experiment_writes_a_relative_out_where_the_user_stands(tmp_path):
    """Run from the user's own directory with ``--out grid``: the cells land in that
    directory's ``grid``, not in the project's."""
    p = dica_run(
        [*DICA, "experiment", "--algorithms", "enhanced",
         "--volumes", "300", "--seeds", "12", "--duration", "20", "--out", "grid", "--quiet"],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert (tmp_path / "grid" / "ch45" / "enhanced" / "v300" / "s12" / "metrics.json").is_file()


def test_an_experiment_on_a_users_net_is_named_after_it(tmp_path):
    """With ``--extra "--net NET --junction J"`` the cells are the user's net's, named
    after it and its junction (they were filed under the built-in layout's name, whose
    option every run was also given)."""
    from tests.user_nets import make, tool

    net = tmp_path / "mine.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "2", "--grid.length", "200",
          "--grid.attach-length", "150", "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    p = dica_run(
        [*DICA, "experiment", "--algorithms", "enhanced", "--volumes", "200", "--seeds", "1",
         "--duration", "20", "--out", str(tmp_path / "grid"), "--quiet",
         "--extra", f"--net {net} --junction A0"],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    cell = tmp_path / "grid" / "mine-A0" / "enhanced" / "v200" / "s1"
    run = json.loads((cell / "config.json").read_text())["run"]
    assert run["junction_id"] == "A0" and Path(run["net_path"]).name == "mine.net.xml"
    assert not (tmp_path / "grid" / "ch45").exists()
