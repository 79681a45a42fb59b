"""The EV ordering problem: candidates, orders, their entries and delay, the greedy order
(see :mod:`dica.ica.core.ordering`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

EPS_S = 1e-9  # [s] entry times closer than this count as equal
EXHAUSTIVE_LIMIT = 1_000_000  # orders; about a second of search at 12 candidates
_NEG = -np.inf


class OrderingError(ValueError):
    """A problem that is not well formed (sizes, non-finite times, negative separations)."""


class TooManyOrders(OrderingError):
    """The exhaustive search would have to try more orders than its limit."""


@dataclass(frozen=True, slots=True, eq=False)
class Problem:
    """Candidates ``0..n-1``: lane index, release time [s], separations [s], the EV's index,
    and optionally a deadline per candidate [s] (the latest entry it may be given; inf or
    None: none), which is how a bound on the delay a reordering adds reaches the solvers.

    Within a lane, candidates keep the order of their indices (front first).
    """

    lane: np.ndarray  # int64 (n,)
    release_s: np.ndarray  # float64 (n,)
    sep_s: np.ndarray  # float64 (n, n): sep_s[j, k] when j enters before k
    ev: int
    deadline_s: np.ndarray | None = None  # float64 (n,), inf where there is none

    def __post_init__(self) -> None:
        lane = np.ascontiguousarray(self.lane, dtype=np.int64)
        release = np.ascontiguousarray(self.release_s, dtype=float)
        sep = np.ascontiguousarray(self.sep_s, dtype=float)
        n = len(lane)
        if n < 1 or release.shape != (n,) or sep.shape != (n, n):
            raise OrderingError(
                f"need n >= 1 lanes, releases and an n x n separation matrix, got "
                f"{lane.shape}, {release.shape}, {sep.shape}"
            )
        if not (np.isfinite(release).all() and np.isfinite(sep).all()):
            raise OrderingError("release times and separations must be finite")
        if (sep < 0).any():
            raise OrderingError("separations must not be negative")
        if (lane < 0).any():
            raise OrderingError("lane indices must not be negative")
        if not 0 <= self.ev < n:
            raise OrderingError(f"the EV index {self.ev} is not a candidate (n = {n})")
        deadline = (
            np.full(n, np.inf)
            if self.deadline_s is None
            else np.ascontiguousarray(self.deadline_s, dtype=float)
        )
        if deadline.shape != (n,) or np.isnan(deadline).any():
            raise OrderingError(f"need n deadlines (inf for none), got {deadline.shape}")
        object.__setattr__(self, "deadline_s", deadline)
        object.__setattr__(self, "lane", lane)
        object.__setattr__(self, "release_s", release)
        object.__setattr__(self, "sep_s", sep)

    @property
    def n(self) -> int:
        return len(self.lane)

    @property
    def bounded(self) -> bool:
        """Does any candidate have a deadline?"""
        assert self.deadline_s is not None
        return bool(np.isfinite(self.deadline_s).any())

    def lateness_s(self, entry_s: np.ndarray) -> float:
        """How far the latest candidate of ``entry_s`` (by index) enters past its deadline
        (0 or less: every deadline kept)."""
        assert self.deadline_s is not None
        return float(np.max(entry_s - self.deadline_s))

    def queues(self) -> list[np.ndarray]:
        """Candidate indices per lane that has any, front first (lanes in ascending id)."""
        return [np.flatnonzero(self.lane == ln) for ln in np.unique(self.lane)]


@dataclass(frozen=True, slots=True, eq=False)
class Solution:
    order: tuple[int, ...]
    entry_s: np.ndarray  # per candidate index
    ev_entry_s: float
    delay_s: float  # total delay of the candidates other than the EV over their release
    work: int  # orders (exhaustive), labels (exact) or individuals (ga) evaluated
    solve_s: float  # wall time of the solve

    def key(self) -> tuple[float, float]:
        return (self.ev_entry_s, self.delay_s)


@dataclass(frozen=True, slots=True)
class GaParams:
    """The dissertation's settings (chapter 5)."""

    n_pop: int = 100
    n_no_change: int = 10
    p_crossover: float = 0.85
    p_mutation: float = 0.05
    n_max: int = 100

    def __post_init__(self) -> None:
        if self.n_pop < 2 or self.n_max < 1 or self.n_no_change < 1:
            raise OrderingError("GA needs n_pop >= 2, n_max >= 1 and n_no_change >= 1")
        if not (0 <= self.p_crossover <= 1 and 0 <= self.p_mutation <= 1):
            raise OrderingError("GA probabilities must lie in [0, 1]")


