#!/usr/bin/env bash
# Start the whole cluster on this host: a Zenoh router, the ICA, the Rerun
# observer, N vehicle agents and the SUMO gateway (for a network of junctions:
# a router per roadside unit in a mesh, an ICA and an observer per junction, and one
# observer of the whole network from above),
# each its own process with
# its own log in RUN_DIR/logs/, optionally behind a link emulator that delays,
# loses, duplicates and reorders their messages. A role that crashes is
# restarted (the ICA from its journal; a dead agent's vehicles go to the
# others meanwhile) and the run goes on; the run ends when the gateway does.
# Ctrl-C stops everything.
set -euo pipefail
# [s] after the run's end, how long a role may take to stop on its own before it is told
END_GRACE_S=10
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
here="$PWD"  # the caller's: relative paths given on the command line are read from here
cd "$root"
from_caller() { case "$1" in /*|'') echo "$1" ;; *) echo "$here/$1" ;; esac; }

usage() {
  cat <<'EOF'
usage: tools/run_cluster.sh [options] [-- extra gateway options]

Runs one scenario end to end over Zenoh on loopback and writes metrics.json,
vehicles.csv, timeseries.csv, ica.json and spacetime.rrd into the run directory.

scenario and roles:
  --layout ch45|ch3     built-in intersection (default ch45; ch45-walk, ...: with sidewalks
                        and crossings)
  --net FILE --junction ID
                        any SUMO net instead
  --net FILE --junctions all|J1,J2,... --routes FILE
                        a network: each junction signal-free under its own ICA process,
                        the vehicles from the route file, every agent serving every junction
  --rsus N              with --junctions: the roadside units, each with its own Zenoh router
                        serving a run of consecutive junctions (default: one per junction;
                        with --secure each router has its own certificate and log-in);
                        each router connects to the ones before it (a mesh); the gateway
                        and agent i connect to roadside unit 1 and i (round robin)
  --netns               each roadside unit a host of its own: a Linux network namespace
                        (router, its junctions' ICAs and observers) on a private LAN
                        (10.77.0.0/24, a bridge in a namespace of its own) with the
                        gateway and agents on another; the link emulator, if any, sits
                        on the vehicles' host before each roadside unit. Needs root
  --algorithm NAME      ICA controller: enhanced (default), basic, t1..t4, fifo, ...,
                        rdica (reactive DICA: emergency vehicles first)
  --ev-prob P           probability an arrival is an emergency vehicle (default 0.02
                        for rdica, else 0)
  --solver NAME         rdica's ordering solver: exact (default), ga, exhaustive
  --max-added-delay S   rdica: the most reorderings may add to any one vehicle [s]
  --no-platoon          a vehicle asks only once the vehicle ahead of it has entered the
                        junction (the dissertation's rule); by default it may ask once
                        that vehicle flies its plan, and crosses behind it as a platoon
  --headway S           a follower keeps behind its leader's plan by S seconds (default
                        0.3 with platoons, 0 without)
  --no-run-up           a vehicle that must wait slows to 2 m/s at least, else stops at
                        the line; by default it enters at speed (slows to as little as
                        0.5 m/s, or stands back far enough to reach the crossing cap)
  --no-exit-spacing     a vehicle never leaves the junction faster than a slower vehicle
                        ahead on its exit lane (checkFV's cap alone); by default it may,
                        late enough that the road's driver never brakes behind it
  --volume N            vehicles per 10 min (default 500)
  --duration S          simulated seconds (default 600)
  --seed N              random seed (default 12)
  --routes FILE         a SUMO demand file instead of the random demand (needs --net):
                        SUMO drives its vehicles and the junction takes each over in its
                        region
  --begin S             with --routes: the simulated time the run starts at (default 0)
  --peds N              people on foot: N an hour at every crossing (a net with crossings,
                        e.g. --layout ch45-walk); the gateway asks the ICA for each
  --cav-share P         mixed traffic: the share of connected vehicles (default 1); the
                        others are SUMO's drivers, each held at a signal head of its lane
                        that the gateway asks the ICA to turn green
  --agents N            vehicle-agent processes (default 2)
  --per-agent K         most vehicles one agent hosts at a time (default 0: no limit)
  --clock lockstep|realtime
                        lockstep: deterministic, as fast as the slowest process;
                        realtime: paced to the wall clock (default lockstep)
  --speed F             realtime clock speed factor (default 1)
  --no-record           no Rerun observer and no .rrd
  --live                the observer also serves the recording on 127.0.0.1:9876
                        as it is made (a network: its view from above); watch with:
                        .venv/bin/dica view --live [--web]
  --secure              TLS, log-ins and per-role access rules on the routers, and every
                        message sealed by its writer, with fresh secrets in RUN_DIR/zenoh/
                        (see dica secure-config --help)
  --no-router-rules     with --secure: the router lets every logged-in client do anything,
                        so only the roles' own checks of each message's seal hold (to test
                        them)

imperfect links (a user-space emulator between the chosen roles and the router;
change them while running with: dica link set RUN_DIR/link --role R --delay MS ...):
  --delay MS            one-way delay on each faulty link (default 0)
  --jitter MS           extra one-way delay, uniform in [0, MS] (default 0)
  --loss P              probability a batch of Zenoh data (a publication, query or
                        reply) is lost on a faulty link
  --dup P               probability such a batch is sent twice
  --reorder P           probability such a batch is held back behind later ones
  --faulty ROLES        whose links: all (default), or a comma list of agents, ica,
                        gateway, observer
  --time-pad S          the ICA grows every confirmed occupancy interval by S on each
                        side (default: 0 in lockstep; in realtime 0.05, or jitter/1000
                        plus 0.05 if larger)
  --green-late S        how late after its green time a human driver's head may still
                        turn green [sim s]; a later LIT is dropped and the head stays
                        red (default: 0 in lockstep; in realtime (delay + jitter) x
                        speed x the faulty hops a round trip takes between gateway
                        and ICA (2 or 4) + 0.2 s)
  --lead auto|S         realtime: how far ahead of its observation a REQUEST's plan
                        starts [sim s] (default auto: measured round trip plus margin)
  --max-age S           the ICA refuses REQUESTs observed longer ago (default 1; in
                        realtime with faults, 2 x (delay + jitter) x speed + 1 s)
  --no-restart          a role that dies stops the cluster instead of being restarted

other:
  --port P              router port on 127.0.0.1 (default: a free one)
  --out DIR             run directory (default runs/cluster-TIMESTAMP); what an
                        earlier run left there is kept aside in DIR/earlier-TIMESTAMP/
  -h, --help            this help

Each process's PID is in RUN_DIR/pids/NAME while it runs. View the recording
afterwards with: .venv/bin/dica view RUN_DIR
EOF
}

die() { echo "run_cluster: $*" >&2; exit 2; }
number() { [[ "$2" =~ ^[0-9]+([.][0-9]+)?$ ]] || die "$1 wants a non-negative number, got '$2'"; }
prob() { number "$1" "$2"; awk -v p="$2" 'BEGIN { exit !(p <= 0.9) }' || die "$1 must be at most 0.9, got $2"; }

layout=ch45 net="" junction="" junctions="" rsus="" netns=0 algorithm=enhanced volume=500 duration=600 seed=12
agents=2 per_agent=0 clock=lockstep speed=1 record=1 port="" out="" secure=0 live=()
delay=0 jitter=0 loss=0 dup=0 reorder=0 faulty=all time_pad="" green_late="" lead=auto
max_age="" restart=1 router_rules=1 ev_prob="" solver="" max_added="" platoon=(--platoon) headway="" run_up=(--run-up)
exit_spacing=(--exit-spacing)
demand=()
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --layout) layout="$2"; shift 2 ;;
    --net) net="$(from_caller "$2")"; shift 2 ;;
    --junction) junction="$2"; shift 2 ;;
    --junctions) junctions="$2"; shift 2 ;;
    --rsus) rsus="$2"; shift 2 ;;
    --netns) netns=1; shift ;;
    --algorithm) algorithm="$2"; shift 2 ;;
    --ev-prob) ev_prob="$2"; shift 2 ;;
    --solver) solver="$2"; shift 2 ;;
    --max-added-delay) max_added="$2"; shift 2 ;;
    --no-platoon) platoon=(--no-platoon); shift ;;
    --headway) headway="$2"; shift 2 ;;
    --no-run-up) run_up=(--no-run-up); shift ;;
    --no-exit-spacing) exit_spacing=(--no-exit-spacing); shift ;;
    --volume) volume="$2"; shift 2 ;;
    --duration) duration="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --routes) demand+=(--routes "$(from_caller "$2")"); shift 2 ;;
    --begin) demand+=(--begin "$2"); shift 2 ;;
    --peds) demand+=(--peds "$2"); peds="$2"; shift 2 ;;
    --cav-share) demand+=(--cav-share "$2"); shift 2 ;;
    --agents) agents="$2"; shift 2 ;;
    --per-agent) per_agent="$2"; shift 2 ;;
    --clock) clock="$2"; shift 2 ;;
    --speed) speed="$2"; shift 2 ;;
    --no-record) record=0; shift ;;
    --live) live=(--live); shift ;;
    --secure) secure=1; shift ;;
    --delay) delay="$2"; shift 2 ;;
    --jitter) jitter="$2"; shift 2 ;;
    --loss) loss="$2"; shift 2 ;;
    --dup) dup="$2"; shift 2 ;;
    --reorder) reorder="$2"; shift 2 ;;
    --faulty) faulty="$2"; shift 2 ;;
    --time-pad) time_pad="$2"; shift 2 ;;
    --green-late) green_late="$2"; shift 2 ;;
    --lead) lead="$2"; shift 2 ;;
    --max-age) max_age="$2"; shift 2 ;;
    --no-restart) restart=0; shift ;;
    --no-router-rules) router_rules=0; shift ;;
    --port) port="$2"; shift 2 ;;
    --out) out="$(from_caller "$2")"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; extra=("$@"); break ;;
    *) echo "run_cluster: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$agents" in ''|*[!0-9]*|0) die "--agents wants a positive integer" ;; esac
case "$clock" in lockstep|realtime) ;; *) die "--clock must be lockstep or realtime" ;; esac
number --delay "$delay"; number --jitter "$jitter"
awk -v d="$delay" -v j="$jitter" 'BEGIN { exit !(d <= 10000 && j <= 10000) }' ||
  die "--delay and --jitter must be at most 10000 ms"
prob --loss "$loss"; prob --dup "$dup"; prob --reorder "$reorder"
[ -z "$time_pad" ] || number --time-pad "$time_pad"
[ -z "$green_late" ] || number --green-late "$green_late"
[ -z "$max_age" ] || number --max-age "$max_age"
[ -z "$ev_prob" ] || number --ev-prob "$ev_prob"
[ -z "$headway" ] || { number --headway "$headway"; platoon+=(--headway "$headway"); }
solver_args=()  # the roles refuse a --solver that is not rdica's, and one they do not know
[ -z "$solver" ] || solver_args=(--solver "$solver")
ev_args=("${solver_args[@]}")
[ -z "$max_added" ] || { [ "$max_added" = inf ] || number --max-added-delay "$max_added"; solver_args+=(--max-added-delay "$max_added"); }
[ -z "$ev_prob" ] || ev_args+=(--ev-prob "$ev_prob")
[ "$lead" = auto ] || number --lead "$lead"
[ "$lead" = auto ] || [ "$clock" = realtime ] ||
  die "--lead is the real-time clock's (lockstep plans from the observed step, as dica run does by default); give --clock realtime, or leave it out"
[ -z "$port" ] || [[ "$port" =~ ^[0-9]+$ ]] || die "--port wants a port number"
faulty_roles=()
IFS=',' read -r -a parts <<< "$faulty"
for r in "${parts[@]}"; do
  case "$r" in
    all) faulty_roles+=(agents ica gateway observer) ;;
    agents|ica|gateway|observer) faulty_roles+=("$r") ;;
    *) die "--faulty takes all or a comma list of agents, ica, gateway, observer; got '$r'" ;;
  esac
done
if [ "$netns" = 1 ]; then
  [ "${#live[@]}" = 0 ] || die "--live serves on the gateway's host; not with --netns"
  if [ "$faulty" = all ]; then faulty_roles=(agents gateway); fi
  for r in "${faulty_roles[@]}"; do
    case "$r" in agents|gateway) ;; *) die "with --netns the emulated links are the vehicles' host's to the roadside units: --faulty agents,gateway" ;; esac
  done
  [ "$(id -u)" = 0 ] || die "--netns makes network namespaces: run as root"
  command -v ip >/dev/null || die "--netns needs the ip command (iproute2)"
fi
lossy=$(awk -v a="$loss" -v b="$dup" -v c="$reorder" 'BEGIN { print (a + b + c > 0) ? 1 : 0 }')
faults=$(awk -v a="$delay" -v b="$jitter" 'BEGIN { print (a + b > 0) ? 1 : 0 }')
[ "$lossy" = 1 ] && faults=1
[ "$router_rules" = 0 ] && [ "$secure" = 0 ] && die "--no-router-rules goes with --secure"
[ "$secure" = 1 ] && [ "$lossy" = 1 ] &&
  die "--secure links are TLS streams the emulator cannot read message by message: use --delay and --jitter only"
if [ -z "$time_pad" ]; then
  if [ "$clock" = realtime ]; then
    time_pad=$(awk -v j="$jitter" 'BEGIN { p = j / 1000 + 0.05; printf "%.3f", p }')
  else
    time_pad=0
  fi
fi
if [ -z "$green_late" ]; then  # a LIT's round trip at worst, in sim time, and a margin
  if [ "$clock" = realtime ]; then
    # each way, the gateway's link and the ICA's, where they are faulty
    hops=0
    for r in "${faulty_roles[@]}"; do case "$r" in gateway|ica) hops=$((hops + 2)) ;; esac; done
    green_late=$(awk -v n="$hops" -v d="$delay" -v j="$jitter" -v s="$speed" \
      'BEGIN { a = n * (d + j) / 1000 * s + 0.2; if (a > 5) a = 5; printf "%.3f", a }')
  else
    green_late=0
  fi
fi
if [ -z "$max_age" ]; then
  max_age=$(awk -v d="$delay" -v j="$jitter" -v s="$speed" \
    'BEGIN { a = 2 * (d + j) / 1000 * s + 1; if (a > 30) a = 30; printf "%.3f", a }')
fi

bash tools/setup.sh
dica=.venv/bin/dica
py=.venv/bin/python

# the compiled core into numba's cache once, on both cores, before the roles race to
"$py" -m dica.tools.warm
# one scenario for every role: build (or find) it once, before anyone races to
built_in=0  # a built-in layout: its junction is known good
if [ -z "$net" ]; then
  built_in=1
  read -r net junction < <("$py" -c "
import sys
from dica.sim_gateway.scenario import ScenarioError, default_scenario
try:
    sc = default_scenario(sys.argv[1])
except ScenarioError as e:
    sys.exit(f'run_cluster: {e}')
print(sc.net_path, sc.junction_id)" "$layout") || exit 2
fi
[ -f "$net" ] || die "no net file $net"
routes_file=""  # the route file, if any: its longest vehicle decides which junctions "all" serves
for k in "${!demand[@]}"; do [ "${demand[$k]}" = --routes ] && routes_file="${demand[$((k + 1))]}"; done
ids=()  # a network's junctions (one ICA and one observer each)
if [ -n "$junctions" ]; then
  [ -z "$junction" ] || die "--junction names one junction, --junctions several: give one"
  [[ " ${demand[*]} " == *" --routes "* ]] || die "--junctions takes its vehicles from a route file: give --routes"
  read -r -a ids < <("$py" -c "
import sys
from dica.ica.netfile import NetworkError, load_intersection
from dica.tools.args import chosen_junctions
from dica.tools.options import UsageError
from pathlib import Path
try:
    ids = chosen_junctions(Path(sys.argv[1]), sys.argv[2], sys.argv[3] or None)
    for j in ids:  # each one the ICA can serve, before any role starts
        load_intersection(sys.argv[1], j)
        if '/' in j:  # each junction's ICA, log and recording are files named by it
            raise UsageError(f'junction id {j!r} has a /, and the files the cluster keeps per '
                             'junction are named by it: run it embedded (dica run --junctions), '
                             'or give it another id in the net')
except (UsageError, NetworkError) as e:
    sys.exit(f'run_cluster: {e}')
print(' '.join(ids))" "$net" "$junctions" "$routes_file") || exit 2
  [ -n "$rsus" ] || rsus=${#ids[@]}
  [[ "$rsus" =~ ^[0-9]+$ ]] && [ "$rsus" -ge 1 ] && [ "$rsus" -le "${#ids[@]}" ] ||
    die "--rsus wants 1 to ${#ids[@]} (the junctions), got '$rsus'"
  [[ "${peds:-0}" =~ ^0*(\.0*)?$ ]] ||
    die "--peds in a network runs embedded for now (dica run --junctions ... --peds N), not as a cluster"
  scen=(--net "$net" --junctions "$(IFS=,; echo "${ids[*]}")")
else
  [ -z "$rsus" ] || die "--rsus goes with --junctions"
  [ -n "$junction" ] || die "--net needs --junction"
  # the junction and the route file read once, before any role starts (a role that
  # refuses them would otherwise die and be restarted, and the run say why only then)
  [ "$built_in" = 1 ] || "$py" -c "
import sys
from pathlib import Path
from dica.ica.netfile import NetworkError, load_intersection
try:
    load_intersection(sys.argv[1], sys.argv[2])
    if sys.argv[3] and not Path(sys.argv[3]).is_file():
        raise NetworkError(f'route file not found: {sys.argv[3]}')
except NetworkError as e:
    sys.exit(f'run_cluster: {e}')" "$net" "$junction" "$routes_file" || exit 2
  scen=(--net "$net" --junction "$junction")
fi

out="${out:-runs/cluster-$(date +%Y%m%d-%H%M%S)}"
# what an earlier run left in --out (its logs, figures, recordings) is kept aside, so that
# none of it is printed or read as this run's (logs were appended to, and a run that
# failed showed the earlier run's summary and metrics)
earlier=()
for f in "$out/logs" "$out/pids" "$out/metrics.json" "$out/config.json" "$out"/*.csv \
         "$out/tripinfo.xml" "$out"/*.rrd; do
  [ -e "$f" ] && earlier+=("$f")
done
if [ "${#earlier[@]}" -gt 0 ]; then
  kept="$out/earlier-$(date +%Y%m%d-%H%M%S)"
  mkdir -p "$kept" && mv "${earlier[@]}" "$kept"/
  echo "run_cluster: $out holds an earlier run's outputs; kept in $kept" >&2
fi
mkdir -p "$out/logs" "$out/pids"
# an ICA restarted within a run replays its journal and adds to its figures; those left
# in --out by an earlier run would fill this run's ICAs with that run's reservations and
# count its ICA as one of this run's lives: kept aside, never replayed
for jf in "$out/ica-journal.msgpack" "$out"/ica/*/ica-journal.msgpack; do
  if [ -f "$jf" ]; then
    mv -f "$jf" "$jf.prev"
    [ -f "${jf%/*}/ica.json" ] && mv -f "${jf%/*}/ica.json" "${jf%/*}/ica.json.prev"
    echo "run_cluster: $out holds an earlier run; its ICA journal is kept as $jf.prev, not replayed" >&2
  fi
done
free_port() { "$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
[ -n "$port" ] || port="$(free_port)"
# roadside units: RSU k's router on rsu_port[k]; a single junction has one
n_rsu=${rsus:-1}
declare -A rsu_port=() rsu_of=()
rsu_port[1]=$port
for k in $(seq 2 "$n_rsu"); do rsu_port[$k]="$(free_port)"; done
for i in "${!ids[@]}"; do rsu_of[${ids[$i]}]=$((i * n_rsu / ${#ids[@]} + 1)); done
# where each roadside unit's router is reached: loopback, or (--netns) its host's address
declare -A rsu_addr=()
for k in $(seq "$n_rsu"); do rsu_addr[$k]=127.0.0.1; done
tag=$(($$ % 10000))  # this run's namespaces and links
lan="dica$tag-lan" vehicles="dica$tag-veh"
host_ns() { echo "dica$tag-rsu$1"; }
netns_down() {
  local k
  for k in $(seq "$n_rsu"); do ip netns del "$(host_ns "$k")" 2>/dev/null || true; done
  ip netns del "$vehicles" 2>/dev/null || true
  ip netns del "$lan" 2>/dev/null || true
}
netns_host() {  # netns_host NS ADDR I: a host on the LAN's bridge
  ip netns add "$1"
  ip link add "d${tag}v$3" type veth peer name "d${tag}b$3"
  ip link set "d${tag}v$3" netns "$1"
  ip link set "d${tag}b$3" netns "$lan"
  ip -n "$lan" link set "d${tag}b$3" master br0 up
  ip -n "$1" addr add "$2/24" dev "d${tag}v$3"
  ip -n "$1" link set "d${tag}v$3" up
  ip -n "$1" link set lo up
}
in_ns=()  # in_ns_of NAME sets in_ns: the command prefix that runs NAME on its host
in_ns_of() { in_ns=(); [ "$netns" = 1 ] && in_ns=(ip netns exec "$1"); return 0; }
if [ "$netns" = 1 ]; then
  netns_down
  trap netns_down EXIT  # until stop_all takes over
  ip netns add "$lan" || die "cannot make network namespaces here"
  ip -n "$lan" link add br0 type bridge
  ip -n "$lan" link set br0 up
  netns_host "$vehicles" 10.77.0.2 0
  for k in $(seq "$n_rsu"); do
    rsu_addr[$k]="10.77.0.$((10 + k))"
    rsu_port[$k]=7447
    netns_host "$(host_ns "$k")" "${rsu_addr[$k]}" "$k"
  done
fi
scheme=tcp
router_conf=()
if [ "$secure" = 1 ]; then
  site_junctions=()
  for j in "${ids[@]:-$junction}"; do site_junctions+=(--junction "$j"); done
  [ "${#ids[@]}" -gt 1 ] && site_junctions+=(--ica-per-junction)  # each ICA its own log-in
  site_hosts=(--host 127.0.0.1)  # the certificates name every address a router is reached at
  for k in $(seq "$n_rsu"); do [ "${rsu_addr[$k]}" = 127.0.0.1 ] || site_hosts+=(--host "${rsu_addr[$k]}"); done
  "$dica" secure-config --force --out "$out/zenoh" --agents "$agents" "${site_junctions[@]}" \
    --rsus "$n_rsu" "${site_hosts[@]}" >/dev/null
  router_conf=(--config "$out/zenoh/router.json5" --log-refused)
  [ "$router_rules" = 1 ] || for k in $(seq "$n_rsu"); do
    conf="$out/zenoh/router.json5"; [ "$k" = 1 ] || conf="$out/zenoh/router-$k.json5"
    "$py" - "$conf" <<'PY'
import json, os, sys
path = sys.argv[1]
text = open(path).read()
head = "".join(l for l in text.splitlines(True) if l.startswith("//"))
conf = json.loads("".join(l for l in text.splitlines(True) if not l.startswith("//")))
conf["access_control"]["enabled"] = False
with open(path + ".tmp", "w") as f:
    f.write(head + "// Access rules switched off (run_cluster.sh --no-router-rules).\n")
    f.write(json.dumps(conf, indent=1))
os.chmod(path + ".tmp", 0o600)
os.replace(path + ".tmp", path)
PY
  done
  scheme=tls
fi

# the link emulator: one proxy per faulty process, faults per role in $out/link/faults.json
is_faulty() { local r; for r in "${faulty_roles[@]}"; do [ "$r" = "$1" ] && return 0; done; return 1; }
proxy_json=()
declare -A endpoint=()
route_through_link() {  # route_through_link NAME ROLE RSU: a proxy on NAME's host
  local lp framed
  lp="$(free_port)"
  framed=$([ "$secure" = 1 ] && echo false || echo true)
  proxy_json+=("{\"name\": \"$1\", \"role\": \"$2\", \"listen_port\": $lp, \"router_port\": ${rsu_port[$3]}, \"router_host\": \"${rsu_addr[$3]}\", \"framed\": $framed}")
  endpoint[$1]="$scheme/127.0.0.1:$lp"
}
top=0  # a network recorded: one observer more, of the whole network from above
[ "$record" = 1 ] && [ "${#ids[@]}" -gt 1 ] && top=1
declare -A router_of=()  # each process's roadside unit
router_of[gateway]=1
names_all=(gateway)
if [ "${#ids[@]}" -gt 0 ]; then
  for j in "${ids[@]}"; do
    names_all+=("ica-$j"); router_of["ica-$j"]=${rsu_of[$j]}
    if [ "$record" = 1 ]; then names_all+=("observer-$j"); router_of["observer-$j"]=${rsu_of[$j]}; fi
  done
  if [ "$top" = 1 ]; then names_all+=(observer-network); router_of[observer-network]=1; fi
else
  names_all+=(ica); router_of[ica]=1
  if [ "$record" = 1 ]; then names_all+=(observer); router_of[observer]=1; fi
fi
for i in $(seq "$agents"); do names_all+=("agent-$i"); router_of["agent-$i"]=$(((i - 1) % n_rsu + 1)); done
for name in "${names_all[@]}"; do
  role="${name%%-*}"; [ "$role" = agent ] && role=agents
  k=${router_of[$name]}
  if [ "$faults" = 1 ] && is_faulty "$role"; then
    route_through_link "$name" "$role" "$k"
  else
    endpoint[$name]="$scheme/${rsu_addr[$k]}:${rsu_port[$k]}"
  fi
done

# -- processes: start, watch, restart ----------------------------------------------------
declare -A pid_of=() cmd_of=() restarts=()
order=()
start() {  # start NAME CMD...: own process group, own log (appended across restarts)
  local name="$1"; shift
  cmd_of[$name]="$(printf '%q ' "$@")"
  setsid "$@" >>"$out/logs/$name.log" 2>&1 &
  pid_of[$name]=$!
  echo "$!" > "$out/pids/$name"
  [[ " ${order[*]} " == *" $name "* ]] || order+=("$name")
}
restart_role() {  # the same command again (the observer into a new .rrd, never over the old)
  local name="$1" n="${restarts[$1]:-0}"
  restarts[$name]=$((n + 1))
  local cmd="${cmd_of[$name]}"
  if [[ "$name" == observer* ]]; then
    if [ "$n" = 0 ]; then cmd="${cmd//.rrd /.1.rrd }"; else cmd="${cmd//.$n.rrd /.$((n + 1)).rrd }"; fi
  fi
  echo "$(date +%H:%M:%S) restarting $name (restart $((n + 1)))" >> "$out/logs/restarts.log"
  echo "run_cluster: $name died; restarting it (restart $((n + 1)))" >&2
  eval "setsid $cmd >>\"$out/logs/$name.log\" 2>&1 &"
  pid_of[$name]=$!
  echo "$!" > "$out/pids/$name"
  cmd_of[$name]="$cmd"
}
alive() { kill -0 "$1" 2>/dev/null; }
stop_all() {  # reverse start order: TERM each group, then KILL what is left after a grace
  local i name pid deadline
  [ -n "${tail_pid:-}" ] && kill -TERM -- "-$tail_pid" 2>/dev/null || true
  for ((i = ${#order[@]} - 1; i >= 0; i--)); do
    pid="${pid_of[${order[$i]}]}"; alive "$pid" && kill -TERM -- "-$pid" 2>/dev/null || true
  done
  deadline=$((SECONDS + 10))
  for name in "${order[@]}"; do
    pid="${pid_of[$name]}"
    while alive "$pid" && [ "$SECONDS" -lt "$deadline" ]; do sleep 0.1; done
    alive "$pid" && kill -KILL -- "-$pid" 2>/dev/null || true
  done
  wait 2>/dev/null || true
  rm -f "$out"/pids/*
  [ "$netns" = 0 ] || netns_down
}
trap stop_all EXIT
trap 'echo "run_cluster: interrupted, stopping all processes" >&2; exit 130' INT TERM

wait_ready() {  # wait_ready NAME: its log says ready
  for _ in $(seq 100); do
    grep -q '^ready' "$out/logs/$1.log" 2>/dev/null && return 0
    alive "${pid_of[$1]}" || { echo "run_cluster: the $1 died:" >&2; tail -n 5 "$out/logs/$1.log" >&2; exit 1; }
    sleep 0.1
  done
  die "the $1 did not start"
}

if [ "${#ids[@]}" -gt 0 ]; then  # a router per roadside unit, each connected to the ones before
  mesh=()
  for k in $(seq "$n_rsu"); do
    peers=(); [ "${#mesh[@]}" -gt 0 ] && peers=(--connect "$(IFS=,; echo "${mesh[*]}")")
    in_ns_of "$(host_ns "$k")"
    # secured: each roadside unit's router its own config (certificate, log-in to the others)
    [ "$secure" = 1 ] && [ "$k" -gt 1 ] && router_conf=(--config "$out/zenoh/router-$k.json5" --log-refused)
    start "router-$k" "${in_ns[@]}" "$dica" router "${router_conf[@]}" \
      --listen "$scheme/${rsu_addr[$k]}:${rsu_port[$k]}" "${peers[@]}"
    wait_ready "router-$k"
    mesh+=("$scheme/${rsu_addr[$k]}:${rsu_port[$k]}")
  done
else
  in_ns_of "$(host_ns 1)"
  start router "${in_ns[@]}" "$dica" router "${router_conf[@]}" --listen "$scheme/${rsu_addr[1]}:${rsu_port[1]}"
  wait_ready router
fi
if [ "${#proxy_json[@]}" -gt 0 ]; then
  mkdir -p "$out/link"
  { echo "{\"seed\": $seed, \"proxies\": ["; (IFS=','; echo "${proxy_json[*]}"); echo "]}"; } > "$out/link/spec.json"
  "$py" - "$out/link/faults.json" "$delay" "$jitter" "$loss" "$dup" "$reorder" "${faulty_roles[@]}" <<'PY'
import sys
from pathlib import Path
from dica.deploy.linkem import Faults, write_profile
path, d, j, l, du, r, *roles = sys.argv[1:]
f = Faults(float(d), float(j), float(l), float(du), float(r))
write_profile(Path(path), {role: f for role in roles})
PY
  in_ns_of "$vehicles"
  start link "${in_ns[@]}" "$dica" link serve "$out/link"
  wait_ready link
fi
link_for() {  # link_for NAME ROLE: role_link = the options that connect NAME to the router
  role_link=(--connect "${endpoint[$1]}")
  if [ "$secure" = 1 ]; then  # its log-in, and the keys it seals with and checks against
    role_link=(--zenoh-config "$out/zenoh/$2.json5" --keyring "$out/zenoh/keyring.json"
      "${role_link[@]}")
    if [ -f "$out/zenoh/$2.seal" ]; then role_link+=(--seal "$out/zenoh/$2.seal"); fi
  fi
}
# a route file's vehicle types set where lanes' lines stand: every role reads them alike
fleet=()
[ -z "$routes_file" ] || fleet=(--routes "$routes_file")
ica_args=("${fleet[@]}" --algorithm "$algorithm" --time-pad "$time_pad" --green-late "$green_late"
  --max-age "$max_age" --seed "$seed"
  "${solver_args[@]}" "${platoon[@]}" "${run_up[@]}" "${exit_spacing[@]}")
if [ "${#ids[@]}" -gt 0 ]; then  # each junction's ICA (its figures and journal in ica/J/)
  first=1
  for j in "${ids[@]}"; do
    ica_id=ica; [ "${#ids[@]}" -gt 1 ] && ica_id="ica-$j"  # each its own log-in and seal
    link_for "ica-$j" "$ica_id"
    in_ns_of "$(host_ns "${rsu_of[$j]}")"
    start "ica-$j" "${in_ns[@]}" "$dica" ica --net "$net" --junction "$j" --out "$out/ica/$j" "${ica_args[@]}" \
      "${role_link[@]}"
    if [ "$record" = 1 ]; then  # spacetime.rrd for the first, spacetime-J.rrd beside it
      rrd="$out/spacetime-$j.rrd"; [ "$first" = 1 ] && rrd="$out/spacetime.rrd"
      link_for "observer-$j" observer
      one=(); [ "${#ids[@]}" = 1 ] && one=("${live[@]}")  # several: the top view is live
      start "observer-$j" "${in_ns[@]}" "$dica" observer --net "$net" --junction "$j" --rrd "$rrd" \
        --time-pad "$time_pad" "${fleet[@]}" "${one[@]}" "${role_link[@]}"
    fi
    first=0
  done
  if [ "$top" = 1 ]; then  # the network from above: network.rrd
    link_for observer-network observer
    in_ns_of "$(host_ns 1)"
    start observer-network "${in_ns[@]}" "$dica" observer --rrd "$out/network.rrd" --net "$net" \
      --junctions "$(IFS=,; echo "${ids[*]}")" "${fleet[@]}" "${live[@]}" "${role_link[@]}"
  fi
else
  link_for ica ica
  in_ns_of "$(host_ns 1)"
  start ica "${in_ns[@]}" "$dica" ica "${scen[@]}" --out "$out" "${ica_args[@]}" "${role_link[@]}"
  if [ "$record" = 1 ]; then
    link_for observer observer
    start observer "${in_ns[@]}" "$dica" observer "${scen[@]}" --rrd "$out/spacetime.rrd" --time-pad "$time_pad" \
      "${fleet[@]}" "${live[@]}" "${role_link[@]}"
  fi
fi
for i in $(seq "$agents"); do
  link_for "agent-$i" "agent-$i"
  in_ns_of "$vehicles"
  start "agent-$i" "${in_ns[@]}" "$dica" agent --id "agent-$i" "${scen[@]}" --lead "$lead" "${fleet[@]}" \
    "${role_link[@]}"
done
observers=$((record + top))  # per junction: its own observer, and the top view's
link_for gateway gateway
in_ns_of "$vehicles"
start gateway "${in_ns[@]}" "$dica" gateway "${scen[@]}" --algorithm "$algorithm" --volume "$volume" \
  --duration "$duration" --seed "$seed" --agents "$agents" --per-agent "$per_agent" \
  --clock "$clock" --speed "$speed" --observers "$observers" --time-pad "$time_pad" \
  --green-late "$green_late" \
  --out "$out" "${ev_args[@]}" "${platoon[@]}" "${demand[@]}" "${role_link[@]}" "${extra[@]}"
gateway_pid="${pid_of[gateway]}"
if [ "${#ids[@]}" -gt 0 ]; then
  echo "run_cluster: ${#ids[@]} junctions (${ids[*]}) on $n_rsu roadside units' routers from tcp/127.0.0.1:$port; ${#order[@]} processes; logs in $out/logs/"
else
  echo "run_cluster: router on tcp/127.0.0.1:$port; ${#order[@]} processes; logs in $out/logs/"
fi
if [ "$faults" = 1 ]; then
  echo "run_cluster: links of ${faulty_roles[*]}: delay ${delay} ms, jitter ${jitter} ms, loss $loss, dup $dup, reorder $reorder (dica link set $out/link ...)"
fi

# progress: the gateway's own lines, as they come (own process group: stopped as one)
setsid bash -c 'tail -n +1 -F "$1" 2>/dev/null | grep --line-buffered -E "t=|ICA and|ERROR|is gone|is back"' \
  _ "$out/logs/gateway.log" &
tail_pid=$!

# the gateway finishing is the normal end; roles that stop cleanly on the clock's end
# (exit 0) may go first; any other exit is a crash: restart the role (up to 5 times)
status=0
while :; do
  running=()
  for name in "${order[@]}"; do
    pid="${pid_of[$name]}"
    [ -n "$pid" ] && running+=("$pid")
  done
  st=0
  wait -n -p died "${running[@]}" || st=$?
  if [ "$died" = "$gateway_pid" ]; then status=$st; break; fi
  dead_name=""
  for name in "${order[@]}"; do [ "${pid_of[$name]}" = "$died" ] && dead_name="$name"; done
  [ -n "$dead_name" ] || continue
  if [ "$st" = 0 ]; then pid_of[$dead_name]=""; rm -f "$out/pids/$dead_name"; continue; fi
  if [ "$restart" = 1 ] && [ "${restarts[$dead_name]:-0}" -lt 5 ] && alive "$gateway_pid"; then
    tail -n 3 "$out/logs/$dead_name.log" >&2 || true
    restart_role "$dead_name"
    continue
  fi
  kill -TERM -- "-$tail_pid" 2>/dev/null || true
  echo "run_cluster: process $dead_name died (exit status $st); stopping the cluster" >&2
  tail -n 5 "$out/logs/$dead_name.log" >&2 || true
  exit 1
done
kill -TERM -- "-$tail_pid" 2>/dev/null || true
complete=$("$py" -c 'import json, sys; print(json.load(open(sys.argv[1])).get("complete", False))' \
  "$out/metrics.json" 2>/dev/null || echo False)
if [ "$complete" != True ]; then  # exit 1 with complete metrics: the run finished, and collided
  [ "$status" = 0 ] && status=1
  echo "run_cluster: the gateway stopped the run (exit status $status):" >&2
  grep -E 'ERROR|^dica( [a-z-]+)?: ' "$out/logs/gateway.log" | tail -n 5 >&2 || true
  if [ -f "$out/metrics.json" ]; then
    echo "run_cluster: what the run knew by then (marked incomplete): $out/metrics.json" >&2
  fi
  exit "$status"
fi
# the run is over: the ICA, the agents and the observer stop on the clock's end. One
# restarted after the end went out never hears it (it cannot tell a run that is over
# from a gateway not up yet): after END_GRACE_S it is told to stop (SIGTERM, the same
# clean stop), and every role then has up to 120 s to write what it holds
end_grace=$((SECONDS + END_GRACE_S))
for name in "${order[@]}"; do
  case "$name" in router|router-*|link) continue ;; esac  # these go last
  pid="${pid_of[$name]}"
  [ -n "$pid" ] || continue
  while alive "$pid" && [ "$SECONDS" -lt "$end_grace" ]; do sleep 0.2; done
  if alive "$pid"; then
    echo "run_cluster: $name had not stopped ${END_GRACE_S} s after the run's end; stopping it" >&2
    kill -TERM -- "-$pid" 2>/dev/null || true
  fi
done
deadline=$((SECONDS + 120))
for name in "${order[@]}"; do
  case "$name" in router|router-*|link) continue ;; esac
  pid="${pid_of[$name]}"
  [ -n "$pid" ] || continue
  while alive "$pid" && [ "$SECONDS" -lt "$deadline" ]; do sleep 0.2; done
done
echo
sed -n '/generated, /,$p' "$out/logs/gateway.log"
if [ -s "$out/logs/restarts.log" ]; then
  echo "run_cluster: restarts:"; sed 's/^/  /' "$out/logs/restarts.log"
fi
echo "run_cluster: metrics  $out/metrics.json"
[ "$record" = 1 ] && echo "run_cluster: rerun    $out/spacetime.rrd  (view: .venv/bin/dica view $out)"
if [ "$top" = 1 ]; then echo "run_cluster: network  $out/network.rrd (the junctions from above)"; fi
echo "run_cluster: logs     $out/logs/"
exit "$status"
