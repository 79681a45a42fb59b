"""Rows kept per entity and sent to Rerun as one column chunk each.

A Rerun log call costs 0.1-0.5 ms and the web viewer pays dearly for every
chunk, so the views only add rows here; :meth:`RowBuffer.send` sends an
entity's rows as one chunk once it holds MAX_ROWS of them, or everything (at
the end, or every time in a live recording). Every row is on the one
timeline, ``sim_time``.

A chart draws the rows of the last PAST_S, so a row that draws something
lasting (a plan, a reserved interval) is logged once more when that ends
(:meth:`RowBuffer.again`), and dropped from that queue if it is withdrawn
first (:meth:`RowBuffer.forget`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import rerun as rr

TIMELINE = "sim_time"
MAX_ROWS = 4096  # rows of one entity sent as one chunk (Rerun's own compaction limit)


class EntityRows:
    """Rows of one entity, kept until they are sent as one column chunk."""

    def __init__(self, entity: str, archetype: Any, style: Mapping[str, Any] | None = None) -> None:
        self.entity = entity
        self.archetype = archetype
        self.style = style or {}  # fields with one value for every row
        self.times: list[np.ndarray] = []
        self.lengths: list[np.ndarray] = []
        self.fields: dict[str, list[Any]] = {}

    def add(self, t_s: float, n: int, **fields: Any) -> None:
        """One row of ``n`` instances at ``t_s``."""
        self.add_many(np.array([t_s]), np.array([n]), **fields)

    @property
    def n_rows(self) -> int:
        return sum(len(t) for t in self.times)

    def add_many(self, times: np.ndarray, lengths: np.ndarray, **fields: Any) -> None:
        """Many rows at once: ``lengths[i]`` instances at ``times[i]``, the instances of
        all rows one after the other in each field."""
        self.times.append(np.asarray(times, dtype=float))
        self.lengths.append(np.asarray(lengths, dtype=int))
        for k, v in fields.items():
            self.fields.setdefault(k, []).append(v)

    def send(self, rec: rr.RecordingStream) -> None:
        """All rows as one chunk, in time order (rows at one time in the order added)."""
        if not self.times:
            return
        times = np.concatenate(self.times)
        lengths = np.concatenate(self.lengths)
        order = np.argsort(times, kind="stable")
        data = {k: _joined(v) for k, v in self.fields.items()}
        if not np.all(order == np.arange(len(order))):  # rows added out of time order
            starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
            take = np.concatenate([np.arange(starts[i], starts[i] + lengths[i]) for i in order])
            data = {k: _take(v, take) for k, v in data.items()}
            times, lengths = times[order], lengths[order]
        cols = list(self.archetype.columns(**data).partition(lengths))
        if self.style:
            n = len(times)
            each = {k: _each(k, v, n) for k, v in self.style.items()}
            cols += list(self.archetype.columns(**each).partition(np.ones(n, dtype=int)))
        rec.send_columns(
            self.entity, indexes=[rr.TimeColumn(TIMELINE, duration=times)], columns=cols
        )
        self.times, self.lengths, self.fields = [], [], {}


def _each(field: str, value: Any, n: int) -> Any:
    """One style value for each of ``n`` rows; a packed colour (0xRRGGBBAA) as an array of
    them, which Rerun reads unambiguously (three or four plain ints it could take for
    one colour's channels, and warned)."""
    if field == "colors" and isinstance(value, int):
        return np.full(n, value, dtype=np.uint32)
    return [value] * n


def _joined(parts: list[Any]) -> Any:
    """Rows of one field as one batch; floats as float32, which Rerun converts twice as fast."""
    if isinstance(parts[0], list):
        return [x for part in parts for x in part]
    joined = np.concatenate([np.asarray(p) for p in parts])
    return joined.astype(np.float32) if joined.dtype == np.float64 else joined


def _take(v: Any, take: np.ndarray) -> Any:
    if isinstance(v, list):
        return [v[i] for i in take]
    return v[take]


@dataclass(slots=True)
class _Repeat:
    """A row to log once more at ``t_s``, when what it draws ends."""

    t_s: float
    entity: str
    archetype: Any
    n: int
    fields: dict[str, Any]


class RowBuffer:
    """Every entity's rows until they are sent, and the rows due to be logged again."""

    def __init__(self, styles: Mapping[str, Mapping[str, Any]]) -> None:
        """``styles``: per entity, the fields with one value for every row."""
        self._styles = styles
        self._rows: dict[str, EntityRows] = {}
        self._repeats: list[_Repeat] = []

    def _entity(self, entity: str, archetype: Any) -> EntityRows:
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = EntityRows(entity, archetype, self._styles.get(entity))
        return rows

    def add(self, entity: str, archetype: Any, t_s: float, n: int, **fields: Any) -> None:
        """One row of ``n`` instances at ``t_s``."""
        self._entity(entity, archetype).add(t_s, n, **fields)

    def add_many(
        self, entity: str, archetype: Any, times: np.ndarray, lengths: np.ndarray, **fields: Any
    ) -> None:
        """Many rows at once: ``lengths[i]`` instances at ``times[i]``."""
        self._entity(entity, archetype).add_many(times, lengths, **fields)

    def again(
        self, t_end: float, now: float, entity: str, archetype: Any, n: int, fields: dict
    ) -> None:
        """Log a row once more when what it draws ends, if that is later than now:
        a chart shows the rows of the last PAST_S, and a plan or a reserved interval
        must stay as long as any of it is in the window."""
        if t_end > now + 1e-9:
            self._repeats.append(_Repeat(t_end, entity, archetype, n, fields))

    def due(self, t_s: float) -> None:
        """Add the rows of :meth:`again` that the run has reached."""
        keep = []
        for r in self._repeats:
            if r.t_s <= t_s + 1e-9:
                self.add(r.entity, r.archetype, r.t_s, r.n, **r.fields)
            else:
                keep.append(r)
        self._repeats = keep

    def forget(self, label_prefixes: tuple[str, ...]) -> None:
        """Log none of the waiting repeats with a label that starts with one of these."""
        self._repeats = [
            r
            for r in self._repeats
            if not any(str(lb).startswith(label_prefixes) for lb in r.fields.get("labels", ()))
        ]

    def send(self, rec: rr.RecordingStream, everything: bool) -> None:
        """Send the rows of entities that hold MAX_ROWS of them, or ``everything``."""
        for rows in self._rows.values():
            if everything or rows.n_rows >= MAX_ROWS:
                rows.send(rec)