def better(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Is objective ``a`` (EV entry, delay) strictly better than ``b``?"""
    if a[0] < b[0] - EPS_S:
        return True
    if a[0] > b[0] + EPS_S:
        return False
    return a[1] < b[1] - EPS_S


# -- evaluation ----------------------------------------------------------------------
@njit("float64(int64[::1], float64[::1], float64[:, ::1], int64, float64[::1])", cache=True)
def entries_of(
    order: np.ndarray, release: np.ndarray, sep: np.ndarray, ev: int, out: np.ndarray
) -> float:
    """Entry times of ``order`` into ``out`` (by candidate); returns the others' total delay."""
    n = len(order)
    delay = 0.0
    for i in range(n):
        k = order[i]
        t = release[k]
        for q in range(i):
            j = order[q]
            v = out[j] + sep[j, k]
            if v > t:
                t = v
        out[k] = t
        if k != ev:
            delay += t - release[k]
    return delay


def entries_reference(problem: Problem, order: list[int]) -> tuple[list[float], float]:
    """:func:`evaluate` in plain Python: the oracle of the compiled loop."""
    e = [0.0] * problem.n
    delay = 0.0
    for i, k in enumerate(order):
        t = float(problem.release_s[k])
        for j in order[:i]:
            t = max(t, e[j] + float(problem.sep_s[j, k]))
        e[k] = t
        if k != problem.ev:
            delay += t - float(problem.release_s[k])
    return e, delay


def feasible(problem: Problem, order: list[int] | tuple[int, ...] | np.ndarray) -> bool:
    """A permutation of the candidates that keeps every lane's order."""
    order = list(order)
    if sorted(order) != list(range(problem.n)):
        return False
    for q in problem.queues():
        pos = [order.index(int(k)) for k in q]
        if pos != sorted(pos):
            return False
    return True


def evaluate(problem: Problem, order) -> tuple[np.ndarray, float, float]:
    """Entry times (by candidate), the EV's entry and the others' total delay of ``order``."""
    o = np.ascontiguousarray(order, dtype=np.int64)
    if not feasible(problem, o):
        raise OrderingError(f"{list(o)} is not a feasible order of {problem.n} candidates")
    out = np.empty(problem.n)
    delay = entries_of(o, problem.release_s, problem.sep_s, problem.ev, out)
    return out, float(out[problem.ev]), float(delay)


def total_delay(problem: Problem, order: np.ndarray) -> float:
    """The others' total delay of an order the solvers made (feasible by construction)."""
    e = np.empty(problem.n)
    return float(entries_of(order, problem.release_s, problem.sep_s, problem.ev, e))


def ev_bound_s(problem: Problem) -> float:
    """The EV's earliest entry: its lane's candidates ahead of it, taken alone."""
    q = next(q for q in problem.queues() if problem.ev in q)
    ahead = q[: int(np.flatnonzero(q == problem.ev)[0]) + 1]
    out = np.empty(problem.n)
    entries_of(ahead.astype(np.int64), problem.release_s, problem.sep_s, problem.ev, out)
    return float(out[problem.ev])


def count_orders(problem: Problem) -> int:
    """How many orders keep every lane's order: n! / prod(n_lane!)."""
    total = math.factorial(problem.n)
    for q in problem.queues():
        total //= math.factorial(len(q))
    return total


def solution_of(problem: Problem, order: np.ndarray, work: int, t0: float) -> Solution:
    o = np.ascontiguousarray(order, dtype=np.int64)
    e = np.empty(problem.n)
    delay = entries_of(o, problem.release_s, problem.sep_s, problem.ev, e)
    ev_e = float(e[problem.ev])
    return Solution(
        tuple(int(k) for k in order), e, ev_e, delay, int(work), time.perf_counter() - t0
    )


def lane_members(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(members (L, width) padded with -1, sizes (L,), lane position of each candidate)."""
    queues = problem.queues()
    width = max(len(q) for q in queues)
    members = np.full((len(queues), width), -1, dtype=np.int64)
    sizes = np.zeros(len(queues), dtype=np.int64)
    slot = np.zeros(problem.n, dtype=np.int64)  # lane slot (0..L-1) of each candidate
    for i, q in enumerate(queues):
        members[i, : len(q)] = q
        sizes[i] = len(q)
        slot[q] = i
    return members, sizes, slot


def greedy(problem: Problem) -> np.ndarray:
    """A good order fast: the EV's lane up to the EV, then always the lane whose next
    vehicle can enter first, the lowest lane on ties (the exact solver's first bound).
    Compiled; :func:`greedy_reference` is the same in Python."""
    members, sizes, slot = lane_members(problem)
    return greedy_order(problem.release_s, problem.sep_s, problem.ev, members, sizes, slot)


def greedy_reference(problem: Problem) -> np.ndarray:
    """:func:`greedy` in plain Python (its oracle)."""
    members, sizes, slot = lane_members(problem)
    taken = np.zeros(len(sizes), dtype=np.int64)
    e = np.full(problem.n, _NEG)
    order: list[int] = []

    def entry(k: int) -> float:
        t = float(problem.release_s[k])
        for j in order:
            t = max(t, e[j] + problem.sep_s[j, k])
        return t

    def take(li: int) -> None:
        k = int(members[li, taken[li]])
        e[k] = entry(k)
        order.append(k)
        taken[li] += 1

    ev_lane = int(slot[problem.ev])
    while problem.ev not in order:
        take(ev_lane)
    while len(order) < problem.n:
        open_ = [li for li in range(len(sizes)) if taken[li] < sizes[li]]
        take(min(open_, key=lambda li: (entry(int(members[li, taken[li]])), li)))
    return np.array(order, dtype=np.int64)


@njit(
    "int64[::1](float64[::1], float64[:, ::1], int64, int64[:, ::1], int64[::1], int64[::1])",
    cache=True,
)
def greedy_order(
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    members: np.ndarray,
    sizes: np.ndarray,
    slot: np.ndarray,
) -> np.ndarray:
    n = len(release)
    taken = np.zeros(len(sizes), dtype=np.int64)
    e = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    done = 0
    ev_done = False
    while done < n:
        if not ev_done:
            li = slot[ev]
        else:
            li, best = -1, np.inf
            for cand in range(len(sizes)):
                if taken[cand] >= sizes[cand]:
                    continue
                k = members[cand, taken[cand]]
                t = release[k]
                for q in range(done):
                    v = e[order[q]] + sep[order[q], k]
                    if v > t:
                        t = v
                if t < best:
                    li, best = cand, t
        k = members[li, taken[li]]
        t = release[k]
        for q in range(done):
            v = e[order[q]] + sep[order[q], k]
            if v > t:
                t = v
        e[k] = t
        order[done] = k
        done += 1
        taken[li] += 1
        if k == ev:
            ev_done = True
    return order
