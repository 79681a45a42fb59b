"""Wire messages: every kind round-trips, and untrusted bytes only ever give DecodeError."""

from __future__ import annotations

import contextlib
import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dica.schemas import keys
from dica.schemas.codec import MAX_PAYLOAD, DecodeError, Why, decode, encode
from dica.schemas.messages import (
    MAX_SAMPLES,
    MESSAGES,
    VERSION,
    Ack,
    Across,
    AskGreen,
    Cancel,
    Clock,
    Command,
    Detect,
    EvComing,
    Go,
    Lit,
    People,
    PersonPlace,
    Place,
    Reject,
    Reorder,
    Request,
    Response,
    Revoke,
    Setpoint,
    Shrunk,
    Sighting,
    Spotted,
    State,
    Stats,
    Unlit,
    VehicleState,
    Walk,
)

T = np.arange(0.0, 2.0, 0.05)


def _vs(vin: str = "v00001", detected: float = math.nan) -> VehicleState:
    return VehicleState(vin, "r1", "W_in_0", 42.5, 13.9, -50.2, 1.6, 90.0, 5.0, 1.8, 19.4, True,
                        detected, False, 7, -1, 5, True, True, "agent-1", T[:3] - 9.0)  # fmt: skip


SAMPLES = {
    Request: Request(
        "v00001",
        3,
        "W_in_0",
        "E_out_0",
        5.0,
        1.8,
        12.35,
        41.2,
        13.9,
        T,
        T * 10,
        T * 0,
        T * 0 + 0.1,
        12.3,
        17,
    ),
    Response: Response("v00001", 3, "W_in_0->E_out_0", T, T * 3, T, T * 0, 14.1, 16.0, 0.4, 2, 5),
    Reject: Reject("v00001", 3, "not_head", "v00000 is ahead", 1),
    Ack: Ack("v00001", 3, "response", 2),
    Cancel: Cancel("v00001", 3, 7),
    Walk: Walk("p0001", ":C_c0", 12.5, 22.0, 1.3, 1, 2.0, 1.2, 7),
    Across: Across("p0001", ":C_c0", 40.25, 8),
    Go: Go("p0001", ":C_c0", 14.0, 28.8, 7, 12.5, 1, 3.5, 2.25, 0.8, 1.4, 26.0),
    Spotted: Spotted("h00004", "W_in_0", 10.05, 9),
    AskGreen: AskGreen("h00004", 18.5, 5.0, 1.8, 0.5, False, 10, 7.5),
    Lit: Lit("h00004", 21.0, 18.5, 0.5, 5.0, 1.8, ("W_S", "W_E", "W_N"), 11, 21.39, 0.05, 7.5, 0.2),
    Unlit: Unlit("h00004", 21.35, 21.0, 13),
    Sighting: Sighting("h00004", 22.5, ":C_3_0", 2.75, 4.2, 12),
    Shrunk: Shrunk("h00004", 22.5, ("W_E",), 13),
    EvComing: EvComing("v00031", "W_in", "E_out", 41.5, 30.05, 14),
    People: People(247, 12.35, (PersonPlace(1.5, -2.0, True), PersonPlace(3.0, 4.0, False)), 8),
    Detect: Detect("v00001", "W_in_0", 10.05, True, 12.5, 3),
    Revoke: Revoke("v00001", 3, 12.4, 9),
    Reorder: Reorder(
        "ev1",
        "N_in_1",
        12.4,
        "exact",
        (Place("w1", 40, "dropped", 13.1), Place("ev1", -1, "", 12.4), Place("w2", 7, "kept", 13)),
        30.5,
        24.25,
        "",
        10,
    ),
    State: State("agent-1", 247, 1, 12.35, (_vs(), _vs("v00002", 3.2)), 4),
    Command: Command(
        "agent-1",
        247,
        0,
        (
            Setpoint("v00001", 3, 12.35, T, 1e9, False),
            Setpoint("v2", -1, math.nan, T[:0], -1e9, False),
            Setpoint("v3", 4, math.nan, T[:0], 1e9, True),
        ),
        5,
    ),
    Clock: Clock(247, 12.35, "lockstep", 1.0, False, 6),
    Stats: Stats("agent", "agent-1", '{"hosted": 3}', 8),
}


