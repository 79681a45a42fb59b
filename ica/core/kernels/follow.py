"""Krauss's safe speed behind a vehicle leaving by the same exit lane, compiled.

``ica.core.envelope.follow_delay_numpy`` in one call: the same samples and the
same arithmetic in the same order (numpy's interpolation and binary search),
so the same delay bit for bit. A green's search and the exit-lane order ask it
once or twice per human reservation onto an exit lane, every round; as numpy
calls it cost about 0.1 ms each.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from dica.ica.core.kernels.interp import interp_rising, searchsorted


class Follower(NamedTuple):
    """The vehicle behind: its samples' clock, its route through the junction, and
    from which of its positions on it is watched (a plan: its entry line)."""

    t0_s: float
    step_s: float
    cross_m: float
    length_m: float
    from_m: float


class Lead(NamedTuple):
    """The vehicle ahead, carried on at its last speed beyond its samples."""

    t0_s: float
    step_s: float
    cross_m: float
    length_m: float


class Krauss(NamedTuple):
    """SUMO's car-following driver: reaction time, the braking its safe speed
    assumes, standstill gap."""

    tau_s: float
    decel_mps2: float
    min_gap_m: float


@njit(
    "float64(UniTuple(float64, 5), float64[::1], UniTuple(float64, 4), float64[::1],"
    " UniTuple(float64, 3))",
    cache=True,
    nogil=True,
)
def follow_delay(
    follower_args: tuple, s_m: np.ndarray, lead_args: tuple, lead_s_m: np.ndarray,
    krauss_args: tuple,
) -> float:  # fmt: skip
    """The follower (front positions ``s_m``) against the lead (``lead_s_m``): how
    much later the follower must start (0: it never brakes inside)."""
    f, ld, kr = Follower(*follower_args), Lead(*lead_args), Krauss(*krauss_args)
    t0_s, step_s, cross_m, length_m, from_m = f.t0_s, f.step_s, f.cross_m, f.length_m, f.from_m
    lead_t0_s, lead_step_s = ld.t0_s, ld.step_s
    lead_cross_m, lead_length_m = ld.cross_m, ld.length_m
    tau_s, decel_mps2, min_gap_m = kr.tau_s, kr.decel_mps2, kr.min_gap_m
    n = len(s_m) - 1
    t = np.empty(n)
    u_f = np.empty(n)
    v_f = np.empty(n)
    m = 0  # the follower's samples watched while its rear is inside
    for j in range(n):
        u = s_m[j] - cross_m
        if u - length_m < 0.0 and s_m[j] >= from_m:
            t[m] = t0_s + step_s * j
            u_f[m] = u
            v_f[m] = (s_m[j + 1] - s_m[j]) / step_s
            m += 1
    if m == 0:
        return 0.0
    t, u_f, v_f = t[:m], u_f[:m], v_f[:m]
    # the lead's front and speed at those times: standing at its first sample before
    # it, carried on at its last speed after it
    ln = len(lead_s_m)
    lt = np.empty(ln)
    for j in range(ln):
        lt[j] = lead_t0_s + lead_step_s * j
    pos = np.empty(m)
    if ln >= 2:
        interp_rising(t, lt, lead_s_m, pos)
        v_last = (lead_s_m[ln - 1] - lead_s_m[ln - 2]) / lead_step_s
    else:
        for j in range(m):
            pos[j] = lead_s_m[0]
        v_last = 0.0
    end = lt[ln - 1]
    tb = tau_s * decel_mps2
    bad = np.zeros(m, dtype=np.bool_)
    v_l = np.empty(m)
    nbad = 0
    for j in range(m):
        if t[j] > end:
            pos[j] = lead_s_m[ln - 1] + v_last * (t[j] - end)
            v_l[j] = v_last
        else:
            k = int((t[j] - lead_t0_s) / lead_step_s)
            k = min(max(k, 0), ln - 1)
            k = min(k, ln - 2) if ln >= 2 else 0
            v_l[j] = (lead_s_m[k + 1] - lead_s_m[k]) / lead_step_s if ln >= 2 else 0.0
        rear = pos[j] - lead_cross_m - lead_length_m
        gap = rear - u_f[j] - min_gap_m
        safe = -tb + math.sqrt(tb * tb + v_l[j] * v_l[j] + 2.0 * decel_mps2 * max(gap, 0.0))
        if gap < 0.0 or v_f[j] > safe + 1e-9:
            bad[j] = True
            nbad += 1
    if nbad == 0:
        return 0.0
    # the gap at which it need not brake, and when the lead's rear is that far ahead
    target = np.empty(nbad)
    tbad = np.empty(nbad)
    q = 0
    for j in range(m):
        if bad[j]:
            w = v_f[j] + tb
            need = max((w * w - tb * tb - v_l[j] * v_l[j]) / (2.0 * decel_mps2), 0.0)
            target[q] = u_f[j] + min_gap_m + need + lead_cross_m + lead_length_m
            tbad[q] = t[j]
            q += 1
    idx = np.empty(nbad, dtype=np.int64)
    searchsorted(lead_s_m, target, False, idx)
    worst = -math.inf
    for j in range(nbad):
        if target[j] > lead_s_m[ln - 1]:
            reach = end + (target[j] - lead_s_m[ln - 1]) / max(v_last, 0.1)
        else:
            reach = lead_t0_s + lead_step_s * min(idx[j], ln - 1)
        worst = max(worst, reach - tbad[j])
    return max(worst, step_s)
