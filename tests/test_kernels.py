"""The compiled loops give numpy's results: bit for bit where the arithmetic is IEEE's
basic operations and square root, within :data:`LIBM_ULPS` where a libm function
(``atan2``) feeds a value."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dica.ica.core.dica as dica_module
import dica.ica.core.search as search_module
from dica.ica.core import validate
from dica.ica.core.config import IcaConfig
from dica.ica.core.conflict import follow_conflict, follow_conflict_reference, pack
from dica.ica.core.dtot import build_dtot, grid_intervals
from dica.ica.core.kernels.interp import searchsorted
from dica.ica.core.occupancy import footprints
from dica.ica.core.planner import Kinematics, Planner
from dica.ica.core.proposal import propose
from dica.ica.core.request import Reason, RequestError
from dica.ica.core.trajectory import Trajectory, sample
from dica.ica.core.zones import ConflictTables
from dica.sim_gateway.stream import StreamSpec, run_stream
from tests.test_bad_input import cases, tss_with
from tests.test_dtot import SHAPES, trajectories

# A heading is atan2 of a rear-to-front difference. The kernels call the platform's libm
# (glibc documents its atan2 within 1 ulp of the true value); numpy calls its own SIMD
# arctan2 where the CPU has one (AVX-512: Intel's SVML, which numpy's accuracy tests hold
# within a few ulps of the correctly rounded value), and on an AVX-512 Xeon the two were
# seen to differ in the last bit. Two results each within 2 ulps of the true value differ
# by at most 4. IEEE's basic operations and square root are held bit for bit.
LIBM_ULPS = 4


def assert_libm_close(fast: np.ndarray, oracle: np.ndarray) -> None:
    """A libm-fed result against its numpy oracle: within :data:`LIBM_ULPS`."""
    np.testing.assert_array_max_ulp(fast, oracle, maxulp=LIBM_ULPS)


def _atan2_a_last_bit_off(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """np.arctan2 with every other result one ulp up: what a SIMD arctan2 may give."""
    h = np.arctan2(y, x)
    h[::2] = np.nextafter(h[::2], np.inf)
    return h


ORACLE_ATAN2 = {"numpy": np.arctan2, "numpy a last bit off": _atan2_a_last_bit_off}


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
        searchsorted(a, keys, right, out)
        assert np.array_equal(out, np.searchsorted(a, keys, side=side))


@pytest.mark.parametrize("exact", [True, False])
@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_grid_dtot_is_the_numpy_one(request, junction, exact):
    inter = request.getfixturevalue(junction)
    tables = ConflictTables(inter, margin_m=0.25, exact_oti=exact)
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
                lb, ub = grid_intervals(fast.t_s, fast.s_m, rects, grid)
                assert np.array_equal(fast.rects.centre, rects.centre)
                assert np.array_equal(fast.rects.heading, rects.heading)
                assert fast.rects.half_length == rects.half_length
                assert fast.rects.half_width == rects.half_width
                assert np.array_equal(fast.lb_s, lb)
                assert np.array_equal(fast.ub_s, ub)
                assert np.array_equal(fast.grid_idx, grid.index(fast.s_m))


def test_sampled_plans_are_numpys_positions():
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(400):
        pl = Planner(
            float(rng.uniform(0.0, 60)),
            float(rng.uniform(0, 19)),
            70 / 3.6,
            float(rng.uniform(4, 18)),
            float(rng.uniform(15, 45)),
            Kinematics(),
        )
        if not pl.feasible():
            continue
        p = pl.at_or_after(pl.earliest_entry_s() + float(rng.choice([0.0, rng.uniform(0, 30)])))
        if p is None:
            continue
        traj = sample(p, 3.0, 0.05, pl.s_end_m)
        assert np.array_equal(traj.s_m, p.position(0.05 * np.arange(len(traj))))
        checked += 1
    assert checked > 300


@pytest.mark.parametrize("junction", ["ch45", "skewed"])
def test_follow_conflict_is_the_numpy_one(request, monkeypatch, junction):
    """Every lane-leader check of a congested stream, against the numpy version."""
    inter = request.getfixturevalue(junction)
    calls = {"all": 0, "violations": 0}

    def checked(follower, leader, length_m, gap_m):
        fast = follow_conflict(follower, leader, length_m, gap_m)
        assert fast == follow_conflict_reference(follower, leader, length_m, gap_m)
        calls["all"] += 1
        calls["violations"] += fast is not None
        return fast

    monkeypatch.setattr(search_module, "follow_conflict", checked)
    # the Python round loop calls follow_conflict (the compiled one calls the
    # kernel itself, see tests/test_resolve_compiled.py)
    monkeypatch.setattr(dica_module.Dica, "compiled_loop", False)
    spec = StreamSpec(volume_per_10min=2400.0, n_vehicles=40, seed=9)
    res = run_stream(inter, IcaConfig(), spec)
    assert len(res.confirmed) == len(res.vehicles)
    assert calls["all"] > 50


def test_follow_conflict_is_the_numpy_one_close_behind():
    """Random leader and follower plans in one lane, many of them too close."""
    rng = np.random.default_rng(21)
    kin = Kinematics()
    violations = 0
    for _ in range(500):
        d_l = float(rng.uniform(0.0, 30))
        lead = Planner(d_l, float(rng.uniform(0, 15)), 70 / 3.6, 10.0, 30.0, kin)
        d_f = d_l + float(rng.uniform(3.0, 15))
        follow = Planner(d_f, float(rng.uniform(0, 15)), 70 / 3.6, 10.0, 30.0, kin)
        if not (lead.feasible() and follow.feasible()):
            continue
        pl = lead.at_or_after(lead.earliest_entry_s() + float(rng.uniform(0, 6)))
        pf = follow.at_or_after(follow.earliest_entry_s() + float(rng.uniform(0, 6)))
        if pl is None or pf is None:
            continue
        t0_l = float(rng.uniform(-1.0, 0.0))
        lt = sample(pl, t0_l, 0.05, 30.0)
        ft = sample(pf, 0.0, 0.05, 30.0)
        for length in (4.0, 5.0, 7.5):
            fast = follow_conflict(ft, lt, length, 0.5)
            assert fast == follow_conflict_reference(ft, lt, length, 0.5)
            violations += fast is not None
    assert violations > 100


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_project_is_the_numpy_one(request, junction):
    inter = request.getfixturevalue(junction)
    rng = np.random.default_rng(4)
    for route in inter.routes:
        for noise in (0.0, 0.01, 0.3, 3.0):
            s = np.sort(rng.uniform(route.s[0] - 2, route.s[-1] + 2, 200))
            p = route.points(s) + rng.normal(0, noise, (len(s), 2))
            for xy in (p, route.xy):  # vertices exactly: ties between segments
                fast, slow = route.project(xy), route.project_reference(xy)
                assert np.array_equal(fast[0], slow[0])
                assert np.array_equal(fast[1], slow[1])


@pytest.mark.parametrize("junction", ["ch45", "skewed", "tee"])
def test_route_points_are_the_numpy_ones(request, junction):
    inter = request.getfixturevalue(junction)
    rng = np.random.default_rng(6)
    for route in inter.routes:
        lo, hi = route.s[0], route.s[-1]
        for s in (
            rng.uniform(lo - 5, hi + 5, 300),
            np.sort(rng.uniform(lo - 5, hi + 5, 300)),
            route.s.copy(),  # the vertices exactly
            np.concatenate([route.s, [np.nan, lo, hi, lo - 1e-12, hi + 1e-12]]),
            np.zeros(0),
        ):
            assert np.array_equal(route.points(s), route.points_reference(s), equal_nan=True)
            assert route.points(s).shape == route.points_reference(s).shape


@pytest.mark.parametrize("oracle", ORACLE_ATAN2)
@pytest.mark.parametrize("junction", ["ch45", "tee"])
def test_trajectory_fronts_headings_and_entries_are_the_numpy_ones(request, junction, oracle):
    """A TSS's times, front points and headings (the answer to a request), a plan's
    entry time (Algorithm 1's next target) and a confirmed DTOT's packed rows come from
    compiled calls: numpy's bit for bit, the headings (atan2) within LIBM_ULPS. Also
    against an oracle whose arctan2 is a last bit off, as a SIMD one may be."""
    inter = request.getfixturevalue(junction)
    atan2 = ORACLE_ATAN2[oracle]
    shape = SHAPES[0]
    seen = 0
    for route in inter.routes:
        for traj in trajectories(route, shape, seed=len(route.id)):
            front, heading = traj.xy_heading(route, shape.length_m)
            ref_front = route.points_reference(traj.s_m)
            d = ref_front - route.points_reference(traj.s_m - shape.length_m)
            assert np.array_equal(front, ref_front)
            assert_libm_close(heading, atan2(d[:, 1], d[:, 0]))
            t, x, y, h = traj.tss(route, shape.length_m)
            assert np.array_equal(t, traj.t_s)
            assert np.array_equal(x, ref_front[:, 0]) and np.array_equal(y, ref_front[:, 1])
            assert np.array_equal(h, heading)  # both compiled: the same libm
            assert traj.entry_time_s() == traj.entry_time_reference()
            for estimated in (True, False):  # a confirmed DTOT's rows for the batched getCV
                grid = ConflictTables(inter, 0.25).grid(route, shape)
                dt = build_dtot(route, shape, traj, 0.25, grid, estimated)
                r = dt.rects
                cols = [dt.lb_s, dt.ub_s, *r.centre.T, *r.heading.T]
                cols += [np.full(len(dt), r.half_length), np.full(len(dt), r.half_width)]
                assert np.array_equal(pack(dt), np.stack([*cols, dt.grid_idx], axis=1))
            seen += 1
    edges = [
        np.array([-3.0, -2.0, -1.0]),  # never enters
        np.array([0.5, 1.0]),  # inside from the first sample
        np.array([-1.0, 0.0, 0.0, 2.0]),  # stands on the line
        np.array([-1.0, np.nan, 1.0]),
        np.array([-0.1]),
    ]
    for s in edges:
        traj = Trajectory(3.0, 0.05, s)
        fast, slow = traj.entry_time_s(), traj.entry_time_reference()
        assert np.array_equal([fast], [slow], equal_nan=True)
    assert seen > 10


def test_the_heading_bound_takes_a_last_bit_off_that_an_exact_check_fails_on(ch45):
    """What the bound is for, on any machine: the kernel's headings are within it of
    numpy's (which on an AVX-512 numpy differ in the last bit, and elsewhere agree);
    headings a last bit off the kernel's fail an exact check and pass the bound, and
    headings LIBM_ULPS + 1 ulps off fail it (the bound is not idle). Footprint
    headings, which decide conflicts, stay exact."""
    route = ch45.routes[0]
    shape = SHAPES[0]
    traj = next(trajectories(route, shape, seed=3))
    _, heading = traj.xy_heading(route, shape.length_m)
    ref = route.points_reference(traj.s_m)
    d = ref - route.points_reference(traj.s_m - shape.length_m)
    assert_libm_close(heading, np.arctan2(d[:, 1], d[:, 0]))
    off = heading.copy()
    off[::2] = np.nextafter(off[::2], np.inf)
    assert not np.array_equal(heading, off)  # the exact check fails on it
    assert_libm_close(heading, off)  # the stated bound takes it
    far = heading.copy()
    for _ in range(LIBM_ULPS + 1):
        far[len(far) // 2] = np.nextafter(far[len(far) // 2], np.inf)
    with pytest.raises(AssertionError):
        assert_libm_close(heading, far)
    grid = ConflictTables(ch45, 0.25).grid(route, shape)
    dt = build_dtot(route, shape, traj, 0.25, grid, estimated=True)
    rects = footprints(route, dt.s_m, shape.length_m, shape.width_m, 0.25)
    assert np.array_equal(dt.rects.heading, rects.heading)


def test_plan_phases_and_bisection_are_the_python_ones():
    rng = np.random.default_rng(8)
    kin = Kinematics()
    bisected = 0
    for _ in range(300):
        pl = Planner(
            float(rng.uniform(0.0, 60)),
            float(rng.choice([0.0, rng.uniform(0, 19)])),
            70 / 3.6,
            float(rng.uniform(4, 18)),
            30.0,
            kin,
        )
        for v_m in [*rng.uniform(0, 20, 20), 0.0, pl.v0_mps, pl.cap_mps]:
            assert pl._a_phases(float(v_m)) == pl._a_phases_reference(float(v_m))
        if not pl.feasible():
            continue
        v_hi, v_lo = pl._v_max(), pl._v_min_a()
        lo = pl._a_phases_reference(v_lo) if v_lo < v_hi else None
        if lo is None or lo[3] <= pl.earliest_entry_s() + 1e-6:
            continue
        t = float(rng.uniform(pl.earliest_entry_s() + 1e-6, lo[3]))
        lo_v, hi_v = v_lo, v_hi  # the loop as it was written in Python
        for _ in range(60):
            mid = 0.5 * (lo_v + hi_v)
            ph = pl._a_phases_reference(mid)
            if ph is None or ph[3] > t:
                lo_v = mid
            else:
                hi_v = mid
            if hi_v - lo_v < 1e-10:
                break
        assert pl.at_or_after(t).s_m.tolist() == pl._build_a(hi_v).s_m.tolist()
        bisected += 1
    assert bisected > 100


def test_plan_constants_are_the_python_planners():
    """The compiled loop's constants per planner, bit for bit the Python planner's,
    over standing, slow and fast vehicles, near and far, holding or not, both stop
    rules, and vehicles that cannot stop or cannot slow to the cap."""
    rng = np.random.default_rng(9)
    kinds = {"stops": 0, "cannot stop": 0, "infeasible": 0}
    for k in range(1500):
        kin = Kinematics() if k % 3 else Kinematics.at_the_line()
        pl = Planner(
            float(rng.choice([0.0, rng.uniform(0.0, 60), rng.uniform(0.0, 2.0)])),
            float(rng.choice([0.0, rng.uniform(0, 19.5), rng.uniform(0, 2)])),
            70 / 3.6,
            float(rng.uniform(2, 18)),
            float(rng.uniform(10, 40)),
            kin,
            hold=bool(k % 2),
        )
        fast, slow = pl.plan_constants(), pl.plan_constants_reference()
        for name in fast._fields:
            a, b = getattr(fast, name), getattr(slow, name)
            if isinstance(a, np.ndarray):
                assert np.array_equal(a, b) and a.shape == b.shape, name
            else:
                assert a == b, name
        ph = pl._a_phases_reference(pl._v_max())
        assert pl.earliest_entry_s() == (np.inf if ph is None else ph[3])
        kinds["stops"] += bool(np.isfinite(fast.stop_entry_s) and len(fast.b_segs))
        kinds["cannot stop"] += not np.isfinite(fast.stop_entry_s)
        kinds["infeasible"] += not fast.hi_ok
    assert min(kinds.values()) > 20, kinds


def _outcome(check, req, route, cfg):
    try:
        return ("ok", check(req, route, cfg).s_m.tolist())
    except RequestError as e:
        return (e.reason, e.detail)


@pytest.mark.parametrize("junction", ["ch45", "skewed"])
def test_tss_checks_are_the_numpy_ones(request, junction):
    """Every TSS check passes or fails, with the same message, as the numpy version.

    The heading check's deviation comes from atan2 (libm in the kernel, numpy's SIMD
    one in the reference on some CPUs); the deviations drawn here lie far from the
    tolerance (0.2 rad) and from the rounding of the message's two decimals, so a
    last-bit difference changes no outcome."""
    inter = request.getfixturevalue(junction)
    cfg = IcaConfig()
    rng = np.random.default_rng(14)
    outcomes: set[object] = set()
    for k, route in enumerate(inter.routes):
        for d, v in ((40.0, 12.0), (3.0, 0.0), (30.0, 14.0)):
            req = propose(route, vin=f"v{k}", seq=0, t0_s=2.0, dist_to_entry_m=d, speed_mps=v)
            bad = [r for rs in cases(req).values() for r in rs]
            t = req.tss
            n = len(t.t_s)
            for _ in range(12):  # small disturbances around every threshold
                j = int(rng.integers(n))
                which = rng.choice(["x_m", "y_m", "t_s", "heading_rad"])
                a = getattr(t, which).copy()
                a[j:] += rng.choice([-1, 1]) * rng.choice([1e-7, 1e-3, 0.05, 0.3, 2.0])
                bad.append(tss_with(req, **{which: a}))
                bad.append(dataclasses.replace(req, speed_mps=v + float(rng.uniform(-2, 2))))
            for r in [req, *bad]:
                if not isinstance(r.length_m, float) or not np.isfinite(r.length_m):
                    continue
                if r.length_m <= 0 or r.length_m > cfg.max_length_m or r.in_lane != req.in_lane:
                    continue
                if r.out_lane != req.out_lane:
                    continue
                fast = _outcome(validate._check_tss, r, route, cfg)
                assert fast == _outcome(validate._check_tss_reference, r, route, cfg)
                outcomes.add(fast[0])
    assert {"ok", Reason.BAD_TIME, Reason.NOT_FINITE, Reason.OFF_ROUTE, Reason.BAD_STATE} <= (
        outcomes
    )
    assert Reason.LIMITS in outcomes
