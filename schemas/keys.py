"""The Zenoh key-expression layout, in one place (documented in docs/protocol.md).

``dica/<junction>/...`` is the ICA's side (requests, confirmations, acks),
``sim/<junction>/...`` the world's (clock, vehicle states, commands). An id
used as a key chunk must not contain Zenoh's special characters.
"""

from __future__ import annotations

import re
import zlib

_CHUNK = re.compile(r"^[A-Za-z0-9_.:\-+]{1,128}$")


class KeyChunkError(ValueError):
    """An id that cannot be a key chunk."""


def chunk(name: str) -> str:
    if not _CHUNK.match(name):
        raise KeyChunkError(f"{name!r} cannot be part of a key: use letters, digits and _.:-+")
    return name


def safe_chunk(name: str, short: int = 128) -> str:
    """``name`` as a key chunk: as it is when it is one (at most ``short`` characters),
    else (SUMO allows ``*``, ``/``, spaces and more in an id) its other characters as
    ``_`` and a hash of the name that keeps it apart from every other. Every role maps a
    name alike, so they meet on the same keys."""
    if _CHUNK.match(name) and len(name) <= short:
        return name
    tag = f"{zlib.crc32(name.encode()):08x}"
    return re.sub(r"[^A-Za-z0-9_.:\-+]", "_", name)[:100] + "-" + tag


def _junction(junction: str) -> str:
    """A junction id as a key chunk (:func:`safe_chunk`)."""
    return safe_chunk(junction)


def request(junction: str, agent: str = "*") -> str:
    """Queryable (ICA, on ``*``): an agent's REQUEST -> RESPONSE | REJECT, on its own chunk."""
    return f"dica/{_junction(junction)}/request/{_one(agent)}"


def detect(junction: str, agent: str = "*") -> str:
    """Queryable (ICA, on ``*``): DETECT -> ACK | REJECT."""
    return f"dica/{_junction(junction)}/detect/{_one(agent)}"


def cancel(junction: str, agent: str = "*") -> str:
    """Queryable (ICA, on ``*``): CANCEL -> ACK | REJECT."""
    return f"dica/{_junction(junction)}/cancel/{_one(agent)}"


def walk(junction: str, asker: str = "*") -> str:
    """Queryable (ICA): a walker asks to cross (WALK), or is across (ACROSS), through
    ``asker`` (the roadside)."""
    return f"dica/{_junction(junction)}/walk/{_one(asker)}"


def walks(junction: str, person: str = "*") -> str:
    """The ICA publishes each slot it gives a walker (GO), for observers."""
    return f"dica/{_junction(junction)}/walks/{_one(person)}"


def human(junction: str, asker: str = "*") -> str:
    """Queryable (ICA): the roadside tells of a human driver (SPOTTED), asks for its
    green (ASKGREEN) or shrinks its reservations (SIGHTING), through ``asker``."""
    return f"dica/{_junction(junction)}/human/{_one(asker)}"


def ev(junction: str, asker: str = "*") -> str:
    """Queryable (ICA): the roadside tells of an emergency vehicle on its way (EVCOMING),
    through ``asker``."""
    return f"dica/{_junction(junction)}/ev/{_one(asker)}"


def greens(junction: str, vin: str = "*") -> str:
    """The ICA publishes each green it gives a human driver (LIT), for observers."""
    return f"dica/{_junction(junction)}/greens/{_one(vin)}"


def ack(junction: str, agent: str = "*") -> str:
    """Publication (agent): ACK of a RESPONSE received."""
    return f"dica/{_junction(junction)}/ack/{_one(agent)}"


def revoke(junction: str, agent: str = "*") -> str:
    """Publication (ICA): a confirmation taken back from one of the agent's vehicles."""
    return f"dica/{_junction(junction)}/revoke/{_one(agent)}"


def reorder(junction: str) -> str:
    """Publication (ICA): reactive DICA's reorderings and what became of revoked plans."""
    return f"dica/{_junction(junction)}/reorder"


def confirmed(junction: str, vin: str = "*") -> str:
    """Publication (ICA): every new confirmation, for observers."""
    return f"dica/{_junction(junction)}/confirmed/{_one(vin)}"


def ica_alive(junction: str) -> str:
    return f"dica/{_junction(junction)}/alive/ica"  # liveliness token


def ica_stats(junction: str) -> str:
    return f"dica/{_junction(junction)}/stats"  # queryable (ICA): its statistics


def clock(junction: str) -> str:
    return f"sim/{_junction(junction)}/clock"


def state(junction: str, agent: str = "*") -> str:
    return f"sim/{_junction(junction)}/state/{_one(agent)}"


def vehicles(junction: str) -> str:
    return f"sim/{_junction(junction)}/vehicles"  # every vehicle in the region (ICA, observers)


def people(junction: str) -> str:
    return f"sim/{_junction(junction)}/people"  # the people near the junction (observers)


def command(junction: str, agent: str = "*") -> str:
    return f"sim/{_junction(junction)}/command/{_one(agent)}"


def agent_alive(junction: str, agent: str = "*") -> str:
    return f"sim/{_junction(junction)}/alive/{_one(agent)}"


def agent_stats(junction: str, agent: str = "*") -> str:
    return f"sim/{_junction(junction)}/stats/{_one(agent)}"  # queryable (agent): its statistics


def observer_alive(junction: str, name: str = "*") -> str:
    return f"sim/{_junction(junction)}/observer/{_one(name)}"


def last(key: str) -> str:
    """The last chunk of a key (the agent, VIN or observer it names)."""
    return key.rsplit("/", 1)[-1]


def _one(name: str) -> str:
    return name if name == "*" else chunk(name)


def ica_name(junction: str) -> str:
    """The identity of junction ``junction``'s ICA on a site of several junctions, where
    each ICA has its own log-in and seal (a one-junction site's ICA is plain ``ica``)."""
    return f"ica-{_junction(junction)}"


def writer_of(key: str, action: str) -> str | None:
    """The one role (or agent) that may write a message on ``key``.

    ``action`` is ``put`` (a publication), ``query`` (asking) or ``reply``
    (answering a query on that key). None: nobody may; in particular a key with
    a wildcard or an unknown layout has no writer.
    """
    parts = key.split("/")
    if len(parts) not in (3, 4) or not all(_CHUNK.match(p) for p in parts):
        return None
    space, _junction, kind, *rest = parts
    name = rest[0] if rest else None
    if space == "sim":
        if (kind in ("clock", "vehicles", "people") and name is None) or (kind == "state" and name):
            return "gateway" if action == "put" else None
        if kind == "command" and name:
            return name if action == "put" else None
        if kind == "stats" and name:
            return {"query": "gateway", "reply": name}.get(action)
    elif space == "dica":
        if kind in ("request", "detect", "cancel", "walk", "human", "ev") and name:
            return {"query": name, "reply": "ica"}.get(action)
        if kind == "ack" and name:
            return name if action == "put" else None
        if kind in ("confirmed", "revoke", "walks", "greens") and name:
            return "ica" if action == "put" else None
        if kind == "stats" and name is None:
            return {"query": "gateway", "reply": "ica"}.get(action)
        if kind == "reorder" and name is None:
            return "ica" if action == "put" else None
    return None
