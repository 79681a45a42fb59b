"""msgpack encoding of :mod:`schemas.messages`, and the one place bytes become objects.

Wire form: a msgpack map ``{"v": VERSION, "k": KIND, <field>: <value>, ...}``.
Numbers and text are msgpack scalars, float arrays are little-endian float64
bytes (compact, and decoded without a per-item loop), nested records are maps.

:func:`decode` trusts nothing: a payload that is too big, not msgpack, of an
unknown version or kind, with a missing, extra or mistyped field, a value out
of its range or an oversize array raises :class:`DecodeError` with a stable
reason code, never anything else.
"""

from __future__ import annotations

import dataclasses
import math
import time
import typing
from enum import StrEnum
from functools import cache

import msgpack
import numpy as np

from dica.schemas.messages import MAX_SAMPLES, MAX_TEXT, MAX_VEHICLES, MESSAGES, VERSION

MAX_PAYLOAD = 1 << 20  # [bytes] a full TSS is 4 x 64 KiB; a STATE of MAX_VEHICLES about 400 KiB
_BY_KIND = {m.KIND: m for m in MESSAGES}


class Why(StrEnum):
    TOO_BIG = "too_big"
    NOT_MSGPACK = "not_msgpack"
    NOT_A_MAP = "not_a_map"
    UNKNOWN_VERSION = "unknown_version"
    UNKNOWN_KIND = "unknown_kind"
    UNEXPECTED_KIND = "unexpected_kind"
    MISSING_FIELD = "missing_field"
    UNKNOWN_FIELD = "unknown_field"
    BAD_TYPE = "bad_type"
    OUT_OF_RANGE = "out_of_range"
    TOO_LARGE = "too_large"


class DecodeError(Exception):
    """Bytes that are not a valid message; ``why`` is stable, ``detail`` for people."""

    def __init__(self, why: Why, detail: str, kind: str | None = None) -> None:
        super().__init__(f"{why.value}: {detail}")
        self.why = why
        self.detail = detail
        self.kind = kind


def now_ns() -> int:
    return time.time_ns()


# -- encoding -------------------------------------------------------------------
def encode(msg) -> bytes:
    """Bytes for one message (any class of :data:`schemas.messages.MESSAGES`)."""
    body = _pack_record(msg)
    body["v"] = VERSION
    body["k"] = type(msg).KIND
    return msgpack.packb(body, use_bin_type=True)


def _pack_record(rec) -> dict:
    out = {}
    for name in _names(type(rec)):
        value = getattr(rec, name)
        if isinstance(value, np.ndarray):
            value = np.ascontiguousarray(value, dtype="<f8").tobytes()
        elif isinstance(value, tuple):
            value = [x if isinstance(x, str) else _pack_record(x) for x in value]
        elif isinstance(value, np.generic):
            value = value.item()
        out[name] = value
    return out


