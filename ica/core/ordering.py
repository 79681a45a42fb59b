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

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

SOLVERS = ("exact", "ga", "exhaustive")
EPS_S = 1e-9  # [s] entry times closer than this count as equal
EXHAUSTIVE_LIMIT = 1_000_000  # orders; about a second of search at 12 candidates
_NEG = -np.inf


class OrderingError(ValueError):
    """A problem that is not well formed (sizes, non-finite times, negative separations)."""


class TooManyOrders(OrderingError):
    """The exhaustive search would have to try more orders than its limit."""


@dataclass(frozen=True, slots=True, eq=False)
class Problem:
    """Candidates ``0..n-1``: lane index, release time [s], separations [s], the EV's index.

    Within a lane, candidates keep the order of their indices (front first).
    """

    lane: np.ndarray  # int64 (n,)
    release_s: np.ndarray  # float64 (n,)
    sep_s: np.ndarray  # float64 (n, n): sep_s[j, k] when j enters before k
    ev: int

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
        object.__setattr__(self, "lane", lane)
        object.__setattr__(self, "release_s", release)
        object.__setattr__(self, "sep_s", sep)

    @property
    def n(self) -> int:
        return len(self.lane)

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
def _entries(
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
    delay = _entries(o, problem.release_s, problem.sep_s, problem.ev, out)
    return out, float(out[problem.ev]), float(delay)


def _delay(problem: Problem, order: np.ndarray) -> float:
    """The others' total delay of an order the solvers made (feasible by construction)."""
    e = np.empty(problem.n)
    return float(_entries(order, problem.release_s, problem.sep_s, problem.ev, e))


def ev_bound_s(problem: Problem) -> float:
    """The EV's earliest entry: its lane's candidates ahead of it, taken alone."""
    q = next(q for q in problem.queues() if problem.ev in q)
    ahead = q[: int(np.flatnonzero(q == problem.ev)[0]) + 1]
    out = np.empty(problem.n)
    _entries(ahead.astype(np.int64), problem.release_s, problem.sep_s, problem.ev, out)
    return float(out[problem.ev])


def count_orders(problem: Problem) -> int:
    """How many orders keep every lane's order: n! / prod(n_lane!)."""
    total = math.factorial(problem.n)
    for q in problem.queues():
        total //= math.factorial(len(q))
    return total


def _solution(problem: Problem, order: np.ndarray, work: int, t0: float) -> Solution:
    o = np.ascontiguousarray(order, dtype=np.int64)
    e = np.empty(problem.n)
    delay = _entries(o, problem.release_s, problem.sep_s, problem.ev, e)
    ev_e = float(e[problem.ev])
    return Solution(
        tuple(int(k) for k in order), e, ev_e, delay, int(work), time.perf_counter() - t0
    )


def _lanes(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    members, sizes, slot = _lanes(problem)
    return _greedy(problem.release_s, problem.sep_s, problem.ev, members, sizes, slot)


def greedy_reference(problem: Problem) -> np.ndarray:
    """:func:`greedy` in plain Python (its oracle)."""
    members, sizes, slot = _lanes(problem)
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
def _greedy(
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


# -- exact: dynamic programme over lane progress --------------------------------------
@njit("float64[:, ::1](float64[:, ::1], int64)", cache=True)
def _grow2(a: np.ndarray, cap: int) -> np.ndarray:
    out = np.empty((cap, a.shape[1]))
    out[: a.shape[0]] = a
    return out


@njit("float64[::1](float64[::1], int64)", cache=True)
def _grow1(a: np.ndarray, cap: int) -> np.ndarray:
    out = np.empty(cap)
    out[: len(a)] = a
    return out


@njit("int64[::1](int64[::1], int64)", cache=True)
def _grow1i(a: np.ndarray, cap: int) -> np.ndarray:
    out = np.empty(cap, dtype=np.int64)
    out[: len(a)] = a
    return out


@njit("boolean[::1](boolean[::1], int64)", cache=True)
def _grow1b(a: np.ndarray, cap: int) -> np.ndarray:
    out = np.zeros(cap, dtype=np.bool_)
    out[: len(a)] = a
    return out


@njit(
    "Tuple((int64[::1], float64, int64))(float64[::1], float64[:, ::1], int64, int64[:, ::1], "
    "int64[::1], int64[::1], float64, float64, int64, int64)",
    cache=True,
)
def _exact(
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    members: np.ndarray,
    sizes: np.ndarray,
    slot: np.ndarray,
    ev_bound: float,
    ub_delay: float,
    max_labels: int,
    beam: int,
) -> tuple[np.ndarray, float, int]:
    """Labels per state of lane progress; returns (order, delay, labels made).

    With ``beam`` > 0 each state keeps only its ``beam`` least-delay labels:
    not exact, but a quick and usually tight bound for the exact pass.

    A label holds the entries of the vehicles taken so far that can still bind a
    later vehicle (others set to -inf: they can never exceed the last entry), the
    last entry, the EV's entry and the delay so far. Every later entry grows
    monotonically with all of these, so a label no better in any of them than
    another of the same state can be dropped without losing the optimum.
    """
    n = len(release)
    n_lanes = len(sizes)
    eps = 1e-9
    stride = np.ones(n_lanes, dtype=np.int64)
    for li in range(1, n_lanes):
        stride[li] = stride[li - 1] * (sizes[li - 1] + 1)
    n_states = stride[n_lanes - 1] * (sizes[n_lanes - 1] + 1)
    maxsep = np.zeros(n)
    ev_lane = slot[ev]
    ev_pos = 0
    while members[ev_lane, ev_pos] != ev:
        ev_pos += 1

    cap = 1024
    lab_e = np.empty((cap, n))
    lab_last = np.empty(cap)
    lab_ev = np.empty(cap)
    lab_delay = np.empty(cap)
    lab_parent = np.empty(cap, dtype=np.int64)
    lab_veh = np.empty(cap, dtype=np.int64)
    lab_next = np.empty(cap, dtype=np.int64)
    lab_dead = np.zeros(cap, dtype=np.bool_)
    head = np.full(n_states, -1, dtype=np.int64)

    lab_e[0, :] = -np.inf
    lab_last[0] = -np.inf
    lab_ev[0] = np.inf
    lab_delay[0] = 0.0
    lab_parent[0] = -1
    lab_veh[0] = -1
    lab_next[0] = -1
    head[0] = 0
    n_lab = 1

    counts = np.zeros(n_lanes, dtype=np.int64)
    e_new = np.empty(n)
    chain = np.empty(n)
    for sid in range(n_states):
        rem = sid
        for li in range(n_lanes):
            counts[li] = rem // stride[li] % (sizes[li] + 1)
        # how long each vehicle can still hold back one not yet taken (only those count)
        for j in range(n):
            maxsep[j] = 0.0
        for li2 in range(n_lanes):
            for p in range(counts[li2], sizes[li2]):
                k2 = members[li2, p]
                for j in range(n):
                    if sep[j, k2] > maxsep[j]:
                        maxsep[j] = sep[j, k2]
        q = head[sid]
        while q >= 0:
            if lab_dead[q]:
                q = lab_next[q]
                continue
            for li in range(n_lanes):
                if counts[li] >= sizes[li]:
                    continue
                k = members[li, counts[li]]
                t = release[k]
                if lab_last[q] > t:
                    t = lab_last[q]
                for j in range(n):
                    v = lab_e[q, j] + sep[j, k]
                    if v > t:
                        t = v
                ev_t = lab_ev[q]
                if k == ev:
                    if t > ev_bound + eps:
                        continue
                    ev_t = t
                # entries that can no longer bind anyone drop out of the label
                for j in range(n):
                    e_new[j] = lab_e[q, j]
                    if e_new[j] + maxsep[j] <= t:
                        e_new[j] = -np.inf
                e_new[k] = t if t + maxsep[k] > t else -np.inf
                delay = lab_delay[q] + (t - release[k] if k != ev else 0.0)
                # the EV's lane taken alone from here is the EV's best: over the bound, drop
                if ev_t == np.inf:
                    start = counts[ev_lane] + (1 if li == ev_lane else 0)
                    late = False
                    for p in range(start, ev_pos + 1):
                        m = members[ev_lane, p]
                        tm = release[m]
                        if t > tm:
                            tm = t
                        for j in range(n):
                            v = e_new[j] + sep[j, m]
                            if v > tm:
                                tm = v
                        for p2 in range(start, p):
                            m2 = members[ev_lane, p2]
                            v = chain[p2] + sep[m2, m]
                            if v > tm:
                                tm = v
                        chain[p] = tm
                        if tm > ev_bound + eps:
                            late = True
                            break
                    if late:
                        continue
                # everyone still to come enters no earlier than t, nor before its lane
                # leader plus their separation: a lower bound on the delay still to come
                lb = delay
                for li2 in range(n_lanes):
                    c2 = counts[li2] + (1 if li2 == li else 0)
                    prev_t = -np.inf
                    prev = -1
                    if c2 > 0:
                        prev = members[li2, c2 - 1]
                        prev_t = e_new[prev]
                    for p in range(c2, sizes[li2]):
                        m = members[li2, p]
                        tm = release[m]
                        if t > tm:
                            tm = t
                        if prev >= 0 and prev_t + sep[prev, m] > tm:
                            tm = prev_t + sep[prev, m]
                        if p == c2:  # the lane's next vehicle: everyone taken holds it back
                            for j in range(n):
                                v = e_new[j] + sep[j, m]
                                if v > tm:
                                    tm = v
                        if m != ev:
                            lb += tm - release[m]
                        prev, prev_t = m, tm
                if lb > ub_delay + eps:
                    continue
                # insert into the next state unless dominated; drop what it dominates
                nxt = sid + stride[li]
                dominated = False
                r = head[nxt]
                if beam > 0:
                    alive, worst = 0, -1
                    while r >= 0:
                        if not lab_dead[r]:
                            alive += 1
                            if worst < 0 or lab_delay[r] > lab_delay[worst]:
                                worst = r
                        r = lab_next[r]
                    if alive >= beam:
                        if lab_delay[worst] <= delay:
                            continue
                        lab_dead[worst] = True
                while r >= 0:
                    if not lab_dead[r]:
                        a_le = lab_last[r] <= t and lab_ev[r] <= ev_t and lab_delay[r] <= delay
                        b_le = t <= lab_last[r] and ev_t <= lab_ev[r] and delay <= lab_delay[r]
                        j = 0
                        while j < n and (a_le or b_le):
                            if lab_e[r, j] > e_new[j]:
                                a_le = False
                            if e_new[j] > lab_e[r, j]:
                                b_le = False
                            j += 1
                        if a_le:
                            dominated = True
                            break
                        if b_le:
                            lab_dead[r] = True
                    r = lab_next[r]
                if dominated:
                    continue
                if n_lab == cap:
                    if cap >= max_labels:
                        return np.zeros(0, dtype=np.int64), np.inf, -1
                    cap *= 2
                    lab_e = _grow2(lab_e, cap)
                    lab_last = _grow1(lab_last, cap)
                    lab_ev = _grow1(lab_ev, cap)
                    lab_delay = _grow1(lab_delay, cap)
                    lab_parent = _grow1i(lab_parent, cap)
                    lab_veh = _grow1i(lab_veh, cap)
                    lab_next = _grow1i(lab_next, cap)
                    lab_dead = _grow1b(lab_dead, cap)
                x = n_lab
                n_lab += 1
                lab_e[x, :] = e_new
                lab_last[x] = t
                lab_ev[x] = ev_t
                lab_delay[x] = delay
                lab_parent[x] = q
                lab_veh[x] = k
                lab_dead[x] = False
                lab_next[x] = head[nxt]
                head[nxt] = x
            q = lab_next[q]

    best = -1
    r = head[n_states - 1]
    while r >= 0:
        if not lab_dead[r] and (best < 0 or lab_delay[r] < lab_delay[best]):
            best = r
        r = lab_next[r]
    if best < 0:
        return np.zeros(0, dtype=np.int64), np.inf, n_lab
    order = np.empty(n, dtype=np.int64)
    r = best
    for i in range(n - 1, -1, -1):
        order[i] = lab_veh[r]
        r = lab_parent[r]
    return order, lab_delay[best], n_lab


MAX_LABELS = 1 << 22  # the exact solver's memory guard (about 1 GB at 30 candidates)
QUICK_BEAM = 3  # labels per state in the quick pass that bounds the exact one


def exact(problem: Problem) -> Solution:
    """The optimal order (EV entry first, the others' total delay second)."""
    t0 = time.perf_counter()
    members, sizes, slot = _lanes(problem)
    args = (problem.release_s, problem.sep_s, problem.ev, members, sizes, slot)
    ub = _delay(problem, _greedy(*args))
    bound = ev_bound_s(problem)
    quick, _, quick_work = _exact(*args, bound, ub, MAX_LABELS, QUICK_BEAM)
    if len(quick):
        ub = min(ub, _delay(problem, quick))
    order, _, work = _exact(*args, bound, ub, MAX_LABELS, 0)
    work += max(quick_work, 0)
    if work < 0:
        raise OrderingError(f"the exact solver ran past {MAX_LABELS} labels")
    if len(order) == 0:  # cannot happen: the greedy order is within both bounds
        raise OrderingError("the exact solver found no order within its bounds")
    return _solution(problem, order, work, t0)


# -- exhaustive: every feasible order ---------------------------------------------------
@njit(
    "Tuple((int64[::1], int64))(float64[::1], float64[:, ::1], int64, int64[:, ::1], int64[::1])",
    cache=True,
)
def _exhaustive(
    release: np.ndarray, sep: np.ndarray, ev: int, members: np.ndarray, sizes: np.ndarray
) -> tuple[np.ndarray, int]:
    """Depth first through every interleaving of the lane queues; returns (best, orders)."""
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
    orders = 0
    depth = 0
    next_lane = np.zeros(n + 1, dtype=np.int64)  # next lane to try at each depth
    while depth >= 0:
        if depth == n:
            orders += 1
            ev_t, d = e[ev], delay_at[n]
            if ev_t < best_ev - eps or (ev_t <= best_ev + eps and d < best_delay - eps):
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
        e[k] = t
        order[depth] = k
        lane_at[depth] = li
        delay_at[depth + 1] = delay_at[depth] + (t - release[k] if k != ev else 0.0)
        counts[li] += 1
        depth += 1
        next_lane[depth] = 0
    return best, orders


def exhaustive(problem: Problem, limit: int = EXHAUSTIVE_LIMIT) -> Solution:
    """The best of every feasible order; :class:`TooManyOrders` above ``limit`` orders."""
    total = count_orders(problem)
    if total > limit:
        raise TooManyOrders(
            f"exhaustive search refused: {problem.n} vehicles in {len(problem.queues())} lanes "
            f"have {total:,} orders, over the limit of {limit:,}"
        )
    t0 = time.perf_counter()
    members, sizes, _ = _lanes(problem)
    best, orders = _exhaustive(problem.release_s, problem.sep_s, problem.ev, members, sizes)
    return _solution(problem, best, orders, t0)


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
    "void(int64[:, ::1], float64[::1], float64[:, ::1], int64, float64[::1], float64[::1])",
    cache=True,
)
def _fitness(
    pop: np.ndarray,
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    ev_out: np.ndarray,
    delay_out: np.ndarray,
) -> None:
    e = np.empty(pop.shape[1])
    for r in range(pop.shape[0]):
        delay_out[r] = _entries(pop[r], release, sep, ev, e)
        ev_out[r] = e[ev]


def ga(problem: Problem, params: GaParams | None = None, seed: int = 0) -> Solution:
    """The dissertation's GA (Algorithm 3 of chapter 5), seeded."""
    p = params or GaParams()
    t0 = time.perf_counter()
    n = problem.n
    rng = np.random.default_rng(seed)
    members, _, slot = _lanes(problem)
    pop = np.ascontiguousarray(rng.permuted(np.tile(np.arange(n), (p.n_pop, 1)), axis=1))
    _repair(pop, slot, members)
    ev_e, delay = np.empty(p.n_pop), np.empty(p.n_pop)
    _fitness(pop, problem.release_s, problem.sep_s, problem.ev, ev_e, delay)
    work = p.n_pop
    pop, ev_e, delay = _select(pop, ev_e, delay, p.n_pop)
    best = (float(ev_e[0]), float(delay[0]))
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
        k_ev, k_delay = np.empty(len(kids)), np.empty(len(kids))
        _fitness(kids, problem.release_s, problem.sep_s, problem.ev, k_ev, k_delay)
        work += len(kids)
        pop, ev_e, delay = _select(
            np.concatenate([pop, kids]),
            np.concatenate([ev_e, k_ev]),
            np.concatenate([delay, k_delay]),
            p.n_pop,
        )
        top = (float(ev_e[0]), float(delay[0]))
        if better(top, best):
            best, unchanged = top, 0
        else:
            unchanged += 1
        generation += 1
    return _solution(problem, pop[0], work, t0)


def _select(
    pop: np.ndarray, ev_e: np.ndarray, delay: np.ndarray, keep: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best ``keep`` individuals (EV entry first, to EPS_S; then delay), stable."""
    rank = np.lexsort((delay, np.round(ev_e / EPS_S)))[:keep]
    return np.ascontiguousarray(pop[rank]), ev_e[rank], delay[rank]


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
        return _solution(problem, np.zeros(1, dtype=np.int64), 1, t0)
    if solver == "exact":
        return exact(problem)
    if solver == "ga":
        return ga(problem, ga_params, seed)
    return exhaustive(problem, limit)
