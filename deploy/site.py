"""`dica secure-config`: the Zenoh configs of a secured site, with fresh secrets.

The router of ``deploy/zenoh/secure/router.json5`` speaks TLS only, makes
every client log in and refuses whatever its allow lists do not name (its
comments say why). Every vehicle agent has an identity of its own, so the
router can keep an agent to its own keys, and every rule names the site's
junctions exactly. This writes, into one directory
only its owner can read:

* ``users.txt``: one ``user:password`` line per role and per agent, random
  passwords;
* ``router.json5``: that router, with its TLS key and certificate inside,
  pointed at ``users.txt``, with one copy of the agent rules per agent; on a
  site of several roadside units (``rsus``), ``router-2.json5`` and so on: one
  router each, with a certificate of its own (common name ``rsu-<k>``), in a
  mesh (see :func:`_peer_rules`);
* ``ica.json5``, ``gateway.json5``, ``observer.json5`` and ``<agent>.json5``
  for each agent: the client config of each (``deploy/zenoh/client.json5``)
  with its credentials and the site's CA certificate inside, for
  ``--zenoh-config``;
* ``ca.pem``: that CA certificate, for other tools;
* ``site.json``: the junctions the site serves, for issuing agents later;
* ``ica.seal``, ``gateway.seal`` and ``<agent>.seal``: each writer's own
  signing key, and ``keyring.json``: every writer's public key, which every
  role checks what it acts on against (``--seal`` and ``--keyring``, see
  :mod:`dica.deploy.seal`): a message a role may not write is refused even if the
  router's rules let it through.

Each file stands alone: copy a role's file to the host that runs it. The
CA's private key signs the router's certificate and is then thrown away, so
nobody can issue another certificate this site's clients would trust. Agents
log in with a password rather than a client certificate for that reason:
issuing one more agent later needs no CA key, only a new line in
``users.txt`` and a new copy of the agent rules.

The router reads ``users.txt`` and its rules when it starts, and only then:
an added agent gets in, and a revoked one is refused, once it restarts.
"""

from __future__ import annotations

import base64
import copy
import datetime as dt
import ipaddress
import json
import os
import re
import secrets
from collections.abc import Sequence
from pathlib import Path

from dica.deploy import ZENOH_CONFIGS

ROUTER_TEMPLATE = ZENOH_CONFIGS / "secure" / "router.json5"
CLIENT_TEMPLATE = ZENOH_CONFIGS / "client.json5"
ROLES = ("ica", "gateway", "observer")  # one identity each; agents have one apiece
KEYRING = "keyring.json"
# every site's files; the ICA's (ica.json5 and ica.seal, or one pair per junction's ICA
# on a site of several junctions: see ica_users) besides
FILES = (
    "users.txt", "router.json5", "ca.pem", "site.json", KEYRING,
    "gateway.json5", "observer.json5", "gateway.seal",
)  # fmt: skip
AGENT = "@agent"  # the template's stand-ins (verbatim key chunks, which match no real key)
JUNCTION = "@j"
DEFAULT_HOSTS = ("127.0.0.1", "localhost")
DEFAULT_JUNCTIONS = ("C",)  # the built-in layouts' junction (sim_gateway.scenario)
PORT = 7447
MAX_RSUS = 64
# every kind of message a router passes on to another router of the mesh
PEER_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
)  # fmt: skip
# a key chunk (schemas/keys.py) without ':' (users.txt's separator), starting
# with a letter or digit so that it is a plain file name too
_AGENT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+\-]{0,63}$")
_RESERVED = {*ROLES, "router", "users", "ca"}


class SecureConfigError(Exception):
    """Why the configs were not written (one line for the user)."""


def ica_users(junctions: Sequence[str], own: bool = False) -> tuple[str, ...]:
    """The ICAs' identities: ``ica`` for them all, or (``own``) each junction's ICA its
    own (``ica-<J>``, :func:`schemas.keys.ica_name`), so the router keeps it to its own
    junction's keys and its seal is good for those only."""
    from dica.schemas.keys import ica_name

    return tuple(ica_name(j) for j in junctions) if own else ("ica",)


