#!/usr/bin/env bash
# docker-compose.yml for real, from nothing, on this machine: builds the images (racer's and the stand-ins of
# deploy/cluster/compose.test.yml), `WORKERS=3 docker compose up -d`, waits for two checkpoints in the bucket, scales to 5
# workers and sees them live in `racer status`, kills a worker's process (training goes on, the restart policy
# brings it back), lists the checkpoints with `racer models ls`, takes everything down and up again and sees the
# run resume from its latest checkpoint, then removes all it created. Exits 0 only when every check held; prints
# its figures (time of each phase, total) last. All traffic stays on loopback. docs/docker.md describes it.
set -euo pipefail
# shellcheck source=deploy/cluster/docker-test-lib.sh
. "$(dirname "$0")/docker-test-lib.sh"

usage() {
    echo "Usage: deploy/cluster/check-compose.sh [options]"
    usage_common
}
parse_common "$@"

SCRIPT_RUN_ID=compose-check
PROJECT=racer-check-$$
LOG=$(mktemp)
dc() {
    timeout "${DC_TIMEOUT:-300}" "${COMPOSE[@]}" --env-file "$ENV_FILE" -p "$PROJECT" \
        -f "$ROOT/docker-compose.yml" -f "$ROOT/deploy/cluster/compose.test.yml" "$@"
}
containers() {  # containers of a service of this project (compose v1 and v2 label them alike)
    docker ps -aq --filter "label=com.docker.compose.project=$PROJECT" --filter "label=com.docker.compose.service=$1"
}

CLEANED=0
clean_up() {
    ((CLEANED)) && return 0
    CLEANED=1
    phase "clean up"
    [[ -n ${ENV_FILE:-} ]] && { dc down -v --remove-orphans --timeout 10 >>"$LOG" 2>&1 || log "compose down failed"; }
    remove_images
    run_cleanups
    local left; left=$(docker ps -aq --filter "label=com.docker.compose.project=$PROJECT")
    [[ -z $left ]] || log "containers left behind: $left"
    rm -f "$LOG"
}
on_exit() {
    local rc=$?
    trap - EXIT
    if ((rc != 0)) && [[ -n ${ENV_FILE:-} ]] && ((!CLEANED)); then
        log "diagnostics (the run failed):"
        tail -30 "$LOG" || true
        dc ps || true
        dc logs --no-color --tail=25 2>&1 | grep -v SIM_TRACE_LOG | tail -80 || true
    fi
    finish "$rc"
}
trap on_exit EXIT
trap 'exit 130' INT TERM

kill_hard() {  # SIGKILL a container's main process from outside, as a crash or the OOM killer would
    local pid=$1
    kill -KILL "$pid" 2>/dev/null \
        || docker run --rm --pid host --user 0 --entrypoint sh "racer-standin-redis:$TAG" -c "kill -KILL $pid"
}

# --- 0. what this machine has ---------------------------------------------------------------------------------------
phase "prerequisites"
need_docker
command -v python3 >/dev/null || fail "python3 is needed on the host"
pick_compose
pick_racer
figure "racer on the host" "${RACER_HOST[*]}"
figure docker "$(docker version --format 'client {{.Client.Version}}, server {{.Server.Version}}')"

# --- 1. images ------------------------------------------------------------------------------------------------------
phase "build images"
build_images
write_env

# --- 2. up with 3 workers, until two checkpoints --------------------------------------------------------------------
phase "up (WORKERS=3) until 2 checkpoints"
WORKERS=3 dc up -d >>"$LOG" 2>&1 || fail "compose up failed: $(tail -3 "$LOG")"
wait_until "checkpoint version 2 in s3://$RACER_BUCKET" 300 checkpoints_at_least 2
wait_until "3 live workers in racer status" 120 workers_exactly 3
trainer_health() { [[ $(docker inspect -f '{{.State.Health.Status}}' "$(containers trainer)") == healthy ]]; }
wait_until "the trainer's health check (racer status --quiet) to pass" 60 trainer_health
figure "checkpoints after up" "$(checkpoint_versions)"

