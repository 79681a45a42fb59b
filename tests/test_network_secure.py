"""A secured network of junctions: each junction's ICA its own log-in and seal.

Someone holding the log-in and signing key of junction J00's ICA (a roadside unit
broken into) tries, for the whole run, to act as J10's ICA: to serve J10's
requests with fake plans, publish confirmations and revocations on J10's keys and
hold J10's ICA token. Once with the router's rules on (the router refuses it and
logs each refusal), once with them off (every role refuses what J10's ICA did not
seal). Both runs are lockstep: the same decisions as the embedded run, byte for
byte, zero collisions.
"""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from dica.tools.loopback import free_port
from tests.cluster_proc import logs_tail, stop_cluster
from tests.network_corridor import DURATION, ROOT, corridor_and_its_embedded_run

THIEF = "ica-J00"  # the stolen identity
VICTIM = "J10"  # the junction it attacks


@pytest.fixture(scope="module")
def corridor(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return corridor_and_its_embedded_run(tmp_path_factory.mktemp("corridor"))


class Thief(threading.Thread):
    """J00's ICA's credentials, used against J10, over and over."""

    def __init__(self, site: Path, endpoint: str) -> None:
        super().__init__(daemon=True)
        self.site, self.endpoint = site, endpoint
        self.stop = threading.Event()
        self.answered = 0  # J10's REQUESTs its impostor queryable got to answer
        self.rounds = 0
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self._attack()
        except BaseException as e:  # reported by the test, not lost in a thread
            self.error = e

    def _attack(self) -> None:
        from dica.deploy.seal import Seal
        from dica.deploy.transport import open_session
        from dica.schemas.codec import encode, now_ns
        from dica.schemas.messages import Response, Revoke

        seal = Seal(THIEF, self.site / f"{THIEF}.seal")
        s = open_session(self.site / f"{THIEF}.json5", self.endpoint)
        j = VICTIM

        def fake(vin: str, seq: int) -> bytes:
            x = np.zeros(3)
            return seal.seal(
                encode(Response(vin, seq, "x", x, x, x, x, 0.0, 1.0, 0.0, 1, now_ns()))
            )

        def fake_answer(query) -> None:
            try:
                env = msgpack.unpackb(query.payload.to_bytes(), raw=False)
                req = msgpack.unpackb(env["body"], raw=False)
                query.reply(query.key_expr, fake(req["vin"], req["seq"]))
                self.answered += 1
            except Exception:
                pass
            finally:
                query.drop()

        decls = [s.declare_queryable(f"dica/{j}/request/*", fake_answer)]
        tokens = [s.liveliness().declare_token(f"dica/{j}/alive/ica")]
        while not self.stop.wait(0.1):
            self.rounds += 1
            for n in range(40):
                vin = f"v{n:05d}"
                s.put(f"dica/{j}/confirmed/{vin}", fake(vin, 99))
                s.put(f"dica/{j}/revoke/agent-1", seal.seal(encode(Revoke(vin, 1, 1.0, now_ns()))))
        for d in decls:
            d.undeclare()
        for t in tokens:
            t.undeclare()
        s.close()


def _run_under_attack(out: Path, corridor: dict, router_rules: bool) -> tuple[dict, Thief]:
    port = free_port()
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(out), "--secure", "--no-record",
           "--port", str(port), *corridor["scen"], "--duration", DURATION]  # fmt: skip
    if not router_rules:
        cmd.append("--no-router-rules")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, start_new_session=True)  # fmt: skip
    thief = None
    try:
        log = out / "logs" / "gateway.log"
        deadline = time.monotonic() + 120
        while not (log.exists() and f"agents up at {corridor['junctions'][-1]}" in log.read_text()):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, logs_tail(out)
            time.sleep(0.1)
        thief = Thief(out / "zenoh", f"tls/127.0.0.1:{port}")
        thief.start()
        try:
            stdout, stderr = proc.communicate(timeout=300)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the run did not end in 300 s\n{logs_tail(out)}")
    finally:
        if thief is not None:
            thief.stop.set()
            thief.join(10)
        stop_cluster(proc)
    assert proc.returncode == 0, stdout + stderr
    assert thief.error is None, thief.error
    assert thief.rounds > 20  # it really kept at it
    m = json.loads((out / "metrics.json").read_text())
    assert m["complete"] is True
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    # lockstep: the attack changed no decision at all
    for name in ("vehicles.csv", "trips.csv"):
        assert (out / name).read_bytes() == (corridor["embedded"] / name).read_bytes(), name
    return m, thief


def test_each_junctions_ica_has_its_own_identity(tmp_path):
    from dica.deploy.site import site_agents, write_secure_configs

    paths = write_secure_configs(tmp_path, agents=2, junctions=("J00", "J10"), own_icas=True)
    assert {"ica-J00.json5", "ica-J00.seal", "ica-J10.json5", "ica-J10.seal"} <= set(paths)
    assert "ica.json5" not in paths  # no identity good for every junction
    assert site_agents(tmp_path) == ("agent-1", "agent-2")
    users = [line.split(":")[0] for line in (tmp_path / "users.txt").read_text().splitlines()]
    assert users[:2] == ["ica-J00", "ica-J10"]


