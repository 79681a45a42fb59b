#!/usr/bin/env bash
# Make .venv/ hold everything the project needs. Idempotent: a second call with
# an unchanged pyproject.toml returns in well under a second.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

need_py() {
  command -v python3 >/dev/null 2>&1 &&
    python3 -c 'import sys, venv; sys.exit(sys.version_info < (3, 11))' 2>/dev/null
}
if ! need_py; then
  echo "setup: installing Python 3.11+ with apt-get" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq && apt-get install -y -qq python3 python3-venv python3-pip >/dev/null
  need_py || { echo "setup: Python >= 3.11 with venv is required" >&2; exit 1; }
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv" >&2
  python3 -m venv .venv
fi

stamp=.venv/.dica-installed
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing packages into .venv (first run takes about a minute)" >&2
  .venv/bin/python -m pip install -q --upgrade pip
  # the build backend warns about editable installs on every run; nothing to act on
  PYTHONWARNINGS=ignore .venv/bin/python -m pip install -q -e '.[dev]'
  # numba's on-disk caches of the compiled kernels name the modules they came from; one
  # written under an older layout fails to load once a module has moved: compile anew
  find ica sim_gateway vehicle_agent -name '*.nb[ic]' -delete 2>/dev/null || true
  echo "$want" > "$stamp"
fi
# every process of a run or a test imports the project's own modules: compiled once
# here, not again in each of them (a machine that sets PYTHONDONTWRITEBYTECODE never
# keeps what Python compiles, and recompiles the sources in every process: about
# 0.5 s each, hundreds of processes in the test suite). Only what changed is compiled.
.venv/bin/python -m compileall -q -j 2 ica sim_gateway vehicle_agent schemas deploy tools >/dev/null
