#!/usr/bin/env bash
# The main job on a fresh machine: set up, then run the default scenario end to end:
# 10 simulated minutes of the chapter 4-5 intersection at 500 vehicles per 10 min under
# enhanced DICA in SUMO, with metrics and the independent collision check.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="runs/main-$(date +%Y%m%d-%H%M%S)"
exec .venv/bin/dica run --layout ch45 --algorithm enhanced --volume 500 --duration 600 \
  --seed 12 --out "$out" "$@"