def test_the_routers_of_a_secured_mesh_log_in_to_each_other(tmp_path):
    """Roadside unit 2's router logs in to unit 1's with its own password and trusts
    unit 1 by its certificate: an agent behind unit 2 reaches the ICA behind unit 1,
    and still only on its own keys (unit 2 keeps it to them). A router with a wrong
    password never joins the mesh."""
    from dica.deploy.site import _written, write_secure_configs
    from dica.tools.loopback import client, router

    site = tmp_path / "site"
    write_secure_configs(site, agents=2, junctions=("J00", "J10"), own_icas=True, rsus=2)
    conf = _written(site / "router-2.json5")
    assert conf["transport"]["auth"]["usrpwd"]["user"] == "rsu-2"
    conf["transport"]["auth"]["usrpwd"]["password"] = "not-its-password"
    (tmp_path / "wrong.json5").write_text(json.dumps(conf))

    def answered(session, key: str, within_s: float) -> bool:
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            if any(r.ok is not None for r in session.get(key, timeout=1.0)):
                return True
            time.sleep(0.2)
        return False

    with router(site / "router.json5", "tls") as first:
        ica = client(site / "ica-J00.json5", first)
        serve = ica.declare_queryable(
            "dica/J00/request/*", lambda q: (q.reply(q.key_expr, b"ok"), q.drop())
        )
        try:
            with router(tmp_path / "wrong.json5", "tls", connect=first) as second:
                agent = client(site / "agent-1.json5", second)
                assert not answered(agent, "dica/J00/request/agent-1", 4.0)
                agent.close()
            with router(site / "router-2.json5", "tls", connect=first) as second:
                agent = client(site / "agent-1.json5", second)
                assert answered(agent, "dica/J00/request/agent-1", 15.0)
                assert not answered(agent, "dica/J00/request/agent-2", 3.0)  # not its key
                agent.close()
        finally:
            serve.undeclare()
            ica.close()


def test_a_site_of_several_roadside_units_keeps_their_log_ins_apart(tmp_path):
    from dica.deploy.site import SecureConfigError, _written, add_agents, write_secure_configs

    paths = write_secure_configs(tmp_path, agents=1, junctions=("J00", "J10"), rsus=2)
    assert {"router.json5", "router-2.json5"} <= set(paths) and "rsu-2.json5" not in paths
    first, second = _written(tmp_path / "router.json5"), _written(tmp_path / "router-2.json5")
    assert first["transport"]["auth"]["usrpwd"].get("user") is None  # it opens no link
    subjects = {s["id"]: s for s in second["access_control"]["subjects"]}
    assert subjects["routers-out"]["cert_common_names"] == ["rsu-1"]
    assert {s["id"]: s for s in first["access_control"]["subjects"]}["routers-in"]["usernames"] == [
        "rsu-2"
    ]
    key1 = first["transport"]["link"]["tls"]["listen_certificate_base64"]
    assert key1 != second["transport"]["link"]["tls"]["listen_certificate_base64"]
    with pytest.raises(SecureConfigError, match="taken"):
        add_agents(tmp_path, "rsu-3")  # an agent may not pose as a router
    add_agents(tmp_path, "car-9")  # issuing an agent keeps both routers' own material
    again = _written(tmp_path / "router-2.json5")
    assert again["transport"]["link"]["tls"] == second["transport"]["link"]["tls"]
    assert any(r["id"] == "agent-ask/car-9" for r in again["access_control"]["rules"])


def test_the_router_keeps_a_stolen_ica_login_to_its_own_junction(tmp_path, corridor):
    out = tmp_path / "on"
    _, thief = _run_under_attack(out, corridor, router_rules=True)
    assert thief.answered == 0  # no REQUEST for J10 ever reached its queryable
    router = (out / "logs" / "router-1.log").read_text()
    for what in (
        f"Declare Queryable (ingress) on dica/{VICTIM}/request/*",
        f"Put (ingress) on dica/{VICTIM}/confirmed/v00001",
        f"Declare/Undeclare Liveliness Token (ingress) on dica/{VICTIM}/alive/ica",
    ):
        assert f"refused {THIEF}: {what}" in router, what


def test_with_the_router_s_rules_off_the_roles_refuse_another_junctions_ica(tmp_path, corridor):
    out = tmp_path / "off"
    m, thief = _run_under_attack(out, corridor, router_rules=False)
    assert thief.answered > 0  # this time its queryable did get J10's REQUESTs
    agents = m["roles"][VICTIM]["agents"]
    assert sum(a["bad_replies"] for a in agents.values()) > 0  # and its answers were refused
    refused = {k: n for a in agents.values() for k, n in a["refused_unsealed"].items()}
    assert any(f"{THIEF!r}" in k for k in refused), refused
