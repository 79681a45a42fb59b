"""`dica secure-config`: the Zenoh configs of a secured site, with fresh secrets.

The router of ``deploy/zenoh/secure/router.json5`` speaks TLS only, makes
every client log in and lets each role write only what it owns (its comments
list the rules). This writes, into one directory only its owner can read:

* ``users.txt``: one ``user:password`` line per role, random passwords;
* ``router.json5``: that router, with its TLS key and certificate inside,
  pointed at ``users.txt``;
* ``ica.json5``, ``gateway.json5``, ``agent.json5``, ``observer.json5``: the
  client config of each role (``deploy/zenoh/client.json5``) with its
  credentials and the site's CA certificate inside, for ``--zenoh-config``;
* ``ca.pem``: that CA certificate, for other tools.

Each file stands alone: copy a role's file to the host that runs it. The
CA's private key signs the router's certificate and is then thrown away, so
nobody can issue another certificate this site's clients would trust.
"""

from __future__ import annotations

import base64
import datetime as dt
import ipaddress
import json
import os
import secrets
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROUTER_TEMPLATE = ROOT / "deploy" / "zenoh" / "secure" / "router.json5"
CLIENT_TEMPLATE = ROOT / "deploy" / "zenoh" / "client.json5"
ROLES = ("ica", "gateway", "agent", "observer")
FILES = ("users.txt", "router.json5", "ca.pem", *(f"{r}.json5" for r in ROLES))
DEFAULT_HOSTS = ("127.0.0.1", "localhost")
PORT = 7447


class SecureConfigError(Exception):
    """Why the configs were not written (one line for the user)."""


def write_secure_configs(
    out: Path, force: bool = False, hosts: tuple[str, ...] = DEFAULT_HOSTS, days: int = 365
) -> dict[str, Path]:
    """Write the router's and every role's config into ``out``; the paths by name.

    ``hosts`` are the names and addresses clients reach the router by (its
    certificate is valid for these only; the first is the clients' default
    endpoint). Refuses to overwrite earlier configs unless ``force``: their
    secrets may be deployed already.
    """
    import zenoh

    if not hosts:
        raise SecureConfigError("the router needs at least one --host")
    if days < 1:
        raise SecureConfigError(f"--days must be at least 1, got {days}")
    out = out.resolve()
    clash = [f for f in FILES if (out / f).exists()]
    if clash and not force:
        raise SecureConfigError(f"{out} already holds {', '.join(clash)} (--force replaces them)")
    ca_pem, key_pem, cert_pem = _certificates(hosts, days)
    passwords = {role: secrets.token_urlsafe(24) for role in ROLES}
    paths = {name: out / name for name in FILES}

    router = json.loads(str(zenoh.Config.from_file(str(ROUTER_TEMPLATE))))
    router["transport"]["auth"]["usrpwd"]["dictionary_file"] = str(paths["users.txt"])
    tls = router["transport"]["link"].setdefault("tls", {})
    tls["listen_private_key_base64"] = _b64(key_pem)
    tls["listen_certificate_base64"] = _b64(cert_pem)
    stamp = f"by dica secure-config on {dt.date.today()}, for {', '.join(hosts)}"
    texts = {
        "users.txt": "".join(f"{r}:{pw}\n" for r, pw in passwords.items()),
        "router.json5": f"// The site's router, {stamp}. Holds its TLS key: keep it private.\n"
        + json.dumps(router, indent=1),
        "ca.pem": ca_pem.decode(),
    }
    for role, pw in passwords.items():
        conf = json.loads(str(zenoh.Config.from_file(str(CLIENT_TEMPLATE))))
        conf["connect"]["endpoints"] = [f"tls/{_endpoint_host(hosts[0])}:{PORT}"]
        conf["transport"]["auth"]["usrpwd"].update(user=role, password=pw)
        conf["transport"]["link"].setdefault("tls", {})["root_ca_certificate_base64"] = _b64(ca_pem)
        head = (
            f"// The {role} role's client config, {stamp}. Holds its password: keep it private.\n"
        )
        texts[f"{role}.json5"] = head + json.dumps(conf, indent=1)
    try:
        out.mkdir(parents=True, exist_ok=True)
        out.chmod(0o700)
        for name, text in texts.items():
            _private(paths[name], text)
    except OSError as e:
        raise SecureConfigError(f"cannot write {e.filename or out}: {e.strerror}") from None
    return paths


def _certificates(hosts: tuple[str, ...], days: int) -> tuple[bytes, bytes, bytes]:
    """A fresh CA, and the router's key and certificate signed by it (PEM)."""
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
    key = ec.generate_private_key(ec.SECP256R1())
    names = [_san(h) for h in hosts]
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, hosts[0])]))
        .issuer_name(ca_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(until)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_usage(cert_sign=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    key_pem = key.private_bytes(
        pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    return ca.public_bytes(pem), key_pem, cert.public_bytes(pem)


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


def _b64(pem: bytes) -> str:
    return base64.b64encode(pem).decode()


def _private(path: Path, text: str) -> None:
    """Write ``text`` readable by its owner only, from the first byte on."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    path.chmod(0o600)
