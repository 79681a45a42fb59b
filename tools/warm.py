"""Fill numba's cache of the compiled core on both cores before the processes that use it.

A cold cache makes each process that imports the core compile every kernel on
one core (about 45 s here). The kernels form a small tree: the round loop
(``resolve``) calls the DTOT, getCV and planner kernels. Their two halves, and
the EV ordering, compile in two processes side by side, then the round loop
alone, from the cached halves; with a warm cache each import loads in well
under a second and this costs next to nothing. ``run_cluster.sh`` and
``test.sh`` run it before they start processes that import the core.

    python -m dica.tools.warm
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HALVES = (
    (
        "dica.ica.core.kernels.dtot",
        "dica.ica.core.kernels.conflict",
        "dica.ica.core.kernels.follow",
    ),
    (
        "dica.ica.core.kernels.validate",
        "dica.ica.core.kernels.planner",
        "dica.ica.core.kernels.handover",
        "dica.ica.core.ordering",
    ),
)
LAST = ("dica.ica.core.kernels.resolve", "dica.ica.core.dica", "dica.ica.core.controller")


def _importing(modules: tuple[str, ...]) -> subprocess.Popen:
    code = "import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m)"
    return subprocess.Popen([sys.executable, "-c", code, *modules])


def _warm() -> bool:
    """Every module of the compiled core that caches kernels has them cached for
    today's sources (read from the files: importing would compile)."""
    from dica.ica.core import kernels  # the package alone: no kernel in it

    core = Path(kernels.__file__).resolve().parents[1]
    try:
        stamp = (core / "kernels" / "__pycache__" / kernels.STAMP_NAME).read_text()
    except OSError:
        return False
    if stamp != kernels.sources_stamp(core / "kernels"):
        return False
    return all(
        any((src.parent / "__pycache__").glob(f"{src.stem}.*.nbi"))
        for folder in (core / "kernels", core / "ordering")
        for src in folder.glob("*.py")
        if "cache=True" in src.read_text()
    )


def main() -> int:
    if _warm():
        return 0
    halves = [_importing(h) for h in HALVES]
    status = [p.wait() for p in halves]
    last = _importing(LAST).wait()
    return max(*status, last)


if __name__ == "__main__":
    sys.exit(main())
