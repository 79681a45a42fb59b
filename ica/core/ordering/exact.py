"""The exact solver: a dynamic programme over how far each lane's queue has been taken."""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from dica.ica.core.ordering.problem import (
    EPS_S,
    OrderingError,
    Problem,
    Solution,
    entries_of,
    ev_bound_s,
    greedy_order,
    lane_members,
    solution_of,
    total_delay,
)


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
    "int64[::1], int64[::1], float64[::1], float64, float64, int64, int64)",
    cache=True,
)
def _exact(
    release: np.ndarray,
    sep: np.ndarray,
    ev: int,
    members: np.ndarray,
    sizes: np.ndarray,
    slot: np.ndarray,
    deadline: np.ndarray,
    ev_bound: float,
    ub_delay: float,
    max_labels: int,
    beam: int,
) -> tuple[np.ndarray, float, int]:
    """Labels per state of lane progress; returns (order, delay, labels made).

    With ``beam`` > 0 each state keeps only its ``beam`` least-delay labels:
    not exact, but a quick and usually tight bound for the exact pass.

    A vehicle is never given an entry past its ``deadline``, and a label is dropped as
    soon as a lower bound of a vehicle still to come passes that vehicle's: entries only
    grow along a label, so this loses no order that keeps every deadline. The EV's entry
    is pruned at ``ev_bound`` (inf: not at all) and the delay at ``ub_delay``; the label
    returned is the least EV entry, then the least delay.

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
                if t > deadline[k] + eps:
                    continue
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
                overdue = False
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
                        if tm > deadline[m] + eps:
                            overdue = True
                        if m != ev:
                            lb += tm - release[m]
                        prev, prev_t = m, tm
                if overdue or lb > ub_delay + eps:
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
        if not lab_dead[r] and (
            best < 0
            or lab_ev[r] < lab_ev[best] - eps
            or (lab_ev[r] <= lab_ev[best] + eps and lab_delay[r] < lab_delay[best])
        ):
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
    """The optimal order (EV entry first, the others' total delay second) among those
    that keep every candidate's deadline.

    First with the EV's entry held to its bound (its own lane alone) and the delay to
    the best quick order's; if the deadlines leave the EV no order at its bound, again
    with neither pruning (slower, still exact)."""
    t0 = time.perf_counter()
    members, sizes, slot = lane_members(problem)
    args = (problem.release_s, problem.sep_s, problem.ev, members, sizes, slot,
            problem.deadline_s)  # fmt: skip
    ub = np.inf
    greedy = greedy_order(*args[:-1])
    if _kept(problem, greedy):
        ub = total_delay(problem, greedy)
    bound = ev_bound_s(problem)
    quick, _, quick_work = _exact(*args, bound, ub, MAX_LABELS, QUICK_BEAM)
    if len(quick):
        ub = min(ub, total_delay(problem, quick))
    order, _, work = _exact(*args, bound, ub, MAX_LABELS, 0)
    if work >= 0 and len(order) == 0 and problem.bounded:
        order, _, more = _exact(*args, np.inf, np.inf, MAX_LABELS, 0)
        work = -1 if more < 0 else work + more
    if work < 0:
        raise OrderingError(f"the exact solver ran past {MAX_LABELS} labels")
    work += max(quick_work, 0)
    if len(order) == 0:  # with no deadlines the greedy order is within both bounds
        raise OrderingError("no order keeps every vehicle's deadline")
    return solution_of(problem, order, work, t0)


def _kept(problem: Problem, order: np.ndarray) -> bool:
    e = np.empty(problem.n)
    entries_of(order, problem.release_s, problem.sep_s, problem.ev, e)
    return problem.lateness_s(e) <= EPS_S
