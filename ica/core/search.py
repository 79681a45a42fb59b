"""Algorithm 1's search for one request: its rounds, and the choice of two plans.

A head vehicle's request is resolved against an ICA's confirmed set
(:class:`ica.core.dica.Dica`): each round builds the plan's DTOT, finds the
conflicting vehicles (getCV, the lane leader and the exit rules) and, if any,
asks the planner for a new plan from the request's state entering no
earlier than the first conflict's delay allows. Entry times only grow, every
round by at least one sample step, so the rounds end.

For enhanced DICA the rounds run as one compiled call
(:func:`ica.core.kernels.resolve.resolve_rounds`). It knows nothing of the
exit rules: a plan of it that breaks one is delayed here as the Python loop
would delay it, and the compiled loop goes on from there. Where it would
raise, the Python loop runs from the start and raises with its message. The
Python loop is also the reference the compiled one is tested against
(``tests/test_resolve_compiled.py``), and the loop of every other variant.

With exit spacing a request whose crossing cap binds is planned twice
(:meth:`Search.best`): capped, and at its route's own cap delayed until it
leaves far enough behind every slower vehicle ahead on its exit lane; the
plan that leaves first is kept.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from dica.ica.core.conflict import Conflict, follow_conflict
from dica.ica.core.dtot import Dtot, build_dtot, dtot_of_arrays
from dica.ica.core.kernels.resolve import (
    BLOCKED,
    INFEASIBLE,
    PAUSED,
    RESOLVED,
    TOO_LATE,
    Controls,
    Leader,
    resolve_rounds,
)
from dica.ica.core.kernels.validate import over_cap
from dica.ica.core.planner import Planner, approach_of
from dica.ica.core.request import Reason, Request, RequestError
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory, sample
from dica.ica.core.zones import RouteGrid, Shape

if TYPE_CHECKING:
    from dica.ica.core.dica import Confirmed, Dica

# rounds of the capped search of a request planned twice before the fast one runs
# (Search.best): most searches end sooner, a few run on for dozens
PAUSE_ROUNDS = 12


@dataclass(frozen=True, slots=True, eq=False)
class Found:
    """One search's conflict-free plan. Its exit (time the rear leaves, speed) is all
    the exit rules and the choice between two searches ask of it; its DTOT, which the
    search's last round built, is a :class:`Dtot` from the Python loop, the compiled
    DTOT's arrays from the compiled one (made a Dtot for the plan kept only)."""

    traj: Trajectory
    out_s: float
    out_mps: float
    iterations: int
    earliest: float
    dtot: Dtot | None = None
    arrays: tuple | None = None

    def kept_dtot(self, route: Route, shape: Shape, margin_m: float) -> Dtot:
        """The plan's DTOT, footprints grown by ``margin_m``: the one its round built."""
        if self.dtot is not None:
            return self.dtot
        if self.arrays is None:
            raise ValueError("a found plan without its DTOT")
        return dtot_of_arrays(route, shape, self.traj, margin_m, self.arrays)


@dataclass(frozen=True, slots=True)
class Paused:
    """A compiled search out of rounds: it goes on from ``iterations`` + 1, entering at
    or after ``target`` (relative to the state)."""

    iterations: int
    target: float


def finish(search: Generator[None, None, Found]) -> Found:
    """Run a search (:meth:`Search.rounds`) to its end: its plan, or its error."""
    while True:
        try:
            next(search)
        except StopIteration as done:
            return done.value


def plan_entry(
    planner: Planner, t0_s: float, entry_rel_s: float, step_s: float, s_end: float
) -> Trajectory:
    """The plan entering soonest at or after ``entry_rel_s`` after the state, sampled."""
    profile = planner.at_or_after(entry_rel_s)
    if profile is None:
        raise RequestError(
            Reason.INFEASIBLE,
            f"cannot delay the entry to t={t0_s + entry_rel_s:.2f} s from the state",
        )
    return sample(profile, t0_s, step_s, s_end)


def _exit_of(traj: Trajectory, arrays: tuple) -> tuple[float, float]:
    """(``t_s[-1]``, ``exit_speed_mps``) of the DTOT of ``traj`` given as the compiled
    DTOT's arrays, without making it a :class:`Dtot` (the same arithmetic)."""
    k0, t = arrays[0], arrays[1]
    s = traj.s_m
    if len(s) < 2:
        return float(t[-1]), 0.0
    k = min(max(k0 + len(t) - 2, 0), len(s) - 2)
    return float(t[-1]), float(s[k + 1] - s[k]) / traj.step_s


