"""The cluster end to end: real Zenoh on loopback, real SUMO, separate processes.

* lockstep with three agents, then one, makes exactly the embedded run's decisions
  (the lockstep gateway keeps the order of ICA contacts);
* lockstep waits for the agents only on steps where one must talk to the ICA;
* garbage sent to the ICA's keys is refused or dropped and the ICA keeps serving;
* reactive DICA revokes over Zenoh, and the observer's recording shows EVs in
  their colour, each reordering, and withdrawn exactly the plans that were dropped.

Faults (late, lost and repeated messages, killed processes) are in test_timing.py.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dica.tools.loopback import free_port, router_and_ica
from tests.cluster_proc import logs_tail, stop_cluster
from tests.dica_cli import dica_run
from tests.user_nets import ROUTES, build_nets

ROOT = Path(__file__).resolve().parents[1]
DICA = [sys.executable, "-m", "dica.tools.cli"]


_free_port = free_port


def _cluster(out: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """run_cluster.sh to its end; one still running after ``timeout`` fails the test
    with its roles' logs, and is stopped with every role."""
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(out), *args]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        start_new_session=True,
    )  # fmt: skip
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the run did not end in {timeout:g} s\n{logs_tail(out)}")
    finally:
        stop_cluster(proc)
    return subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)


def _rows(path: Path) -> dict[str, dict[str, str]]:
    with path.open() as fh:
        return {r["vin"]: r for r in csv.DictReader(fh)}


def _no_leftovers(port: int) -> None:
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-f", f"127.0.0.1:{port}"], capture_output=True, text=True)
    assert left.stdout.strip() == "", f"processes left running: {left.stdout}"