# --- 3. scale to 5 workers -------------------------------------------------------------------------------------------
phase "scale to 5 workers"
dc up -d --no-recreate --scale worker=5 >>"$LOG" 2>&1 || fail "compose up --scale worker=5 failed"
wait_until "5 live workers in racer status" 180 workers_exactly 5

# --- 4. a worker killed ----------------------------------------------------------------------------------------------
phase "kill a worker, see it restarted"
victim=$(containers worker | head -1)
pid=$(docker inspect -f '{{.State.Pid}}' "$victim")
worker_id() { docker logs "$victim" 2>&1 | sed -n 's/.* worker \([^ ]*\) acting with policy version .*/\1/p' | tail -1; }
live_ids() { status_json | json_get '" ".join(sorted(w["worker_id"] for w in d["workers"]))'; }
old_id=$(worker_id)
v_kill=$(policy_version)
[[ -n $old_id && " $(live_ids) " == *" $old_id "* ]] || fail "cannot tell the live id of worker ${victim:0:12}"
log "SIGKILL to worker container ${victim:0:12} (pid $pid, worker $old_id) at policy version $v_kill"
kill_hard "$pid"
restarted() {
    local state; state=$(docker inspect -f '{{.RestartCount}} {{.State.Running}} {{.State.Pid}}' "$victim")
    [[ $state != 0\ * && $state == *" true "* && ${state##* } != "$pid" ]]
}
wait_until "the restart policy to bring the worker back" 90 restarted
wait_until "training to go on (policy version >= $((v_kill + 2)))" 180 policy_at_least $((v_kill + 2))
replaced() {  # 5 live workers: the restarted one under its new id, the dead one's heartbeat expired
    local ids new; ids=" $(live_ids) " new=$(worker_id)
    [[ $(wc -w <<<"$ids") == 5 && $new != "$old_id" && $ids == *" $new "* && $ids != *" $old_id "* ]]
}
wait_until "5 live workers again, $old_id gone and the restarted worker live" 120 replaced
figure "killed worker" "container ${victim:0:12} at v$v_kill: $old_id, restarted $(docker inspect -f '{{.RestartCount}}' \
    "$victim") time(s), now $(worker_id)"

# --- 5. racer models ls from the host -------------------------------------------------------------------------------
phase "racer models ls from the host (and status, models ls in the trainer)"
racer_host models ls --store "s3://$RACER_BUCKET/" --s3-endpoint "$HOST_S3_URL" --run-id "$RACER_RUN_ID" \
    || fail "racer models ls failed"
n=$(checkpoint_versions | wc -w)
((n >= 2)) || fail "racer models ls lists $n checkpoints"
# ... and inside the trainer's container, as docs/docker.md tells users to (its environment names Redis and S3).
dc exec -T trainer racer status >/dev/null || fail "docker compose exec trainer racer status failed"
dc exec -T trainer racer models ls --run-id "$RACER_RUN_ID" >/dev/null \
    || fail "docker compose exec trainer racer models ls failed"
figure "checkpoints listed" "$(checkpoint_versions)"

# --- 6. down, up again: the run resumes -----------------------------------------------------------------------------
phase "down and up again, the run resumes"
before=$(newest_checkpoint)
dc down --timeout 20 >>"$LOG" 2>&1 || fail "compose down failed"
[[ -z $(docker ps -aq --filter "label=com.docker.compose.project=$PROJECT") ]] || fail "containers left after down"
log "down at checkpoint v$before; up again"
WORKERS=3 dc up -d >>"$LOG" 2>&1 || fail "compose up (again) failed: $(tail -3 "$LOG")"
resumed_at() { dc logs --no-color trainer 2>/dev/null | sed -n 's/.*resumed run .* at version \([0-9]*\) .*/\1/p' | tail -1; }
has_resumed() { [[ -n $(resumed_at) ]]; }
wait_until "the trainer to resume" 240 has_resumed
v_resumed=$(resumed_at)
((v_resumed >= before)) || fail "the trainer resumed at v$v_resumed, older than the newest checkpoint v$before"
wait_until "a checkpoint newer than v$v_resumed" 240 checkpoints_at_least $((v_resumed + 1))
figure "resume" "down at v$before, resumed at v$v_resumed, then v$(newest_checkpoint)"

clean_up