def _same(a, b) -> None:
    assert type(a) is type(b)
    if isinstance(a, str):
        assert a == b
        return
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert np.array_equal(x, y)
        elif isinstance(x, tuple):
            assert len(x) == len(y)
            for p, q in zip(x, y, strict=True):
                _same(p, q)
        elif isinstance(x, float) and math.isnan(x):
            assert math.isnan(y)
        else:
            assert x == y, name


def test_every_message_kind_has_a_sample() -> None:
    assert set(SAMPLES) == set(MESSAGES)


@pytest.mark.parametrize("cls", MESSAGES, ids=lambda c: c.KIND)
def test_round_trip(cls) -> None:
    msg = SAMPLES[cls]
    back = decode(encode(msg), cls)
    _same(msg, back)


def _raw(msg) -> dict:
    return msgpack.unpackb(encode(msg), raw=False)


def _pack(body: dict) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def _why(data: bytes, *kinds) -> Why:
    with pytest.raises(DecodeError) as e:
        decode(data, *kinds)
    assert e.value.detail
    return e.value.why


def test_garbage_and_truncated_payloads() -> None:
    assert _why(b"") is Why.NOT_MSGPACK
    assert _why(b"\xc1\xff\x00") is Why.NOT_MSGPACK
    good = encode(SAMPLES[Request])
    for cut in (1, 7, len(good) // 2, len(good) - 1):
        assert _why(good[:cut]) is Why.NOT_MSGPACK
    assert _why(_pack([1, 2, 3])) is Why.NOT_A_MAP
    assert _why(b"\x00" * (MAX_PAYLOAD + 1)) is Why.TOO_BIG


def test_version_kind_and_fields() -> None:
    body = _raw(SAMPLES[Detect])
    assert _why(_pack({**body, "v": VERSION + 1})) is Why.UNKNOWN_VERSION
    assert _why(_pack({**body, "v": VERSION - 1})) is Why.UNKNOWN_VERSION  # the old wire
    assert _why(_pack({k: v for k, v in body.items() if k != "v"})) is Why.UNKNOWN_VERSION
    assert _why(_pack({**body, "k": "teleport"})) is Why.UNKNOWN_KIND
    assert _why(_pack(body), Request) is Why.UNEXPECTED_KIND
    assert _why(_pack({k: v for k, v in body.items() if k != "lane"})) is Why.MISSING_FIELD
    assert _why(_pack({**body, "colour": "red"})) is Why.UNKNOWN_FIELD


def test_wrong_types_and_ranges() -> None:
    body = _raw(SAMPLES[Request])
    assert _why(_pack({**body, "vin": 7})) is Why.BAD_TYPE
    assert _why(_pack({**body, "seq": "3"})) is Why.BAD_TYPE
    assert _why(_pack({**body, "seq": True})) is Why.BAD_TYPE
    assert _why(_pack({**body, "seq": -1})) is Why.OUT_OF_RANGE
    assert _why(_pack({**body, "speed_mps": float("nan")})) is Why.OUT_OF_RANGE
    assert _why(_pack({**body, "length_m": 1e6})) is Why.OUT_OF_RANGE
    assert _why(_pack({**body, "t_s": [0.0, 0.05]})) is Why.BAD_TYPE
    assert _why(_pack({**body, "t_s": b"\x00" * 12})) is Why.BAD_TYPE
    assert _why(_pack({**body, "x_m": np.array([np.inf]).tobytes()})) is Why.OUT_OF_RANGE
    assert _why(_pack({**body, "vin": "v" * 200})) is Why.TOO_LARGE
    # NaN is allowed exactly where a field says so (not yet detected)
    state = _raw(SAMPLES[State])
    state["vehicles"][0]["speed_mps"] = float("nan")
    assert _why(_pack(state)) is Why.OUT_OF_RANGE
    state["vehicles"][0] = "not a map"
    assert _why(_pack(state)) is Why.BAD_TYPE
    # a reordering: the EV's entries may be unknown (NaN), the places' times may not
    reorder = _raw(SAMPLES[Reorder])
    assert math.isnan(decode(_pack({**reorder, "ev_entry_before_s": math.nan})).ev_entry_before_s)
    reorder["order"][0]["t_s"] = float("nan")
    assert _why(_pack(reorder)) is Why.OUT_OF_RANGE
    reorder["order"][0] = {"vin": "w1", "seq": 40, "plan": "x" * 17, "t_s": 1.0}
    assert _why(_pack(reorder)) is Why.TOO_LARGE
    # a walker's shortest way, and the people's places and flags: at their limits and
    # one past them
    walk = _raw(SAMPLES[Walk])
    assert decode(_pack({**walk, "near_lo_m": 0.0})).near_lo_m == 0.0
    assert decode(_pack({**walk, "near_lo_m": 1000.0})).near_lo_m == 1000.0
    for bad in (-1e-9, 1000.0001, math.inf):
        assert _why(_pack({**walk, "near_lo_m": bad})) is Why.OUT_OF_RANGE
    people = _raw(SAMPLES[People])
    people["people"][0]["waiting"] = 1
    assert _why(_pack(people)) is Why.BAD_TYPE
    people["people"] = [{"x_m": 0.0, "y_m": 0.0, "waiting": False}] * 2049
    assert _why(_pack(people)) is Why.NOT_MSGPACK  # over MAX_VEHICLES: the unpacker stops
    go = _raw(SAMPLES[Go])
    assert _why(_pack({**go, "side": 2})) is Why.OUT_OF_RANGE
    assert _why(_pack({key: v for key, v in go.items() if key != "given_s"})) is Why.MISSING_FIELD


def test_oversize_arrays_are_refused() -> None:
    big = np.zeros(MAX_SAMPLES + 1)
    body = _raw(SAMPLES[Response])
    why = _why(_pack({**body, "t_s": big.tobytes()}))
    assert why in (Why.TOO_LARGE, Why.NOT_MSGPACK)  # msgpack's own bin limit may fire first
    many = _raw(SAMPLES[State])
    many["vehicles"] = many["vehicles"] * 1500
    # too many vehicles, or (the sample's full arrays) more bytes than a payload may have
    assert _why(_pack(many)) in (Why.TOO_LARGE, Why.NOT_MSGPACK, Why.TOO_BIG)
    long = _raw(SAMPLES[Reorder])
    long["order"] = long["order"][:1] * 2049
    assert _why(_pack(long)) in (Why.TOO_LARGE, Why.NOT_MSGPACK)
    long["order"] = long["order"][:2048]
    assert len(decode(_pack(long), Reorder).order) == 2048  # the limit itself passes


@settings(max_examples=400, derandomize=True, deadline=None)
@given(st.binary(max_size=512))
def test_random_bytes_never_crash(data: bytes) -> None:
    with contextlib.suppress(DecodeError):
        decode(data)


@settings(max_examples=300, derandomize=True, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 255))
def test_corrupted_messages_never_crash(pos: int, byte: int) -> None:
    for msg in SAMPLES.values():
        data = bytearray(encode(msg))
        data[pos % len(data)] = byte
        with contextlib.suppress(DecodeError):
            decode(bytes(data))


