"""A secured site (`dica secure-config`, `run_cluster.sh --secure`), on a real
Zenoh router process on loopback:

* its files are readable by their owner only and never silently replaced;
  agents are issued and revoked in place;
* only the site's clients get in: TLS with the site's CA, and the right
  user and password (another site's, a guessed one, plain TCP: refused); a
  revoked agent once the router has restarted;
* the router's certificate names the hosts it was made for;
* every role may do what the key table gives it (docs/deploy.md), and
  nothing else: every role as attacker, every action, on the exact keys of
  others, on every wildcard form that intersects them and on keys outside
  the project's space, is refused; the very same attempts get through the
  same router with its access control off; nobody deletes;
* an agent's credentials cannot steer another agent's vehicles.
"""

from __future__ import annotations

import base64
import json
import os
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from dica.deploy.site import (
    FILES,
    SecureConfigError,
    add_agents,
    revoke_agents,
    site_agents,
    write_secure_configs,
)
from dica.tools.loopback import (
    ACTIONS,
    Attempt,
    Inconclusive,
    client,
    free_port,
    got_through,
    router,
    tried,
)
from tests.test_cluster import DICA, ROOT, _cluster, _embedded, _same_decisions

J = "C"  # the junction under attack
D = "D"  # where owners hold control tokens: a witness sees a token's key, not its holder
A, B = "agent-1", "agent-2"  # the victim agent, and the agent that attacks it
USERS = ("ica", "gateway", "observer", A, B)
ATTACKERS = ("ica", "gateway", "observer", B)


# -- the site's files -------------------------------------------------------------------
def test_configs_are_private_and_never_silently_replaced(tmp_path):
    paths = write_secure_configs(tmp_path / "z", agents=2)
    assert stat.S_IMODE((tmp_path / "z").stat().st_mode) == 0o700
    assert set(paths) == {
        *FILES,
        "ica.json5",
        "ica.seal",
        *(f"{x}.{e}" for x in (A, B) for e in ("json5", "seal")),
    }
    for path in paths.values():
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path.name
    users = paths["users.txt"].read_text().split()
    assert [u.split(":")[0] for u in users] == ["ica", "gateway", "observer", A, B]
    assert len({u.split(":")[1] for u in users}) == 5  # one password each
    with pytest.raises(SecureConfigError, match="--force"):
        write_secure_configs(tmp_path / "z")
    assert paths["users.txt"].read_text().split() == users  # untouched
    write_secure_configs(tmp_path / "z", force=True, agents=["car-17"])
    assert paths["users.txt"].read_text().split() != users  # fresh passwords
    assert site_agents(tmp_path / "z") == ("car-17",)
    assert not paths[f"{A}.json5"].exists()  # the earlier site's agents are gone with it
    assert not paths[f"{A}.seal"].exists()
    assert set(json.loads(paths["keyring.json"].read_text())) == {"ica", "gateway", "car-17"}


def test_agents_are_issued_and_revoked_in_place(tmp_path):
    out = tmp_path / "z"
    write_secure_configs(out, agents=["car-17", "car-18"])
    before = {p.name: p.read_text() for p in out.iterdir()}
    added = add_agents(out, "car-19")
    assert stat.S_IMODE(added["car-19"].stat().st_mode) == 0o600
    assert site_agents(out) == ("car-17", "car-18", "car-19")
    for name in ("ica.json5", "car-17.json5", "ca.pem"):  # nothing deployed changes
        assert (out / name).read_text() == before[name]
    with pytest.raises(SecureConfigError, match="already has agent car-19"):
        add_agents(out, ["car-19"])
    assert "car-19" in json.loads((out / "keyring.json").read_text())  # it may seal now
    assert revoke_agents(out, "car-17") == ("car-18", "car-19")
    assert not (out / "car-17.json5").exists()
    assert not (out / "car-17.seal").exists()
    keyring = json.loads((out / "keyring.json").read_text())
    assert "car-17" not in keyring and "car-18" in keyring  # its seal opens nothing any more
    assert "car-17" not in (out / "router.json5").read_text()  # no rules left for it
    router_tls = json.loads(before["router.json5"].split("\n", 2)[2])["transport"]["link"]["tls"]
    now = json.loads((out / "router.json5").read_text().split("\n", 2)[2])
    assert now["transport"]["link"]["tls"] == router_tls  # the same key: clients still trust it
    users = (out / "users.txt").read_text()
    assert before["users.txt"].split("\n")[4] in users  # car-18 keeps its password
    for path in out.iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path.name
    with pytest.raises(SecureConfigError, match="has no agent car-17"):
        revoke_agents(out, ["car-17"])
    for bad in ("ica", "a:b", "-x", "a/b"):
        with pytest.raises(SecureConfigError, match="agent name"):
            add_agents(out, [bad])
    with pytest.raises(SecureConfigError, match="no site"):
        add_agents(tmp_path / "nowhere", ["car-20"])


