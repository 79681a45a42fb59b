"""The compiled loops give numpy's results bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from ica.core.dtot import build_dtot, estimated_intervals
from ica.core.kernels import _searchsorted
from ica.core.occupancy import footprints
from ica.core.trajectory import Trajectory
from ica.core.zones import ConflictTables
from tests.test_dtot import SHAPES, trajectories


@pytest.mark.parametrize("right", [False, True])
def test_searchsorted_is_numpys_even_on_unsorted_input(right):
    rng = np.random.default_rng(3)
    side = "right" if right else "left"
    for _ in range(300):
        a = np.sort(rng.integers(0, 30, rng.integers(1, 40)).astype(float))
        if rng.random() < 0.5:  # not quite sorted, as a trajectory off by a rounding error
            k = rng.integers(len(a))
            a[k] += rng.choice([-1.0, 1.0]) * rng.random() * 3
        keys = rng.integers(-3, 33, rng.integers(1, 60)).astype(float)
        if rng.random() < 0.5:
            keys = np.sort(keys)
        out = np.empty(len(keys), np.int64)
        _searchsorted(a, keys, right, out)
        assert np.array_equal(out, np.searchsorted(a, keys, side=side))


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_estimated_dtot_is_the_numpy_one(request, junction):
    inter = request.getfixturevalue(junction)
    tables = ConflictTables(inter, margin_m=0.25)
    rng = np.random.default_rng(11)
    for k, route in enumerate(inter.routes):
        for shape in SHAPES:
            grid = tables.grid(route, shape)
            trajs = list(trajectories(route, shape, k))
            if trajs:  # one trajectory a rounding error off monotone
                s = trajs[0].s_m.copy()
                j = int(rng.integers(1, len(s) - 1))
                s[j] = np.nextafter(s[j - 1], -np.inf)
                trajs.append(Trajectory(trajs[0].t0_s, trajs[0].step_s, s))
            for traj in trajs:
                fast = build_dtot(route, shape, traj, 0.25, grid, estimated=True)
                rects = footprints(route, fast.s_m, shape.length_m, shape.width_m, 0.25)
                lb, ub = estimated_intervals(fast.t_s, fast.s_m, grid)
                assert np.array_equal(fast.rects.centre, rects.centre)
                assert np.array_equal(fast.rects.heading, rects.heading)
                assert fast.rects.half_length == rects.half_length
                assert fast.rects.half_width == rects.half_width
                assert np.array_equal(fast.lb_s, lb)
                assert np.array_equal(fast.ub_s, ub)
                assert np.array_equal(fast.grid_idx, grid.index(fast.s_m))
