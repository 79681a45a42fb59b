"""The exhaustive solver: every feasible order, depth first, up to a limit."""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from dica.ica.core.ordering.problem import (
    EXHAUSTIVE_LIMIT,
    OrderingError,
    Problem,
    Solution,
    TooManyOrders,
    count_orders,
    lane_members,
    solution_of,
)


# -- exhaustive: every feasible order ---------------------------------------------------
@njit(
    "Tuple((int64[::1], int64, boolean))(float64[::1], float64[:, ::1], int64, int64[:, ::1], "
    "int64[::1], float64[::1])",
    cache=True,
)
def _exhaustive(
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    members: np.ndarray,
    sizes: np.ndarray,
    deadline: np.ndarray,
) -> tuple[np.ndarray, int, bool]:
    """Depth first through every interleaving of the lane queues that keeps every
    deadline (a branch ends where a vehicle would enter past its own); returns (best,
    orders, whether any order kept them)."""
    n = len(release)
    n_lanes = len(sizes)
    eps = 1e-9
    order = np.empty(n, dtype=np.int64)
    lane_at = np.empty(n, dtype=np.int64)  # which lane was taken at each depth
    e = np.empty(n)
    delay_at = np.zeros(n + 1)
    counts = np.zeros(n_lanes, dtype=np.int64)
    best = np.empty(n, dtype=np.int64)
    best_ev, best_delay = np.inf, np.inf
    found = False
    orders = 0
    depth = 0
    next_lane = np.zeros(n + 1, dtype=np.int64)  # next lane to try at each depth
    while depth >= 0:
        if depth == n:
            orders += 1
            ev_t, d = e[ev], delay_at[n]
            if (
                not found
                or ev_t < best_ev - eps
                or (ev_t <= best_ev + eps and d < best_delay - eps)
            ):
                found = True
                best_ev, best_delay = ev_t, d
                best[:] = order
            depth -= 1
            if depth >= 0:
                counts[lane_at[depth]] -= 1
            continue
        li = next_lane[depth]
        while li < n_lanes and counts[li] >= sizes[li]:
            li += 1
        if li == n_lanes:
            next_lane[depth] = 0
            depth -= 1
            if depth >= 0:
                counts[lane_at[depth]] -= 1
            continue
        next_lane[depth] = li + 1
        k = members[li, counts[li]]
        t = release[k]
        for q in range(depth):
            j = order[q]
            v = e[j] + sep[j, k]
            if v > t:
                t = v
        if t > deadline[k] + eps:
            continue  # every order from here lets k in too late
        e[k] = t
        order[depth] = k
        lane_at[depth] = li
        delay_at[depth + 1] = delay_at[depth] + (t - release[k] if k != ev else 0.0)
        counts[li] += 1
        depth += 1
        next_lane[depth] = 0
    return best, orders, found


def exhaustive(problem: Problem, limit: int = EXHAUSTIVE_LIMIT) -> Solution:
    """The best of every feasible order that keeps the deadlines; :class:`TooManyOrders`
    above ``limit`` orders (counted without the deadlines, which only prune)."""
    total = count_orders(problem)
    if total > limit:
        raise TooManyOrders(
            f"exhaustive search refused: {problem.n} vehicles in {len(problem.queues())} lanes "
            f"have {total:,} orders, over the limit of {limit:,}"
        )
    t0 = time.perf_counter()
    members, sizes, _ = lane_members(problem)
    best, orders, found = _exhaustive(
        problem.release_s, problem.sep_s, problem.ev, members, sizes, problem.deadline_s
    )
    if not found:
        raise OrderingError("no order keeps every vehicle's deadline")
    return solution_of(problem, best, orders, t0)
