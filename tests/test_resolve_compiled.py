"""Enhanced DICA's compiled round loop (``ica.core.kernels.resolve.resolve_rounds``)
gives every answer of the Python loop of ``Search.rounds``, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

import dica.ica.core.search as search_module
from dica.ica.core.config import IcaConfig, Techniques
from dica.ica.core.controller import ControllerSpec, build_controller
from dica.ica.core.dica import Dica
from dica.ica.core.kernels.resolve import Controls
from dica.ica.core.planner import Planner
from dica.ica.core.proposal import propose
from dica.ica.core.request import Reason, RequestError
from dica.ica.core.search import Search, finish
from dica.ica.core.validate import check_request
from dica.sim_gateway.stream import StreamSpec, run_stream


def _resolve(rounds, search: Search, compiled: bool, args: tuple):
    """(what to compare, the result or the exception) of one search run to its end."""
    search.ica.compiled_loop = compiled
    try:
        found = finish(rounds(search, *args))
    except RequestError as e:
        return ("raised", e.reason, e.detail), e
    finally:
        del search.ica.compiled_loop
    return _key(search, found), found


def _key(search: Search, found) -> tuple:
    d = found.kept_dtot(search.route, search.shape, search.ica.config.margin_m)
    assert (found.out_s, found.out_mps) == (float(d.t_s[-1]), d.exit_speed_mps)
    iterations, earliest = found.iterations, found.earliest
    key = (
        d.trajectory.t0_s,
        d.trajectory.step_s,
        d.trajectory.s_m.tobytes(),
        d.k0,
        *(a.tobytes() for a in (d.t_s, d.s_m, d.lb_s, d.ub_s, d.grid_idx)),
        *(a.tobytes() for a in (d.rects.centre, d.rects.heading)),
        d.rects.half_length,
        d.rects.half_width,
        iterations,
        earliest,
    )
    return key


@pytest.mark.parametrize(
    ("junction", "volume", "seed", "variant", "exit_spacing"),
    [
        ("ch45", 3000.0, 3, "enhanced", False),
        ("ch45", 6000.0, 12, "enhanced", False),
        ("skewed", 2500.0, 7, "enhanced", False),
        ("tee", 2500.0, 9, "enhanced", False),
        ("ch45", 6000.0, 12, "t1+2+3+4", False),
        ("skewed", 2500.0, 7, "t1+2+3+4", False),
        ("ch45", 3000.0, 3, "enhanced", True),
        ("skewed", 2500.0, 7, "enhanced", True),
    ],
)
def test_compiled_rounds_equal_python_rounds(
    request, monkeypatch, junction, volume, seed, variant, exit_spacing
):
    """Every request of a heavy stream is resolved both ways, from the same
    state: same plan, DTOT, rounds and earliest entry, or the same rejection.
    Both kinds of technique 3's intervals: exact, and the dissertation's; with
    exit spacing the compiled loop goes on after each exit delay, and each
    request may be resolved twice (capped and fast), both ways each time."""
    inter = request.getfixturevalue(junction)
    rounds = Search.rounds
    rng = np.random.default_rng(seed)
    seen = {"requests": 0, "rounds": 0, "raised": 0, "stops": 0, "exit_delays": 0, "planned": 0,
            "paused": 0}  # fmt: skip

    def both(self: Search, cap: float, bound: list[float], pause_rounds: int = 0):
        """The compiled search as the request runs it (paused, its bound lowered
        meanwhile, and half the time lowered again at random), then the Python loop
        with the bound it ended with, from the start."""
        assert self.ica._compiled_rounds()
        run = rounds(self, cap, bound, pause_rounds)
        try:
            while True:
                next(run)
                seen["paused"] += 1
                yield
                if rng.uniform() < 0.5:  # lower it further: the search must give up there
                    bound[0] = rng.uniform(0.0, bound[0])
        except StopIteration as done:
            out = done.value
            fast = _key(self, out)
        except RequestError as e:
            out, fast = e, ("raised", e.reason, e.detail)
        slow, _ = _resolve(rounds, self, False, (cap, [bound[0]]))
        assert fast == slow
        seen["requests"] += 1
        if isinstance(out, RequestError):
            seen["raised"] += 1
            raise out
        seen["rounds"] += out.iterations
        return out

    monkeypatch.setattr(Search, "rounds", both)
    monkeypatch.setattr(search_module, "PAUSE_ROUNDS", 3)  # pauses often: every way on is met
    build_b = Planner._build_b

    def counted(self: Planner, wait_s: float):
        seen["stops"] += 1
        return build_b(self, wait_s)

    monkeypatch.setattr(Planner, "_build_b", counted)
    exit_conflict = Search._exit_conflict

    def delayed(self: Search, *args):
        late = exit_conflict(self, *args)
        seen["exit_delays"] += late is not None
        return late

    monkeypatch.setattr(Search, "_exit_conflict", delayed)
    resolve_rounds = search_module.resolve_rounds

    def planning(*args):
        # the loop plans its first entry
        seen["planned"] += not math.isnan(Controls(*args[-1]).target0)
        return resolve_rounds(*args)

    monkeypatch.setattr(search_module, "resolve_rounds", planning)
    spec = StreamSpec(
        volume_per_10min=volume,
        n_vehicles=60,
        seed=seed,
        length_range_m=(3.5, 7.5),
        width_range_m=(1.6, 2.3),
    )
    cfg = IcaConfig(techniques=Techniques.parse(variant), exit_spacing=exit_spacing)
    res = run_stream(inter, cfg, spec)
    assert len(res.confirmed) == len(res.vehicles)
    assert seen["stops"] > 0  # plans of the stop family too
    assert seen["requests"] >= 60
    assert seen["rounds"] > 3 * seen["requests"]  # most requests took several rounds
    assert seen["planned"] > 0  # a first plan over the cap, or after an exit delay
    if exit_spacing:
        assert seen["exit_delays"] > 0  # exit rules delayed plans: the compiled loop went on
        assert seen["paused"] > 0  # capped searches paused for the fast one, and went on


def test_compiled_rounds_only_for_enhanced(ch45):
    assert Dica(ch45, IcaConfig())._compiled_rounds()
    assert Dica(ch45, IcaConfig(techniques=Techniques.parse("t1+2+3+4")))._compiled_rounds()
    for variant in ("basic", "t1", "t2", "t3", "t4", "t2+4", "t1+2+4"):
        assert not Dica(ch45, IcaConfig(techniques=Techniques.parse(variant)))._compiled_rounds()


def test_controllers_get_tables_of_their_interval_kind(ch45):
    """build_controller hands each DICA variant offline tables of its kind of intervals."""
    for name, exact in (("enhanced", True), ("basic", True), ("t3", False), ("t1+2+3+4", False)):
        ica = build_controller(ControllerSpec.of(name, 0.25), ch45)
        assert ica.tables.exact_oti is exact
        assert ica.config.techniques.exact_oti is exact


def _in_turn(search: Search):
    """The two searches of a request planned twice, one after the other: capped first,
    then the fast one given up once its entry is past the capped plan's exit."""
    ica, route = search.ica, search.route
    cap = ica.front_cap_mps(route)
    if not ica.config.exit_spacing or cap >= route.speed_cap_mps:
        return search.resolve(cap)
    try:
        capped = search.resolve(cap)
    except RequestError:
        return search.resolve(route.speed_cap_mps)
    give_up = min(ica.config.max_wait_s, capped.out_s - search.req.t0_s)
    try:
        fast = search.resolve(route.speed_cap_mps, give_up)
    except RequestError:
        return capped
    return fast if fast.out_s < capped.out_s else capped


