#!/usr/bin/env bash
# People crossing: the chapter 4-5 layout with sidewalks and crossings (ch45-walk),
# signal-free (enhanced DICA, walkers held at the kerb until the ICA's moment) against
# SUMO's actuated and fixed-time lights with their pedestrian phases, at VOLUMES vehicles
# per 10 min and PEDS people an hour at every crossing, seeds SEEDS, DURATION simulated
# seconds each; then the report (peds.md, peds.png). Resumable: finished runs are
# skipped. Two runs at a time.
#   bash tools/peds.sh [OUT] [DURATION]        (default runs/peds 3600)
#   VOLUMES="100 300 500" PEDS="0 200 600" SEEDS="12 21 66" bash tools/peds.sh
#   CONTROLS="enhanced" bash tools/peds.sh     (only these controls; default all three)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="${1:-runs/peds}"
duration="${2:-3600}"
mkdir -p "$out"
jobs="$out/jobs.txt"
: > "$jobs"
for seed in ${SEEDS:-12 21 66}; do
  for peds in ${PEDS:-0 200 600}; do
    for v in ${VOLUMES:-100 300 500}; do
      for control in ${CONTROLS:-enhanced actuated fixed}; do
        echo "$control-v$v-p$peds-s$seed --algorithm $control --volume $v --peds $peds --seed $seed" >> "$jobs"
      done
    done
  done
done
run_one() {
  local name="$1" dir
  shift
  dir="$out/$name"
  [ -f "$dir/metrics.json" ] && return 0
  rm -rf "$dir"
  local rc=0
  .venv/bin/dica run --layout ch45-walk --duration "$duration" --out "$dir.tmp" --quiet "$@" \
      > "$out/$name.log" 2>&1 || rc=$?
  # status 1 with metrics written: the run ended and something collided (a light's SUMO
  # drivers may): a result to report, not a failure
  if [ "$rc" = 0 ] || { [ "$rc" = 1 ] && [ -f "$dir.tmp/metrics.json" ]; }; then
    mv "$dir.tmp" "$dir"
    [ "$rc" = 0 ] || echo "peds: $name ended with collisions (see $out/$name.log)" >&2
  else
    echo "peds: $name failed (see $out/$name.log)" >&2
  fi
}
export -f run_one
export out duration
total=$(wc -l < "$jobs")
echo "peds: $total runs into $out, two at a time"
xargs -P 2 -L 1 bash -c 'run_one "$@"' _ < "$jobs"
.venv/bin/python -m dica.tools.peds_report "$out"