def _infeasible() -> RequestError:
    return RequestError(
        Reason.INFEASIBLE, "cannot slow to the crossing speed cap before the entry line"
    )


def _too_late(max_wait_s: float) -> RequestError:
    return RequestError(Reason.INFEASIBLE, f"no conflict-free entry within {max_wait_s:.0f} s")


def _blocked(vin: str, leader: str) -> RequestError:
    """A plan that stops at the line runs into the lane leader whatever it waits there:
    the vehicle asks again once its own law has stopped it behind the leader."""
    return RequestError(
        Reason.FOLLOW,
        f"{vin} cannot draw up to the line behind {leader}: ask again once standing",
    )


def _too_close(
    req: Request, traj: Trajectory, leader: Confirmed, lag: Trajectory, gap_m: float, step_s: float
) -> RequestError:
    """The state itself is too close to the lane leader: a bad state if within the gap
    of the leader's plan, else only within the headway behind it (ask again soon)."""
    ahead = follow_conflict(traj, leader.dtot.trajectory, leader.dtot.shape.length_m, gap_m)
    if lag is leader.dtot.trajectory or (
        ahead is not None and ahead[0] <= req.t0_s + step_s + 1e-9
    ):
        return RequestError(
            Reason.BAD_STATE, f"the state is within {gap_m:.2f} m of {leader.vin} ahead in the lane"
        )
    return RequestError(
        Reason.FOLLOW, f"{req.vin} is within the headway behind {leader.vin}: ask again"
    )


_NO_SAMPLES = np.zeros(0)


