"""A network of junctions as a cluster: one ICA process per junction, one Zenoh router
per roadside unit in a mesh, agents that serve every junction; real SUMO, real Zenoh.

* lockstep over loopback, two roadside units: the embedded run's decisions, byte for
  byte, with every junction recorded by its own observer and the network from above;
* each roadside unit a host of its own (a Linux network namespace on a private LAN),
  the gateway and the agents on another: lockstep equals the embedded run again, and
  real time with delayed, lost and repeated messages between the hosts is safe;
* nine ICAs on a grid driven past saturation: lockstep equals the embedded run with
  the network gate closed, and in real time the gate holds;
* one junction's ICA killed, then its router: its vehicles stop short of its line,
  the others go on, nothing collides, and the ICA comes back from its journal.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from dica.tools.loopback import free_port
from tests.cluster_proc import logs_tail, stop_cluster
from tests.dica_cli import dica_run
from tests.network_corridor import DICA, DURATION, corridor_and_its_embedded_run

ROOT = Path(__file__).resolve().parents[1]

needs_netns = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("ip") is None,
    reason="network namespaces need root and iproute2",
)


@pytest.fixture(scope="module")
def corridor(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return corridor_and_its_embedded_run(tmp_path_factory.mktemp("corridor"))


def _cluster(out: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
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


def _safe_and_whole(m: dict) -> None:
    assert m["complete"] is True
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert m["unconfirmed_entries"] == 0 and m["stood_inside"] == 0
    acc = m["accounted"]
    assert acc["lost"] == 0
    assert acc["crossed"] + acc["in_region"] + acc["not_yet_in_region"] == acc["generated"]


def _same_as_embedded(out: Path, corridor: dict) -> dict:
    emb = corridor["embedded"]
    for name in ("vehicles.csv", "trips.csv"):
        assert (out / name).read_bytes() == (emb / name).read_bytes(), name
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)
    assert m["mode"] == "cluster" and m["clock"] == "lockstep"
    assert m["crossed"] > 50
    # a vehicle keeps its agent from one junction to the next: each was handed once
    vins = {line.split(",", 1)[0] for line in (out / "vehicles.csv").read_text().splitlines()[1:]}
    assert sum(m["agents"].values()) == len(vins)
    for j in corridor["junctions"]:
        ica = json.loads((out / "ica" / j / "ica.json").read_text())
        assert ica["confirmed"] >= m["junctions"][j]["crossed"] > 10
    return m


def test_lockstep_network_cluster_makes_the_embedded_decisions(tmp_path, corridor):
    out = tmp_path / "cl"
    port = free_port()
    p = _cluster(out, *corridor["scen"], "--duration", DURATION, "--rsus", "2", "--port", str(port))
    assert p.returncode == 0, p.stdout + p.stderr
    assert "4 junctions" in p.stdout and "2 roadside units" in p.stdout
    _same_as_embedded(out, corridor)
    for j, rrd in zip(corridor["junctions"], ("spacetime.rrd", "spacetime-J10.rrd",
                                              "spacetime-J20.rrd", "spacetime-J30.rrd"),
                      strict=True):  # fmt: skip
        assert (out / rrd).stat().st_size > 10_000, j
        assert (out / "logs" / f"observer-{j}.log").exists()
    assert {f"router-{k}.log" for k in (1, 2)} <= {f.name for f in (out / "logs").iterdir()}
    # the network from above, from the wire: every junction, its vehicles and their plans
    from tests.test_recording import _read, _rows, _static

    top = _read(out / "network.rrd")
    assert sorted(_static(top["/network/names"], "Points2D:labels")) == list(corridor["junctions"])
    vehicles = _rows(top["/network/vehicles"], "LineStrips2D:strips")
    assert len(vehicles) >= 60 and max(len(v) for _, v in vehicles) >= 5
    plans = _rows(top["/network/plans"], "LineStrips2D:strips")
    assert sum(1 for _, p in plans if p) >= 50
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-f", f"127.0.0.1:{port}"], capture_output=True, text=True)
    assert left.stdout.strip() == "", f"processes left running: {left.stdout}"


@needs_netns
def test_roadside_units_on_hosts_of_their_own(tmp_path, corridor):
    before = set(_namespaces())  # (another run's on this host are not this one's to clean)
    # secured: each roadside unit's router on a host of its own with its own certificate,
    # logging in to the ones before it across the LAN; the same decisions (the plain
    # mesh's are the lockstep test's above, on loopback)
    out = tmp_path / "secure"
    p = _cluster(out, *corridor["scen"], "--duration", DURATION, "--netns", "--no-record",
                 "--secure")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    _same_as_embedded(out, corridor)
    for k in range(1, len(corridor["junctions"]) + 1):
        log = (out / "logs" / f"router-{k}.log").read_text()
        assert f"listening on tls/10.77.0.{10 + k}:7447" in log
        assert "refused rsu-" not in log  # nothing between the routers was refused
    # every agent asked every junction's ICA
    agent = (out / "logs" / "agent-2.log").read_text()
    assert all(f"stopped at {j}" in agent for j in corridor["junctions"])
    left = [n for n in _namespaces() if n.startswith("dica") and n not in before]
    assert not left, f"namespaces left behind: {left}"

    # real time, the links between the vehicles' host and the roadside units late, lossy
    out = tmp_path / "rt"
    p = _cluster(
        out, *corridor["scen"], "--duration", "60", "--netns", "--no-record",
        "--clock", "realtime", "--speed", "3",
        "--delay", "15", "--jitter", "10", "--loss", "0.02", "--dup", "0.02",
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)
    assert m["clock"] == "realtime" and m["crossed"] > 50
    ages = [v["cluster"]["command_age_ms"]["median"] for v in m["junctions"].values()]
    assert min(ages) > 15  # the delay was really there
    for k in range(1, len(corridor["junctions"]) + 1):  # each on a host of its own
        log = (out / "logs" / f"router-{k}.log").read_text()
        assert f"listening on tcp/10.77.0.{10 + k}:7447" in log
    left = [n for n in _namespaces() if n.startswith("dica") and n not in before]
    assert not left, f"namespaces left behind: {left}"


def test_lockstep_cluster_of_a_gated_grid_makes_the_embedded_decisions(tmp_path):
    """The test grid's heavy streams, nine ICAs: the network gate closes (a guarded link
    promised all of its room), and lockstep over Zenoh still equals the embedded run byte
    for byte, each junction told the room the ones before it this step left."""
    from tests.test_gridlock import HEAVY
    from tests.user_nets import build_nets

    net = build_nets(tmp_path)["grid"]
    routes = tmp_path / "heavy.rou.xml"
    routes.write_text(HEAVY)
    scen = ["--net", str(net), "--junctions", "all", "--routes", str(routes), "--duration", "60"]
    emb = tmp_path / "emb"
    e = dica_run(
        [*DICA, "run", *scen, "--out", str(emb), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert e.returncode == 0, e.stderr
    out = tmp_path / "cl"
    p = _cluster(out, *scen, "--rsus", "3", "--no-record")
    assert p.returncode == 0, p.stdout + p.stderr
    for name in ("vehicles.csv", "trips.csv"):
        assert (out / name).read_bytes() == (emb / name).read_bytes(), name
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)
    assert m["network_gate"]["peak_share"] >= 0.95 and m["crossed"] > 90


def test_a_lockstep_network_cluster_under_reactive_dica_makes_the_embedded_decisions(tmp_path):
    """Emergency vehicles down the corridor's arterial, every junction's ICA process
    reactive DICA: the EVs' events and their notices ahead are decided in the ICA
    processes, and lockstep over Zenoh equals the embedded run with the cluster's
    revocations (drop) byte for byte."""
    from dica.sim_gateway.network_layouts import build_network
    from dica.sim_gateway.od_demand import OdDemand, write_od_routes

    g = build_network("corridor", tmp_path / "net")
    routes = tmp_path / "ev.rou.xml"
    demand = OdDemand(250.0, 90.0, 12, entry_vph=(("W00_J00", 700.0), ("E30_J30", 700.0)),
                      ev_prob=0.1)  # fmt: skip
    write_od_routes(g.net_path, g.junctions, demand, routes)
    scen = ["--net", str(g.net_path), "--junctions", "all", "--routes", str(routes),
            "--algorithm", "rdica", "--duration", "90"]  # fmt: skip
    emb = tmp_path / "emb"
    e = dica_run(
        [*DICA, "run", *scen, "--revocation", "drop", "--ev-notices", "--out", str(emb), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert e.returncode == 0, e.stderr
    out = tmp_path / "cl"
    p = _cluster(out, *scen, "--rsus", "2", "--no-record", "--", "--ev-notices")
    assert p.returncode == 0, p.stdout + p.stderr
    for name in ("vehicles.csv", "trips.csv"):
        assert (out / name).read_bytes() == (emb / name).read_bytes(), name
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)
    events = {j: r["ica"]["reactive"]["events"] for j, r in m["roles"].items() if "ica" in r}
    assert set(events) == set(g.junctions) and sum(events.values()) >= 5, events
    assert m["network"]["emergency"]["vehicles"] >= 5
    # the EVs' notices to the junctions ahead went over Zenoh (EVCOMING), each taken
    notices = {j: r["ica"]["notices"] for j, r in m["roles"].items() if "ica" in r}
    assert all(n > 0 for n in notices.values()), notices
    assert all(r["cluster"]["notices_unanswered"] == 0 for r in m["junctions"].values())


def test_a_real_time_cluster_keeps_the_network_gate(tmp_path):
    """Nine ICAs answering at once, none waiting for the others' answers, on the test
    grid's six heavy streams: a guarded link is promised all of its room and never
    more, since each junction's vehicles are told the room less every vehicle asking to
    enter anywhere, and vehicles put onto a guarded link wait for room less those too."""
    from tests.test_gridlock import HEAVY
    from tests.user_nets import build_nets

    net = build_nets(tmp_path)["grid"]
    routes = tmp_path / "heavy.rou.xml"
    routes.write_text(HEAVY)
    out = tmp_path / "rt"
    p = _cluster(
        out, "--net", str(net), "--junctions", "all", "--routes", str(routes),
        "--duration", "100", "--clock", "realtime", "--speed", "3", "--rsus", "3",
        "--no-record",
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)
    gate = m["network_gate"]
    assert gate["links"] == 24 and gate["rule"] == "route"
    # a guarded link promised all of its room: an answer still in flight holds its
    # vehicle's room against the other ICAs and the route file's insertions, and a
    # vehicle sent round holds its new way's, counted once. Far behind real time
    # (speed 10 to 12) one vehicle more than the room was still seen in 1 of 9 runs
    # (1.016): an open race of the real-time gate, bounded here by one
    # vehicle, not hidden (the lockstep gate keeps 1.0, tests/test_gridlock.py)
    from dica.ica.core.gridlock import QUEUE_GAP_M

    one = (7.0 + QUEUE_GAP_M) / gate["least_link_capacity_m"]  # HEAVY's van
    assert 0.95 <= gate["peak_share"] <= 1.0 + one


@needs_netns
def test_a_junctions_ica_then_its_router_killed(tmp_path, corridor):
    import signal

    from dica.ica.journal import records

    out = tmp_path / "kill"
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(out), *corridor["scen"],
           "--duration", "90", "--netns", "--no-record", "--clock", "realtime",
           "--speed", "2", "--", "--progress-every", "5"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        start_new_session=True,
    )  # fmt: skip
    try:
        _at(out, 20, proc)
        os.kill(int((out / "pids" / "ica-J10").read_text()), signal.SIGKILL)
        # the router's outage counts apart only once the restarted ICA is back
        _said(out, "the ICA of J10 is back", proc)
        _at(out, 40, proc)
        os.kill(int((out / "pids" / "router-2").read_text()), signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the run did not end\n{logs_tail(out)}")
    finally:
        stop_cluster(proc)
    assert proc.returncode == 0, stdout + stderr
    assert "restarting ica-J10" in stdout and "restarting router-2" in stdout
    m = json.loads((out / "metrics.json").read_text())
    _safe_and_whole(m)  # no vehicle entered J10 unconfirmed: they stopped short of its line
    per = m["junctions"]
    assert per["J10"]["cluster"]["ica_outages"] == 2  # the ICA, then its router
    assert all(per[j]["cluster"]["ica_outages"] == 0 for j in ("J00", "J20", "J30"))
    assert all(per[j]["crossed"] > 15 for j in per)  # the rest went on, J10 too after
    ica = json.loads((out / "ica" / "J10" / "ica.json").read_text())
    assert ica["journal_replays"] == 1 and len(ica["incarnations"]) == 2
    replayed = ica["incarnations"][1]["journal_replayed"]["confirmations"]
    assert replayed > 0  # it kept the promises made before the crash
    confirms = [
        r for r in records(out / "ica" / "J10" / "ica-journal.msgpack")[0] if r["k"] == "confirm"
    ]
    assert len(confirms) > replayed + 10  # and went on confirming
    log = (out / "logs" / "gateway.log").read_text()
    assert log.count("the ICA of J10 is back") == 2


def _at(out: Path, t_s: int, proc: subprocess.Popen, timeout: float = 180) -> None:
    _said(out, f"t={t_s} s", proc, timeout)


def _said(out: Path, words: str, proc: subprocess.Popen, timeout: float = 180) -> None:
    """Wait until the gateway's log says `words` (the cluster still running)."""
    log = out / "logs" / "gateway.log"
    deadline = time.monotonic() + timeout
    while not (log.exists() and words in log.read_text()):
        assert proc.poll() is None, logs_tail(out)
        assert time.monotonic() < deadline, f"the gateway never said {words!r}\n{logs_tail(out)}"
        time.sleep(0.1)


