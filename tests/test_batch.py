"""The batched getCV (techniques 1, 2 and 4 over all confirmed vehicles at once)
answers every round exactly as the per-vehicle search does."""

from __future__ import annotations

import pytest

from ica.core.config import IcaConfig, Techniques
from ica.core.conflict import get_cv
from ica.core.dica import Dica
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
