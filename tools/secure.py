"""`dica secure-config`: the Zenoh configs of a secured site, with fresh passwords.

The router of ``deploy/zenoh/secure/router.json5`` makes every client log in
and lets each role write only what it owns (its comments list the rules).
This writes, into one directory only its owner can read:

* ``users.txt``: one ``user:password`` line per role, random passwords;
* ``router.json5``: that router, pointed at ``users.txt``;
* ``ica.json5``, ``gateway.json5``, ``agent.json5``, ``observer.json5``: the
  client config of each role (``deploy/zenoh/client.json5``) with its
  credentials, for ``--zenoh-config``.

Copy each role's file to the host that runs it. Passwords authenticate; they
do not encrypt the link (see ``docs/deploy.md``).
"""

from __future__ import annotations

import json
import os
import secrets
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROUTER_TEMPLATE = ROOT / "deploy" / "zenoh" / "secure" / "router.json5"
CLIENT_TEMPLATE = ROOT / "deploy" / "zenoh" / "client.json5"
ROLES = ("ica", "gateway", "agent", "observer")
FILES = ("users.txt", "router.json5", *(f"{r}.json5" for r in ROLES))


class SecureConfigError(Exception):
    """Why the configs were not written (one line for the user)."""


def write_secure_configs(out: Path, force: bool = False) -> dict[str, Path]:
    """Write the router's and every role's config into ``out``; the paths by name.

    Refuses to overwrite earlier ones unless ``force``: their passwords may be
    deployed already.
    """
    import zenoh

    out = out.resolve()
    clash = [f for f in FILES if (out / f).exists()]
    if clash and not force:
        raise SecureConfigError(f"{out} already holds {', '.join(clash)} (--force replaces them)")
    try:
        out.mkdir(parents=True, exist_ok=True)
        out.chmod(0o700)
    except OSError as e:
        raise SecureConfigError(f"cannot make {out}: {e.strerror}") from None
    passwords = {role: secrets.token_urlsafe(24) for role in ROLES}
    paths = {name: out / name for name in FILES}
    router = zenoh.Config.from_file(str(ROUTER_TEMPLATE))
    users = json.dumps(str(paths["users.txt"]))
    router.insert_json5("transport/auth/usrpwd/dictionary_file", users)
    texts = {"users.txt": "".join(f"{r}:{pw}\n" for r, pw in passwords.items())}
    texts["router.json5"] = str(router)
    for role, pw in passwords.items():
        conf = zenoh.Config.from_file(str(CLIENT_TEMPLATE))
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(role))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(pw))
        texts[f"{role}.json5"] = str(conf)
    try:
        for name, text in texts.items():
            _private(paths[name], text)
    except OSError as e:
        raise SecureConfigError(f"cannot write {e.filename}: {e.strerror}") from None
    return paths


def _private(path: Path, text: str) -> None:
    """Write ``text`` readable by its owner only, from the first byte on."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    path.chmod(0o600)