@cache
def _names(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


# -- decoding -------------------------------------------------------------------
def decode(data: bytes, *kinds: type):
    """The message in ``data``; if ``kinds`` are given it must be one of them."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DecodeError(Why.BAD_TYPE, f"payload is {type(data).__name__}, not bytes")
    if len(data) > MAX_PAYLOAD:
        raise DecodeError(Why.TOO_BIG, f"payload of {len(data)} bytes exceeds {MAX_PAYLOAD}")
    try:
        body = msgpack.unpackb(
            bytes(data),
            raw=False,
            strict_map_key=True,
            max_bin_len=MAX_SAMPLES * 8,
            max_str_len=64 * 1024,
            max_array_len=MAX_VEHICLES,
            max_map_len=64,
            max_ext_len=0,
        )
    except Exception as e:  # msgpack raises several types for corrupt input
        raise DecodeError(Why.NOT_MSGPACK, f"cannot unpack: {type(e).__name__}: {e}") from None
    if not isinstance(body, dict):
        raise DecodeError(Why.NOT_A_MAP, f"top level is {type(body).__name__}, not a map")
    version = body.pop("v", None)
    if version != VERSION:
        raise DecodeError(Why.UNKNOWN_VERSION, f"version {version!r}; this side speaks {VERSION}")
    kind = body.pop("k", None)
    cls = _BY_KIND.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise DecodeError(Why.UNKNOWN_KIND, f"unknown message kind {kind!r}")
    if kinds and cls not in kinds:
        want = ", ".join(k.KIND for k in kinds)
        raise DecodeError(Why.UNEXPECTED_KIND, f"got {kind}, expected {want}", kind)
    try:
        return _record(cls, body, kind)
    except DecodeError as e:
        e.kind = kind
        raise


@cache
def _spec(cls: type) -> tuple[tuple[str, object, tuple], ...]:
    hints = typing.get_type_hints(cls)
    return tuple((f.name, hints[f.name], f.metadata["lim"]) for f in dataclasses.fields(cls))


def _record(cls: type, body: dict, where: str):
    missing = [name for name, _, _ in _spec(cls) if name not in body]
    if missing:
        raise DecodeError(Why.MISSING_FIELD, f"{where}: missing {', '.join(missing)}")
    if len(body) != len(_spec(cls)):
        extra = sorted(set(map(str, body)) - {name for name, _, _ in _spec(cls)})
        raise DecodeError(Why.UNKNOWN_FIELD, f"{where}: unknown field(s) {', '.join(extra)}")
    values = {}
    for name, hint, (lo, hi, n) in _spec(cls):
        values[name] = _value(f"{where}.{name}", body[name], hint, lo, hi, n)
    return cls(**values)


def _value(where: str, x, hint, lo, hi, n):
    if hint is str:
        if not isinstance(x, str):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be text, got {type(x).__name__}")
        if n is not None and len(x) > n:
            raise DecodeError(Why.TOO_LARGE, f"{where} is {len(x)} characters, at most {n}")
        return x
    if hint is bool:
        if not isinstance(x, bool):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be true/false, got {type(x).__name__}")
        return x
    if hint is int:
        if not isinstance(x, int) or isinstance(x, bool):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be an integer, got {type(x).__name__}")
        if not lo <= x <= hi:
            raise DecodeError(Why.OUT_OF_RANGE, f"{where} = {x} outside [{lo}, {hi}]")
        return x
    if hint is float:
        if not isinstance(x, (int, float)) or isinstance(x, bool):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be a number, got {type(x).__name__}")
        x = float(x)
        if math.isnan(x) and n == -1:
            return x
        if not math.isfinite(x) or not lo <= x <= hi:
            raise DecodeError(Why.OUT_OF_RANGE, f"{where} = {x} outside [{lo:g}, {hi:g}]")
        return x
    if hint is np.ndarray:
        if not isinstance(x, bytes):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be float64 bytes")
        if len(x) % 8:
            raise DecodeError(Why.BAD_TYPE, f"{where}: {len(x)} bytes is not whole float64s")
        if len(x) // 8 > n:
            raise DecodeError(Why.TOO_LARGE, f"{where} has {len(x) // 8} values, at most {n}")
        arr = np.frombuffer(x, dtype="<f8").astype(float)
        if not np.all(np.isfinite(arr)):
            raise DecodeError(Why.OUT_OF_RANGE, f"{where} holds NaN or infinite values")
        return arr
    if typing.get_origin(hint) is tuple:
        item = typing.get_args(hint)[0]
        if not isinstance(x, list):
            raise DecodeError(Why.BAD_TYPE, f"{where} must be a list, got {type(x).__name__}")
        if len(x) > n:
            raise DecodeError(Why.TOO_LARGE, f"{where} has {len(x)} items, at most {n}")
        if item is str:  # ids: each as long as any text id may be
            return tuple(_value(f"{where}[{i}]", v, str, None, None, MAX_TEXT)
                         for i, v in enumerate(x))  # fmt: skip
        out = []
        for i, rec in enumerate(x):
            if not isinstance(rec, dict):
                raise DecodeError(Why.BAD_TYPE, f"{where}[{i}] must be a map")
            out.append(_record(item, rec, f"{where}[{i}]"))
        return tuple(out)
    raise TypeError(f"no wire rule for {hint!r}")  # a schema bug, caught by the tests
