"""The order in which reorderable vehicles cross so that an emergency vehicle enters first.

When an emergency vehicle (EV) approaches, reactive DICA may still change the
crossing order of some vehicles (the modifiable set). This module states that
choice as a small scheduling problem and solves it three ways. It knows
nothing of routes or plans: the caller turns vehicles into candidates.

**The problem.** Candidate ``k`` has a lane, a release time ``r_k`` [s] (the
earliest it can enter the junction) and, for every other candidate ``j``, a
separation ``sep[j, k] >= 0`` [s]: the least time from ``j``'s entry to
``k``'s when ``j`` goes first (0 for compatible routes). An order is a
permutation that keeps every lane's order (vehicles cannot overtake in a
lane; candidates of one lane are listed front to back). Its entry times are

    e_k = max(r_k, max over j before k of (e_j + sep[j, k])).

The dissertation's recursion uses only the immediate predecessor ``j``; a
vehicle could then follow its lane leader with no gap if a compatible vehicle
of another lane was slotted between them. Counting every earlier vehicle is
what the dissertation's pairwise constraint asks for, and it removes that
loophole. Entries never decrease along an order (``sep >= 0``).

**The objective**, lexicographic: the EV's entry ``e_ev`` first, then the
total delay of the others, ``sum over k != ev of (e_k - r_k)``.

Adding a vehicle before the EV can only delay it (every entry is a maximum
over more terms), so the EV's best entry is that of its own lane's vehicles
ahead of it taken alone (:func:`ev_bound_s`); what the solvers really search
for is where the other vehicles can go at the least total delay without
costing the EV anything.

**The solvers** (:data:`SOLVERS`):

* ``exact``: a dynamic program over how far each lane's queue has been
  taken (``prod(n_lane + 1)`` states, polynomial for a fixed number of
  lanes). A state keeps the Pareto-minimal labels (entry times still able to
  bind a later vehicle, last entry, delay so far); labels that would delay
  the EV beyond its bound, or whose delay cannot beat a greedy order's, are
  dropped. Optimal for the objective above.
* ``exhaustive``: every feasible order, depth first; refuses with
  :class:`TooManyOrders` above a limit instead of running for hours.
* ``ga``: the dissertation's genetic algorithm (permutation encoding,
  one-point crossover with duplicate repair, swap mutation, lane-order
  repair, keep the best ``n_pop``), seeded, with the objective above as its
  fitness (the dissertation's fitness is ``1 / e_ev`` alone).

The inner loops are compiled with numba (explicit signatures, cached on
disk, as in :mod:`ica.core.kernels`); :func:`entries_reference` is the plain
Python oracle of the compiled evaluation.
"""

from __future__ import annotations

import time

import numpy as np

from dica.ica.core.config import SOLVERS
from dica.ica.core.ordering.exact import exact
from dica.ica.core.ordering.exhaustive import exhaustive
from dica.ica.core.ordering.ga import ga
from dica.ica.core.ordering.problem import (
    EPS_S,
    EXHAUSTIVE_LIMIT,
    GaParams,
    OrderingError,
    Problem,
    Solution,
    TooManyOrders,
    better,
    count_orders,
    entries_reference,
    ev_bound_s,
    evaluate,
    feasible,
    greedy,
    greedy_reference,
    solution_of,
)


def solve(
    problem: Problem,
    solver: str,
    *,
    seed: int = 0,
    ga_params: GaParams | None = None,
    limit: int = EXHAUSTIVE_LIMIT,
) -> Solution:
    """One solver by name (:data:`SOLVERS`)."""
    if solver not in SOLVERS:
        raise OrderingError(f"unknown solver {solver!r}: use {', '.join(SOLVERS)}")
    if problem.n == 1:  # nothing to order
        t0 = time.perf_counter()
        return solution_of(problem, np.zeros(1, dtype=np.int64), 1, t0)
    if solver == "exact":
        return exact(problem)
    if solver == "ga":
        return ga(problem, ga_params, seed)
    return exhaustive(problem, limit)


__all__ = [
    "EPS_S", "EXHAUSTIVE_LIMIT", "SOLVERS", "GaParams", "OrderingError", "Problem", "Solution",
    "TooManyOrders", "better", "count_orders", "entries_reference", "ev_bound_s", "evaluate",
    "exact", "exhaustive", "feasible", "ga", "greedy", "greedy_reference", "solve",
]  # fmt: skip
