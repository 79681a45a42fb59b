"""A real SUMO in this process, for tests that drive one part of the world alone.

libsumo runs one simulation per process: :func:`open_sumo` starts one with the
runs' own command line and closes it whatever the test does, so the next test
in the same process can start its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from dica.sim_gateway.sumo_io import import_libsumo, sumo_command

STEP_S = 0.05  # [s] the runs' step


@contextmanager
def open_sumo(net_path: Path | str, step_s: float = STEP_S) -> Iterator:
    """libsumo, started on ``net_path`` as a run starts it, and closed on leaving."""
    ls = import_libsumo()
    ls.start(sumo_command(str(net_path), step_s, ()))
    try:
        yield ls
    finally:
        ls.close()
