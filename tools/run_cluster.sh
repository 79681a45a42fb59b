#!/usr/bin/env bash
# Start the whole cluster on this host: a Zenoh router, the ICA, the Rerun
# observer, N vehicle agents and the SUMO gateway, each its own process with
# its own log in RUN_DIR/logs/. Stops everything on Ctrl-C, at the end of the
# run, or as soon as any process dies (then with a non-zero exit status and
# the name of the process that died).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

usage() {
  cat <<'EOF'
usage: tools/run_cluster.sh [options] [-- extra gateway options]

Runs one scenario end to end over Zenoh on loopback and writes metrics.json,
vehicles.csv, timeseries.csv, ica.json and spacetime.rrd into the run directory.

options:
  --layout ch45|ch3     built-in intersection (default ch45)
  --net FILE --junction ID
                        any SUMO net instead
  --algorithm NAME      ICA controller: enhanced (default), basic, t1..t4, fifo, ...
  --volume N            vehicles per 10 min (default 500)
  --duration S          simulated seconds (default 600)
  --seed N              random seed (default 12)
  --agents N            vehicle-agent processes (default 2)
  --per-agent K         most vehicles one agent hosts at a time (default 0: no limit)
  --clock lockstep|realtime
                        lockstep: deterministic, as fast as the slowest process;
                        realtime: paced to the wall clock (default lockstep)
  --speed F             realtime clock speed factor (default 1)
  --no-record           no Rerun observer and no .rrd
  --live                the observer also serves the recording on 127.0.0.1:9876
                        as it is made; watch with: .venv/bin/dica view --live [--web]
  --secure              TLS, log-ins and per-role access rules on the router, with
                        fresh secrets in RUN_DIR/zenoh/ (see dica secure-config --help)
  --port P              router port on 127.0.0.1 (default: a free one)
  --out DIR             run directory (default runs/cluster-TIMESTAMP)
  -h, --help            this help

View the recording afterwards with: .venv/bin/dica view RUN_DIR
EOF
}

layout=ch45 net="" junction="" algorithm=enhanced volume=500 duration=600 seed=12
agents=2 per_agent=0 clock=lockstep speed=1 record=1 port="" out="" secure=0 live=()
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --layout) layout="$2"; shift 2 ;;
    --net) net="$2"; shift 2 ;;
    --junction) junction="$2"; shift 2 ;;
    --algorithm) algorithm="$2"; shift 2 ;;
    --volume) volume="$2"; shift 2 ;;
    --duration) duration="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --agents) agents="$2"; shift 2 ;;
    --per-agent) per_agent="$2"; shift 2 ;;
    --clock) clock="$2"; shift 2 ;;
    --speed) speed="$2"; shift 2 ;;
    --no-record) record=0; shift ;;
    --live) live=(--live); shift ;;
    --secure) secure=1; shift ;;
    --port) port="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "run_cluster: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$agents" in ''|*[!0-9]*|0) echo "run_cluster: --agents wants a positive integer" >&2; exit 2 ;; esac

bash tools/setup.sh
dica=.venv/bin/dica
py=.venv/bin/python