def _embedded(out: Path, common: list[str]) -> None:
    e = dica_run(
        [*DICA, "run", *common, "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert e.returncode == 0, e.stderr


def _lockstep_evidence(cl_dir: Path) -> str:
    """What may have made a lockstep run leave the embedded run's decisions: a query
    given up (no_answer), a STATE sent again, a late COMMAND, REVOKEs and the ICA's
    refusals, from the run's metrics (the gateway's, and the roles' own it gathered).
    Shown with a mismatch, so that a failure on a loaded host says which."""
    m = json.loads((cl_dir / "metrics.json").read_text())
    roles = m.get("roles", {})

    def some(d: dict, *keys: str) -> str:
        return json.dumps({k: d.get(k) for k in keys})

    lines = [
        f"{name}: " + some(a, "no_answer", "rtt_p99_ms", "max_lag_ms", "revokes_received",
                           "rejections")
        for name, a in sorted(roles.get("agents", {}).items())
    ]  # fmt: skip
    lines.append("gateway: " + some(m, "resent_states", "stale_commands", "revoke_waves",
                                    "step_wait_p99_ms"))  # fmt: skip
    ica = roles.get("ica") or {}
    lines.append("ica: " + some(ica, "revokes_sent", "revoke_acks", "compute_p99_ms", "rejections"))
    return "\n".join(lines)


def _same_decisions(cl_dir: Path, emb_dir: Path) -> None:
    cl, emb = _rows(cl_dir / "vehicles.csv"), _rows(emb_dir / "vehicles.csv")
    assert cl.keys() == emb.keys(), _lockstep_evidence(cl_dir)
    for vin, row in emb.items():
        for col in ("entered_s", "confirmed_s", "exited_s", "stopped"):
            assert cl[vin][col] == row[col], (vin, col, _lockstep_evidence(cl_dir))
    m = json.loads((cl_dir / "metrics.json").read_text())
    me = json.loads((emb_dir / "metrics.json").read_text())
    for k in ("generated", "crossed", "mean_trip_time_s", "stopped_rate", "min_gap_m"):
        assert m[k] == me[k], k


def test_lockstep_clusters_make_the_embedded_decisions(tmp_path):
    """Three agents, then one agent into the same --out: each run makes exactly the
    embedded run's decisions (with several agents, waves keep the ICA's order), and the
    second starts its ICA empty: the first run's journal is kept aside, not replayed
    (its reservations would fill this run's ICA)."""
    out = tmp_path / "cl"
    _three_agents(out, tmp_path / "emb3")
    port = _free_port()
    common = ["--volume", "500", "--duration", "90", "--seed", "12"]
    p = _cluster(out, "--agents", "1", "--port", str(port), *common)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "metrics" in p.stdout and "spacetime.rrd" in p.stdout
    assert "its ICA journal is kept as" in p.stderr
    assert (out / "ica-journal.msgpack.prev").is_file()
    # the first run's logs and figures kept aside: none of it is this run's
    assert "holds an earlier run's outputs; kept in" in p.stderr
    (kept,) = out.glob("earlier-*")
    assert (kept / "metrics.json").is_file() and (kept / "logs" / "gateway.log").is_file()
    assert (out / "logs" / "gateway.log").read_text().count("generated, ") == 1
    _no_leftovers(port)
    _embedded(tmp_path / "emb", common)

    m = json.loads((out / "metrics.json").read_text())
    assert m["mode"] == "cluster" and m["clock"] == "lockstep"
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["crossed"] > 40
    ica = json.loads((out / "ica.json").read_text())
    assert ica["confirmed"] >= m["crossed"]
    assert ica["bad_messages"] == 0 and ica["journal_replays"] == 0
    assert len(ica["incarnations"]) == 1  # the earlier run's ICA is not one of its lives
    _same_decisions(out, tmp_path / "emb")


def _three_agents(out: Path, emb: Path) -> None:
    """Three agents, recorded: the embedded decisions, every agent hosting vehicles, the
    recording holding every confirmation, and lockstep waiting only when it must."""
    port = _free_port()
    common = ["--volume", "500", "--duration", "60", "--seed", "66"]  # waves happen here
    p = _cluster(out, *("--agents", "3", "--per-agent", "40", "--port", str(port)), *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    # several agents: still exactly the embedded decisions (waves keep the ICA's order)
    _embedded(emb, common)
    _same_decisions(out, emb)
    m = json.loads((out / "metrics.json").read_text())
    assert m["multi_wave_steps"] > 0  # the case the waves exist for did happen
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert set(m["agents"]) == {"agent-1", "agent-2", "agent-3"}
    assert min(m["agents"].values()) > 5  # every agent really hosted vehicles
    for name in ("router", "ica", "observer", "agent-1", "agent-2", "agent-3", "gateway"):
        assert (out / "logs" / f"{name}.log").exists(), name

    from rerun.chunk import RrdReader

    from dica.sim_gateway.recording import TOP_EVERY

    rrd = out / "spacetime.rrd"
    steps: set[int] = set()
    confirmations = 0
    for chunk in RrdReader(rrd).stream():
        path = str(chunk.entity_path)
        batch = chunk.to_record_batch()
        if path == "/junction/vehicles" and "sim_time" in batch.schema.names:
            steps.update(batch.column("sim_time").cast("int64").to_pylist())
        if path == "/tables/confirmed" and "sim_time" in batch.schema.names:
            confirmations += batch.num_rows
    ica = json.loads((out / "ica.json").read_text())
    assert confirmations == ica["confirmed"] > 20  # every confirmation drawn once
    assert len(steps) > 0.85 * 60 / 0.05 / TOP_EVERY  # the top view on (almost) every frame
    # the agents were asked only when a vehicle had to talk to the ICA, not every step
    assert m["lockstep_waits"] < 0.2 * 60 / 0.05
    assert m["lockstep_waits"] >= sum(m["agents"].values())  # at least each DETECT


def test_the_planning_rules_off_reach_the_clusters_ica(tmp_path):
    """--no-run-up and --no-exit-spacing are the ICA's (run_cluster.sh hands them over):
    the cluster then makes the embedded run's decisions under the earlier rules. Each
    rule alone decides otherwise than both together, so a rule lost on its way to the
    ICA process would show."""
    port = _free_port()
    common = ["--volume", "500", "--duration", "60", "--seed", "12"]
    both = ["--no-run-up", "--no-exit-spacing"]
    p = _cluster(tmp_path / "cl", "--agents", "1", "--port", str(port), "--no-record",
                 *both, *common)  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    _embedded(tmp_path / "emb", [*common, *both])
    _same_decisions(tmp_path / "cl", tmp_path / "emb")
    decided = _rows(tmp_path / "emb" / "vehicles.csv")
    for name, rules in (("default", []), ("run-up", both[:1]), ("spacing", both[1:])):
        _embedded(tmp_path / name, [*common, *rules])
        assert _rows(tmp_path / name / "vehicles.csv") != decided, name


# -- the ICA under bad input -------------------------------------------------------
@pytest.fixture
def ica_on_loopback(tmp_path):
    with router_and_ica(ica_args=("--out", str(tmp_path)), ica_log=tmp_path / "ica.log") as (
        session,
        ica,
    ):
        yield session, ica, tmp_path


def _ask(session, key: str, payload: bytes, timeout: float = 5.0):
    from dica.schemas.codec import decode

    replies = [r for r in session.get(key, payload=payload, timeout=timeout) if r.ok is not None]
    return [decode(r.ok.payload.to_bytes()) for r in replies]


def test_ica_refuses_garbage_and_keeps_serving(ica_on_loopback):
    from dica.ica.convert import request_from_core
    from dica.ica.core.proposal import propose
    from dica.ica.netfile import load_intersection
    from dica.schemas import keys
    from dica.schemas.codec import encode, now_ns
    from dica.schemas.messages import Ack, Clock, Detect, Reject, Response
    from dica.sim_gateway.scenario import default_scenario

    session, ica, tmp_path = ica_on_loopback
    request, detect = keys.request("C", "tester"), keys.detect("C", "tester")
    good_detect = encode(Detect("v1", "W_in_0", 0.0, False, 10.0, now_ns()))
    for bad in (b"", b"\x00\xff garbage", good_detect[:-3], b"\x93\x01\x02\x03", good_detect):
        (answer,) = _ask(session, request, bad)
        assert isinstance(answer, Reject) and answer.reason == "bad_message", answer
    # oversize: refused by the decoder (a REJECT) or dropped by the transport; never a crash
    answers = _ask(session, request, b"\x00" * (3 << 20), timeout=3.0)
    assert all(isinstance(a, Reject) for a in answers)
    session.put(keys.clock("C"), b"not a clock")
    assert ica.poll() is None

    # ...and it still serves a real vehicle, once
    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    route = inter.routes_from(inter.in_lanes[0])[0]
    session.put(keys.clock("C"), encode(Clock(1, 0.05, "lockstep", 1.0, False, now_ns())))
    (ack,) = _ask(session, detect, encode(Detect("v1", route.in_lane, 0.0, False, 10.0, now_ns())))
    assert isinstance(ack, Ack)
    confirmed = []
    sub = session.declare_subscriber(keys.confirmed("C"), lambda s: confirmed.append(s))
    req = propose(route, vin="v1", seq=0, t0_s=0.05, dist_to_entry_m=30.0, speed_mps=10.0)
    payload = encode(request_from_core(req))
    (first,) = _ask(session, request, payload)
    (again,) = _ask(session, request, payload)
    assert isinstance(first, Response) and isinstance(again, Response)
    assert np.array_equal(first.t_s, again.t_s) and np.array_equal(first.x_m, again.x_m)
    time.sleep(0.5)
    assert len(confirmed) == 1  # one reservation, published once
    sub.undeclare()

    session.put(keys.clock("C"), encode(Clock(2, 0.1, "lockstep", 1.0, True, now_ns())))
    assert ica.wait(15) == 0
    stats = json.loads((tmp_path / "ica.json").read_text())
    assert stats["confirmed"] == 1 and stats["repeated"] == 1
    assert stats["bad_messages"] >= 6
    assert "dropped a bad request message" in (tmp_path / "ica.log").read_text()


def test_realtime_clock_is_paced_and_safe(tmp_path):
    port = _free_port()
    out = tmp_path / "rt"
    p = _cluster(
        out,
        *("--agents", "1", "--no-record", "--port", str(port), "--clock", "realtime"),
        *("--speed", "4", "--volume", "500", "--duration", "20", "--seed", "66"),
    )
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    m = json.loads((out / "metrics.json").read_text())
    assert m["clock"] == "realtime" and m["speed"] == 4
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["wall_s"] >= 0.95 * 20 / 4  # paced: never faster than 4x the wall clock
    assert m["crossed"] > 5


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--agents", "0"], "--agents wants a positive integer"),
        (["--layout", "ch9"], "unknown layout"),
        (["--bogus"], "unknown option --bogus"),
        (["--volume", "5000", "--duration", "5"], "--volume must be between 1 and 2000"),
        (["--agents", "1", "--per-agent", "1", "--no-record", "--duration", "120"], "has room"),
    ],
)
def test_bad_input_to_run_cluster_is_one_clear_line(tmp_path, args, says):
    p = _cluster(tmp_path / "bad", *args, timeout=120)
    assert p.returncode == 2
    assert says in p.stderr and "Traceback" not in p.stderr + p.stdout


def _terminal_signals() -> None:
    """SIGINT as a terminal's shell leaves it to what it starts: handled by default and
    not blocked (a test worker's own state must not leak into the script: bash cannot
    trap a signal that was ignored when it started)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def test_ctrl_c_stops_everything_and_keeps_the_recording(tmp_path):
    from rerun.chunk import RrdReader

    port = _free_port()
    out = tmp_path / "cl"
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(out), "--agents", "1"]
    cmd += ["--port", str(port), "--duration", "600", "--volume", "300"]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        start_new_session=True, preexec_fn=_terminal_signals,
    )  # fmt: skip
    try:
        log = out / "logs" / "gateway.log"
        deadline = time.monotonic() + 120
        while not (log.exists() and "t=30 s" in log.read_text()):
            assert time.monotonic() < deadline, "the cluster never got going"
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        # a terminal's Ctrl-C: SIGINT to the foreground process group (the script and
        # whatever it runs in the foreground; the roles run in their own sessions)
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130
    assert "interrupted" in stderr
    _no_leftovers(port)
    # the observer closed its file on SIGTERM: it reads back
    chunks = list(RrdReader(out / "spacetime.rrd").stream())
    assert any(str(c.entity_path) == "/junction/vehicles" for c in chunks)


def _reactive_recording(rrd: Path) -> dict:
    """What a .rrd shows of reactive DICA, read back with Rerun's reader: the reorders
    table's reorderings and its rows on revoked plans that stand (time, row), the
    plans withdrawn (time, VIN), how many reorder marks the lane charts hold, and
    whether an EV is drawn in its colour in the top view and in the lane charts."""
    from rerun.chunk import RrdReader

    from dica.sim_gateway.recording import STATUS_STYLE, Status

    r, g, b = STATUS_STYLE[Status.EMERGENCY][1]
    red = (r << 24) | (g << 16) | (b << 8) | 0xFF
    out = {"reorders": [], "kept": [], "withdrawn": [], "marks": 0, "ev_top": False,
           "ev_charts": False}  # fmt: skip
    for chunk in RrdReader(rrd).stream():
        path, batch = str(chunk.entity_path), chunk.to_record_batch()
        if "sim_time" not in batch.schema.names:
            continue
        times = [round(t / 1e9, 3) for t in batch.column("sim_time").cast("int64").to_pylist()]

        def column(name: str, batch=batch) -> list:
            return batch.column(name).to_pylist() if name in batch.schema.names else []

        if path == "/tables/reorders":
            for t, (txt,) in zip(times, column("TextLog:text"), strict=True):
                stands = "kept its plan" in txt or "no answer before" in txt
                out["kept" if stands else "reorders"].append((t, txt))
        elif path == "/tables/rejected":
            rows = [
                (t, txt.split()) for t, (txt,) in zip(times, column("TextLog:text"), strict=True)
            ]
            out["withdrawn"] += [(t, w[0]) for t, w in rows if w[1:] == ["revoked"]]
        elif path.startswith("/charts/data/lanes/") and path.endswith("/reorders"):
            out["marks"] += batch.num_rows
        elif path == "/junction/vehicles":
            out["ev_top"] |= any(red in (cs or []) for cs in column("LineStrips2D:colors"))
        elif path.startswith("/charts/data/lanes/") and path.endswith("/actual"):
            out["ev_charts"] |= any(red in (cs or []) for cs in column("Points2D:colors"))
    for rows in ("reorders", "kept", "withdrawn"):
        out[rows].sort()
    return out


def _revoked_at(reorders: list[tuple[float, str]]) -> dict[str, float]:
    """When each starred (revoked) vehicle of the reorders table was first revoked."""
    out: dict[str, float] = {}
    for t, row in reorders:
        for v in row.split():
            if v.endswith("*"):
                out.setdefault(v[:-1], t)
    return out


def test_lockstep_rdica_cluster_revokes_over_zenoh_as_dica_run_drop_does(tmp_path):
    """Two agents: an EV on one revokes vehicles of the other, whose agent gets no STATE
    while they fly; the gateway wakes it in the same step (revoke_waves). Before it did,
    one REVOKE waited 5 s for the agent to idle and its plan expired unanswered. The
    observer's recording shows the EVs in their colour, each reordering, and withdraws
    exactly the plans that were dropped."""
    port = _free_port()
    common = ["--algorithm", "rdica", "--ev-prob", "0.2", "--volume", "400", "--duration", "90",
              "--max-added-delay", "inf"]  # (no bound: every reordering revokes)  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "2", "--port", str(port), *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    _embedded(tmp_path / "emb", [*common, "--revocation", "drop"])

    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    ica = json.loads((tmp_path / "cl" / "ica.json").read_text())
    reactive = ica["incarnations"][0]["reactive"]
    assert ica["incarnations"][0]["revoke_acks"] >= 1  # taken back over the wire, and ACKed
    assert reactive["acknowledged"] + reactive["restored"] == reactive["revoked"]
    assert reactive["pending"] == 0 and reactive["expired"] == 0
    assert m["timing"]["plans_dropped"] >= 1
    assert m["revoke_waves"] >= 1  # the case did happen
    config = json.loads((tmp_path / "cl" / "config.json").read_text())
    assert config["run"]["revocation"] == "drop"
    _same_decisions(tmp_path / "cl", tmp_path / "emb")

    rec = _reactive_recording(tmp_path / "cl" / "spacetime.rrd")
    assert rec["ev_top"] and rec["ev_charts"]  # EVs in their colour, top view and charts
    assert rec["marks"] >= 1 and len(rec["reorders"]) == reactive["events"]
    # withdrawn: exactly the plans the actuators dropped (the gateway's own count) and the
    # ICA heard dropped, each after its REVOKE went out; the plans kept stay drawn
    withdrawn = rec["withdrawn"]
    assert len(withdrawn) == m["timing"]["plans_dropped"] == reactive["acknowledged"]
    assert len(rec["kept"]) == reactive["restored"] + reactive["expired"]
    revoked = _revoked_at(rec["reorders"])
    assert all(vin in revoked and t > revoked[vin] for t, vin in withdrawn)


def test_an_rdica_cluster_under_a_bound_checks_orders_on_a_copy_and_answers_every_revocation(
    tmp_path,
):
    """Under a bound on what reorderings add, the ICA process carries each order out on a
    copy of itself before revoking (its deep copy works in the process as in dica run),
    and the revocations it then sends are all answered; the run is safe."""
    port = _free_port()
    common = ["--algorithm", "rdica", "--ev-prob", "0.2", "--volume", "500", "--duration",
              "150", "--max-added-delay", "4"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "2", "--port", str(port), "--no-record", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    ica = json.loads((tmp_path / "cl" / "ica.json").read_text())["incarnations"][0]
    reactive = ica["reactive"]
    assert reactive["max_added_delay_s"] == 4.0
    assert reactive["bound_trials"] >= 1 and reactive["revoked"] >= 1  # both happened
    assert reactive["acknowledged"] + reactive["restored"] == reactive["revoked"]
    assert reactive["pending"] == 0 and ica["revoke_acks"] >= 1


def test_two_agents_revoke_safely_and_the_recording_withdraws_only_dropped_plans(tmp_path):
    """On a secured site: the ICA's REORDERs pass the router's rules and their seals."""
    port = _free_port()
    out = tmp_path / "cl"
    common = ["--algorithm", "rdica", "--ev-prob", "0.2", "--volume", "400", "--duration", "90",
              "--max-added-delay", "inf"]  # (no bound: every reordering revokes)  # fmt: skip
    p = _cluster(out, "--secure", "--agents", "2", "--port", str(port), *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _no_leftovers(port)
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert set(m["agents"]) == {"agent-1", "agent-2"} and min(m["agents"].values()) > 5
    ica = json.loads((out / "ica.json").read_text())["incarnations"][0]
    reactive = ica["reactive"]
    assert ica["revoke_acks"] >= 1 and reactive["revoked"] >= 1  # revocations happened
    assert reactive["acknowledged"] + reactive["restored"] == reactive["revoked"]
    assert reactive["pending"] == 0
    assert ica["refused_unsealed"] == {}
    rec = _reactive_recording(out / "spacetime.rrd")
    assert rec["ev_top"] and rec["marks"] >= 1 and len(rec["reorders"]) == reactive["events"]
    # withdrawn: every plan its vehicle dropped (ACK or CANCEL), none that was kept
    assert len(rec["withdrawn"]) == reactive["acknowledged"] >= ica["revoke_acks"]
    assert len(rec["kept"]) == reactive["restored"] + reactive["expired"]
    revoked = _revoked_at(rec["reorders"])
    assert all(vin in revoked and t >= revoked[vin] for t, vin in rec["withdrawn"])


def test_lockstep_cluster_with_a_route_file_makes_the_embedded_decisions(tmp_path):
    """A user's net and demand file: SUMO drives the vehicles to the region, the agents
    and the ICA take over there, byte for byte as in one process."""
    (tmp_path / "nets").mkdir()
    nets = build_nets(tmp_path / "nets")
    routes = tmp_path / "demand.rou.xml"
    routes.write_text(ROUTES)
    common = ["--net", str(nets["grid"]), "--junction", "B1", "--routes", str(routes),
              "--duration", "150"]  # fmt: skip
    p = _cluster(tmp_path / "cl", "--agents", "2", "--no-record", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    _embedded(tmp_path / "emb", common)
    m = json.loads((tmp_path / "cl" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["crossed"] > 20
    cl, emb = (tmp_path / d / "vehicles.csv" for d in ("cl", "emb"))
    assert cl.read_bytes() == emb.read_bytes()
