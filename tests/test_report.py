"""The report's saturation volume: the highest volume up to which throughput and delay hold."""

from __future__ import annotations

import json

from dica.tools.report import GROWTH, SATURATION_RHO, SLACK_S, bounded, saturation


def row(rho: float, middle: float, last: float, settled: float | None = None) -> dict:
    return {
        "throughput": rho,
        "settled_throughput": rho if settled is None else settled,
        "delay_by_third_s": [1.0, middle, last],
        "stopped_rate": 0.1,
        "mean_trip_time_s": 6.0,
        "effective_mean_trip_time_s": 6.0 / rho,
        "mean_system_time_s": 7.0,
        "mean_system_delay_s": 2.0,
    }


def test_bounded_delay_is_the_last_third_against_the_middle_one():
    assert bounded(row(0.99, 10.0, GROWTH * 10.0 + SLACK_S))
    assert not bounded(row(0.99, 10.0, GROWTH * 10.0 + SLACK_S + 0.01))
    assert not bounded(row(0.99, 10.0, None))


def test_saturation_is_the_last_volume_before_the_first_failure():
    ok, slow, jammed = row(0.99, 2.0, 2.5), row(SATURATION_RHO - 0.01, 2.0, 2.5), row(0.97, 5, 40)
    agg = {
        ("L", "", "dica", 300.0): ok,
        ("L", "", "dica", 600.0): ok,
        ("L", "", "dica", 800.0): jammed,  # the delay grows: saturated
        ("L", "", "dica", 1000.0): ok,  # a lucky run above it does not count
        ("L", "", "light", 300.0): slow,
        ("L", "", "light", 600.0): ok,
        ("L", "", "other", 300.0): ok,
        ("L", "", "other", 600.0): ok,
        ("L", "to 900", "other", 100.0): jammed,  # a ramp is not a steady volume
    }
    sat = saturation(agg)
    assert sat[("L", "dica")]["volume"] == 600.0 and not sat[("L", "dica")]["above"]
    assert sat[("L", "light")]["volume"] is None
    assert sat[("L", "other")]["volume"] == 600.0 and sat[("L", "other")]["above"]
    assert sat[("L", "other")]["volumes"] == [300.0, 600.0]


def test_settled_throughput_forgives_the_vehicles_still_waiting_at_the_end():
    """A light with a long cycle: rho under 0.95 from end effects, queues not growing."""
    agg = {("L", "", "light", v): row(0.92, 20.0, 22.0, settled=0.99) for v in (300.0, 500.0)}
    assert saturation(agg)[("L", "light")]["volume"] is None
    assert saturation(agg, "settled_throughput")[("L", "light")]["volume"] == 500.0


def test_the_ev_table_names_the_worst_seed_of_the_normal_vehicles_longest_trips():
    from dica.tools.report import _ev_row, _ev_table

    def run(seed: int, normal_max: float, added: float | None = None) -> dict:
        m = {
            "ev": {"crossed": 1, "mean_trip_time_s": 6.0},
            "normal": {"max_trip_time_s": normal_max},
        }
        if added is not None:
            m["reactive"] = {
                "events": 1, "solve_s_total": 0.001, "refused": 0,
                "added_delay_max_s": added, "replanned_later_max_s": added + 0.5,
            }  # fmt: skip
        return {"seed": seed, "metrics": m}

    plain = _ev_row([run(1, 20.0), run(2, 10.0)])
    mine = _ev_row([run(1, 21.0, 2.0), run(2, 13.0, 3.0)])  # seed 2 is 1.30x, the mean 1.13x
    table = "\n".join(
        _ev_table(
            [
                (("L", "", "enhanced", 500.0), {"ev": plain}),
                (("L", "", "rdica-exact", 500.0), {"ev": mine}),
            ]
        )
    )
    assert "| rdica-exact | 500 | - | - | 1.13 | 1.30 (seed 2) |" in table
    assert mine["added_max"] == 3.0 and mine["replanned_later"] == 3.5


