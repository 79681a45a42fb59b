"""Seals: only the one writer of a key is believed, whatever the router let through."""

from __future__ import annotations

import json
import os
import time

import pytest

from dica.deploy.seal import Guard, Keyring, Seal, SealError, load_guard, new_key
from dica.schemas import keys


@pytest.fixture
def site(tmp_path):
    ring = {}
    for name in ("ica", "gateway", "agent-1", "agent-2"):
        pem, pub = new_key()
        (tmp_path / f"{name}.seal").write_text(pem)
        ring[name] = pub
    (tmp_path / "keyring.json").write_text(json.dumps(ring))
    return tmp_path


def test_a_message_opens_only_for_its_key_s_writer(site):
    ring = Keyring(site / "keyring.json")
    clock = Seal("gateway", site / "gateway.seal").seal(b"CLOCK")
    assert ring.open(clock, keys.writer_of("sim/C/clock", "put")) == b"CLOCK"
    forged = Seal("agent-2", site / "agent-2.seal").seal(b"CLOCK")  # a real key, not the writer
    assert ring.open(forged, keys.writer_of("sim/C/clock", "put")) is None
    assert ring.open(b"CLOCK", "gateway") is None  # not sealed at all
    tampered = clock.replace(b"CLOCK", b"CLOCX")
    assert ring.open(tampered, "gateway") is None
    assert ring.open(clock, None) is None  # a key nobody may write
    assert sum(ring.refused.values()) == 4


def test_a_revoked_writer_is_refused_once_the_keyring_changes(site):
    ring = Keyring(site / "keyring.json")
    cmd = Seal("agent-1", site / "agent-1.seal").seal(b"COMMAND")
    assert ring.open(cmd, "agent-1") == b"COMMAND"
    kept = {k: v for k, v in json.loads((site / "keyring.json").read_text()).items()
            if k != "agent-1"}  # fmt: skip
    time.sleep(0.01)
    (site / "keyring.json").write_text(json.dumps(kept))
    os.utime(site / "keyring.json", (time.time() + 1, time.time() + 1))
    assert ring.open(cmd, "agent-1") is None
    assert any("revoked" in why for why in ring.refused)


def test_each_key_has_one_writer_and_wildcards_none():
    w = keys.writer_of
    assert w("sim/C/clock", "put") == "gateway"
    assert w("sim/C/state/agent-1", "put") == "gateway"
    assert w("sim/C/command/agent-1", "put") == "agent-1"
    assert w("dica/C/request/agent-1", "query") == "agent-1"
    assert w("dica/C/request/agent-1", "reply") == "ica"
    assert w("dica/C/confirmed/v7", "put") == "ica"
    assert w("dica/C/reorder", "put") == "ica"
    assert w("dica/C/walks/p7", "put") == "ica" and w("sim/C/people", "put") == "gateway"
    assert w("sim/C/stats/agent-1", "reply") == "agent-1"
    assert w("dica/C/stats", "query") == "gateway"
    for key in ("*/C/clock", "sim/C/cl$*", "**", "sim/C/command/*", "dica/C/request/*",
                "sim/C/clock/extra", "other/C/clock", "dica/C/reorder/v7",
                "dica/*/reorder"):  # fmt: skip
        for action in ("put", "query", "reply"):
            assert w(key, action) is None, (key, action)
    assert w("sim/C/clock", "query") is None and w("dica/C/confirmed/v7", "reply") is None
    assert w("dica/C/reorder", "query") is None and w("dica/C/reorder", "reply") is None


def test_an_open_site_passes_everything_and_a_seal_needs_a_keyring(site):
    open_site = Guard(None, None)
    assert open_site.out(b"x") == b"x" and open_site.take(b"x", None) == b"x"
    with pytest.raises(SealError, match="--seal needs --keyring"):
        load_guard("ica", site / "ica.seal", None)
    listener = load_guard("observer", None, site / "keyring.json")  # checks, never seals
    assert listener.out(b"x") == b"x"
    with pytest.raises(SealError, match="cannot read the signing key"):
        Seal("ica", site / "nothing.seal")
