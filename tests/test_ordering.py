"""The EV ordering solvers: exact equals every-order search, the GA never beats exact,
the compiled evaluation equals its Python oracle, and hand-made cases."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dica.ica.core.ordering import (
    GaParams,
    OrderingError,
    Problem,
    TooManyOrders,
    better,
    count_orders,
    entries_reference,
    ev_bound_s,
    evaluate,
    exact,
    exhaustive,
    feasible,
    ga,
    greedy,
    greedy_reference,
    solve,
)

TIMES = st.sampled_from([0.0, 0.5, 1.0, 1.5, 2.0, 3.1, 4.0, 6.0])
SEPS = st.sampled_from([0.0, 0.0, 0.7, 1.3, 2.0, 2.6])


@st.composite
def problems(draw, max_n: int = 7, max_lanes: int = 4) -> Problem:
    n = draw(st.integers(1, max_n))
    lane = np.array(draw(st.lists(st.integers(0, max_lanes - 1), min_size=n, max_size=n)))
    release = np.array(draw(st.lists(TIMES, min_size=n, max_size=n)))
    sep = np.array(draw(st.lists(SEPS, min_size=n * n, max_size=n * n))).reshape(n, n)
    same = draw(st.sampled_from([0.0, 1.0, 1.8]))
    sep[lane[:, None] == lane[None, :]] = same  # one headway within a lane
    np.fill_diagonal(sep, 0.0)
    return Problem(lane, release, sep, draw(st.integers(0, n - 1)))


def brute_force(p: Problem) -> tuple[float, float]:
    """Every permutation, the lane-order ones kept, evaluated in plain Python."""
    best = None
    for perm in itertools.permutations(range(p.n)):
        if not feasible(p, perm):
            continue
        e, delay = entries_reference(p, list(perm))
        key = (e[p.ev], delay)
        if best is None or better(key, best):
            best = key
    assert best is not None
    return best


def same_key(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return not better(a, b) and not better(b, a)


@settings(max_examples=150, deadline=None)
@given(problems())
def test_exact_equals_exhaustive_and_brute_force(p):
    e, x = exact(p), exhaustive(p)
    assert feasible(p, e.order) and feasible(p, x.order)
    assert same_key(e.key(), x.key())
    if p.n <= 6:
        assert same_key(e.key(), brute_force(p))


@settings(max_examples=60, deadline=None)
@given(problems(max_n=9, max_lanes=5), st.integers(0, 2**31 - 1))
def test_ga_is_never_better_than_exact(p, seed):
    g, e = ga(p, seed=seed), exact(p)
    assert feasible(p, g.order)
    assert not better(g.key(), e.key())


@settings(max_examples=100, deadline=None)
@given(problems(max_n=9, max_lanes=5), st.randoms(use_true_random=False))
def test_compiled_evaluation_equals_the_python_oracle(p, rnd):
    queues = [list(q) for q in p.queues()]
    order = []
    while any(queues):
        q = rnd.choice([q for q in queues if q])
        order.append(int(q.pop(0)))
    e, ev_e, delay = evaluate(p, order)
    ref, ref_delay = entries_reference(p, order)
    assert list(e) == ref
    assert ev_e == ref[p.ev]
    assert delay == pytest.approx(ref_delay, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(problems(max_n=12, max_lanes=5))
def test_compiled_greedy_equals_its_python_oracle(p):
    assert list(greedy(p)) == list(greedy_reference(p))


@settings(max_examples=100, deadline=None)
@given(problems(max_n=8))
def test_nothing_before_the_ev_makes_it_earlier_than_its_own_lane(p):
    assert exact(p).ev_entry_s == pytest.approx(ev_bound_s(p), abs=1e-9)


def test_a_free_vehicle_goes_before_the_ev_when_it_costs_the_ev_nothing():
    # lane 0: the EV, arriving at 5 s; lane 1: a conflicting car ready now; 1.5 s apart
    sep = np.array([[0.0, 1.5], [1.5, 0.0]])
    p = Problem(np.array([0, 1]), np.array([5.0, 0.0]), sep, ev=0)
    for solver in ("exact", "exhaustive", "ga"):
        s = solve(p, solver)
        assert s.order == (1, 0) and s.ev_entry_s == 5.0 and s.delay_s == 0.0


def test_a_conflicting_vehicle_waits_when_it_would_delay_the_ev():
    sep = np.array([[0.0, 2.0], [2.0, 0.0]])
    p = Problem(np.array([0, 1]), np.array([1.0, 0.0]), sep, ev=0)
    s = exact(p)
    assert s.order == (0, 1) and s.ev_entry_s == 1.0 and s.delay_s == pytest.approx(3.0)


def test_the_lane_ahead_of_the_ev_goes_first_and_keeps_its_order():
    # lane 0: two cars then the EV; lane 1: one car; every pair conflicts
    sep = np.full((4, 4), 1.0)
    np.fill_diagonal(sep, 0.0)
    p = Problem(np.array([0, 0, 0, 1]), np.array([0.0, 0.0, 0.0, 0.0]), sep, ev=2)
    s = exact(p)
    assert s.order == (0, 1, 2, 3)
    assert s.ev_entry_s == 2.0


def test_compatible_vehicles_cross_together():
    p = Problem(np.array([0, 1, 2]), np.array([1.0, 1.0, 1.0]), np.zeros((3, 3)), ev=1)
    s = exact(p)
    assert s.ev_entry_s == 1.0 and s.delay_s == 0.0


def test_a_lone_ev():
    p = Problem(np.array([3]), np.array([2.5]), np.zeros((1, 1)), ev=0)
    for solver in ("exact", "exhaustive", "ga"):
        assert solve(p, solver).order == (0,)


def test_exhaustive_refuses_above_its_limit_and_says_why():
    n = 9
    p = Problem(np.arange(n), np.zeros(n), np.ones((n, n)) - np.eye(n), ev=0)
    assert count_orders(p) == 362_880
    with pytest.raises(TooManyOrders, match="362,880 orders, over the limit of 362,879"):
        exhaustive(p, limit=362_879)
    assert exhaustive(p, limit=362_880).work == 362_880


def test_count_orders_is_the_multinomial():
    p = Problem(np.array([0, 0, 1, 1, 1, 2]), np.zeros(6), np.zeros((6, 6)), ev=0)
    assert count_orders(p) == 60  # 6! / (2! 3! 1!)


def test_ga_is_reproducible_with_its_seed():
    rng = np.random.default_rng(3)
    n = 12
    sep = rng.choice([0.0, 1.0, 2.0], size=(n, n))
    p = Problem(rng.integers(0, 4, n), rng.uniform(0, 5, n), sep, ev=5)
    a, b = ga(p, seed=7), ga(p, seed=7)
    assert a.order == b.order and a.work == b.work


def test_ga_settings_are_checked():
    with pytest.raises(OrderingError):
        GaParams(n_pop=1)
    with pytest.raises(OrderingError):
        GaParams(p_crossover=1.5)


@pytest.mark.parametrize(
    ("lane", "release", "sep", "ev"),
    [
        ([0, 1], [0.0, 0.0], [[0.0, -1.0], [0.0, 0.0]], 0),  # negative separation
        ([0, 1], [0.0, np.inf], [[0.0, 0.0], [0.0, 0.0]], 0),  # never released
        ([0, 1], [0.0, 0.0], [[0.0, 0.0], [0.0, 0.0]], 2),  # no such EV
        ([0, 1], [0.0], [[0.0, 0.0], [0.0, 0.0]], 0),  # sizes disagree
    ],
)
def test_malformed_problems_are_refused(lane, release, sep, ev):
    with pytest.raises(OrderingError):
        Problem(np.array(lane), np.array(release), np.array(sep), ev)


def test_an_order_that_breaks_a_lane_is_refused():
    p = Problem(np.array([0, 0]), np.zeros(2), np.zeros((2, 2)), ev=1)
    assert not feasible(p, [1, 0])
    with pytest.raises(OrderingError):
        evaluate(p, [1, 0])
    with pytest.raises(OrderingError, match="unknown solver"):
        solve(p, "annealing")


# -- a bound on what a reordering may add to anyone ------------------------------------
BUDGETS = st.sampled_from([0.0, 0.0, 0.4, 1.3, 3.0, np.inf])


@st.composite
def bounded_problems(draw, max_n: int = 7, max_lanes: int = 4) -> tuple[Problem, list[int]]:
    """A problem whose deadlines are, as reactive DICA sets them, each vehicle's entry in
    the present order plus what it may still be delayed (the EV has none), and that
    present order (which therefore keeps them all)."""
    p = draw(problems(max_n, max_lanes))
    queues = [list(q) for q in p.queues()]
    present: list[int] = []
    while any(queues):
        q = draw(st.sampled_from([q for q in queues if q]))
        present.append(int(q.pop(0)))
    e, _, _ = evaluate(p, present)
    budget = np.array(draw(st.lists(BUDGETS, min_size=p.n, max_size=p.n)))
    deadline = e + budget
    deadline[p.ev] = np.inf
    return Problem(p.lane, p.release_s, p.sep_s, p.ev, deadline), present


def brute_force_within(p: Problem) -> tuple[float, float] | None:
    """:func:`brute_force` over the orders that keep every deadline (None: no such order)."""
    best = None
    for perm in itertools.permutations(range(p.n)):
        if not feasible(p, perm):
            continue
        e, delay = entries_reference(p, list(perm))
        if any(e[k] > p.deadline_s[k] + 1e-9 for k in range(p.n)):
            continue
        key = (e[p.ev], delay)
        if best is None or better(key, best):
            best = key
    return best


def keeps_deadlines(p: Problem, order) -> bool:
    e, _, _ = evaluate(p, order)
    return p.lateness_s(e) <= 1e-9


@settings(max_examples=200, deadline=None)
@given(bounded_problems())
def test_under_deadlines_exact_equals_exhaustive_and_brute_force(pp):
    p, present = pp
    e, x = exact(p), exhaustive(p)
    assert keeps_deadlines(p, e.order) and keeps_deadlines(p, x.order)
    assert same_key(e.key(), x.key())
    if p.n <= 6:
        best = brute_force_within(p)
        assert best is not None  # the present order keeps them
        assert same_key(e.key(), best)
    # never worse for the EV than the present order
    _, ev_present, _ = evaluate(p, present)
    assert e.ev_entry_s <= ev_present + 1e-9


@settings(max_examples=60, deadline=None)
@given(bounded_problems(max_n=9, max_lanes=5), st.integers(0, 2**31 - 1))
def test_under_deadlines_the_ga_keeps_them_or_says_so(pp, seed):
    p, _ = pp
    best = exact(p)
    try:
        g = ga(p, seed=seed)
    except OrderingError as err:
        assert "deadline" in str(err)
        return
    assert keeps_deadlines(p, g.order)
    assert not better(g.key(), best.key())


def test_a_zero_bound_keeps_the_present_order_and_enough_room_lets_the_ev_first():
    # lane 0: a (released 0) then b (released 0.5); lane 1: the EV (released 1.0);
    # a conflicts with the EV (2 s either way); b is compatible with everyone
    sep = np.array([[0.0, 1.0, 2.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    free = Problem(np.array([0, 0, 1]), np.array([0.0, 0.5, 1.0]), sep, 2)
    present = [0, 1, 2]  # a, b, EV: the EV enters at 2.0
    e_present, ev_present, _ = evaluate(free, present)
    assert ev_present == pytest.approx(2.0)
    # unbounded, the EV goes first (1.0) and a waits till 3.0, b till 4.0
    unbounded = exact(free)
    assert unbounded.ev_entry_s == pytest.approx(1.0)
    assert unbounded.entry_s[0] == pytest.approx(3.0)
    deadline = e_present.copy()
    deadline[2] = np.inf
    bounded = Problem(free.lane, free.release_s, free.sep_s, 2, deadline)
    for sol in (exact(bounded), exhaustive(bounded)):
        assert list(sol.order) == present
        assert sol.ev_entry_s == pytest.approx(2.0)
    # 3 s to spare for a and b: the EV goes first again; 2.9 s: not yet
    for spare, ev_entry in ((2.9, 2.0), (3.0, 1.0)):
        d = e_present + spare
        d[2] = np.inf
        p = Problem(free.lane, free.release_s, free.sep_s, 2, d)
        for sol in (exact(p), exhaustive(p)):
            assert sol.ev_entry_s == pytest.approx(ev_entry)


def test_deadlines_no_order_keeps_are_refused_by_every_solver():
    sep = np.array([[0.0, 2.0], [2.0, 0.0]])
    p = Problem(np.array([0, 1]), np.array([0.0, 0.0]), sep, 1, np.array([1.0, 1.0]))
    for solver in ("exact", "exhaustive", "ga"):
        with pytest.raises(OrderingError, match="deadline"):
            solve(p, solver)
    with pytest.raises(OrderingError, match="deadlines"):
        Problem(np.array([0, 1]), np.array([0.0, 0.0]), sep, 1, np.array([1.0, np.nan]))