def test_runs_apart_in_what_they_ran_are_not_averaged_as_seeds(tmp_path):
    """Two route files, two junctions or two shares of connected vehicles on one net are
    different experiments, not seeds of one: each gets its own row."""
    import json

    from dica.tools.report import aggregate, load_runs

    base = {"net_path": "nets/g3.net.xml", "algorithm": "enhanced", "volume_per_10min": 300.0,
            "seed": 12, "junction_id": "B1", "duration_s": 60.0, "until_left": True}  # fmt: skip
    runs = {
        "a": {},
        "b": {"routes_path": "/x/trucks.rou.xml"},
        "c": {"junction_id": "A2"},
        "d": {"cav_share": 0.3},
        "e": {"seed": 21},  # a seed of a's
    }
    metrics = {"generated": 10, "collisions": 0, "min_gap_m": 1.0}
    for name, extra in runs.items():
        d = tmp_path / name
        d.mkdir()
        (d / "config.json").write_text(json.dumps({"run": {**base, **extra}}))
        (d / "metrics.json").write_text(json.dumps(metrics))
    agg = aggregate(load_runs(tmp_path))
    assert len(agg) == 4
    assert sorted(row["seeds"] for row in agg.values()) == [[12], [12], [12], [12, 21]]
    shapes = sorted(key[1] for key in agg)
    assert shapes == ["junction A2", "junction B1", "junction B1; connected 0.3",
                      "junction B1; routes trucks.rou.xml"]  # fmt: skip


def test_a_run_says_when_reorderings_went_over_their_bound(capsys, tmp_path):
    """The bound on what reorderings add is kept on the plans the solvers foresee; near
    saturation the real re-plans came 133 s later with nothing said. The run says so."""
    from types import SimpleNamespace

    from dica.tools.args import report_run

    def result(added: float):
        return SimpleNamespace(
            metrics={"generated": 10, "crossed": 9, "throughput": 0.9, "mean_trip_time_s": 5.0,
                     "effective_mean_trip_time_s": 5.0, "stopped_rate": 0.1},
            extra={"reactive": {"max_added_delay_s": 2.0, "added_delay_max_s": added}},
            safety={"overlaps": 0, "min_gap_m": 1.0}, sumo_collisions=0, simulated_s=60.0,
            wall_s=1.0,
        )  # fmt: skip

    assert report_run(tmp_path, result(1.9)) == 0
    assert "over the" not in capsys.readouterr().out
    assert report_run(tmp_path, result(133.2)) == 0
    assert "reorderings added up to 133.2 s to a vehicle, over the 2 s bound" in (
        capsys.readouterr().out
    )
    # a cluster's: each ICA process's figures, one junction's or several
    cl = result(0.0)
    cl.extra = {"roles": {"ica": {"reactive": {"max_added_delay_s": 2.0,
                                               "added_delay_max_s": 9.7}}}}  # fmt: skip
    report_run(tmp_path, cl)
    assert "added up to 9.7 s" in capsys.readouterr().out
    cl.extra = {"roles": {"J1": {"ica": {"reactive": {"max_added_delay_s": 2.0,
                                                      "added_delay_max_s": 4.5}}}}}  # fmt: skip
    report_run(tmp_path, cl)
    assert "added up to 4.5 s" in capsys.readouterr().out


def test_a_run_cut_short_is_left_out_of_the_report_with_a_note(tmp_path, capsys):
    """A metrics.json that is not JSON (a run killed while writing, an edit) is named and
    left out; the report does not end in a traceback."""
    from dica.tools.cli import main as dica

    bad = tmp_path / "runs" / "a"
    bad.mkdir(parents=True)
    (bad / "metrics.json").write_text('{"generated": 1\n"crossed": 1}')
    (bad / "config.json").write_text('{"run": {}}')
    code = dica(["report", str(tmp_path / "runs"), "--out", str(tmp_path / "rep")])
    err = capsys.readouterr().err
    assert "runs/a: not a run dica report can read" in err, err
    assert "Traceback" not in err and code == 2


def test_metrics_are_strict_json(tmp_path):
    """No NaN or Infinity in metrics.json (JSON has neither; other readers refuse the
    file): the cluster's link figures, NaN where no message came, are written null."""
    import math

    from dica.sim_gateway.outputs import _strict
    from dica.tools.cli import main as dica

    got = _strict({"a": math.nan, "b": [1.0, math.inf, {"c": -math.inf}], "d": (2, "x")})
    assert got == {"a": None, "b": [1.0, None, {"c": None}], "d": [2, "x"]}
    out = tmp_path / "run"
    assert dica(["run", "--duration", "3", "--out", str(out), "--quiet"]) == 0

    def refuse(name: str) -> None:
        raise ValueError(f"{name} in metrics.json")

    m = json.loads((out / "metrics.json").read_text(), parse_constant=refuse)
    assert m["simulated_s"] == 3.0
