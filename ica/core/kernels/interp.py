"""Binary search and linear interpolation, numpy's own, step for step.

Where the numpy versions call ``np.searchsorted`` and ``np.interp``, the
kernels call these: the same answers bit for bit, also on input a rounding
error off sorted, where numpy's answer depends on how it searches.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit("int64(float64[::1], float64, boolean)", cache=True, nogil=True)
def searchsorted_one(a: np.ndarray, key: float, right: bool) -> int:
    """np.searchsorted for one key (a plain binary search: a is sorted here)."""
    lo, hi = 0, len(a)
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        if a[mid] <= key if right else a[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit("void(float64[::1], float64[::1], boolean, int64[::1])", cache=True, nogil=True)
def searchsorted(a: np.ndarray, keys: np.ndarray, right: bool, out: np.ndarray) -> None:
    """np.searchsorted(a, keys), numpy's own algorithm step for step.

    numpy narrows the search with the previous key, so on input that is not
    sorted its answer depends on that; copying it keeps the answer identical
    wherever a trajectory is not monotone by a rounding error.
    """
    n = len(a)
    lo, hi = 0, n
    last = keys[0] if len(keys) else 0.0
    for q in range(len(keys)):
        key = keys[q]
        if (last <= key) if right else (last < key):
            hi = n
        else:
            lo = 0
            hi = hi + 1 if hi < n else n
        last = key
        while lo < hi:
            mid = lo + ((hi - lo) >> 1)
            if (a[mid] <= key) if right else (a[mid] < key):
                lo = mid + 1
            else:
                hi = mid
        out[q] = lo


@njit("boolean(float64[::1])", cache=True, nogil=True)
def strictly_increasing(a: np.ndarray) -> bool:
    for k in range(len(a) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if not a[k] < a[k + 1]:
            return False
    return True


@njit(cache=True, nogil=True)
def nondecreasing(a: np.ndarray) -> bool:
    for k in range(len(a) - 1):  # noqa: SIM110 (a plain loop compiles best)
        if not a[k] <= a[k + 1]:
            return False
    return True


@njit("void(float64[::1], float64[::1], float64[::1], float64[::1])", cache=True, nogil=True)
def interp_rising(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, out: np.ndarray) -> None:
    """``np.interp(x, xp, fp)`` into ``out``, for strictly increasing ``xp`` (2 points or more).

    numpy's arithmetic and special cases (numba's copy of ``arr_interp``);
    only the search differs: on strictly increasing ``xp`` the segment j is
    the last one with ``xp[j] <= x``, which a walk from the previous query
    finds as numpy's binary search does, in O(1) for sorted queries.
    """
    n = len(xp)
    lval = fp[0]
    rval = fp[n - 1]
    j = 0
    for i in range(len(x)):
        xv = x[i]
        if np.isnan(xv):
            out[i] = xv
            continue
        if xv > xp[n - 1]:
            out[i] = rval
            continue
        if xv < xp[0]:
            out[i] = lval
            continue
        # the largest j with xp[j] <= xv: what numpy's search finds on strictly increasing xp
        while j + 1 < n and xp[j + 1] <= xv:
            j += 1
        while xp[j] > xv:
            j -= 1
        if j == n - 1 or xp[j] == xv:  # numpy's two cases giving fp[j]
            out[i] = fp[j]
        else:
            slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
            r = slope * (xv - xp[j]) + fp[j]
            if np.isnan(r):
                r = slope * (xv - xp[j + 1]) + fp[j + 1]
                if np.isnan(r) and fp[j] == fp[j + 1]:
                    r = fp[j]
            out[i] = r


@njit("float64[::1](float64[::1], float64[::1], float64[::1])", cache=True, nogil=True)
def interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp``: :func:`interp_rising` where ``xp`` rises strictly, numba's copy otherwise."""
    if len(xp) >= 2 and strictly_increasing(xp):
        out = np.empty(len(x))
        interp_rising(x, xp, fp, out)
        return out
    return np.interp(x, xp, fp)
