"""A secured cluster under attack by someone holding a vehicle agent's credentials.

The attacker logs in as ``agent-2`` (its password, its signing key) beside the
real agent-2 and, for the whole run, tries to impersonate the ICA with
wildcard queryables and answer vehicles with fake plans, end the run and make
time jump with forged clocks, publish forged confirmations and states, hold
fake liveliness tokens, command and cancel agent-1's vehicles. Once with the
router's rules on (they stop it at the router, which logs each refusal), once
with them off (the roles' own checks of every message's seal must stop it).
Both runs are lockstep, so "the attack changed nothing" is exact: the same
decisions as the embedded run, zero collisions, every vehicle accounted for.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest

from dica.tools.loopback import free_port
from tests.cluster_proc import logs_tail, stop_cluster
from tests.dica_cli import dica_run

ROOT = Path(__file__).resolve().parents[1]
DICA = [sys.executable, "-m", "dica.tools.cli"]
COMMON = ["--volume", "500", "--duration", "40", "--seed", "21"]


class Attacker(threading.Thread):
    """Everything an agent's stolen credentials might try, over and over."""

    def __init__(self, site: Path, endpoint: str, user: str = "agent-2") -> None:
        super().__init__(daemon=True)
        self.site, self.endpoint, self.user = site, endpoint, user
        self.stop = threading.Event()
        self.answered = 0  # vehicles' REQUESTs its impostor queryables got to answer
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
        from dica.schemas.messages import Cancel, Clock, Command, Response, Setpoint, State

        seal = Seal(self.user, self.site / f"{self.user}.seal")
        s = open_session(self.site / f"{self.user}.json5", self.endpoint)
        decls, tokens = [], []

        def fake_answer(query) -> None:
            try:
                env = msgpack.unpackb(query.payload.to_bytes(), raw=False)
                req = msgpack.unpackb(env["body"], raw=False)
                fake = Response(req["vin"], req["seq"], "x", _f(req["t_s"]), _f(req["x_m"]),
                                _f(req["y_m"]), _f(req["heading_rad"]), 0.0, 1.0, 0.0, 1,
                                now_ns())  # fmt: skip
                for body in (encode(fake), seal.seal(encode(fake))):
                    query.reply(query.key_expr, body)
                self.answered += 1
            except Exception:
                pass
            finally:
                query.drop()

        for key in ("*/C/request/*", "dica/C/request/*", "d$*/C/request/**", "**"):
            decls.append(s.declare_queryable(key, fake_answer))
        for key in ("sim/C/alive/agent-9", "dica/C/alive/ica", "*/C/alive/*", "sim/C/alive/**"):
            tokens.append(s.liveliness().declare_token(key))
        k = 10**6
        while not self.stop.wait(0.02):
            self.rounds += 1
            k += 1
            jump = encode(Clock(k, 1e6, "lockstep", 1.0, False, now_ns()))
            end = encode(Clock(k, 0.1, "lockstep", 1.0, True, now_ns()))
            for key in ("sim/C/clock", "*/C/clock", "sim/C/cl$*", "**"):
                for body in (jump, end, seal.seal(jump), seal.seal(end)):
                    s.put(key, body)
            plan = Setpoint("v00001", 9, 0.0, _f(range(0, 400, 2)), -1e9, False)
            order = encode(Command("agent-1", k, 0, (plan,), now_ns()))
            s.put("sim/C/command/agent-1", order)
            s.put("sim/C/command/agent-1", seal.seal(order))
            s.put("sim/C/state/agent-1", seal.seal(encode(State("agent-1", k, 0, 1.0, (), 1))))
            s.put("dica/C/confirmed/v00001", seal.seal(encode(Response(
                "v00001", 9, "x", _f([0.0]), _f([0.0]), _f([0.0]), _f([0.0]), 0.0, 1.0, 0.0, 1,
                now_ns()))))  # fmt: skip
            # its own key, its own seal, but other vehicles: the ICA knows whose they are
            for n in range(0, 40):
                cancel = seal.seal(encode(Cancel(f"v{n:05d}", 2**31 - 1, now_ns())))
                s.get("dica/C/cancel/agent-2", payload=cancel, timeout=0.5)
        for d in decls:
            d.undeclare()
        for t in tokens:
            t.undeclare()
        s.close()


