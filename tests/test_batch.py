"""The batched getCV (techniques 1, 2 and 4 over all confirmed vehicles at once)
answers every round exactly as the per-vehicle search does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dica.ica.core.config import IcaConfig, Techniques
from dica.ica.core.conflict import get_cv, occupancies
from dica.ica.core.dica import Dica
from dica.ica.core.kernels.conflict import Occupancies, Rows, first_conflict
from dica.sim_gateway.stream import StreamSpec, run_stream


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
        g, rows = batch.gathered, batch.rows
        order = np.argsort(g.packed[rows.m_idx, 0])
        rows = rows._replace(
            m_idx=rows.m_idx[order],
            row=rows.row[order],
            row_lo=rows.row_lo[order],
            row_hi=rows.row_hi[order],
            lb_s=np.ascontiguousarray(g.packed[rows.m_idx[order], 0]),
        )
        heads = [c.first_time_s for c in found[:1]]
        for bound in (math.inf, *heads, *(h - 0.05 for h in heads)):
            v, first, delay = first_conflict(occupancies(dtot), rows, bound)
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


def _first(rows: list[tuple[float, float, int]], span: float) -> tuple[int, float, float]:
    """first_conflict of one occupancy held from 10 to 11 s against confirmed rows
    (lb, ub, vehicle) on a grid point that always touches it."""
    n = len(rows)
    packed = np.zeros((n, 9))
    for q, (lb, ub, _) in enumerate(rows):
        packed[q, :2] = lb, ub
    one = np.zeros(1, np.int64)
    occ = Occupancies(
        lb_s=np.array([10.0]),
        ub_s=np.array([11.0]),
        grid_idx=one,
        centre=np.zeros((1, 2)),
        heading=np.array([[1.0, 0.0]]),
        half_l_m=1.0,
        half_w_m=1.0,
    )
    vid = np.array([v for *_, v in rows], np.int64)
    zeros = np.zeros(n, np.int64)
    confirmed = Rows(
        packed=packed,
        vid=vid,
        m_idx=np.arange(n),
        row=zeros,
        row_lo=zeros,
        row_hi=zeros,
        codes=np.full(1, 2, np.int8),  # TOUCH
        width=1,
        nv=int(vid.max()) + 1,
        span_s=span,
        lb_s=np.array([lb for lb, *_ in rows]),
    )
    return first_conflict(occ, confirmed, math.inf)


def test_first_conflict_skips_only_rows_that_end_before_the_requester():
    """The binary-search skip of rows that start more than the longest interval before
    the requester: a row that ends exactly when the requester starts still conflicts
    (closed intervals), one that ends a hair before does not, whether or not it is the
    longest; with no skip (a NaN span) the answer is the same."""
    cases = {
        "touching, the longest": ([(8.0, 10.0, 0)], (0, 8.0, 0.0)),
        "touching, a longer one before it": ([(7.0, 9.999, 1), (8.0, 10.0, 0)], (0, 8.0, 0.0)),
        "ends a hair before": ([(8.0, 10.0 - 1e-9, 0)], (-1, 0.0, 0.0)),
        "overlaps": ([(7.0, 9.5, 1), (9.0, 10.5, 0)], (0, 9.0, 0.5)),
    }
    for name, (rows, want) in cases.items():
        span = max(ub - lb for lb, ub, _ in rows)
        assert _first(rows, span) == want, name
        assert _first(rows, math.nan) == want, name