def _namespaces() -> list[str]:
    p = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True)
    return [line.split()[0] for line in p.stdout.splitlines() if line.strip()]


@pytest.mark.parametrize(
    "args, says",
    [
        (["--junctions", "J00,NOPE"], "junction 'NOPE' not in"),
        # (it started every role, two ICAs under one name, and then hung)
        (["--junctions", "J00,J00"], "names a junction twice"),
        (["--junctions", "all", "--rsus", "9"], "--rsus wants 1 to 4"),
        (["--junctions", "all", "--junction", "J00"], "--junction names one junction"),
        (["--junction", "J00", "--rsus", "2"], "--rsus goes with --junctions"),
        (["--junctions", "all", "--netns", "--faulty", "ica", "--delay", "5"], "--faulty agents"),
        (["--junctions", "all", "--peds", "100"], "--peds in a network runs embedded"),
    ],
)
def test_a_network_the_cluster_cannot_run_is_one_clear_line(tmp_path, corridor, args, says):
    scen = [a for a in corridor["scen"] if a not in ("--junctions", "all")]
    p = subprocess.run(
        ["bash", "tools/run_cluster.sh", "--out", str(tmp_path / "x"), *scen, *args],
        capture_output=True, text=True, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert p.returncode == 2, p.stdout + p.stderr
    assert says in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
