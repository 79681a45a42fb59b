"""Offline tables and technique 3's intervals are never less safe than the exhaustive ones."""

from __future__ import annotations

import numpy as np
import pytest

from dica.ica.core.dtot import build_dtot
from dica.ica.core.occupancy import footprints, overlap_matrix, overlap_pairs
from dica.ica.core.planner import Kinematics, Planner
from dica.ica.core.trajectory import Trajectory, sample
from dica.ica.core.zones import ConflictTables, Shape

SHAPES = [Shape.of(5.0, 1.8), Shape.of(7.3, 2.2), Shape.of(3.6, 1.6)]


def trajectories(route, shape, seed):
    rng = np.random.default_rng(seed)
    s_end = route.cross_length_m + shape.length_m
    for _ in range(4):
        pl = Planner(
            float(rng.uniform(0.5, 50)),
            float(rng.uniform(0, 19)),
            70 / 3.6,
            route.speed_cap_mps,
            s_end,
            Kinematics(),
        )
        if not pl.feasible():
            continue
        p = pl.at_or_after(pl.earliest_entry_s() + float(rng.uniform(0, 8)))
        if p is not None:
            yield sample(p, 0.0, 0.05, s_end)


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_estimated_intervals_contain_exhaustive(request, junction):
    """The dissertation's technique 3: never narrower, and wider somewhere."""
    inter = request.getfixturevalue(junction)
    tables = ConflictTables(inter, margin_m=0.25, exact_oti=False)
    wider = 0
    for k, route in enumerate(inter.routes):
        for shape in SHAPES:
            for traj in trajectories(route, shape, k):
                exact = build_dtot(route, shape, traj, 0.25)
                est = build_dtot(
                    route, shape, traj, 0.25, tables.grid(route, shape), estimated=True
                )
                assert (est.lb_s <= exact.lb_s + 1e-12).all()
                assert (est.ub_s >= exact.ub_s - 1e-12).all()
                wider += int((est.ub_s - est.lb_s > exact.ub_s - exact.lb_s).any())
    assert wider > 0


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_exact_grid_intervals_are_the_exhaustive_ones(request, junction):
    """Enhanced DICA's technique 3 finds getOTI's intervals exactly, also a rounding
    error off monotone and at a standstill inside the junction."""
    inter = request.getfixturevalue(junction)
    tables = ConflictTables(inter, margin_m=0.25)
    rng = np.random.default_rng(5)
    for k, route in enumerate(inter.routes):
        for shape in SHAPES:
            grid = tables.grid(route, shape)
            trajs = list(trajectories(route, shape, k))
            for traj in trajs[:2]:
                s = traj.s_m.copy()
                j = int(rng.integers(1, len(s) - 1))
                s[j] = np.nextafter(s[j - 1], -np.inf)
                trajs.append(Trajectory(traj.t0_s, traj.step_s, s))
                inside = np.flatnonzero((s > 1.0) & (s < route.cross_length_m))
                if len(inside):  # stands still for a second somewhere inside
                    q = int(inside[len(inside) // 2])
                    held = np.concatenate([s[:q], np.full(20, s[q]), s[q:]])
                    trajs.append(Trajectory(traj.t0_s, traj.step_s, held))
            for traj in trajs:
                exact = build_dtot(route, shape, traj, 0.25)
                fast = build_dtot(route, shape, traj, 0.25, grid, estimated=True)
                assert np.array_equal(fast.lb_s, exact.lb_s)
                assert np.array_equal(fast.ub_s, exact.ub_s)


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_skip_distances_only_skip_overlapping_footprints(request, junction):
    """Off the grid, any two footprints within the exact tables' skip distance
    overlap, and any two beyond the dissertation's do not."""
    inter = request.getfixturevalue(junction)
    sure = ConflictTables(inter, margin_m=0.25)
    clear = ConflictTables(inter, margin_m=0.25, exact_oti=False)
    rng = np.random.default_rng(9)
    for route in inter.routes:
        for shape in SHAPES[:2]:
            g_sure, g_clear = sure.grid(route, shape), clear.grid(route, shape)
            lo, hi = g_sure.s0_m, g_sure.s0_m + g_sure.ds_m * (len(g_sure.fwd_m) - 1)
            s = rng.uniform(lo, hi, 400)  # a DTOT lies on the grid
            here = footprints(route, s, shape.length_m, shape.width_m, 0.25)
            for sign, sure_m, clear_m in (
                (-1.0, g_sure.skip_behind_m(s), g_clear.skip_behind_m(s)),
                (1.0, g_sure.skip_ahead_m(s), g_clear.skip_ahead_m(s)),
            ):
                assert (sure_m < clear_m).all()
                near = s + sign * sure_m * rng.uniform(0.0, 1.0, len(s))
                far = s + sign * (clear_m + rng.uniform(0.0, 3.0, len(s)))
                for other, want in ((near, True), (far, False)):
                    on = np.flatnonzero((other >= lo) & (other <= hi))
                    there = footprints(route, other[on], shape.length_m, shape.width_m, 0.25)
                    hit = overlap_pairs(here, on, there, np.arange(len(on)))
                    assert (hit == want).all()
            assert (g_sure.fwd_m > 3.0).sum() > len(g_sure.fwd_m) // 2  # it does skip


@pytest.mark.parametrize("junction", ["ch45", "skewed"])
def test_conflict_zones_cover_every_overlap_off_grid(request, junction):
    """Positions between grid points: any real overlap lies inside both zones."""
    inter = request.getfixturevalue(junction)
    tables = ConflictTables(inter, margin_m=0.25)
    rng = np.random.default_rng(7)
    shape = SHAPES[0]
    routes = inter.routes
    for _ in range(40):
        ra, rb = routes[rng.integers(len(routes))], routes[rng.integers(len(routes))]
        sa = rng.uniform(-1.0, ra.cross_length_m + shape.length_m + 1.0, 300)
        sb = rng.uniform(-1.0, rb.cross_length_m + shape.length_m + 1.0, 300)
        fa = footprints(ra, sa, shape.length_m, shape.width_m, 0.25)
        fb = footprints(rb, sb, shape.length_m, shape.width_m, 0.25)
        hit = overlap_matrix(fa, fb)
        za = tables.zone(ra, shape, rb, shape)[tables.grid(ra, shape).index(sa)]
        zb = tables.zone(rb, shape, ra, shape)[tables.grid(rb, shape).index(sb)]
        assert za[hit.any(axis=1)].all()
        assert zb[hit.any(axis=0)].all()
        if tables.compatible(ra, shape, rb, shape):
            assert not hit.any()


def test_compatible_routes_exist_and_same_lane_routes_conflict(ch45):
    tables = ConflictTables(ch45, margin_m=0.25)
    shape = SHAPES[0]
    pairs = [(a, b) for a in ch45.routes for b in ch45.routes if a.id < b.id]
    compatible = [p for p in pairs if tables.compatible(p[0], shape, p[1], shape)]
    assert 0 < len(compatible) < len(pairs)
    for a, b in pairs:
        if a.in_lane == b.in_lane or a.out_lane == b.out_lane:
            assert not tables.compatible(a, shape, b, shape)