def site_roles(junctions: Sequence[str], own_icas: bool = False) -> tuple[str, ...]:
    """Every role's identity on a site serving ``junctions`` (agents apart)."""
    return (*ica_users(junctions, own_icas), *ROLES[1:])


def _is_role(user: str) -> bool:
    return user in ROLES or user.startswith(("ica-", "rsu-"))


def rsu_name(k: int) -> str:
    """Roadside unit ``k``'s router: its log-in to the routers before it, and its
    certificate's common name."""
    return f"rsu-{k}"


def router_file(k: int) -> str:
    """Roadside unit ``k``'s router config (1: ``router.json5``, as on a site of one)."""
    return "router.json5" if k == 1 else f"router-{k}.json5"


def agent_names(agents: int | str | Sequence[str]) -> tuple[str, ...]:
    """The agents' names: N gives agent-1 ... agent-N (as `run_cluster.sh` names
    them); a comma-separated string or a list gives those names, checked."""
    if isinstance(agents, str):
        text = agents.strip()
        agents = int(text) if text.isdigit() else [a.strip() for a in text.split(",")]
    if isinstance(agents, int):
        if agents < 0:
            raise SecureConfigError(f"--agents must be at least 0, got {agents}")
        return tuple(f"agent-{i}" for i in range(1, agents + 1))
    chosen = tuple(agents)
    for name in chosen:
        if not _AGENT_NAME.match(name):
            raise SecureConfigError(
                f"agent name {name!r}: use 1-64 letters, digits and _.+- (a letter or digit first)"
            )
        if name in _RESERVED or name.startswith(("ica-", "rsu-")):
            raise SecureConfigError(f"agent name {name!r} is taken by the site's own files")
    dup = sorted({n for n in chosen if chosen.count(n) > 1})
    if dup:
        raise SecureConfigError(f"agent {', '.join(dup)} named twice")
    return chosen


def names(agents: str | Sequence[str]) -> tuple[str, ...]:
    """Agents' names only (comma-separated or a list), checked: no count here."""
    if isinstance(agents, str):
        agents = [a.strip() for a in agents.split(",")]
    return agent_names(agents)


def junction_names(junctions: str | Sequence[str]) -> tuple[str, ...]:
    """The junctions' ids (comma-separated or a list), checked as key chunks."""
    from dica.schemas.keys import KeyChunkError, chunk

    if isinstance(junctions, str):
        junctions = [j.strip() for j in junctions.split(",")]
    try:
        chosen = tuple(chunk(j) for j in junctions)
    except KeyChunkError as e:
        raise SecureConfigError(f"--junction {e}") from None
    if not chosen or len(set(chosen)) < len(chosen):
        raise SecureConfigError("--junction: give each junction the site serves, once")
    return chosen


