"""`dica ...` run inside the test process: the same ``main()`` the console script calls.

A fresh interpreter spends about 2 s of CPU loading the compiled core before a
run starts, more than a short run itself; over the suite's hundred-odd runs of
the command line that was a fifth of its time. Here the run's own code,
SUMO and the output are the same; only the interpreter is the test's. What
only a process can show (the console script, an exit status as the shell sees
it, a run that must outlive its caller) is left to the tests that start the
roles as processes (``tests/test_cluster.py`` and the like) and to the few that
call :data:`DICA` themselves.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from dica.tools.cli import main

DICA = [sys.executable, "-m", "dica.tools.cli"]


def dica_run(
    cmd: Sequence[str | Path], *, cwd: str | Path | None = None, **_: object
) -> subprocess.CompletedProcess:
    """``subprocess.run([*DICA, *args], capture_output=True, text=True, cwd=cwd)``, in this
    process: its exit status, stdout and stderr (a timeout is not enforced here)."""
    args = [str(a) for a in cmd]
    if args[: len(DICA)] == DICA:
        args = args[len(DICA) :]
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(args)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["dica", *args], code, out.getvalue(), err.getvalue())
