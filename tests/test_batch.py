"""The batched getCV (techniques 1, 2 and 4 over all confirmed vehicles at once)
answers every round exactly as the per-vehicle search does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ica.core.config import IcaConfig, Techniques
from ica.core.conflict import get_cv
from ica.core.dica import Dica
from ica.core.kernels import first_conflict
from tools.stream import StreamSpec, run_stream


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
@pytest.mark.parametrize("variant", ["enhanced", "t1+2+4"])
def test_batched_get_cv_equals_per_vehicle(request, monkeypatch, junction, variant):
    inter = request.getfixturevalue(junction)
    batched = Dica.conflicts
    rounds = {"all": 0, "with_conflicts": 0}

    def checked(self: Dica, dtot):
        fast = batched(self, dtot)
        slow = get_cv(dtot, self.confirmed_dtots(), self.config.techniques, self.tables)
        assert fast == slow  # same vehicles, order, firstTimeAtCollision and delay, bit for bit
        rounds["all"] += 1
        rounds["with_conflicts"] += bool(fast)
        return fast

    monkeypatch.setattr(Dica, "conflicts", checked)
    spec = StreamSpec(
        volume_per_10min=1500.0,
        n_vehicles=40,
        seed=5,
        length_range_m=(3.5, 7.5),
        width_range_m=(1.6, 2.3),
    )
    res = run_stream(inter, IcaConfig(techniques=Techniques.parse(variant)), spec)
    assert len(res.confirmed) == len(res.vehicles)
    assert rounds["with_conflicts"] > 20


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_first_conflict_is_the_sorted_get_cv_head(request, monkeypatch, junction):
    """first_conflict (the compiled round loop's getCV) picks the vehicle that
    heads the batched getCV's sorted list, with its firstTimeAtCollision and
    delay, for any bound of the lane leader's conflict time."""
    inter = request.getfixturevalue(junction)
    batched = Dica.conflicts
    rounds = {"with_conflicts": 0}

    def checked(self: Dica, dtot):
        found = batched(self, dtot)
        batch = self._confirmed_batch(dtot.route, dtot.shape)
        g = batch.gathered
        order = np.argsort(g.packed[batch.m, 0])
        heads = [c.first_time_s for c in found[:1]]
        for bound in (math.inf, *heads, *(h - 0.05 for h in heads)):
            v, first, delay = first_conflict(
                np.ascontiguousarray(dtot.lb_s),
                np.ascontiguousarray(dtot.ub_s),
                np.ascontiguousarray(dtot.grid_idx),
                np.ascontiguousarray(dtot.rects.centre),
                np.ascontiguousarray(dtot.rects.heading),
                dtot.rects.half_length,
                dtot.rects.half_width,
                g.packed,
                g.vid,
                batch.m[order],
                batch.row[order],
                batch.row_lo[order],
                batch.row_hi[order],
                batch.codes,
                batch.width,
                np.ascontiguousarray(g.packed[batch.m[order], 0]),
                batch.span_s,
                bound,
            )
            head = [c for c in found if c.first_time_s <= bound][:1]
            if head:
                assert (g.vins[v], first, delay) == (
                    head[0].vin,
                    head[0].first_time_s,
                    head[0].delay_s,
                )
            else:
                assert v == -1
        rounds["with_conflicts"] += bool(found)
        return found

    monkeypatch.setattr(Dica, "conflicts", checked)
    spec = StreamSpec(
        volume_per_10min=2500.0,
        n_vehicles=50,
        seed=11,
        length_range_m=(3.5, 7.5),
        width_range_m=(1.6, 2.3),
    )
    res = run_stream(inter, IcaConfig(), spec)
    assert len(res.confirmed) == len(res.vehicles)
    assert rounds["with_conflicts"] > 20