def write_secure_configs(
    out: Path,
    force: bool = False,
    hosts: tuple[str, ...] = DEFAULT_HOSTS,
    days: int = 365,
    agents: int | str | Sequence[str] = 1,
    junctions: str | Sequence[str] = DEFAULT_JUNCTIONS,
    own_icas: bool = False,
    rsus: int = 1,
) -> dict[str, Path]:
    """Write a new site into ``out``: the router's config, every role's and one
    per agent (``agents``: see :func:`agent_names`); the paths by file name.
    The rules name ``junctions`` (the roles' ``--junction``), and no other. With
    ``own_icas`` each junction's ICA has an identity of its own (:func:`ica_users`).
    ``rsus`` routers (roadside units) make a mesh: each logs in to the ones before it.

    ``hosts`` are the names and addresses clients reach the router by (its
    certificate is valid for these only; the first is the clients' default
    endpoint). Refuses to overwrite an earlier site unless ``force``: its
    secrets may be deployed already. With ``force``, the earlier site's agent
    files go too (their passwords no longer log in).
    """
    agents = agent_names(agents)
    junctions = junction_names(junctions)
    if not hosts:
        raise SecureConfigError("the router needs at least one --host")
    if days < 1:
        raise SecureConfigError(f"--days must be at least 1, got {days}")
    if not 1 <= rsus <= MAX_RSUS:
        raise SecureConfigError(f"--rsus must be 1 to {MAX_RSUS}, got {rsus}")
    out = out.resolve()
    icas = ica_users(junctions, own_icas)
    earlier = _users(out / "users.txt") if (out / "users.txt").is_file() else {}
    stale = [f"{u}.json5" for u in earlier if u not in ROLES]
    mine = (*FILES, *stale, *(f"{x}.{e}" for x in (*icas, *agents) for e in ("json5", "seal")),
            *(router_file(k) for k in range(2, rsus + 1)))  # fmt: skip
    clash = [f for f in mine if (out / f).exists()]
    if clash and not force:
        raise SecureConfigError(f"{out} already holds {', '.join(clash)} (--force replaces them)")
    names = [hosts[0]] if rsus == 1 else [rsu_name(k) for k in range(1, rsus + 1)]
    ca_pem, keys = _certificates(hosts, days, names)
    tls = [
        {"listen_private_key_base64": _b64(key_pem), "listen_certificate_base64": _b64(cert_pem)}
        for key_pem, cert_pem in keys
    ]
    routers = [rsu_name(k) for k in range(2, rsus + 1)]  # log in to the routers before them
    passwords = {u: _password() for u in (*site_roles(junctions, own_icas), *routers, *agents)}
    endpoint = f"tls/{_endpoint_host(hosts[0])}:{PORT}"
    texts = {
        "ca.pem": ca_pem.decode(),
        "site.json": json.dumps({"junctions": list(junctions), "rsus": rsus}) + "\n",
        **_site_texts(out, passwords, tls, hosts, junctions, ca_pem),
    }
    for user in passwords:
        if user not in routers:
            texts[f"{user}.json5"] = _client_text(user, passwords[user], endpoint, ca_pem, hosts)
    texts.update(_seals((*icas, "gateway", *agents), {}))
    try:
        out.mkdir(parents=True, exist_ok=True)
        out.chmod(0o700)
        for name, text in texts.items():
            _private(out / name, text)
        for name in stale:
            if name not in texts:
                (out / name).unlink(missing_ok=True)
                (out / name.replace(".json5", ".seal")).unlink(missing_ok=True)
    except OSError as e:
        raise SecureConfigError(f"cannot write {e.filename or out}: {e.strerror}") from None
    return {name: out / name for name in texts}


def add_agents(out: Path, agents: str | Sequence[str], force: bool = False) -> dict[str, Path]:
    """Issue an identity to each of ``agents`` on the site in ``out``; the paths
    of their client configs. A name the site has already is refused unless
    ``force``, which gives it a new password (the old one stops working).
    The router lets them in once it restarts."""
    new = names(agents)
    out = out.resolve()
    passwords, tls, hosts, endpoint, ca_pem, junctions = _site(out)
    known = [a for a in new if a in passwords]
    if known and not force:
        raise SecureConfigError(
            f"the site already has agent {', '.join(known)} (--force issues a new password)"
        )
    for name in new:
        passwords[name] = _password()
    texts = {f"{a}.json5": _client_text(a, passwords[a], endpoint, ca_pem, hosts) for a in new}
    texts.update(_site_texts(out, passwords, tls, hosts, junctions, ca_pem))
    texts.update(_seals(new, _keyring(out)))
    _write(out, texts)
    return {a: out / f"{a}.json5" for a in new}


def revoke_agents(out: Path, agents: str | Sequence[str]) -> tuple[str, ...]:
    """Withdraw the identity of each of ``agents``: its password, its rules and
    its client config go. Returns the agents the site still has. The router
    refuses a revoked agent once it restarts; until then its open session and
    its log-ins go on."""
    gone = names(agents)
    out = out.resolve()
    passwords, tls, hosts, _, ca_pem, junctions = _site(out)
    unknown = [a for a in gone if a not in passwords]
    if unknown:
        raise SecureConfigError(f"the site in {out} has no agent {', '.join(unknown)}")
    for name in gone:
        del passwords[name]
    keyring = {k: v for k, v in _keyring(out).items() if k not in gone}
    texts = _site_texts(out, passwords, tls, hosts, junctions, ca_pem)
    texts[KEYRING] = json.dumps(keyring, indent=2) + "\n"
    _write(out, texts)
    for name in gone:
        (out / f"{name}.json5").unlink(missing_ok=True)
        (out / f"{name}.seal").unlink(missing_ok=True)
    return tuple(u for u in passwords if not _is_role(u))


