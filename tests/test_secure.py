"""A secured site (`dica secure-config`, `run_cluster.sh --secure`), on a real
Zenoh router process on loopback:

* its files are readable by their owner only and never silently replaced;
* only the site's clients get in: TLS with the site's CA, and the right
  user and password (another site's, a guessed one, plain TCP: refused);
* the router's certificate names the hosts it was made for;
* each role writes only what it owns: a vehicle cannot answer other vehicles
  as the ICA, publish confirmations, the clock or vehicle states, or hold the
  ICA's liveliness token; the gateway and the observer cannot ask the ICA for
  reservations; the observer only listens;
* the whole cluster runs under it and makes the embedded run's decisions.
"""

from __future__ import annotations

import base64
import contextlib
import json
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from tests.test_cluster import DICA, ROOT, _cluster, _embedded, _same_decisions
from tools.loopback import router
from tools.secure import FILES, SecureConfigError, write_secure_configs

J = "C"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Iterator[tuple[dict[str, Path], str]]:
    """Generated configs and a router process started from them."""
    paths = write_secure_configs(tmp_path_factory.mktemp("site") / "zenoh")
    with router(paths["router.json5"], scheme="tls") as endpoint:
        yield paths, endpoint


def _open(path: Path, endpoint: str, **override: object) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(path))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("connect/timeout_ms", "3000")
    for key, value in override.items():
        conf.insert_json5(key, json.dumps(value))
    return zenoh.open(conf)


@contextlib.contextmanager
def _sessions(paths: dict[str, Path], endpoint: str, *roles: str) -> Iterator[list]:
    opened = [_open(paths[f"{r}.json5"], endpoint) for r in roles]
    try:
        yield opened
    finally:
        for s in opened:
            s.close()


def test_configs_are_private_and_never_silently_replaced(tmp_path):
    paths = write_secure_configs(tmp_path / "z")
    assert stat.S_IMODE((tmp_path / "z").stat().st_mode) == 0o700
    for name in FILES:
        assert stat.S_IMODE(paths[name].stat().st_mode) == 0o600, name
    users = paths["users.txt"].read_text().split()
    assert [u.split(":")[0] for u in users] == ["ica", "gateway", "agent", "observer"]
    assert len({u.split(":")[1] for u in users}) == 4  # one password per role
    with pytest.raises(SecureConfigError, match="--force"):
        write_secure_configs(tmp_path / "z")
    assert paths["users.txt"].read_text().split() == users  # untouched
    write_secure_configs(tmp_path / "z", force=True)
    assert paths["users.txt"].read_text().split() != users  # fresh passwords


def test_secure_config_command_is_one_clear_line_when_it_refuses(tmp_path):
    run = [*DICA, "secure-config", "--out", str(tmp_path / "z")]
    first = subprocess.run(run, capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert first.returncode == 0 and "--zenoh-config" in first.stdout
    again = subprocess.run(run, capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert again.returncode == 2
    assert "already holds" in again.stderr and "Traceback" not in again.stderr


def test_only_the_site_s_clients_get_in(site, tmp_path):
    paths, endpoint = site
    other = write_secure_configs(tmp_path / "other")  # another site: its CA, its passwords
    no_ca = {"transport/link/tls/root_ca_certificate_base64": None}
    for path, override in (
        (paths["agent.json5"], {"transport/auth/usrpwd/password": "guess"}),
        (paths["agent.json5"], {"transport/auth/usrpwd/user": "root"}),
        (paths["agent.json5"], no_ca),  # the right password, but cannot trust the router
        (other["agent.json5"], {}),
        (ROOT / "deploy" / "zenoh" / "client.json5", {}),  # no credentials at all
    ):
        with pytest.raises(zenoh.ZError):
            _open(path, endpoint, **override).close()
    _open(paths["agent.json5"], endpoint).close()  # the site's own can
    with pytest.raises(zenoh.ZError):  # and only over TLS
        _open(paths["agent.json5"], endpoint.replace("tls/", "tcp/")).close()


def test_the_router_certificate_names_the_given_hosts(tmp_path):
    from cryptography import x509

    paths = write_secure_configs(tmp_path / "z", hosts=("10.0.0.1", "rsu.example"))
    conf = json.loads(paths["agent.json5"].read_text().split("\n", 1)[1])
    assert conf["connect"]["endpoints"] == ["tls/10.0.0.1:7447"]
    router_conf = json.loads(paths["router.json5"].read_text().split("\n", 1)[1])
    pem = base64.b64decode(router_conf["transport"]["link"]["tls"]["listen_certificate_base64"])
    names = x509.load_pem_x509_certificate(pem).extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    )
    assert [str(n.value) for n in names.value] == ["10.0.0.1", "rsu.example"]
    with pytest.raises(SecureConfigError, match="neither an IP address nor a host name"):
        write_secure_configs(tmp_path / "y", hosts=("a b",))


def test_a_client_left_outside_says_where_it_waits(site, tmp_path):
    """With timeout_ms -1 a refused client waits; its log says where and why."""
    paths, endpoint = site
    bad = tmp_path / "bad.json5"
    conf = zenoh.Config.from_file(str(paths["agent.json5"]))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps("guess"))
    bad.write_text(str(conf))
    code = (
        "import sys; from schemas.link import open_session; "
        "open_session(sys.argv[1], sys.argv[2], waiting_note_s=0.5)"
    )
    with pytest.raises(subprocess.TimeoutExpired) as waited:
        subprocess.run(
            [sys.executable, "-c", code, str(bad), endpoint],
            capture_output=True, text=True, cwd=ROOT, timeout=4,
        )  # fmt: skip
    err = waited.value.stderr
    err = err.decode() if isinstance(err, bytes) else err or ""
    assert f"no router at {endpoint} has let this client in" in err
    assert str(bad) in err


