#!/usr/bin/env bash
# Re-run the dissertation's experiments (chapters 3 and 4) and write the reports.
# Resumable: finished runs are skipped. About 20-30 minutes on 2 cores.
#   bash tools/reproduce.sh [OUT]        (default runs/reproduce)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="${1:-runs/reproduce}"
dica=".venv/bin/dica"
seeds="12,21,66"

# Chapter 3: DICA against Concurrent on the 2-lane intersection (its "volumes 1-3" have no
# stated rate, so a range of volumes)
$dica experiment --layout ch3 --algorithms basic,concurrent --volumes 100,200,300,400,500,600 \
  --seeds "$seeds" --out "$out/ch3"
# Chapter 4: enhanced DICA against the optimised fixed-cycle and SUMO's actuated light,
# and the reservation baselines, on the 3-lane intersection
$dica experiment --layout ch45 --algorithms enhanced,fixed,actuated,fifo,concurrent,tiles \
  --volumes 100,200,300,400,500 --seeds "$seeds" --out "$out/ch45"
# Unbalanced traffic: minor roads (E, W) get 30 % of the major roads' vehicles
$dica experiment --layout ch45 --algorithms enhanced,fixed --volumes 100,200,300,400,500 \
  --seeds "$seeds" --out "$out/unbalanced" --extra "--approach-weights N_in=1,S_in=1,E_in=0.3,W_in=0.3"
# Volume rising from 100 to 500 over 20 minutes
$dica experiment --layout ch45 --algorithms enhanced,fixed,actuated --volumes 100 \
  --seeds "$seeds" --duration 1200 --out "$out/rising" --extra "--volume-end 500 --ramp 1200"
for d in ch3 ch45 unbalanced rising; do $dica report "$out/$d"; done