def site_agents(out: Path) -> tuple[str, ...]:
    """The agents the site in ``out`` has, in the order they were issued."""
    return tuple(u for u in _site(out.resolve())[0] if not _is_role(u))


def site_junctions(out: Path) -> tuple[str, ...]:
    """The junctions the site in ``out`` serves."""
    return _site(out.resolve())[5]


def router_config(
    agents: Sequence[str], junctions: Sequence[str] = DEFAULT_JUNCTIONS, own_icas: bool = False
) -> dict:
    """The router template with every key copied once per junction (``@j``), the
    agent rules once per agent (``@agent``), and no TLS material or password file.
    ``own_icas``: the ICA rules once per junction, each for that junction's ICA."""
    import zenoh

    conf = json.loads(str(zenoh.Config.from_file(str(ROUTER_TEMPLATE))))
    acl = conf["access_control"]
    if own_icas:  # each junction's ICA its own rules, on its own junction's keys
        _own_copies(
            acl,
            "ica",
            {
                ica: {JUNCTION: j}
                for ica, j in zip(ica_users(junctions, True), junctions, strict=True)
            },
        )
    for rule in acl["rules"]:
        keys = (k.replace(JUNCTION, j) for k in rule["key_exprs"] for j in junctions)
        rule["key_exprs"] = list(dict.fromkeys(keys))
    _own_copies(acl, "agent", {name: {AGENT: name} for name in agents})
    return conf


def _own_copies(acl: dict, role: str, users: dict[str, dict[str, str]]) -> None:
    """Replace ``role``'s subject, policy and rules with one copy per user, each rule's
    keys with that user's stand-ins filled in (``users``: name -> {stand-in: value})."""
    policy = next(p for p in acl["policies"] if p["id"] == role)
    subject = next(s for s in acl["subjects"] if s["id"] == role)
    templates = [r for r in acl["rules"] if r["id"] in policy["rules"]]
    acl["rules"] = [r for r in acl["rules"] if r["id"] not in policy["rules"]]
    acl["subjects"].remove(subject)
    acl["policies"].remove(policy)
    for name, fill in users.items():
        for rule in templates:
            own = copy.deepcopy(rule)
            own["id"] = f"{rule['id']}/{name}"
            keys = own["key_exprs"]
            for stand_in, value in fill.items():
                keys = [k.replace(stand_in, value) for k in keys]
            own["key_exprs"] = keys
            acl["rules"].append(own)
        acl["subjects"].append({"id": f"{role}/{name}", "usernames": [name]})
        acl["policies"].append(
            {
                "id": f"{role}/{name}",
                "subjects": [f"{role}/{name}"],
                "rules": [f"{r['id']}/{name}" for r in templates],
            }
        )


