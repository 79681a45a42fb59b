#!/usr/bin/env bash
# The main job on a fresh machine: set up, then run the default scenario end to end.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="runs/main-$(date +%Y%m%d-%H%M%S)"
exec .venv/bin/dica stream --layout ch45 --volume 500 --vehicles 1000 --seed 12 --out "$out" "$@"
