"""The compiled kernels as a package: a request never compiles, a kernel never runs the
stale code of another file, bundles cross into compiled code only as their kind, and the
one rectangle-overlap test is numpy's."""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np
import pytest
from numba import njit
from numba.core.registry import CPUDispatcher

import dica.ica.core.kernels as kernels
from dica.ica.core.config import IcaConfig, Techniques
from dica.ica.core.kernels import STAMP_NAME, drop_stale_caches, sources_stamp
from dica.ica.core.kernels.occupancy import EPS_SAT, Rect, overlaps
from dica.ica.core.kernels.planner import Approach, a_phases
from dica.ica.core.occupancy import separated
from dica.sim_gateway.stream import StreamSpec, run_stream


def _dispatchers() -> dict[str, CPUDispatcher]:
    found = {}
    for info in pkgutil.iter_modules(kernels.__path__):
        module = importlib.import_module(f"{kernels.__name__}.{info.name}")
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                found[f"{info.name}.{name}"] = value
    return found


@pytest.mark.parametrize("variant", ["enhanced", "t1+2+4"])
def test_a_stream_of_requests_compiles_nothing(ch45, variant):
    """Every kernel a request runs has its machine code once the core is imported: a
    heavy stream (the compiled round loop with exit spacing, lane leaders and stops;
    the batched getCV of the Python loop) leaves every dispatcher of the package with
    the signatures it had. A kernel called from Python without its signature fixed
    would compile on its first request and add one."""
    dispatchers = _dispatchers()
    assert {"resolve.resolve_rounds", "dtot.grid_dtot_of", "conflict.batch_conflicts"} <= set(
        dispatchers
    )
    before = {name: list(d.signatures) for name, d in dispatchers.items()}
    spec = StreamSpec(volume_per_10min=3000.0, n_vehicles=40, seed=3)
    cfg = IcaConfig(techniques=Techniques.parse(variant), exit_spacing=True)
    res = run_stream(ch45, cfg, spec)
    assert len(res.confirmed) == len(res.vehicles)
    after = {name: list(d.signatures) for name, d in dispatchers.items()}
    assert after == before


def test_a_bundle_crosses_from_python_only_as_the_plain_tuple_of_its_fields():
    """A kernel called from Python takes a bundle as ``tuple(bundle)``: the named tuple
    itself, or a tuple of other types, is refused at the call, never reinterpreted."""
    approach = Approach(2.0, 4.5, 10.0, 40.0, 19.4, 18.0, 30.0, 0.5, 0.5, True, False, 324.0, 100.0)
    fits, *_ = a_phases(tuple(approach), 12.0)
    assert fits
    with pytest.raises(TypeError):
        a_phases(approach, 12.0)
    with pytest.raises(TypeError):
        a_phases(tuple(approach)[:-1], 12.0)  # a field short


def test_a_changed_source_drops_every_cached_kernel_of_the_package(tmp_path):
    """numba keys a cached kernel to its own file only: once any source of the package
    changes, every cached kernel goes (they hold compiled code of each other's files);
    unchanged sources keep them, and byte code is never touched."""
    for name in ("interp.py", "dtot.py"):
        (tmp_path / name).write_text(f"# {name}\n")
    cache = tmp_path / "__pycache__"
    assert drop_stale_caches(tmp_path)  # no stamp yet
    compiled = [cache / "dtot.grid_dtot-1.py311.nbi", cache / "dtot.grid_dtot-1.py311.1.nbc"]
    byte_code = cache / "dtot.cpython-311.pyc"
    for p in [*compiled, byte_code]:
        p.write_bytes(b"x")
    assert not drop_stale_caches(tmp_path)
    assert all(p.exists() for p in [*compiled, byte_code])
    (tmp_path / "interp.py").write_text("# interp.py, changed\n")  # dtot's cache holds the old
    assert drop_stale_caches(tmp_path)
    assert not any(p.exists() for p in compiled) and byte_code.exists()
    assert not drop_stale_caches(tmp_path)
    assert (cache / STAMP_NAME).read_text() == sources_stamp(tmp_path)


def test_the_installed_kernels_are_stamped_with_their_sources():
    folder = kernels._HERE
    assert (folder / "__pycache__" / STAMP_NAME).read_text() == sources_stamp(folder)


@njit
def _overlaps_all(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    for k in range(len(out)):
        ra = Rect(a[k, 0], a[k, 1], a[k, 2], a[k, 3], a[k, 4], a[k, 5])
        rb = Rect(b[k, 0], b[k, 1], b[k, 2], b[k, 3], b[k, 4], b[k, 5])
        out[k] = overlaps(ra, rb)


def _numpy(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The oracle: ica.core.occupancy.separated on the same pairs (b minus a)."""
    d = b[:, :2] - a[:, :2]
    return ~separated(d[:, 0], d[:, 1], a[:, 2:4], b[:, 2:4], a[:, 4], a[:, 5], b[:, 4], b[:, 5])


def test_the_one_overlap_test_is_numpys_separating_axis_test_bit_for_bit():
    """Random pairs of rectangles, and pairs placed exactly at the touching distance
    (with the tolerance) and one ulp either side of it along each axis: the compiled
    test says what numpy's says, pair for pair."""
    rng = np.random.default_rng(17)
    n = 20000
    ang_a, ang_b = rng.uniform(-np.pi, np.pi, (2, n))
    a = np.column_stack(
        [rng.uniform(-5, 5, (n, 2)), np.cos(ang_a), np.sin(ang_a), rng.uniform(0.5, 4, (n, 2))]
    )
    b = np.column_stack(
        [rng.uniform(-5, 5, (n, 2)), np.cos(ang_b), np.sin(ang_b), rng.uniform(0.5, 4, (n, 2))]
    )
    edge_a, edge_b = [], []
    for la, wa, lb, wb in rng.uniform(0.5, 3.0, (200, 4)):
        for axis, reach in ((0, la + lb + EPS_SAT), (1, wa + wb + EPS_SAT)):
            for step in (-np.inf, None, np.inf):
                d = reach if step is None else np.nextafter(reach, step)
                centre = [0.0, 0.0]
                centre[axis] = d
                edge_a.append([0.0, 0.0, 1.0, 0.0, la, wa])
                edge_b.append([*centre, 1.0, 0.0, lb, wb])
    a = np.vstack([a, edge_a])
    b = np.vstack([b, edge_b])
    out = np.empty(len(a), np.bool_)
    _overlaps_all(a, b, out)
    want = _numpy(a, b)
    assert np.array_equal(out, want)
    assert 0.2 < want.mean() < 0.8  # both answers are common
    tail = want[n:].reshape(-1, 3)  # per edge case: one ulp in, at, one ulp out
    assert tail[:, 0].all() and not tail[:, 2].any()


def test_the_overlap_test_is_inlined_where_it_is_used():
    """numba's ``inline="always"``: each loop gets its own copy of the test, so it
    costs what the three written-out copies it replaced cost."""
    assert overlaps.targetoptions.get("inline") == "always"