def test_secure_config_command_is_one_clear_line_when_it_refuses(tmp_path):
    def dica(*args: str) -> subprocess.CompletedProcess:
        run = [*DICA, "secure-config", "--out", str(tmp_path / "z"), *args]
        return subprocess.run(run, capture_output=True, text=True, cwd=ROOT, timeout=60)

    first = dica("--agents", "2")
    assert first.returncode == 0 and "--zenoh-config" in first.stdout
    assert f"--id {B}" in first.stdout
    for args, says in (
        ((), "already holds"),
        (("--revoke-agent", "car-9"), "has no agent car-9"),
        (("--add-agent", "car-9", "--host", "10.0.0.1"), "make a new site"),
        (("--agents", "a b", "--force"), "agent name"),
        (("--junction", "C/D", "--force"), "cannot be part of a key"),
    ):
        again = dica(*args)
        assert again.returncode == 2, args
        assert says in again.stderr and "Traceback" not in again.stderr
        assert len(again.stderr.strip().splitlines()) == 1
    added = dica("--add-agent", "car-9")
    assert added.returncode == 0 and "restart the router" in added.stdout
    revoked = dica("--revoke-agent", "car-9")
    assert revoked.returncode == 0 and "restart the router" in revoked.stdout


def test_the_router_certificate_names_the_given_hosts(tmp_path):
    from cryptography import x509

    paths = write_secure_configs(tmp_path / "z", hosts=("10.0.0.1", "rsu.example"))
    conf = json.loads(paths[f"{A}.json5"].read_text().split("\n", 2)[2])
    assert conf["connect"]["endpoints"] == ["tls/10.0.0.1:7447"]
    router_conf = json.loads(paths["router.json5"].read_text().split("\n", 2)[2])
    pem = base64.b64decode(router_conf["transport"]["link"]["tls"]["listen_certificate_base64"])
    names = x509.load_pem_x509_certificate(pem).extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    )
    assert [str(n.value) for n in names.value] == ["10.0.0.1", "rsu.example"]
    with pytest.raises(SecureConfigError, match="neither an IP address nor a host name"):
        write_secure_configs(tmp_path / "y", hosts=("a b",))


# -- who gets in ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Iterator[tuple[Path, str]]:
    """A site with agents agent-1 and agent-2 at junctions C and D, and its router running."""
    out = tmp_path_factory.mktemp("site") / "zenoh"
    write_secure_configs(out, agents=[A, B], junctions=[J, D])
    with router(out / "router.json5", scheme="tls") as endpoint:
        yield out, endpoint


def test_only_the_site_s_clients_get_in(site, tmp_path):
    out, endpoint = site
    other = write_secure_configs(tmp_path / "other", agents=[A])  # its CA, its passwords
    no_ca = {"transport/link/tls/root_ca_certificate_base64": None}
    soon = {"connect/timeout_ms": 1000}  # a refused client retries until then
    for path, override in (
        (out / f"{A}.json5", {"transport/auth/usrpwd/password": "guess"}),
        (out / f"{A}.json5", {"transport/auth/usrpwd/user": "root"}),
        (out / f"{A}.json5", {"transport/auth/usrpwd/user": B}),  # its password, not B's
        (out / f"{A}.json5", no_ca),  # the right password, but cannot trust the router
        (other[f"{A}.json5"], {}),
        (ROOT / "deploy" / "zenoh" / "client.json5", {}),  # no credentials at all
    ):
        with pytest.raises(zenoh.ZError):
            client(path, endpoint, **override, **soon).close()
    client(out / f"{A}.json5", endpoint).close()  # the site's own can
    with pytest.raises(zenoh.ZError):  # and only over TLS
        client(out / f"{A}.json5", endpoint.replace("tls/", "tcp/"), **soon).close()