class _Heard:
    """Everything one session hears under a key expression, thread-safe."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: list[tuple[str, bytes]] = []

    def cb(self, sample) -> None:
        with self.lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def wait_for(self, key: str, timeout: float = 5.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if any(k == key for k, _ in self.items):
                    return
            time.sleep(0.02)
        raise AssertionError(f"never heard {key}")

    def heard_keys(self) -> set[str]:
        with self.lock:
            return {k for k, _ in self.items}


def _until(ready, timeout: float = 15.0) -> None:
    """Wait until ``ready()`` is truthy: declarations take a moment to reach the router."""
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() > deadline:
            raise AssertionError("the router never saw the declarations")
        time.sleep(0.1)


def _answers(session, key: str) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(key, timeout=1.5) if r.ok is not None]


def test_only_the_ica_answers_and_only_vehicles_ask(site):
    paths, endpoint = site
    roles = ("ica", "agent", "observer", "gateway", "agent", "observer", "gateway")
    with _sessions(paths, endpoint, *roles) as (ica, *impostors, vehicle, observer, gateway):
        decls = [ica.declare_queryable(f"dica/{J}/request", lambda q: q.reply(q.key_expr, b"ica"))]
        for i, s in enumerate(impostors):
            answer = f"impostor {i}".encode()
            decls.append(
                s.declare_queryable(f"dica/{J}/request", lambda q, a=answer: q.reply(q.key_expr, a))
            )
        _until(lambda: _answers(vehicle, f"dica/{J}/request"))  # declarations have spread
        for _ in range(5):  # whichever queryable the router would pick, only the ICA's
            assert _answers(vehicle, f"dica/{J}/request") == [b"ica"]
        # a session's own queryable would answer it locally: these two have none
        assert _answers(gateway, f"dica/{J}/request") == []  # no reservations but vehicles'
        assert _answers(observer, f"dica/{J}/request") == []
        for d in decls:
            d.undeclare()


def test_each_role_publishes_only_what_it_owns(site):
    paths, endpoint = site
    with _sessions(paths, endpoint, "ica", "gateway", "agent", "observer", "observer") as (
        ica, gateway, agent, observer, listener,
    ):  # fmt: skip
        heard = _Heard()
        subs = [listener.declare_subscriber(k, heard.cb) for k in ("dica/**", "sim/**")]

        def probe() -> bool:  # the subscriptions have reached the router
            gateway.put(f"sim/{J}/vehicles", b"ok")
            return f"sim/{J}/vehicles" in heard.heard_keys()

        _until(probe)
        forbidden = {
            agent: [f"dica/{J}/confirmed/v1", f"sim/{J}/clock", f"sim/{J}/vehicles",
                    f"sim/{J}/state/agent-1"],
            gateway: [f"dica/{J}/confirmed/v2", f"dica/{J}/ack/v2", f"sim/{J}/command/agent-1"],
            observer: [f"dica/{J}/ack/v3", f"sim/{J}/command/agent-1", f"sim/{J}/clock"],
            ica: [f"sim/{J}/clock", f"sim/{J}/command/agent-1"],
        }  # fmt: skip
        allowed = {
            agent: [f"dica/{J}/ack/v1", f"sim/{J}/command/agent-1"],
            gateway: [f"sim/{J}/clock", f"sim/{J}/vehicles", f"sim/{J}/state/agent-1"],
            ica: [f"dica/{J}/confirmed/v4"],
        }
        for s, ks in forbidden.items():
            for k in ks:
                s.put(k, b"forged")
        for s, ks in allowed.items():
            for k in ks:
                s.put(k, b"ok")
        for ks in allowed.values():
            for k in ks:
                heard.wait_for(k)
        time.sleep(0.5)  # time for anything forged to arrive, had it been let through
        assert all(p == b"ok" for _, p in heard.items), heard.items
        for s in subs:
            s.undeclare()


def test_nobody_holds_another_role_s_liveliness_token(site):
    paths, endpoint = site
    with _sessions(paths, endpoint, "ica", "agent", "observer", "gateway") as (
        ica, agent, observer, gateway,
    ):  # fmt: skip
        tokens = [
            agent.liveliness().declare_token(f"dica/{J}/alive/ica"),
            observer.liveliness().declare_token(f"sim/{J}/alive/agent-9"),
            gateway.liveliness().declare_token(f"sim/{J}/observer/fake"),
            agent.liveliness().declare_token(f"sim/{J}/alive/agent-1"),  # its own: allowed
            observer.liveliness().declare_token(f"sim/{J}/observer/main"),  # its own: allowed
        ]

        def alive(key: str) -> list[str]:
            replies = ica.liveliness().get(key, timeout=1.5)
            return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

        _until(lambda: alive(f"sim/{J}/observer/**") and alive(f"sim/{J}/alive/**"))

        assert alive(f"dica/{J}/alive/**") == []
        assert alive(f"sim/{J}/alive/**") == [f"sim/{J}/alive/agent-1"]
        assert alive(f"sim/{J}/observer/**") == [f"sim/{J}/observer/main"]
        for t in tokens:
            t.undeclare()


def test_the_cluster_runs_secured_and_makes_the_embedded_decisions(tmp_path):
    common = ["--volume", "500", "--duration", "60", "--seed", "21"]
    p = _cluster(tmp_path / "cl", "--secure", "--agents", "2", *common)
    assert p.returncode == 0, p.stdout + p.stderr
    out = tmp_path / "cl"
    assert stat.S_IMODE((out / "zenoh" / "users.txt").stat().st_mode) == 0o600
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["crossed"] > 10
    _embedded(tmp_path / "emb", common)
    _same_decisions(out, tmp_path / "emb")
