"""Entry separations for ordering: measured up front, the same as measured on demand."""

from __future__ import annotations

import numpy as np
import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica
from dica.ica.core.separation import SeparationModel
from dica.ica.core.zones import Shape


def _model(inter) -> SeparationModel:
    cfg = IcaConfig()
    tables = Dica(inter, cfg).tables
    return SeparationModel(
        inter, tables, Shape.of(5.0, 1.8), cfg.kinematics, cfg.margin_m, cfg.step_s
    )


@pytest.mark.parametrize("junction", ["tee", "ch45"])
def test_after_precompute_no_separation_is_measured_and_each_is_the_one_measured_on_demand(
    request, monkeypatch, junction
):
    """Every pair of routes and entry speeds a request can bring (standing to beyond
    the road's speed) is looked up, none measured; and each equals what a model that
    measures on demand gives."""
    inter = request.getfixturevalue(junction)
    ahead = _model(inter)
    n = ahead.precompute()
    assert n == len(ahead._measured) > 0

    def measure(*args):
        raise AssertionError(f"measured after precompute: {args}")

    lazy = _model(inter)
    monkeypatch.setattr(ahead, "_measure", measure)
    rng = np.random.default_rng(3)
    routes = inter.routes
    for _ in range(3000):
        a, b = routes[rng.integers(len(routes))], routes[rng.integers(len(routes))]
        va, vb = (float(x) for x in rng.choice([0.0, 1.4, 6.0, 30.0, *rng.uniform(0, 25, 4)], 2))
        assert ahead.separation_s(a, va, b, vb) == lazy.separation_s(a, va, b, vb)
    assert len(lazy._measured) > 0.2 * n  # the draws met a good part of the table