def test_a_client_left_outside_says_where_it_waits(site, tmp_path):
    """With timeout_ms -1 a refused client waits; its log says where and why."""
    out, endpoint = site
    bad = tmp_path / "bad.json5"
    conf = zenoh.Config.from_file(str(out / f"{A}.json5"))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps("guess"))
    bad.write_text(str(conf))
    code = (
        "import sys; from dica.deploy.transport import open_session; "
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


def test_a_revoked_agent_is_refused_once_the_router_restarts(tmp_path):
    """The router reads its users and rules at start only: revoking (or adding)
    takes effect when it restarts, and then holds even for a session opened before,
    while the others' sessions come back by themselves."""
    out = tmp_path / "z"
    write_secure_configs(out, agents=[A, B])
    kept = tmp_path / "stolen.json5"  # B's file, as a thief would keep it
    kept.write_text((out / f"{B}.json5").read_text())
    endpoint = f"tls/127.0.0.1:{free_port()}"
    with router(out / "router.json5", endpoint=endpoint):
        s = {u: client(out / f"{u}.json5", endpoint) for u in ("gateway", A)}
        held = client(kept, endpoint)  # a session B opened before it was revoked
        revoke_agents(out, [B])
        add_agents(out, ["car-9"])
        client(kept, endpoint).close()  # not yet: the router has not read the change
        with pytest.raises(zenoh.ZError):
            client(out / "car-9.json5", endpoint, **{"connect/timeout_ms": 1000}).close()
    try:
        with router(out / "router.json5", endpoint=endpoint):
            with pytest.raises(zenoh.ZError):
                client(kept, endpoint, **{"connect/timeout_ms": 1000}).close()
            client(out / "car-9.json5", endpoint).close()
            # B's old session does not come back: its command never reaches the gateway,
            # while A's, from a session also opened before the restart, does
            command = Attempt(
                "put", f"sim/{J}/command/{B}", s["gateway"], f"sim/{J}/command/*",
                s[A], f"sim/{J}/command/{A}",
            )  # fmt: skip
            assert not got_through(held, command)
    finally:
        for session in (held, *s.values()):
            session.close()


# -- what each role may do --------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Use:
    """One use of a key that the key table gives to ``allowed`` users: ``owner``
    does it on ``owner_key`` and ``witness`` is at the other end (see
    tools.loopback.Attempt). ``serve``: where a user answers from, for replies."""

    action: str
    key: str
    allowed: tuple[str, ...]
    witness: str
    witness_key: str
    owner: str
    owner_key: str
    serve: tuple[tuple[str, str], ...] = ()


def _uses() -> tuple[Use, ...]:
    req, stats = f"dica/{J}/request/{A}", f"sim/{J}/stats/{A}"
    uses = [
        # puts: the owner publishes, the witness subscribes
        Use("put", f"sim/{J}/clock", ("gateway",), A, f"sim/{J}/clock", "gateway", ""),
        Use("put", f"sim/{J}/state/{A}", ("gateway",), A, f"sim/{J}/state/{A}", "gateway", ""),
        Use("put", f"sim/{J}/vehicles", ("gateway",), "observer", f"sim/{J}/vehicles",
            "gateway", ""),
        Use("put", f"dica/{J}/confirmed/v7", ("ica",), "observer", f"dica/{J}/confirmed/*",
            "ica", ""),
        Use("put", f"dica/{J}/revoke/{A}", ("ica",), A, f"dica/{J}/revoke/{A}", "ica", ""),
        Use("put", f"dica/{J}/reorder", ("ica",), "observer", f"dica/{J}/reorder", "ica", ""),
        Use("put", f"dica/{J}/greens/h7", ("ica",), "observer", f"dica/{J}/greens/*",
            "ica", ""),
        Use("put", f"dica/{J}/ack/{A}", (A,), "ica", f"dica/{J}/ack/*", A, ""),
        Use("put", f"sim/{J}/command/{A}", (A,), "gateway", f"sim/{J}/command/*", A, ""),
        # subscriptions: the owner subscribes, the witness publishes
        Use("subscribe", f"sim/{J}/clock", ("ica", A, B, "observer"), "gateway", "", A, ""),
        Use("subscribe", f"sim/{J}/state/{A}", (A,), "gateway", "", A, ""),
        Use("subscribe", f"sim/{J}/vehicles", ("ica", "observer"), "gateway", "", "observer", ""),
        Use("subscribe", f"dica/{J}/confirmed/v7", ("observer", A, B), "ica", "", "observer",
            f"dica/{J}/confirmed/*"),
        Use("subscribe", f"dica/{J}/revoke/{A}", (A, "gateway"), "ica", "", A, ""),
        Use("subscribe", f"dica/{J}/reorder", ("observer",), "ica", "", "observer", ""),
        Use("subscribe", f"dica/{J}/greens/h7", ("observer",), "ica", "", "observer",
            f"dica/{J}/greens/*"),
        Use("subscribe", f"dica/{J}/ack/{A}", ("ica",), A, "", "ica", f"dica/{J}/ack/*"),
        Use("subscribe", f"sim/{J}/command/{A}", ("gateway",), A, "", "gateway",
            f"sim/{J}/command/*"),
        # queryables: the owner serves, the witness asks
        *(Use("queryable", f"dica/{J}/{k}/{A}", ("ica",), A, "", "ica", f"dica/{J}/{k}/*")
          for k in ("request", "detect", "cancel")),
        Use("queryable", f"dica/{J}/stats", ("ica",), "gateway", "", "ica", ""),
        Use("queryable", stats, (A,), "gateway", f"sim/{J}/stats/*", A, ""),
        Use("queryable", f"dica/{J}/walk/gateway", ("ica",), "gateway", "", "ica",
            f"dica/{J}/walk/*"),
        Use("queryable", f"dica/{J}/human/gateway", ("ica",), "gateway", "", "ica",
            f"dica/{J}/human/*"),
        Use("queryable", f"dica/{J}/ev/gateway", ("ica",), "gateway", "", "ica",
            f"dica/{J}/ev/*"),
        # queries: the owner asks, the witness serves
        *(Use("query", f"dica/{J}/{k}/{A}", (A,), "ica", f"dica/{J}/{k}/*", A, "")
          for k in ("request", "detect", "cancel")),
        Use("query", f"dica/{J}/stats", ("gateway",), "ica", "", "gateway", ""),
        Use("query", f"dica/{J}/walk/gateway", ("gateway",), "ica", f"dica/{J}/walk/*",
            "gateway", ""),
        Use("query", f"dica/{J}/human/gateway", ("gateway",), "ica", f"dica/{J}/human/*",
            "gateway", ""),
        Use("query", f"dica/{J}/ev/gateway", ("gateway",), "ica", f"dica/{J}/ev/*",
            "gateway", ""),
        Use("query", stats, ("gateway",), A, "", "gateway", f"sim/{J}/stats/*"),
        # replies travel back on the asked key: answering on another is refused
        Use("reply", stats, (A,), "gateway", f"sim/{J}/stats/*", A, "",
            serve=((B, f"sim/{J}/stats/{B}"),)),
        Use("reply", req, ("ica",), A, "", "ica", f"dica/{J}/request/*",
            serve=(("ica", f"dica/{J}/request/*"),)),
        # liveliness tokens: the owner holds one (at junction D), the witness lists both
        Use("token", f"dica/{J}/alive/ica", ("ica",), "gateway", "", "ica",
            f"dica/{D}/alive/ica"),
        Use("token", f"sim/{J}/alive/{A}", (A,), "gateway", f"sim/{J}/alive/*", A,
            f"sim/{D}/alive/{A}"),
        Use("token", f"sim/{J}/observer/main", ("observer",), "gateway", f"sim/{J}/observer/*",
            "observer", f"sim/{D}/observer/main"),
    ]  # fmt: skip
    for action in ("watch", "alive_query"):  # the witness holds a token, the owner watches
        uses += [
            Use(action, f"dica/{J}/alive/ica", ("gateway", A, B, "observer"), "ica", "", A, ""),
            Use(action, f"sim/{J}/alive/{A}", ("ica", "gateway"), A, "", "gateway",
                f"sim/{J}/alive/*"),
            Use(action, f"sim/{J}/observer/main", ("gateway",), "observer", "", "gateway",
                f"sim/{J}/observer/*"),
        ]  # fmt: skip
    return tuple(
        Use(u.action, u.key, u.allowed, u.witness, u.witness_key or u.key, u.owner,
            u.owner_key or u.key, u.serve)
        for u in uses
    )  # fmt: skip


USES = _uses()
OUTSIDE = ("elsewhere/C/clock", "dica", f"sim/{J}")  # keys in no rule, none of the project's


def forms(key: str) -> list[str]:
    """``key`` and every way of naming it with wildcards: a chunk as ``*``, ``$*``
    inside a chunk, broader prefixes, ``**``."""
    c = key.split("/")
    return list(
        dict.fromkeys([
            key,
            "/".join(["*", *c[1:]]),  # */C/clock
            "/".join([c[0], "*", *c[2:]]),  # sim/*/clock: every junction
            "/".join([*c[:-1], "*"]),  # sim/C/state/*: every agent's
            "/".join(["*"] * len(c)),  # */*/*
            "/".join([c[0][0] + "$*", *c[1:]]),  # d$*/C/request/agent-1
            "/".join([*c[:-1], c[-1][:2] + "$*"]),  # sim/C/cl$*
            f"{c[0]}/**",
            f"{c[0]}/{c[1]}/**",
            "**",
        ])
    )  # fmt: skip


def _attempts(cast: dict, role: str, action: str) -> list[Attempt]:
    """Everything ``role`` must not do with ``action``: each use it is not given,
    in every form; for a reply, every key but the asked one; keys outside."""
    seen: set[str] = set()
    out = []
    for u in USES:
        if u.action != action:
            continue
        keys = forms(u.key)
        if role in u.allowed:
            if action != "reply":
                continue
            keys = keys[1:]
        serve = dict(u.serve).get(role, u.key)
        for key in keys:
            if key not in seen:  # a token is known by its key: one attempt per key
                seen.add(key)
                out.append(
                    Attempt(action, key, cast[u.witness], u.witness_key, cast[u.owner],
                            u.owner_key, serve_key=serve)
                )  # fmt: skip
    if action != "reply":  # to reply, one must be asked first
        out += [Attempt(action, k, cast[role], k) for k in OUTSIDE]  # even to itself
    return out


def _own(cast: dict, role: str, action: str) -> list[Attempt]:
    """What ``role`` is given: each use it is allowed, on the key it uses."""
    out = []
    for u in USES:
        if u.action == action and role in u.allowed:
            mine = u.owner_key if role == u.owner else u.key
            key = u.key if action in ("token", "reply") else mine
            serve = dict(u.serve).get(role, mine)
            out.append(
                Attempt(action, key, cast[u.witness], u.witness_key, cast[u.owner],
                        u.owner_key, serve_key=serve)
            )  # fmt: skip
    return out


@pytest.fixture(scope="module")
def cast(site) -> Iterator[tuple[dict, dict]]:
    """Every user's session doing its part, and a second session each to attack with."""
    out, endpoint = site
    yield from _cast(out, endpoint)


@pytest.fixture(scope="module")
def open_cast(site, tmp_path_factory) -> Iterator[tuple[dict, dict]]:
    """The same users on the same kind of router, with its access control off."""
    out, _ = site
    conf = json.loads((out / "router.json5").read_text().split("\n", 2)[2])
    conf["access_control"]["enabled"] = False
    path = tmp_path_factory.mktemp("open") / "router.json5"
    path.write_text(json.dumps(conf))
    os.chmod(path, 0o600)
    with router(path, scheme="tls") as endpoint:
        yield from _cast(out, endpoint)


def _cast(out: Path, endpoint: str) -> Iterator[tuple[dict, dict]]:
    sessions = {u: client(out / f"{u}.json5", endpoint) for u in USERS}
    attackers = {u: client(out / f"{u}.json5", endpoint) for u in USERS}
    try:
        yield sessions, attackers
    finally:
        for s in (*sessions.values(), *attackers.values()):
            s.close()


def _cases(roles: tuple[str, ...], pick) -> list:
    return [pytest.param(r, a, id=f"{r}-{a}") for r in roles for a in ACTIONS if pick(r, a)]


@pytest.mark.parametrize(
    "role, action", _cases(USERS, lambda r, a: any(r in u.allowed for u in USES if u.action == a))
)
def test_every_role_may_do_its_part(cast, role, action):
    sessions, attackers = cast
    attempts = _own(sessions, role, action)
    refused = [
        a.key for a, ok in zip(attempts, tried(attackers[role], attempts), strict=True) if not ok
    ]
    assert refused == []


@pytest.mark.parametrize("role, action", _cases(ATTACKERS, lambda r, a: True))
def test_no_role_gets_past_its_rules(cast, role, action):
    sessions, attackers = cast
    attempts = _attempts(sessions, role, action)
    through = [
        a.key for a, ok in zip(attempts, tried(attackers[role], attempts), strict=True) if ok
    ]
    assert through == []


@pytest.mark.parametrize("role, action", _cases(ATTACKERS, lambda r, a: True))
def test_the_same_attempts_get_through_with_access_control_off(open_cast, role, action):
    """Each attempt above can fail: without the rules, it gets through. (One not through
    yet is tried again, waiting longer: an attempt with no owner of its own is judged
    once the others' owners got through, and a token may still be on its way then.)"""
    sessions, attackers = open_cast
    left = _attempts(sessions, role, action)
    for settle_s in (0.3, 1.0, 2.0):
        got = tried(attackers[role], left, settle_s=settle_s)
        left = [a for a, ok in zip(left, got, strict=True) if not ok]
        if not left:
            break
    assert [a.key for a in left] == []


def test_an_agent_cannot_steer_or_pose_as_another(cast):
    """B's credentials, on A's command, request, state and liveliness keys: refused;
    on its own keys, let through."""
    s, attackers = cast
    b = attackers[B]

    def attempts(x: str) -> list[Attempt]:  # on x's keys; x's own session is the control
        return [
            Attempt("put", f"sim/{J}/command/{x}", s["gateway"], f"sim/{J}/command/*",
                    s[x], f"sim/{J}/command/{x}"),
            Attempt("query", f"dica/{J}/request/{x}", s["ica"], f"dica/{J}/request/*",
                    s[x], f"dica/{J}/request/{x}"),
            Attempt("subscribe", f"sim/{J}/state/{x}", s["gateway"], f"sim/{J}/state/{x}",
                    s[x], f"sim/{J}/state/{x}"),
            Attempt("token", f"sim/{J}/alive/{x}", s["gateway"], f"sim/{J}/alive/*",
                    s[x], f"sim/{D}/alive/{x}"),
        ]  # fmt: skip

    assert [got_through(b, a) for a in attempts(A)] == [False] * 4
    assert [got_through(b, a) for a in attempts(B)] == [True] * 4


def test_the_gateway_hears_an_agent_s_token_go(cast):
    """The gateway stops a run when an agent dies: the end of a token must get
    through the rules as its start does."""
    s, attackers = cast
    seen: list[str] = []
    put = zenoh.SampleKind.PUT
    watch = (
        s["gateway"]
        .liveliness()
        .declare_subscriber(
            f"sim/{J}/alive/*",
            lambda x: seen.append("+" if x.kind == put else "-"),
            history=True,  # as the gateway's: a token declared before it arrives still counts
        )
    )
    token = attackers[A].liveliness().declare_token(f"sim/{J}/alive/{A}")
    try:
        # an earlier test's token of the same agent may still be going as this one comes
        # (under load its end arrives late): what counts is the last word
        deadline = time.monotonic() + 10
        while not seen or seen[-1] != "+":
            assert time.monotonic() < deadline, f"the token never came: {seen}"
            time.sleep(0.02)
        time.sleep(0.2)
        assert seen[-1] == "+", seen
        came = len(seen)
        token.undeclare()
        token = None
        while seen[came:] != ["-"]:
            assert time.monotonic() < deadline, f"the token never went: {seen}"
            time.sleep(0.02)
    finally:
        watch.undeclare()
        if token is not None:
            token.undeclare()


@pytest.mark.parametrize("routed, heard", [("cast", ["PUT"]), ("open_cast", ["DELETE", "PUT"])])
def test_nobody_deletes_not_even_a_key_s_owner(request, routed, heard):
    """The gateway's clock: its puts arrive, its delete only with access control
    off; the put after the delete shows the delete had time to arrive."""
    s, attackers = request.getfixturevalue(routed)
    kinds: list[str] = []
    put = zenoh.SampleKind.PUT
    sub = s[A].declare_subscriber(
        f"sim/{J}/clock", lambda x: kinds.append("PUT" if x.kind == put else "DELETE")
    )
    try:
        deadline = time.monotonic() + 10
        while "PUT" not in kinds:  # the subscription is up
            assert time.monotonic() < deadline, "the clock never arrived"
            attackers["gateway"].put(f"sim/{J}/clock", b"tick")
            time.sleep(0.1)
        kinds.clear()
        attackers["gateway"].delete(f"sim/{J}/clock")
        attackers["gateway"].put(f"sim/{J}/clock", b"after")
        while "PUT" not in kinds and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
        assert kinds == heard
    finally:
        sub.undeclare()


def test_an_attempt_with_no_way_through_for_its_owner_says_so(cast):
    """The owner's own action is the control: if even it is refused, the helper
    says the attempt proves nothing instead of reporting a refusal."""
    s, attackers = cast
    wrong = Attempt("put", f"sim/{J}/clock", s[A], f"sim/{J}/clock", s["observer"],
                    f"sim/{J}/clock")  # fmt: skip
    with pytest.raises(Inconclusive, match="owners never got through"):
        got_through(attackers[B], wrong, timeout_s=1.0)


# -- the whole cluster ------------------------------------------------------------------
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
