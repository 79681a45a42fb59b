"""The Zenoh key-expression layout, in one place (documented in docs/protocol.md).

``dica/<junction>/...`` is the ICA's side (requests, confirmations, acks),
``sim/<junction>/...`` the world's (clock, vehicle states, commands). An id
used as a key chunk must not contain Zenoh's special characters.
"""

from __future__ import annotations

import re

_CHUNK = re.compile(r"^[A-Za-z0-9_.:\-+]{1,128}$")


class KeyChunkError(ValueError):
    """An id that cannot be a key chunk."""


def chunk(name: str) -> str:
    if not _CHUNK.match(name):
        raise KeyChunkError(f"{name!r} cannot be part of a key: use letters, digits and _.:-+")
    return name


def request(junction: str) -> str:
    return f"dica/{chunk(junction)}/request"  # queryable: REQUEST -> RESPONSE | REJECT


def detect(junction: str) -> str:
    return f"dica/{chunk(junction)}/detect"  # queryable: DETECT -> ACK | REJECT


def confirmed(junction: str, vin: str = "*") -> str:
    return f"dica/{chunk(junction)}/confirmed/{vin if vin == '*' else chunk(vin)}"


def ack(junction: str, vin: str = "*") -> str:
    return f"dica/{chunk(junction)}/ack/{vin if vin == '*' else chunk(vin)}"


def ica_alive(junction: str) -> str:
    return f"dica/{chunk(junction)}/alive/ica"  # liveliness token


def clock(junction: str) -> str:
    return f"sim/{chunk(junction)}/clock"


def state(junction: str, agent: str = "*") -> str:
    return f"sim/{chunk(junction)}/state/{agent if agent == '*' else chunk(agent)}"


def vehicles(junction: str) -> str:
    return f"sim/{chunk(junction)}/vehicles"  # every vehicle in the region, each step (observers)


def command(junction: str, agent: str = "*") -> str:
    return f"sim/{chunk(junction)}/command/{agent if agent == '*' else chunk(agent)}"


def agent_alive(junction: str, agent: str = "*") -> str:
    return f"sim/{chunk(junction)}/alive/{agent if agent == '*' else chunk(agent)}"


def observer_alive(junction: str, name: str = "*") -> str:
    return f"sim/{chunk(junction)}/observer/{name if name == '*' else chunk(name)}"
