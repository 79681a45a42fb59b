"""Sealed messages: who wrote a message, checked by whoever acts on it.

On a secured site the router lets each role write only its own keys, but a
receiver that trusts the router alone trusts every router and every rule
being right. So on a secured site every payload goes out sealed: a msgpack
envelope ``{"v", "k": "sealed", "by", "body", "sig"}`` whose Ed25519
signature covers the writer's name and the message. A receiver opens only
envelopes signed by the one role that may write that key (``writer_of``):
the gateway's CLOCK and STATEs, the ICA's answers and confirmations, an
agent's own REQUESTs, CANCELs, ACKs and COMMANDs. A forged message, one under
another writer's name, or one signed by a key the site has revoked is
dropped and counted, even with the router's rules switched off. A replayed
message is an exact old copy: each receiver's own checks (the clock only
forward, plans only with a higher sequence number, answers only to the
question just asked) make it change nothing.

Keys come from ``dica secure-config``: each signing role's private key in
``<name>.seal``, every public key in ``keyring.json`` (re-read when it
changes, so a revoked agent's messages are refused without a restart).
"""

from __future__ import annotations

import base64
import json
import threading
from collections import Counter
from pathlib import Path

import msgpack

from dica.schemas.messages import VERSION

SEALED = "sealed"


class SealError(Exception):
    """A key file that cannot be read, or an envelope that does not open."""


def new_key() -> tuple[str, str]:
    """A fresh Ed25519 key pair: (private key as PEM, public key as base64)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    ).decode()
    raw = key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return pem, base64.b64encode(raw).decode()


class Seal:
    """A role's own signing key."""

    def __init__(self, name: str, path: Path) -> None:
        from cryptography.hazmat.primitives.serialization import load_pem_private_key

        try:
            self._key = load_pem_private_key(path.read_bytes(), password=None)
        except (OSError, ValueError, TypeError) as e:
            raise SealError(f"cannot read the signing key {path}: {e}") from None
        self.name = name

    def seal(self, body: bytes) -> bytes:
        sig = self._key.sign(self.name.encode() + b"\0" + body)
        return msgpack.packb(
            {"v": VERSION, "k": SEALED, "by": self.name, "body": body, "sig": sig},
            use_bin_type=True,
        )


class Keyring:
    """Every signing role's public key, from ``keyring.json``; re-read when it changes."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._mtime = -1.0
        self._keys: dict = {}
        self._lock = threading.Lock()
        self.refused: Counter[str] = Counter()
        self._load()

    def _load(self) -> None:
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

        try:
            mtime = self.path.stat().st_mtime
            if mtime == self._mtime:
                return
            raw = json.loads(self.path.read_text())
            keys = {
                str(name): Ed25519PublicKey.from_public_bytes(base64.b64decode(pub))
                for name, pub in raw.items()
            }
        except (OSError, ValueError, TypeError, AttributeError) as e:
            if self._mtime < 0:
                raise SealError(f"cannot read the keyring {self.path}: {e}") from None
            return  # keep the keys read before; a half-written file is read next time
        self._keys, self._mtime = keys, mtime

    def names(self) -> set[str]:
        """Every writer the keyring holds a key of."""
        with self._lock:
            self._load()
            return set(self._keys)

    def open(self, data: bytes, writer: str | None) -> bytes | None:
        """The body of an envelope signed by ``writer`` (by name and key); else None."""
        from cryptography.exceptions import InvalidSignature

        try:
            env = msgpack.unpackb(data, raw=False)
            ok = (
                isinstance(env, dict)
                and env.get("k") == SEALED
                and env.get("v") == VERSION
                and isinstance(env.get("body"), bytes)
                and isinstance(env.get("sig"), bytes)
            )
        except (ValueError, msgpack.ExtraData, msgpack.FormatError, msgpack.StackError):
            ok = False
        if not ok:
            self.refused["not sealed"] += 1
            return None
        by = env.get("by")
        if writer is None or by != writer:
            self.refused[f"written by {by!r}, not {writer!r}"] += 1
            return None
        with self._lock:
            self._load()
            key = self._keys.get(by)
        if key is None:
            self.refused[f"{by!r} has no key (revoked?)"] += 1
            return None
        try:
            key.verify(env["sig"], by.encode() + b"\0" + env["body"])
        except InvalidSignature:
            self.refused[f"a bad signature under {by!r}"] += 1
            return None
        return env["body"]


class Guard:
    """A role's seal and the site's keyring: what it sends is sealed, what it acts on opened.

    ``NONE`` (no keys: an open site) passes everything through unchanged.
    """

    def __init__(self, seal: Seal | None, keyring: Keyring | None) -> None:
        self.seal = seal
        self.keyring = keyring

    def out(self, body: bytes) -> bytes:
        return self.seal.seal(body) if self.seal is not None else body

    def take(self, data: bytes, writer: str | None) -> bytes | None:
        """What to decode, if ``writer`` wrote it; None to drop it."""
        if self.keyring is None:
            return data
        return self.keyring.open(data, writer)

    def refused(self) -> dict[str, int]:
        return dict(self.keyring.refused) if self.keyring is not None else {}

    def knows(self, name: str) -> bool:
        """Whether ``name`` is one of the site's writers (always, on an open site)."""
        return self.keyring is None or name in self.keyring.names()


NONE = Guard(None, None)


def load_guard(name: str, seal_path: Path | None, keyring_path: Path | None) -> Guard:
    """The guard a role runs with: both files, or neither (an open site)."""
    if (seal_path is None) != (keyring_path is None) and seal_path is not None:
        raise SealError("--seal needs --keyring (whose keys to check messages against)")
    keyring = Keyring(keyring_path) if keyring_path is not None else None
    seal = Seal(name, seal_path) if seal_path is not None else None
    return Guard(seal, keyring)
