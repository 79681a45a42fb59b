"""Reactive DICA and the reactive light in real SUMO: an EV behind a queue crosses before
cars confirmed ahead of it, every solver runs collision-free, EVs are marked and counted
apart, and bad EV options are one line and status 2."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]

# An EV arrives behind a car on the north approach; just before it, two slow cars from the
# west are confirmed. They can still stop when the EV heads its lane and asks.
SCRIPTED = textwrap.dedent(
    """
    import json, sys
    from dica.ica.netfile import load_intersection
    from dica.sim_gateway.demand import Arrival
    from dica.sim_gateway.embedded import run
    from dica.sim_gateway.runconfig import RunConfig
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    def arr(vin, lanes, t, v, ev=False):
        return Arrival(vin, inter.route(*lanes), t, v, 5.0, 1.8, ev)
    schedule = [
        arr("n1", ("N_in_1", "S_out_1"), 0.0, 9.0),
        arr("ev", ("N_in_1", "S_out_1"), 1.5, 12.0, ev=True),
        arr("w1", ("W_in_1", "E_out_1"), 0.5, 5.0),
        arr("w2", ("W_in_0", "E_out_0"), 1.0, 5.0),
    ]
    cfg = RunConfig(str(sc.net_path), sc.junction_id, algorithm=sys.argv[1], duration_s=30.0,
                    ev_prob=0.02)
    res = run(cfg, inter, schedule=schedule)
    trips = {v: {"confirmed_s": t.confirmed_s, "exited_s": t.exited_s, "ev": t.ev}
             for v, t in res.trips.trips.items()}
    print(json.dumps({"trips": trips, "overlaps": res.safety["overlaps"],
                      "sumo": res.sumo_collisions,
                      "unconfirmed": res.extra["unconfirmed_entries"],
                      "reactive": res.extra.get("reactive")}))
    """
)


def scripted(algorithm: str) -> dict:
    p = subprocess.run(
        [sys.executable, "-c", SCRIPTED, algorithm],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def dica(*args: str) -> subprocess.CompletedProcess:
    return dica_run(
        [*DICA, *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )


def run_metrics(out: Path, *args: str) -> dict:
    """``dica run ARGS --out OUT --quiet``, which must succeed; its metrics.json."""
    p = dica("run", *args, "--out", str(out), "--quiet")
    assert p.returncode == 0, p.stdout + p.stderr
    return json.loads((out / "metrics.json").read_text())


def collision_free(d: dict) -> None:
    assert d["overlaps"] == 0 and d["sumo"] == 0 and d["unconfirmed"] == 0


def test_the_ev_behind_a_queue_crosses_before_cars_confirmed_earlier_that_could_stop():
    plain, reactive = scripted("enhanced"), scripted("rdica")
    collision_free(plain)
    collision_free(reactive)
    p, r = plain["trips"], reactive["trips"]
    assert r["ev"]["ev"] and not r["w1"]["ev"]
    for car in ("w1", "w2"):
        # confirmed before the EV in both runs ...
        assert p[car]["confirmed_s"] < p["ev"]["confirmed_s"]
        assert r[car]["confirmed_s"] < r["ev"]["confirmed_s"]
        # ... out before it under plain DICA, after it under reactive DICA
        assert p[car]["exited_s"] < p["ev"]["exited_s"]
        assert r[car]["exited_s"] > r["ev"]["exited_s"]
    assert r["ev"]["exited_s"] <= p["ev"]["exited_s"]
    [event] = reactive["reactive"]["events_log"]
    assert event["revoked"] >= 2 and event["replan_failed"] == 0


@pytest.mark.parametrize("solver", ["exact", "ga", "exhaustive"])
def test_rdica_runs_collision_free_with_every_solver(tmp_path, solver):
    out = tmp_path / solver
    m = run_metrics(
        out, "--algorithm", "rdica", "--solver", solver, "--volume", "400",
        "--duration", "150", "--seed", "21", "--ev-prob", "0.1",
    )  # fmt: skip
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    r = m["reactive"]
    assert r["solver"] == solver and r["events"] >= 2
    assert m["ev"]["crossed"] >= 1 and m["ev"]["generated"] == r["events"]
    assert m["normal"]["generated"] + m["ev"]["generated"] == m["generated"]
    with (out / "vehicles.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert sum(int(row["ev"]) for row in rows) == m["ev"]["generated"]
    assert json.loads((out / "config.json").read_text())["run"]["solver"] == solver


def test_a_platoon_behind_a_vehicle_that_got_no_new_plan_stops_behind_it(tmp_path):
    """Platoons let several revoked vehicles share a lane. When one of them gets no new
    plan after a reordering it stops short of the line, so those behind it must stop too:
    planned as if it were gone, they ran into it (this seed gave 18 overlaps and 16 SUMO
    collisions before the fix). With the run-up a revoked vehicle rarely lacks a new plan
    (1 of 8 seeds, once), so the case is made under the earlier rule, and with no bound on
    what reorderings add (under one, a vehicle that would get no plan is not revoked)."""
    m = run_metrics(
        tmp_path / "run", "--algorithm", "rdica", "--ev-prob", "0.2", "--volume", "500",
        "--duration", "300", "--seed", "12", "--no-run-up", "--max-added-delay", "inf",
    )  # fmt: skip
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["reactive"]["replan_failed"] >= 2  # the case did happen
    assert m["timing"]["plans_kept"] == 0


def test_the_reactive_light_pre_empts_for_evs_without_collisions(tmp_path):
    out = tmp_path / "light"
    m = run_metrics(
        out, "--algorithm", "reactive-light", "--volume", "300", "--duration", "300",
        "--seed", "12", "--ev-prob", "0.1",
    )  # fmt: skip
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert m["preemption"]["served"] >= 1
    cfg = json.loads((out / "config.json").read_text())
    sig = cfg["signal"]
    assert sig["type"] == "reactive-light"
    # 31 s main greens, 13 s yellows, the safe all-reds; protected turns get what is
    # left of 127 s, at least 5 s, so the cycle may be longer than the dissertation's
    assert {d for d, _, kind in sig["phases"] if kind == "yellow"} == {13.0}
    assert max(d for d, _, kind in sig["phases"] if kind == "green") == 31.0
    assert sig["cycle_s"] == pytest.approx(sum(d for d, _, _ in sig["phases"]), abs=0.01)
    assert sig["cycle_s"] >= 127.0


def test_without_evs_the_files_have_no_ev_column(tmp_path):
    out = tmp_path / "plain"
    p = dica("run", "--volume", "200", "--duration", "60", "--out", str(out), "--quiet")
    assert p.returncode == 0, p.stderr
    header = (out / "vehicles.csv").read_text().splitlines()[0]
    assert header.endswith(",stopped") and "ev" not in header.split(",")
    assert "ev" not in json.loads((out / "metrics.json").read_text())


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--ev-prob", "1.5"], "--ev-prob must be between 0 and 1, got 1.5"),
        (["--algorithm", "rdica", "--solver", "annealing"], "invalid choice"),
    ],
)
def test_bad_ev_options_are_one_line_and_status_2(tmp_path, args, message):
    p = dica("run", "--duration", "10", "--out", str(tmp_path / "x"), "--quiet", *args)
    assert p.returncode == 2
    assert message in p.stderr and "Traceback" not in p.stderr
