"""Algorithm 1's round loop, whole, in one compiled call.

The planner's plan building (:func:`.planner.next_plan`), sampling, the
DTOT with the grid (:func:`.dtot.dtot_of`), getCV (:func:`.conflict.first_conflict`),
the lane-leader check (:func:`.conflict.follow_check`) and the update rule of
``ica.core.search.Search.rounds``, round after round with no Python between
them. Every expression is the Python loop's in the same order, so each round
gives the same plan bit for bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.types import float64 as f8
from numba.types import int64

from dica.ica.core.kernels.conflict import (
    ROWS_ARGS,
    Occupancies,
    Rows,
    conflicts_of,
    first_conflict,
    follow_check,
)
from dica.ica.core.kernels.dtot import (
    DTOT_ARRAYS,
    GRID_ARGS,
    Grid,
    dtot_of,
    entry_time_of,
    no_dtot,
)
from dica.ica.core.kernels.planner import (
    APPROACH_ARGS,
    MAX_SEGS,
    Approach,
    next_plan,
    plan_of,
    py_max,
)

# resolve_rounds' status; BLOCKED: a stop-family plan meets the lane leader where every
# later stop-family plan goes too (the vehicle must stop behind the leader first);
# TOO_LATE: the next entry would be later than ``max_wait_s``;
# PAUSED: round ``last_round`` done, the next round's entry target returned fourth;
# INFEASIBLE: the vehicle cannot slow to the crossing cap before the entry line
RESOLVED, FALL_BACK, BLOCKED, TOO_LATE, PAUSED, INFEASIBLE = 0, 1, 2, 3, 4, 5


class Leader(NamedTuple):
    """The lane leader a plan keeps clear of: its samples (``present`` False: none)."""

    present: bool
    t0_s: float  # its samples' first time (as late as the tracking bound lets it be)
    step_s: float
    s_m: np.ndarray
    length_m: float  # [m] its length and the gap kept behind its rear
    gap_m: float


class Controls(NamedTuple):
    """Where a compiled search starts and where it stops."""

    t0_s: float  # [s] the request's state time and the sample step
    step_s: float
    s_init: np.ndarray  # the first plan's samples
    max_iterations: int  # the round limit
    max_wait_s: float  # the latest entry it may plan, from the state
    first_round: int  # the round it starts with (after rounds the caller made)
    last_round: int  # the round after which it pauses (PAUSED)
    target0: float  # NaN: the first plan is s_init; else the plan entering at or after it


_F1 = np.zeros(1)
LEADER_ARGS = typeof(tuple(Leader(False, 0.0, 0.0, _F1, 0.0, 0.5)))  # see the package
CONTROLS_ARGS = typeof(tuple(Controls(0.0, 0.05, _F1, 100, 120.0, 1, 100, math.nan)))


@njit(
    types.Tuple((int64, int64, f8[::1], f8, f8, DTOT_ARRAYS))(
        APPROACH_ARGS, GRID_ARGS, ROWS_ARGS, LEADER_ARGS, CONTROLS_ARGS
    ),
    cache=True,
    nogil=True,
)
def resolve_rounds(
    approach_args: tuple,
    grid_args: tuple,
    rows_args: tuple,
    leader_args: tuple,
    controls_args: tuple,
) -> tuple[int, int, np.ndarray, float, float, tuple]:
    """The rounds of ``Search.rounds`` (enhanced DICA) from the first plan ``s_init``.

    Bundles as tuples: :class:`~.planner.Approach` (the planner's constants,
    :class:`~.planner.Plan`, are worked out here, :func:`~.planner.plan_of`),
    :class:`~.dtot.Grid`, :class:`~.conflict.Rows` (``ConfirmedBatch``, its
    rows in ascending ``lb_j`` with their longest interval ``span_s``; NaN: a
    NaN bound, never from a real DTOT, and every round then searches all
    rows), :class:`Leader`, :class:`Controls`.

    Returns (status, rounds, samples, target, earliest, DTOT): RESOLVED with the
    conflict-free plan's samples and its DTOT as :func:`~.dtot.dtot_of` gives it
    (which the round built), BLOCKED (see the constant), TOO_LATE (the wait
    exceeded), PAUSED after round ``last_round`` with the next round's entry target
    (go on from there with ``first_round`` one higher and that ``target0``),
    INFEASIBLE before any round, or FALL_BACK where the Python loop raises (no plan,
    the round limit exceeded, the state too close to the lane leader, a plan that
    never leaves): the caller then runs the Python loop, which raises with its
    message. ``earliest`` is the request's earliest entry (``Planner.earliest_entry_s``).
    ``first_round`` goes on from a round the caller made (a delay for an exit rule,
    which this loop does not know); with ``target0`` (NaN: none) the first plan is
    ``Planner.at_or_after`` that entry, sampled, instead of ``s_init``. Every status
    but RESOLVED comes with an empty DTOT.
    """
    plan, grid, rows = plan_of(Approach(*approach_args)), Grid(*grid_args), Rows(*rows_args)
    lead, ctl = Leader(*leader_args), Controls(*controls_args)
    earliest = plan.hi_entry_s
    if not plan.hi_ok:
        return INFEASIBLE, 0, ctl.s_init, math.nan, math.inf, no_dtot()
    t0, step, s_end = ctl.t0_s, ctl.step_s, plan.s_end_m
    nv = rows.nv
    segs = np.empty((MAX_SEGS, 4))
    hit = np.zeros(nv, np.bool_)
    first = np.empty(nv)
    delay = np.empty(nv)
    ordered = not np.isnan(rows.span_s)
    s = ctl.s_init
    b_wait = -1.0  # the current plan's wait if it is of the stop family, else -1
    if not np.isnan(ctl.target0):
        ok, s, wait = next_plan(ctl.target0, plan, step, segs, s)
        if not ok:
            return FALL_BACK, ctl.first_round, s, math.nan, earliest, no_dtot()
        # a plan that goes on from a round knows its wait (Planner.stop_wait_s); the
        # request's own TSS planned anew does not, as in the Python loop
        if ctl.first_round > 1:
            b_wait = wait
    for it in range(ctl.first_round, ctl.max_iterations + 1):
        # the DTOT (ica.core.dtot.build_dtot with the grid)
        dtot = dtot_of(grid, s, s_end, t0, step)
        _, _, _, centre, heading, lb, ub, g = dtot
        occ = Occupancies(lb, ub, g, centre, heading, grid.half_l_m, grid.half_w_m)
        # the lane leader, then getCV, and the first conflict as Search.rounds
        # sorts them (the leader after the others on a tie)
        found, f_first, f_delay = False, 0.0, 0.0
        if lead.present:
            found, f_first, f_delay = follow_check(
                t0, step, s, lead.t0_s, lead.step_s, lead.s_m, lead.length_m, lead.gap_m
            )
            if found and f_first <= t0 + step + 1e-9:
                return FALL_BACK, it, s, math.nan, earliest, no_dtot()
            if found and b_wait >= 0.0 and f_first - t0 <= plan.b_state[0] + b_wait + 1e-9:
                return BLOCKED, it, s, math.nan, earliest, no_dtot()
        best = -1
        best_first = 0.0
        best_delay = 0.0
        if ordered:
            best, best_first, best_delay = first_conflict(occ, rows, f_first if found else math.inf)
        else:
            hit[:] = False
            if conflicts_of(occ, rows, hit, first, delay):
                for v in range(nv):
                    if hit[v] and (best < 0 or first[v] < best_first):
                        best = v
                        best_first = first[v]
                        best_delay = delay[v]
        if found and (best < 0 or f_first < best_first):
            best = nv
            best_first = f_first
            best_delay = py_max(f_delay, 0.0)
        if best < 0:
            return RESOLVED, it, s, math.nan, earliest, dtot
        target = entry_time_of(t0, step, s) - t0 + py_max(best_delay, step)
        if target > ctl.max_wait_s:
            return TOO_LATE, it, s, target, earliest, no_dtot()
        if it >= ctl.last_round and it < ctl.max_iterations:
            return PAUSED, it, s, target, earliest, no_dtot()
        ok, s, b_wait = next_plan(target, plan, step, segs, s)
        if not ok:
            return FALL_BACK, it, s, math.nan, earliest, no_dtot()
    return FALL_BACK, ctl.max_iterations, s, math.nan, earliest, no_dtot()
