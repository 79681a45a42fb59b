#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite plus the linter.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
# pytest keeps its rewritten test modules, and each worker loads them instead of
# rewriting all of them again (on a machine that sets PYTHONDONTWRITEBYTECODE, about
# 10 s of each worker's start)
unset PYTHONDONTWRITEBYTECODE
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# the compiled core into numba's cache once, on both cores, before the workers race to
.venv/bin/python -m dica.tools.warm
# three workers on two cores, a test file each at a time: the real-time cluster tests
# mostly wait on the clock, and the third worker keeps the cores busy meanwhile (on 2
# cores: 11 min against 12.7 min with two). Extra arguments go to pytest (-n 0 runs
# everything in this process).
# (the slowest 30 are listed at the end: where the suite's time goes)
exec .venv/bin/python -m pytest -n 3 --dist loadfile --durations=30 "$@"