def _outcome(resolve) -> tuple:
    try:
        f = resolve()
    except RequestError as e:
        return ("raised", e.reason, e.detail), e
    return (f.traj.t0_s, f.traj.s_m.tobytes(), f.out_s, f.out_mps, f.iterations, f.earliest), f


@pytest.mark.parametrize(
    ("junction", "volume", "seed", "pause"),
    [("ch45", 3000.0, 3, 3), ("ch45", 6000.0, 12, 12), ("skewed", 2500.0, 7, 2)],
)
def test_pausing_the_capped_search_for_the_fast_one_changes_no_answer(
    request, monkeypatch, junction, volume, seed, pause
):
    """Every request of a heavy stream with exit spacing: ``Search.best`` (the
    capped search paused after ``pause`` rounds while the fast one runs) gives the plan,
    or the error, of the two searches in turn. Fails if the paused search goes on
    under a bound it should not have (a plan entering after the fast plan's exit, or
    one given up too soon) or keeps the wrong plan of the two."""
    inter = request.getfixturevalue(junction)
    monkeypatch.setattr(search_module, "PAUSE_ROUNDS", pause)
    best, rounds = Search.best, Search.rounds
    seen = {"twice": 0, "fast kept": 0, "paused": 0, "raised": 0}

    def counted(self: Search, *args):
        run = rounds(self, *args)
        while True:
            try:
                next(run)
            except StopIteration as done:
                return done.value
            seen["paused"] += 1
            yield

    def compare(self: Search):
        want, _ = _outcome(lambda: _in_turn(self))
        got, out = _outcome(lambda: best(self))
        assert got == want
        cap = self.ica.front_cap_mps(self.route)
        if cap < self.route.speed_cap_mps:
            seen["twice"] += 1
            if isinstance(out, RequestError):
                seen["raised"] += 1
            elif out.out_mps > cap + self.ica.config.speed_tol_mps:
                seen["fast kept"] += 1
        if isinstance(out, RequestError):
            raise out
        return out

    monkeypatch.setattr(Search, "rounds", counted)
    monkeypatch.setattr(Search, "best", compare)
    spec = StreamSpec(volume_per_10min=volume, n_vehicles=60, seed=seed)
    res = run_stream(inter, IcaConfig(exit_spacing=True), spec)
    assert len(res.confirmed) == len(res.vehicles)
    assert seen["paused"] > 0
    assert 0 < seen["fast kept"] < seen["twice"]  # both searches' plans were kept


def test_a_plan_that_cannot_slow_to_the_cap_is_infeasible_both_ways(ch45):
    """The compiled loop works out the planner's constants itself, so it also tells a
    vehicle that cannot slow to the crossing cap before the line: the same rejection,
    word for word, as the Python loop's, and for a cap it can slow to the same plan."""
    ica = Dica(ch45, IcaConfig())
    route = max(ch45.routes, key=lambda r: r.speed_cap_mps)
    req = propose(route, vin="a", seq=0, t0_s=0.0, dist_to_entry_m=12.0, speed_mps=14.0)
    route, shape, traj = check_request(req, ch45, ica.config, 0.0)
    search = Search(ica, req, route, shape, traj, None)
    for cap, infeasible in ((2.0, True), (route.speed_cap_mps, False)):
        outcomes = [
            _resolve(Search.rounds, search, compiled, (cap, [120.0]))[0]
            for compiled in (True, False)
        ]
        assert outcomes[0] == outcomes[1]
        assert (outcomes[0][:2] == ("raised", Reason.INFEASIBLE)) is infeasible
