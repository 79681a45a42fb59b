"""Enhanced DICA's compiled round loop (``ica.core.kernels.resolve_rounds``)
gives every answer of the Python loop of ``Dica._resolve``, bit for bit."""

from __future__ import annotations

import math

import pytest

import ica.core.dica as dica_module
from ica.core.baselines import controller_config, make_controller
from ica.core.config import IcaConfig, Techniques
from ica.core.dica import Dica
from ica.core.planner import Planner
from ica.core.request import RequestError
from tools.stream import StreamSpec, run_stream


def _resolve(resolve, ica: Dica, compiled: bool, args: tuple):
    """(what to compare, the result or the exception) of one loop."""
    ica.compiled_loop = compiled
    try:
        found = resolve(ica, *args)
    except RequestError as e:
        return ("raised", e.reason, e.detail), e
    finally:
        del ica.compiled_loop
    route, shape = args[1], args[2]
    d = ica._dtot(found, route, shape)
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
    return key, found


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
    python_loop = Dica._resolve
    seen = {"requests": 0, "rounds": 0, "raised": 0, "stops": 0, "exit_delays": 0, "planned": 0}

    def both(self: Dica, *args):
        assert self._compiled_rounds()
        fast, out = _resolve(python_loop, self, True, args)
        slow, _ = _resolve(python_loop, self, False, args)
        assert fast == slow
        seen["requests"] += 1
        if isinstance(out, RequestError):
            seen["raised"] += 1
            raise out
        seen["rounds"] += out.iterations
        return out

    monkeypatch.setattr(Dica, "_resolve", both)
    build_b = Planner._build_b

    def counted(self: Planner, wait_s: float):
        seen["stops"] += 1
        return build_b(self, wait_s)

    monkeypatch.setattr(Planner, "_build_b", counted)
    exit_conflict = Dica._exit_conflict

    def delayed(self: Dica, *args):
        late = exit_conflict(self, *args)
        seen["exit_delays"] += late is not None
        return late

    monkeypatch.setattr(Dica, "_exit_conflict", delayed)
    rounds = dica_module.resolve_rounds

    def planning(*args):
        seen["planned"] += not math.isnan(args[-1])  # the loop plans its first entry
        return rounds(*args)

    monkeypatch.setattr(dica_module, "resolve_rounds", planning)
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


def test_compiled_rounds_only_for_enhanced(ch45):
    assert Dica(ch45, IcaConfig())._compiled_rounds()
    assert Dica(ch45, IcaConfig(techniques=Techniques.parse("t1+2+3+4")))._compiled_rounds()
    for variant in ("basic", "t1", "t2", "t3", "t4", "t2+4", "t1+2+4"):
        assert not Dica(ch45, IcaConfig(techniques=Techniques.parse(variant)))._compiled_rounds()


def test_controllers_get_tables_of_their_interval_kind(ch45):
    """make_controller hands each DICA variant offline tables of its kind of intervals."""
    for name, exact in (("enhanced", True), ("basic", True), ("t3", False), ("t1+2+3+4", False)):
        ica = make_controller(name, ch45, controller_config(name, 0.25))
        assert ica.tables.exact_oti is exact
        assert ica.config.techniques.exact_oti is exact
