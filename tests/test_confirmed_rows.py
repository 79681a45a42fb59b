"""The confirmed set's rows, kept up to date incrementally, always equal the
rows gathered from scratch, and a snapshot handed out never changes."""

from __future__ import annotations

import random
from types import SimpleNamespace

import numpy as np

from dica.ica.core.conflict import PACKED, ConfirmedRows, Gathered


def _live(g: Gathered) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The vehicles still in ``g``, their rows, and the rows' vehicle by VIN."""
    alive = np.array([v is not None for v in g.vins], bool)
    keep = alive[g.vid] if len(g.vid) else np.zeros(0, bool)
    vins = [v for v in g.vins if v is not None]
    return vins, g.packed[keep], np.array([g.vins[v] for v in g.vid[keep]], dtype=object)


def test_incremental_rows_equal_a_fresh_gather() -> None:
    rng = random.Random(7)
    rows = ConfirmedRows(capacity=64)  # small: forces growth as well as compaction
    live: dict[str, tuple[SimpleNamespace, np.ndarray]] = {}
    snapshots: list[tuple[Gathered, list[str], np.ndarray]] = []
    for step in range(2000):
        if live and (rng.random() < 0.45 or len(live) > 40):
            vin = rng.choice(list(live))
            del live[vin]
            rows.remove(vin)
        else:
            vin = f"v{step}"
            k = rng.randint(1, 120)
            packed = np.random.default_rng(step).random((k, len(PACKED)))
            dtot = SimpleNamespace(route=f"r{k % 5}", shape=(5.0, 1.8))
            live[vin] = (dtot, packed)
            rows.add(vin, dtot, packed)  # type: ignore[arg-type]
        g = rows.gathered()
        assert len(rows) == len(live)
        vins, packed, owner = _live(g)
        assert vins == list(live)  # the set's order
        # gathered from scratch: every live vehicle's rows end to end, in the set's order
        fresh = np.concatenate([p for _, p in live.values()]) if live else packed[:0]
        assert np.array_equal(packed, fresh)
        assert list(owner) == [v for v, (_, p) in live.items() for _ in range(len(p))]
        assert [g.routes[g.vins.index(v)] for v in vins] == [
            (d.route, d.shape) for d, _ in live.values()
        ]
        assert g.packed.flags.c_contiguous and g.vid.dtype == np.int64
        if step % 97 == 0:
            snapshots.append((g, vins, packed.copy()))
    for g, vins, packed in snapshots:  # later changes never reach an earlier snapshot
        again, rows_again, _ = _live(g)
        assert again == vins and np.array_equal(rows_again, packed)
