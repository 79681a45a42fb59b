#!/usr/bin/env bash
# Networks: the built-in corridor of four junctions and the 3x3 grid, every junction
# signal-free (enhanced DICA) against actuated, coordinated fixed-time and max-pressure
# lights, at three demand levels (light, medium, near the lights' saturation), seeds 12,
# 21 and 66, DEMAND seconds of vehicles (default 3600) and then until every vehicle has
# left; then the report (networks.md). Resumable: finished runs are skipped. Two runs at
# a time; about 40 minutes per seed on 2 cores with an hour of demand (the corridor about
# 6 of them). SEEDS="12" runs one seed only, LAYOUTS="corridor" one network only.
# Emergency vehicles: EV_PROB=0.02 draws each vehicle an EV with that probability, and
# CONTROLS chooses the controls (rdica: every junction under reactive DICA; rdica-ahead: the
# same with each EV's notices to the junctions ahead; preempt: fixed-time lights pre-empted
# for each EV).
#   bash tools/networks.sh [OUT] [DEMAND]        (default runs/networks 3600)
#   EV_PROB=0.02 CONTROLS="dica rdica preempt static" bash tools/networks.sh runs/ev
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash tools/setup.sh
out="${1:-runs/networks}"
demand="${2:-3600}"
mkdir -p "$out"
# the corridor: the arterial's two ends at 400, 800 and 1100 vehicles/h, the side roads at
# 200; the grid: every road in at 200, 400 and 650
corridor="400 800 1100"
grid="200 400 650"
case " ${LAYOUTS:-corridor grid} " in *" corridor "*) ;; *) corridor="" ;; esac
case " ${LAYOUTS:-corridor grid} " in *" grid "*) ;; *) grid="" ;; esac
jobs="$out/jobs.txt"
: > "$jobs"
ev="${EV_PROB:-0}"
more=""
tag=""
if [ "$ev" != 0 ]; then more="--ev-prob $ev"; tag="-ev$ev"; fi
for seed in ${SEEDS:-12 21 66}; do
  for control in ${CONTROLS:-dica actuated coordinated max-pressure}; do
    flags="--control $control"
    [ "$control" = rdica ] && flags="--control dica --algorithm rdica"
    [ "$control" = rdica-ahead ] && flags="--control dica --algorithm rdica --ev-notices"
    for v in $corridor; do
      echo "corridor-$v-$control$tag-s$seed --layout corridor --volume 200 --entry-volume W00_J00=$v --entry-volume E30_J30=$v $flags $more --seed $seed" >> "$jobs"
    done
    for v in $grid; do
      echo "grid-$v-$control$tag-s$seed --layout grid --volume $v $flags $more --seed $seed" >> "$jobs"
    done
  done
done
run_one() {
  local name="$1" dir
  shift
  dir="$out/$name"
  [ -f "$dir/metrics.json" ] && return 0
  rm -rf "$dir"
  .venv/bin/dica network "$@" --duration "$demand" --drain 1800 --out "$dir" --quiet \
    > "$out/$name.log" 2>&1 || echo "$name: exit $? (see $out/$name.log)"
}
export -f run_one
export out demand
# a run that fails says so in its log and the report goes on without it
xargs -P 2 -L 1 bash -c 'run_one "$@"' _ < "$jobs" || echo "some runs failed: see $out/*.log"
.venv/bin/dica report "$out" --out "$out/report"
