#!/usr/bin/env bash
# Heavy traffic: enhanced DICA against the two lights past the dissertation's volumes, on
# the chapter 4-5 layout and on two junctions of our own (a skewed 4-way and a T), with
# ramps, then the reports (saturation volumes, stopped rates, delay from the schedule).
# Also chapter 3 light traffic and the technique-3 check (basic, enhanced and the
# dissertation's enhanced DICA, t1+2+3+4). Resumable: finished runs are skipped.
# About 45 minutes on 2 cores.
#   bash tools/heavy.sh [OUT]        (default runs/heavy)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="${1:-runs/heavy}"
dica=".venv/bin/dica"
seeds="12,21,66"
lights="enhanced,fixed,actuated"

$dica experiment --layout ch45 --algorithms "$lights" --volumes 100,200,300,400,500,600,800,1000,1200 \
  --ramps 100-1000 --seeds "$seeds" --out "$out/ch45"
for layout in skewed tee; do
  $dica experiment --layout "$layout" --algorithms "$lights" --volumes 100,300,500,600,800,1000 \
    --seeds "$seeds" --out "$out/$layout"
done
# technique 3: the dissertation's estimated intervals against the exact ones
$dica experiment --layout ch3 --algorithms basic,enhanced,t1+2+3+4 \
  --volumes 100,200,300,400,500,600 --seeds "$seeds" --out "$out/ch3"
$dica experiment --layout ch3 --algorithms basic,enhanced,t1+2+3+4 --volumes 300 \
  --seeds 99,7,4242 --out "$out/ch3-t3"
for d in ch45 skewed tee ch3 ch3-t3; do $dica report "$out/$d" --json; done