def test_keys_refuse_special_characters() -> None:
    assert keys.request("C", "agent-1") == "dica/C/request/agent-1"
    assert keys.request("C") == "dica/C/request/*"
    assert keys.state("C", "agent-1") == "sim/C/state/agent-1"
    assert keys.confirmed("C") == "dica/C/confirmed/*"
    assert keys.reorder("C") == "dica/C/reorder"
    for bad in ("a/b", "x?y", "", "$z", "**"):
        with pytest.raises(keys.KeyChunkError):
            keys.command("C", bad)


def test_a_junction_id_a_key_cannot_hold_is_made_one_alike_by_every_role() -> None:
    """SUMO allows ``*``, ``/``, ``$`` and spaces in a junction id; every role puts an id
    into its keys the same way (its other characters as ``_`` and a hash of the id), so
    they meet on one key per junction, and two ids never share one (each role's keys
    raised before, and the cluster's processes each ended in a traceback)."""
    assert keys.request("c*d") == keys.request("c*d") == "dica/c_d-9064c502/request/*"
    assert keys.clock("c*d").startswith("sim/c_d-") and keys.clock("c*d").endswith("/clock")
    assert keys.request("c_d") == "dica/c_d/request/*"  # a plain id stays as it is
    assert keys.request("c?d") != keys.request("c*d")  # apart, though both read c_d
    assert keys.ica_name("j/1*$x").startswith("ica-j_1__x-")
    assert keys.writer_of(keys.confirmed("c*d", "v1"), "put") == "ica"
    for j in ("a/b", "x?y", "$z", "**", "a b", "é"):
        assert "/" not in keys.clock(j)[4:-6]  # one chunk between sim/ and /clock
