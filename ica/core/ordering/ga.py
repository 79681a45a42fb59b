"""The dissertation's genetic algorithm, with the lexicographic objective as its fitness."""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from dica.ica.core.ordering.problem import (
    EPS_S,
    GaParams,
    OrderingError,
    Problem,
    Solution,
    better,
    entries_of,
    lane_members,
    solution_of,
)


# -- GA: the dissertation's genetic algorithm ----------------------------------------------
@njit("void(int64[:, ::1], int64[::1], int64[:, ::1])", cache=True)
def _repair(pop: np.ndarray, slot: np.ndarray, members: np.ndarray) -> None:
    """feasibilityCheck: the positions a lane's vehicles hold get them in lane order."""
    taken = np.zeros(members.shape[0], dtype=np.int64)
    for r in range(pop.shape[0]):
        taken[:] = 0
        for p in range(pop.shape[1]):
            li = slot[pop[r, p]]
            pop[r, p] = members[li, taken[li]]
            taken[li] += 1


@njit("void(int64[::1], int64[::1], int64, int64[::1])", cache=True)
def _one_point(a: np.ndarray, b: np.ndarray, cut: int, out: np.ndarray) -> None:
    """a's genes before ``cut``, then b's remaining genes in b's order (no duplicates)."""
    n = len(a)
    used = np.zeros(n, dtype=np.bool_)
    for p in range(cut):
        out[p] = a[p]
        used[a[p]] = True
    p = cut
    for q in range(n):
        if not used[b[q]]:
            out[p] = b[q]
            p += 1


@njit(
    "int64[:, ::1](int64[:, ::1], int64[:, ::1], int64[::1], int64[:, ::1])",
    cache=True,
)
def _offspring(
    pop: np.ndarray, pairs: np.ndarray, cuts: np.ndarray, swaps: np.ndarray
) -> np.ndarray:
    """Two children per crossing pair; child ``c`` is then mutated by swapping
    ``swaps[c]`` (a pair of positions; -1 means no mutation)."""
    n = pop.shape[1]
    kids = np.empty((2 * len(pairs), n), dtype=np.int64)
    for i in range(len(pairs)):
        a, b = pop[pairs[i, 0]], pop[pairs[i, 1]]
        _one_point(a, b, cuts[i], kids[2 * i])
        _one_point(b, a, cuts[i], kids[2 * i + 1])
    for c in range(len(kids)):
        if swaps[c, 0] >= 0:
            x, y = swaps[c, 0], swaps[c, 1]
            kids[c, x], kids[c, y] = kids[c, y], kids[c, x]
    return kids


@njit(
    "void(int64[:, ::1], float64[::1], float64[:, ::1], int64, float64[::1], float64[::1], "
    "float64[::1], float64[::1])",
    cache=True,
)
def _fitness(
    pop: np.ndarray,
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    deadline: np.ndarray,
    over_out: np.ndarray,
    ev_out: np.ndarray,
    delay_out: np.ndarray,
) -> None:
    """Per individual: the time its vehicles enter past their deadlines, summed (0 for
    an order that keeps them all), the EV's entry and the others' delay."""
    e = np.empty(pop.shape[1])
    for r in range(pop.shape[0]):
        delay_out[r] = entries_of(pop[r], release, sep, ev, e)
        ev_out[r] = e[ev]
        over = 0.0
        for k in range(len(e)):
            if e[k] > deadline[k]:
                over += e[k] - deadline[k]
        over_out[r] = over


def ga(problem: Problem, params: GaParams | None = None, seed: int = 0) -> Solution:
    """The dissertation's GA (Algorithm 3 of chapter 5), seeded; orders that break a
    deadline rank after every order that keeps them (OrderingError if no order found
    does)."""
    p = params or GaParams()
    t0 = time.perf_counter()
    n = problem.n
    rng = np.random.default_rng(seed)
    members, _, slot = lane_members(problem)
    pop = np.ascontiguousarray(rng.permuted(np.tile(np.arange(n), (p.n_pop, 1)), axis=1))
    _repair(pop, slot, members)
    dl = problem.deadline_s
    over, ev_e, delay = np.empty(p.n_pop), np.empty(p.n_pop), np.empty(p.n_pop)
    _fitness(pop, problem.release_s, problem.sep_s, problem.ev, dl, over, ev_e, delay)
    work = p.n_pop
    pop, over, ev_e, delay = _select(pop, over, ev_e, delay, p.n_pop)
    best = (float(over[0]), float(ev_e[0]), float(delay[0]))
    generation, unchanged = 0, 0
    while generation < p.n_max and unchanged < p.n_no_change and n > 1:
        shuffled = rng.permutation(len(pop))
        pairs = shuffled[: len(pop) // 2 * 2].reshape(-1, 2)
        pairs = np.ascontiguousarray(pairs[rng.random(len(pairs)) < p.p_crossover])
        cuts = rng.integers(1, n, len(pairs))
        swaps = rng.integers(0, n, (2 * len(pairs), 2))
        swaps[rng.random(2 * len(pairs)) >= p.p_mutation] = -1
        kids = _offspring(pop, pairs, cuts, np.ascontiguousarray(swaps))
        _repair(kids, slot, members)
        k_over, k_ev, k_delay = np.empty(len(kids)), np.empty(len(kids)), np.empty(len(kids))
        _fitness(kids, problem.release_s, problem.sep_s, problem.ev, dl, k_over, k_ev, k_delay)
        work += len(kids)
        pop, over, ev_e, delay = _select(
            np.concatenate([pop, kids]),
            np.concatenate([over, k_over]),
            np.concatenate([ev_e, k_ev]),
            np.concatenate([delay, k_delay]),
            p.n_pop,
        )
        top = (float(over[0]), float(ev_e[0]), float(delay[0]))
        if top[0] < best[0] - EPS_S or (
            abs(top[0] - best[0]) <= EPS_S and better(top[1:], best[1:])
        ):
            best, unchanged = top, 0
        else:
            unchanged += 1
        generation += 1
    if over[0] > EPS_S:
        raise OrderingError(
            f"the GA found no order that keeps every vehicle's deadline ({over[0]:.3f} s over)"
        )
    return solution_of(problem, pop[0], work, t0)


def _select(
    pop: np.ndarray, over: np.ndarray, ev_e: np.ndarray, delay: np.ndarray, keep: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The best ``keep`` individuals (least time past the deadlines, then EV entry, both
    to EPS_S; then delay), stable."""
    rank = np.lexsort((delay, np.round(ev_e / EPS_S), np.round(over / EPS_S)))[:keep]
    return np.ascontiguousarray(pop[rank]), over[rank], ev_e[rank], delay[rank]