def _site_texts(
    out: Path,
    passwords: dict[str, str],
    tls: Sequence[dict[str, str]],
    hosts: Sequence[str],
    junctions: Sequence[str],
    ca_pem: bytes,
) -> dict[str, str]:
    """``users.txt`` and a router config per roadside unit (``tls``: each one's key
    and certificate) for these users (roles first, then agents)."""
    agents = [u for u in passwords if not _is_role(u)]
    rsus = len(tls)
    texts = {"users.txt": "".join(f"{u}:{pw}\n" for u, pw in passwords.items())}
    for k in range(1, rsus + 1):
        router = router_config(agents, junctions, own_icas="ica" not in passwords)
        usrpwd = router["transport"]["auth"]["usrpwd"]
        usrpwd["dictionary_file"] = str(out / "users.txt")
        router["transport"]["link"].setdefault("tls", {}).update(tls[k - 1])
        unit = ""
        if rsus > 1:
            unit = f" (roadside unit {k} of {rsus}, {rsu_name(k)})"
            _peer_rules(router["access_control"], k, rsus, junctions)
        if k > 1:  # it opens the links to the routers before it: its log-in, and the CA
            usrpwd.update(user=rsu_name(k), password=passwords[rsu_name(k)])
            router["transport"]["link"]["tls"]["root_ca_certificate_base64"] = _b64(ca_pem)
        head = (
            f"// The site's router{unit}, by dica secure-config on {dt.date.today()}, for "
            f"{', '.join(hosts)}; junctions: {', '.join(junctions)}; "
            f"agents: {', '.join(agents) or '(none)'}.\n"
            "// Holds its TLS key: keep it private. Read once, when the router starts.\n"
        )
        texts[router_file(k)] = head + json.dumps(router, indent=1)
    return texts


def _peer_rules(acl: dict, k: int, rsus: int, junctions: Sequence[str]) -> None:
    """Roadside unit ``k``'s router may pass anything on the site's keys to and from
    the other routers of the mesh. Zenoh judges a message that comes over a link
    between routers by that link's identity, not by the client that sent it, so each
    router keeps its own clients to their rules and trusts its peers to do the same
    (and every role still checks the writer's seal). A router that logs in here
    (those after ``k``) is known by its user name; one this router logged in to
    (those before ``k``) by its certificate's common name, which only the site's CA
    could have signed."""
    later = [rsu_name(j) for j in range(k + 1, rsus + 1)]
    earlier = [rsu_name(j) for j in range(1, k)]
    subjects = []
    if later:
        acl["subjects"].append({"id": "routers-in", "usernames": later})
        subjects.append("routers-in")
    if earlier:
        acl["subjects"].append({"id": "routers-out", "cert_common_names": earlier})
        subjects.append("routers-out")
    keys = [f"{space}/{j}/**" for j in junctions for space in ("dica", "sim")]
    acl["rules"].append(
        {"id": "router-peers", "permission": "allow", "flows": ["ingress", "egress"],
         "messages": list(PEER_MESSAGES), "key_exprs": keys}
    )  # fmt: skip
    acl["policies"].append({"id": "router-peers", "subjects": subjects, "rules": ["router-peers"]})


def _client_text(user: str, password: str, endpoint: str, ca_pem: bytes, hosts) -> str:
    import zenoh

    conf = json.loads(str(zenoh.Config.from_file(str(CLIENT_TEMPLATE))))
    conf["connect"]["endpoints"] = [endpoint]
    conf["transport"]["auth"]["usrpwd"].update(user=user, password=password)
    conf["transport"]["link"].setdefault("tls", {})["root_ca_certificate_base64"] = _b64(ca_pem)
    if user in ROLES:
        who = f"the {user} role"
    elif _is_role(user):
        who = f"the ICA of junction {user.removeprefix('ica-')}"
    else:
        who = f"vehicle agent {user} (dica agent --id {user})"
    return (
        f"// The client config of {who}, by dica secure-config on {dt.date.today()}, "
        f"for {', '.join(hosts)}.\n// Holds its password: keep it private.\n"
        + json.dumps(conf, indent=1)
    )


def _site(out: Path):
    """What a site written before holds: its passwords, the routers' TLS
    material (one per roadside unit), its hosts, the clients' endpoint, the CA
    certificate and the junctions."""
    missing = [f for f in FILES if not (out / f).is_file()]
    if missing:
        raise SecureConfigError(
            f"{out} holds no site written by dica secure-config (no {', '.join(missing)})"
        )
    try:
        written = json.loads((out / "site.json").read_text())
        junctions = junction_names(written["junctions"])
        tls = []
        for k in range(1, int(written.get("rsus", 1)) + 1):
            link = _written(out / router_file(k))["transport"]["link"]["tls"]
            tls.append({n: link[n] for n in ("listen_private_key_base64",
                                              "listen_certificate_base64")})  # fmt: skip
        endpoint = _written(out / "gateway.json5")["connect"]["endpoints"][0]
        ca_pem = (out / "ca.pem").read_bytes()
    except (KeyError, IndexError, TypeError, ValueError, OSError) as e:
        raise SecureConfigError(f"{out}: cannot read the site's configs ({e})") from None
    hosts = _hosts(base64.b64decode(tls[0]["listen_certificate_base64"]))
    return _users(out / "users.txt"), tls, hosts, endpoint, ca_pem, junctions