# one scenario for every role: build (or find) it once, before anyone races to;
# importing the core also compiles its kernels into numba's cache once (cold: ~20 s)
if [ -z "$net" ]; then
  read -r net junction < <("$py" -c "
import sys
import ica.core.dica
from sim_gateway.scenario import ScenarioError, default_scenario
try:
    sc = default_scenario(sys.argv[1])
except ScenarioError as e:
    sys.exit(f'run_cluster: {e}')
print(sc.net_path, sc.junction_id)" "$layout") || exit 2
fi
[ -n "$junction" ] || { echo "run_cluster: --net needs --junction" >&2; exit 2; }
[ -f "$net" ] || { echo "run_cluster: no net file $net" >&2; exit 2; }
"$py" -c "import ica.core.dica"
scen=(--net "$net" --junction "$junction")

out="${out:-runs/cluster-$(date +%Y%m%d-%H%M%S)}"
mkdir -p "$out/logs"
if [ -z "$port" ]; then
  port="$("$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
fi
endpoint="tcp/127.0.0.1:$port"
router_conf=()
if [ "$secure" = 1 ]; then
  "$dica" secure-config --force --out "$out/zenoh" >/dev/null
  router_conf=(--config "$out/zenoh/router.json5")
  endpoint="tls/127.0.0.1:$port"
fi
link=(--connect "$endpoint")
link_for() {  # link_for ROLE: role_link = the options that connect ROLE to the router
  role_link=("${link[@]}")
  if [ "$secure" = 1 ]; then role_link=(--zenoh-config "$out/zenoh/$1.json5" "${link[@]}"); fi
}

pids=() names=()
start() {  # start NAME CMD...: own process group, own log
  local name="$1"; shift
  setsid "$@" >"$out/logs/$name.log" 2>&1 &
  pids+=("$!"); names+=("$name")
}
name_of() {
  local i
  for i in "${!pids[@]}"; do [ "${pids[$i]}" = "$1" ] && { echo "${names[$i]}"; return; }; done
  echo "pid $1"
}
alive() { kill -0 "$1" 2>/dev/null; }
stop_all() {  # reverse start order: TERM each group, then KILL what is left after a grace
  local i pid deadline
  [ -n "${tail_pid:-}" ] && kill -TERM -- "-$tail_pid" 2>/dev/null || true
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
    pid="${pids[$i]}"; alive "$pid" && kill -TERM -- "-$pid" 2>/dev/null || true
  done
  deadline=$((SECONDS + 10))
  for pid in "${pids[@]}"; do
    while alive "$pid" && [ "$SECONDS" -lt "$deadline" ]; do sleep 0.1; done
    alive "$pid" && kill -KILL -- "-$pid" 2>/dev/null || true
  done
  wait "${pids[@]}" 2>/dev/null || true
}
trap stop_all EXIT
trap 'echo "run_cluster: interrupted, stopping all processes" >&2; exit 130' INT TERM

start router "$dica" router "${router_conf[@]}" --listen "$endpoint"
for _ in $(seq 100); do
  grep -q '^ready' "$out/logs/router.log" 2>/dev/null && break
  alive "${pids[0]}" || { echo "run_cluster: the router died:" >&2; tail -n 5 "$out/logs/router.log" >&2; exit 1; }
  sleep 0.1
done
link_for ica
start ica "$dica" ica "${scen[@]}" --algorithm "$algorithm" --out "$out" "${role_link[@]}"
if [ "$record" = 1 ]; then
  link_for observer
  start observer "$dica" observer "${scen[@]}" --rrd "$out/spacetime.rrd" "${live[@]}" "${role_link[@]}"
fi
link_for agent
for i in $(seq "$agents"); do
  start "agent-$i" "$dica" agent --id "agent-$i" "${scen[@]}" "${role_link[@]}"
done
link_for gateway
start gateway "$dica" gateway "${scen[@]}" --algorithm "$algorithm" --volume "$volume" \
  --duration "$duration" --seed "$seed" --agents "$agents" --per-agent "$per_agent" \
  --clock "$clock" --speed "$speed" --observers "$record" --out "$out" "${role_link[@]}" \
  "${extra[@]}"
gateway_pid="${pids[-1]}"
echo "run_cluster: router on $endpoint; ${#pids[@]} processes; logs in $out/logs/"

# progress: the gateway's own lines, as they come (own process group: stopped as one)
setsid bash -c 'tail -n +1 -F "$1" 2>/dev/null | grep --line-buffered -E "t=|ICA and|ERROR"' \
  _ "$out/logs/gateway.log" &
tail_pid=$!

# the gateway finishing is the normal end; roles that stop cleanly on the clock's end
# (exit 0) may go first; any other exit stops the cluster
running=("${pids[@]}")
while :; do
  status=0
  wait -n -p died "${running[@]}" || status=$?
  [ "$died" = "$gateway_pid" ] && break
  if [ "$status" != 0 ]; then
    kill -TERM -- "-$tail_pid" 2>/dev/null || true
    echo "run_cluster: process $(name_of "$died") died (exit status $status); stopping the cluster" >&2
    tail -n 5 "$out/logs/$(name_of "$died").log" >&2 || true
    exit 1
  fi
  rest=()
  for pid in "${running[@]}"; do [ "$pid" != "$died" ] && rest+=("$pid"); done
  running=("${rest[@]}")
done
kill -TERM -- "-$tail_pid" 2>/dev/null || true
if [ ! -f "$out/metrics.json" ]; then
  echo "run_cluster: the gateway failed (exit status $status):" >&2
  grep -E 'ERROR|dica:' "$out/logs/gateway.log" | tail -n 5 >&2 || true
  exit "$status"
fi
# the run is over: the ICA, the agents and the observer stop on the clock's end
deadline=$((SECONDS + 120))
for pid in "${pids[@]}"; do
  [ "$pid" = "${pids[0]}" ] && continue  # the router goes last
  while alive "$pid" && [ "$SECONDS" -lt "$deadline" ]; do sleep 0.2; done
done
echo
sed -n '/generated, /,$p' "$out/logs/gateway.log"
echo "run_cluster: metrics  $out/metrics.json"
[ "$record" = 1 ] && echo "run_cluster: rerun    $out/spacetime.rrd  (view: .venv/bin/dica view $out)"
echo "run_cluster: logs     $out/logs/"
exit "$status"