class Search:
    """Algorithm 1 for one request (its state, route, shape and TSS as a trajectory)
    against ``ica``'s confirmed set, keeping clear of ``leader`` in its lane."""

    def __init__(
        self,
        ica: Dica,
        req: Request,
        route: Route,
        shape: Shape,
        traj: Trajectory,
        leader: Confirmed | None,
    ) -> None:
        self.ica = ica
        self.req = req
        self.route = route
        self.shape = shape
        self.traj = traj
        self.leader = leader
        cfg = ica.config
        self.gap_m = 2.0 * cfg.margin_m  # kept behind the lane leader's rear
        # the leader as late as the tracking bound lets it be, against a requester as early
        lag = leader.dtot.trajectory if leader is not None else None
        behind_s = 2.0 * cfg.time_pad_s + cfg.headway_s
        if lag is not None and behind_s > 0.0:
            lag = lag.shifted(behind_s)
        self.lag = lag
        # what every compiled call of this request reads alike: the grid, the confirmed
        # rows and the lane leader, as tuples (built on the first call)
        self._fixed: tuple[tuple, tuple, tuple] | None = None

    def best(self) -> Found:
        """checkFV's capped plan; with exit spacing also the uncapped one that leaves
        late enough behind slower vehicles, and the one that leaves first.

        What it returns is what the two searches in turn would give, capped first
        and the fast one given up once its entry is past the capped plan's exit.
        The capped search is paused after ``PAUSE_ROUNDS`` rounds: then the fast one
        runs first, and the capped one goes on given up past the fast plan's exit,
        where it could not win (it may wander far behind slower vehicles while the
        fast plan is found in a few rounds). Either way, each search's plans and
        errors up to its bound are its own, so the answer is the same."""
        ica, route, t0 = self.ica, self.route, self.req.t0_s
        cap = ica.front_cap_mps(route)
        if not ica.config.exit_spacing or cap >= route.speed_cap_mps:
            return self.resolve(cap)
        max_wait = ica.config.max_wait_s
        bound = [max_wait]
        capped_search = self.rounds(cap, bound, PAUSE_ROUNDS)
        try:
            next(capped_search)
        except StopIteration as done:  # found within the budget: as in turn
            capped: Found = done.value
            give_up = min(max_wait, capped.out_s - t0)
            try:
                fast = self.resolve(route.speed_cap_mps, give_up)
            except RequestError:
                return capped
            return fast if fast.out_s < capped.out_s else capped
        except RequestError:
            return self.resolve(route.speed_cap_mps)
        try:
            fast = self.resolve(route.speed_cap_mps)
        except RequestError as fast_error:
            try:
                return finish(capped_search)
            except RequestError:
                raise fast_error from None  # in turn: the capped search failed, then this
        bound[0] = min(max_wait, fast.out_s - t0)
        try:
            capped = finish(capped_search)
        except RequestError:
            return fast
        return fast if fast.out_s < capped.out_s else capped

    def resolve(self, cap: float, max_wait_s: float | None = None) -> Found:
        """Algorithm 1's rounds under crossing speed cap ``cap``, giving up on an entry
        more than ``max_wait_s`` after the state (default: the configured limit)."""
        bound = [self.ica.config.max_wait_s if max_wait_s is None else max_wait_s]
        return finish(self.rounds(cap, bound))

    def rounds(
        self, cap: float, bound: list[float], pause_rounds: int = 0
    ) -> Generator[None, None, Found]:
        """:meth:`resolve` as a search that can pause: with ``pause_rounds`` it yields
        once, after that many compiled rounds, and ``bound[0]`` (the wait it gives up
        past) may be lowered before it goes on, as if it had been that from the start."""
        ica, req, route, shape, leader = self.ica, self.req, self.route, self.shape, self.leader
        traj = self.traj
        cfg = ica.config
        s_end = route.cross_length_m + shape.length_m
        d_m, road = max(req.dist_to_entry_m, 0.0), route.road_mps
        # a TSS faster than the cap inside is planned anew, to enter when it would (under
        # the route's own cap it cannot be: validation holds a TSS to that cap, the
        # planner a plan to its own, both as this test does)
        replan = math.nan
        if cap < route.speed_cap_mps and over_cap(traj.s_m, cfg.step_s, cap + cfg.speed_tol_mps):
            replan = traj.entry_time_s() - req.t0_s
        grid = ica.tables.grid(route, shape)
        gap, lag = self.gap_m, self.lag
        if ica._compiled_rounds():
            # the compiled loop knows nothing of the exit rules: a plan of it that breaks
            # one is delayed here as the loop below would, and the compiled loop goes on
            # from there (its rounds are the loop's, and it plans the delayed entry);
            # where it would raise, the loop below runs from the start and raises with
            # its message; the compiled loop works out the planner's constants itself
            approach = approach_of(
                cfg.kinematics, d_m, req.speed_mps, road, cap, s_end, cfg.platoon
            )
            ctl = Controls(
                t0_s=float(req.t0_s),
                step_s=cfg.step_s,
                s_init=np.ascontiguousarray(traj.s_m, dtype=float),
                max_iterations=cfg.max_iterations,
                max_wait_s=bound[0],
                first_round=1,
                last_round=pause_rounds if pause_rounds > 0 else cfg.max_iterations,
                target0=replan,
            )
            while True:
                found = self._compiled(tuple(approach), grid, ctl)
                if isinstance(found, Paused):
                    yield  # the caller may lower the bound meanwhile
                    target = found.target
                    if target > bound[0]:
                        raise _too_late(bound[0])
                    last_round = cfg.max_iterations
                elif found is None:
                    break
                else:
                    late = self._exit_conflict(found.traj, found.out_s, found.out_mps)
                    if late is None:
                        return found
                    target = found.traj.entry_time_s() - req.t0_s + max(late.delay_s, cfg.step_s)
                    if target > bound[0]:
                        raise _too_late(bound[0])
                    if found.iterations >= cfg.max_iterations:
                        break
                    last_round = ctl.last_round
                ctl = ctl._replace(
                    max_wait_s=bound[0],
                    first_round=found.iterations + 1,
                    last_round=last_round,
                    target0=target,
                )

        planner = Planner(
            d_m=d_m,
            v0_mps=req.speed_mps,
            road_mps=road,
            cap_mps=cap,
            s_end_m=s_end,
            kin=cfg.kinematics,
            hold=cfg.platoon,
        )
        earliest = req.t0_s + planner.earliest_entry_s()
        if not math.isfinite(earliest):
            raise _infeasible()
        if not math.isnan(replan):
            traj = plan_entry(planner, req.t0_s, replan, cfg.step_s, s_end)
        b_wait: float | None = None  # the current plan's wait if of the stop family
        for iteration in range(1, cfg.max_iterations + 1):
            dtot = build_dtot(route, shape, traj, cfg.margin_m, grid, cfg.techniques.estimated_oti)
            conflicts = ica.conflicts(dtot)
            if leader is not None:
                lead_dtot = leader.dtot
                found = follow_conflict(traj, lag, lead_dtot.shape.length_m, gap)
                if found is not None:
                    if found[0] <= req.t0_s + cfg.step_s + 1e-9:
                        raise _too_close(req, traj, leader, lag, gap, cfg.step_s)
                    if (
                        b_wait is not None
                        and found[0] - req.t0_s <= planner.stop_time_s() + b_wait + 1e-9
                    ):
                        raise _blocked(req.vin, leader.vin)
                    conflicts.append(Conflict(leader.vin, *found))
                    conflicts.sort(key=lambda c: c.first_time_s)
            out_s, out_mps = float(dtot.t_s[-1]), dtot.exit_speed_mps
            late = self._exit_conflict(traj, out_s, out_mps)
            if late is not None:
                conflicts.append(late)
                conflicts.sort(key=lambda c: c.first_time_s)
            if not conflicts:
                return Found(traj, out_s, out_mps, iteration, earliest, dtot)
            first = conflicts[0]
            target = traj.entry_time_s() - req.t0_s + max(first.delay_s, cfg.step_s)
            if target > bound[0]:
                raise _too_late(bound[0])
            b_wait = planner.stop_wait_s(target)
            traj = plan_entry(planner, req.t0_s, target, cfg.step_s, s_end)
        raise RequestError(
            Reason.INFEASIBLE, f"no conflict-free plan after {cfg.max_iterations} updates"
        )

    def _lane_leader(self) -> Leader:
        """The lane leader as the compiled loop reads it: its plan, delayed (``lag``)."""
        lag = self.lag
        if self.leader is None or lag is None:
            return Leader(False, 0.0, 0.0, _NO_SAMPLES, 0.0, self.gap_m)
        return Leader(
            present=True,
            t0_s=lag.t0_s,
            step_s=lag.step_s,
            s_m=np.ascontiguousarray(lag.s_m, dtype=float),
            length_m=self.leader.dtot.shape.length_m,
            gap_m=self.gap_m,
        )

    def _compiled(
        self, approach_args: tuple, grid: RouteGrid, ctl: Controls
    ) -> Found | Paused | None:
        """Rounds of :meth:`rounds` in one compiled call
        (:func:`ica.core.kernels.resolve.resolve_rounds`, the approach as a tuple):
        the same plans round for round, so the same answer, and the request's earliest
        entry kept with it. None where the loop would raise; paused after round
        ``ctl.last_round``."""
        ica, req = self.ica, self.req
        cfg = ica.config
        if self._fixed is None:
            rows = ica._confirmed_batch(self.route, self.shape).rows
            self._fixed = (
                tuple(grid.kernel_grid(cfg.margin_m)),
                tuple(rows),
                tuple(self._lane_leader()),
            )
        grid_args, rows_args, leader_args = self._fixed
        status, iteration, s, target, earliest, arrays = resolve_rounds(
            approach_args, grid_args, rows_args, leader_args, tuple(ctl)
        )
        if status == INFEASIBLE:
            raise _infeasible()
        if status == BLOCKED:
            raise _blocked(req.vin, self.leader.vin if self.leader is not None else "")
        if status == TOO_LATE:
            raise _too_late(ctl.max_wait_s)
        if status == PAUSED:
            return Paused(iteration, target)
        if status != RESOLVED:
            return None
        final = Trajectory(req.t0_s, cfg.step_s, s)
        out_s, out_mps = _exit_of(final, arrays)
        return Found(final, out_s, out_mps, iteration, req.t0_s + earliest, arrays=arrays)

    def _exit_conflict(self, traj: Trajectory, out_s: float, out_mps: float) -> Conflict | None:
        """The rules the conflict search does not see: the exit rules
        (:meth:`Dica.exit_order`, with exit spacing :meth:`Dica.exit_spacing`) of a
        plan leaving at ``out_s`` at ``out_mps``, and the walkers on the crossings it
        passes (:meth:`Dica.walk_conflict`): the conflict that delays ``traj`` the most,
        or None."""
        ica = self.ica
        late = ica.exit_order(self.route, out_s, out_mps, traj, self.shape.length_m)
        if ica.config.exit_spacing:
            gap = ica.exit_spacing(self.route, out_s, out_mps, self.shape.length_m)
            if gap is not None and (late is None or gap.delay_s > late.delay_s):
                late = gap
        walk = ica.walk_conflict(self.route, self.shape, traj, out_mps)
        if walk is not None and (late is None or walk.delay_s > late.delay_s):
            late = walk
        return late