def _written(path: Path) -> dict:
    """A config this module wrote: JSON after its ``//`` header (Zenoh's own
    reader would hide the secrets it holds)."""
    lines = path.read_text().splitlines()
    return json.loads("\n".join(line for line in lines if not line.startswith("//")))


def _users(path: Path) -> dict[str, str]:
    users: dict[str, str] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise SecureConfigError(f"{path}:{n}: not a user:password line")
        users[user] = password
    return users


def _hosts(cert_pem: bytes) -> tuple[str, ...]:
    """The names the router's certificate is valid for."""
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(cert_pem)
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    return tuple(str(n.value) for n in names)


def _certificates(
    hosts: tuple[str, ...], days: int, names: Sequence[str]
) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    """A fresh CA, and per router a key and a certificate signed by it (PEM), valid for
    ``hosts`` and with the router's name in ``names`` as its common name."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = dt.datetime.now(dt.UTC)
    until = now + dt.timedelta(days=days)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "dica site CA")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_usage(cert_sign=True), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    sans = [_san(h) for h in hosts]
    pem = serialization.Encoding.PEM
    out = []
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(until)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_usage(cert_sign=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        key_pem = key.private_bytes(
            pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
        out.append((key_pem, cert.public_bytes(pem)))
    return ca.public_bytes(pem), out


def _usage(cert_sign: bool):
    from cryptography import x509

    return x509.KeyUsage(
        digital_signature=not cert_sign, content_commitment=False, key_encipherment=False,
        data_encipherment=False, key_agreement=False, key_cert_sign=cert_sign,
        crl_sign=cert_sign, encipher_only=False, decipher_only=False,
    )  # fmt: skip


def _san(host: str):
    """A certificate name for ``host``: an IP address or a DNS name."""
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        pass
    if not host or any(c.isspace() or c in "/:@" for c in host):
        raise SecureConfigError(f"--host {host!r} is neither an IP address nor a host name")
    return x509.DNSName(host)


def _endpoint_host(host: str) -> str:
    try:
        return f"[{host}]" if ipaddress.ip_address(host).version == 6 else host
    except ValueError:
        return host


def _password() -> str:
    return secrets.token_urlsafe(24)


def _b64(pem: bytes) -> str:
    return base64.b64encode(pem).decode()


def _seals(names: Sequence[str], keyring: dict[str, str]) -> dict[str, str]:
    """A fresh signing key for each of ``names``, and the keyring with them added."""
    from dica.deploy.seal import new_key

    texts = {}
    keyring = dict(keyring)
    for name in names:
        texts[f"{name}.seal"], keyring[name] = new_key()
    texts[KEYRING] = json.dumps(keyring, indent=2) + "\n"
    return texts


def _keyring(out: Path) -> dict[str, str]:
    try:
        return dict(json.loads((out / KEYRING).read_text()))
    except (OSError, ValueError) as e:
        raise SecureConfigError(f"cannot read {out / KEYRING}: {e}") from None


def _write(out: Path, texts: dict[str, str]) -> None:
    try:
        for name, text in texts.items():
            _private(out / name, text)
    except OSError as e:
        raise SecureConfigError(f"cannot write {e.filename or out}: {e.strerror}") from None


def _private(path: Path, text: str) -> None:
    """Replace ``path`` with ``text``, readable by its owner only from the first
    byte on; readers see the old file or the new one, never half of one."""
    tmp = path.with_name(f".{path.name}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    tmp.chmod(0o600)
    os.replace(tmp, path)
