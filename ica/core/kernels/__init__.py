"""Compiled inner loops of enhanced DICA (numba), bit for bit the numpy versions.

One round of Algorithm 1 on arrays of a hundred or so occupancies costs
almost nothing in arithmetic; with numpy it is dozens of calls, each paying
its own overhead. These loops do the same arithmetic, in the same order, in
one call each. One module per concern; a caller imports a kernel from the
module that owns it:

* :mod:`.interp`: numpy's binary search and interpolation;
* :mod:`.route`: points, headings and projections on a route's polyline, a TSS;
* :mod:`.occupancy`: the one rectangle-overlap (separating-axis) test;
* :mod:`.dtot`: a trajectory's DTOT with the grid (footprints, grid index,
  technique 3's intervals), where it enters and leaves;
* :mod:`.conflict`: getCV over the confirmed rows, the lane-leader check;
* :mod:`.validate`: the numeric checks of a REQUEST's TSS;
* :mod:`.planner`: the planner's phase arithmetic, plan building and sampling;
* :mod:`.resolve`: Algorithm 1's round loop, whole;
* :mod:`.handover`: the least separation at which the road's driver takes over;
* :mod:`.follow`: Krauss's safe speed behind a vehicle on the same exit lane (a
  human driver's green, the exit-lane order).

Floating-point results equal numpy's exactly where the arithmetic is IEEE's
basic operations and square root: the expressions are written in numpy's
order, numba does not fuse multiply-adds without ``fastmath``, and the binary
search is numpy's own, so it gives numpy's answer even on unsorted input.
Where a libm function feeds a value (``atan2`` of a heading), the kernel
calls the platform's libm and numpy may call its own SIMD version, whose
last bit can differ; no decision reads such a value (see
``tests/test_kernels.py``, which states the bound).

**Bundles.** What travels together goes as one ``typing.NamedTuple``
(:class:`.planner.Approach`, :class:`.dtot.Grid`, :class:`.conflict.Rows`,
:class:`.resolve.Leader`, :class:`.resolve.Controls`, ...), built by the
Python side with named fields, or in compiled code (:class:`.planner.Plan`,
the planner's constants), so the compiled code reads ``plan.cap_mps``, never
the fifth positional float. Between kernels a bundle is that named tuple. A
kernel called from Python takes it as the plain tuple of its fields
(``tuple(bundle)``) and names it again on its first line
(``grid = Grid(*grid_args)``), and hands one back as a plain tuple too
(``plan[:]``): numba types a plain tuple in C when dispatching a call, a
named one in Python, which cost about 2.5 us more per call for a bundle of
15 fields, measured; the order of the fields is the class's, and no code
writes it out. Such a kernel's signature comes from ``numba.typeof`` of a
bundle built at import time.

The functions are compiled when their module is first imported (explicit
signatures) and cached on disk by numba next to the module, like byte code;
deciding a request does no I/O and no compilation. A fresh cache costs some
twenty seconds once; a warm one well under a second per process.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_HERE = Path(__file__).resolve().parent
STAMP_NAME = "kernels-sources.sha256"


def sources_stamp(folder: Path) -> str:
    """A hash of every Python source in ``folder``, names and contents."""
    h = hashlib.sha256()
    for p in sorted(folder.glob("*.py")):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def drop_stale_caches(folder: Path = _HERE) -> bool:
    """Forget every cached kernel of the package once any of its sources changed.

    numba keys a cached function to its own file's source, but a kernel here
    holds the compiled code of the kernels of other files it calls: after a
    change to :mod:`.interp` alone, :mod:`.dtot` would load machine code with
    the old interpolation in it. Returns whether it dropped anything. A
    folder that cannot be written keeps no numba cache of its own either.
    """
    cache = folder / "__pycache__"
    stamp = cache / STAMP_NAME
    now = sources_stamp(folder)
    try:
        if stamp.read_text() == now:
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for p in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            p.unlink(missing_ok=True)
        part = cache / f"{STAMP_NAME}.{os.getpid()}"
        part.write_text(now)
        part.replace(stamp)  # in one step: another process reads the old stamp or this one
    except OSError:
        return False
    return True


drop_stale_caches()