def _f(xs):
    import numpy as np

    return np.asarray(list(xs) if not isinstance(xs, bytes) else np.frombuffer(xs), float)


def _secured_run_under_attack(out: Path, router_rules: bool) -> tuple[dict, Attacker]:
    port = free_port()
    cmd = ["bash", "tools/run_cluster.sh", "--out", str(out), "--secure", "--agents", "2"]
    cmd += ["--port", str(port), "--no-record", *COMMON]
    if not router_rules:
        cmd.append("--no-router-rules")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, start_new_session=True)  # fmt: skip
    attacker = None
    try:
        log = out / "logs" / "gateway.log"
        deadline = time.monotonic() + 120
        while not (log.exists() and "ICA and 2 agents up" in log.read_text()):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.1)
        attacker = Attacker(out / "zenoh", f"tls/127.0.0.1:{port}")
        attacker.start()
        try:
            stdout, stderr = proc.communicate(timeout=300)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the run did not end in 300 s\n{logs_tail(out)}")
    finally:
        if attacker is not None:
            attacker.stop.set()
            attacker.join(10)
        stop_cluster(proc)
    assert proc.returncode == 0, stdout + stderr
    assert attacker.error is None, attacker.error
    assert attacker.rounds > 10  # it really kept at it (some 50 rounds in a 2 s run)
    return json.loads((out / "metrics.json").read_text()), attacker


@pytest.fixture(scope="module")
def embedded(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("emb")
    p = dica_run([*DICA, "run", *COMMON, "--out", str(out), "--quiet"],
                       capture_output=True, text=True, cwd=ROOT, timeout=300)  # fmt: skip
    assert p.returncode == 0, p.stderr
    return out


def _unharmed(m: dict, out: Path, embedded: Path) -> None:
    assert m["complete"] is True
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["accounted"]["lost"] == 0
    # lockstep: the attack changed no decision at all
    assert (out / "vehicles.csv").read_text() == (embedded / "vehicles.csv").read_text()
    # agent-2's credentials could not steer agent-1's vehicles: the ICA refused
    assert m["roles"]["ica"]["not_theirs"] > 0


def test_the_router_stops_a_stolen_agent_login_and_says_so(tmp_path, embedded):
    out = tmp_path / "on"
    m, attacker = _secured_run_under_attack(out, router_rules=True)
    _unharmed(m, out, embedded)
    assert attacker.answered == 0  # no REQUEST ever reached its impostor queryables
    router = (out / "logs" / "router.log").read_text()
    for what in ("Put (ingress) on sim/C/clock", "Put (ingress) on */C/clock",
                 "Declare Queryable (ingress) on */C/request/*",
                 "Put (ingress) on sim/C/command/agent-1"):  # fmt: skip
        assert f"refused agent-2: {what}" in router, what


def test_with_the_router_s_rules_off_every_role_still_refuses_what_is_not_sealed_by_its_writer(
    tmp_path, embedded
):
    out = tmp_path / "off"
    m, attacker = _secured_run_under_attack(out, router_rules=False)
    _unharmed(m, out, embedded)
    # this time the forgeries reached the roles, and each refused them
    assert attacker.answered > 0  # its impostor queryables did get REQUESTs
    assert sum(m["refused_unsealed"].values()) > 0  # the gateway: forged commands
    agents = m["roles"]["agents"]
    assert all(sum(a["refused_unsealed"].values()) > 0 for a in agents.values())
    assert sum(a["bad_replies"] for a in agents.values()) > 0  # the impostor's answers
    assert sum(m["roles"]["ica"]["refused_unsealed"].values()) > 0  # forged clocks
    assert m["fake_tokens"] > 0  # agent-9, and wildcard tokens, were not agents
