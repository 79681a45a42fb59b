#!/usr/bin/env bash
# The main job on a fresh machine: set up, then run the default scenario end to end
# as the real deployment runs it: a Zenoh router, the ICA, two vehicle-agent
# processes, the SUMO gateway and the Rerun observer, talking only over Zenoh on
# loopback. 10 simulated minutes of the chapter 4-5 intersection at 500 vehicles
# per 10 min under enhanced DICA; metrics, the collision check and a .rrd.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
exec bash tools/run_cluster.sh --layout ch45 --algorithm enhanced --volume 500 --duration 600 \
  --seed 12 --agents 2 --out "runs/main-$(date +%Y%m%d-%H%M%S)" "$@"
