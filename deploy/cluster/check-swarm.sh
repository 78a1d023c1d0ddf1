#!/usr/bin/env bash
# docker-compose.yml on a one-node Docker Swarm, for real, from nothing: builds the images (docker stack deploy
# ignores build:), `docker swarm init` on loopback, `docker stack deploy` of docker-compose.yml (depends_on in its
# short form: the only change Swarm needs) with deploy/cluster/compose.test.yml and deploy/cluster/swarm.test.yml, waits for
# checkpoints and WORKERS=3 live workers, `docker service scale` to 5 and sees 5 live workers and training going on,
# then `docker stack rm`, `docker swarm leave --force` and removes all it created. It refuses to run on a node that
# is already part of a swarm. Exits 0 only when every check held; prints its figures last. docs/docker.md.
set -euo pipefail
# shellcheck source=deploy/cluster/docker-test-lib.sh
. "$(dirname "$0")/docker-test-lib.sh"

usage() {
    echo "Usage: deploy/cluster/check-swarm.sh [options]"
    usage_common
}
parse_common "$@"

SCRIPT_RUN_ID=swarm-check
STACK=racer-check-$$
SWARM_STARTED=0

stack_containers() { docker ps -aq --filter "label=com.docker.stack.namespace=$STACK"; }
stack_gone() { [[ -z $(stack_containers) ]] && [[ -z $(docker network ls -q --filter "label=com.docker.stack.namespace=$STACK") ]]; }

# docker swarm init makes the bridge network docker_gwbridge and leaving the swarm keeps it: remove ours.
GWBRIDGE_BEFORE=unknown
remove_gwbridge() {
    [[ -z $GWBRIDGE_BEFORE ]] || return 0
    local t0; t0=$(date +%s)
    until timeout 30 docker network rm docker_gwbridge >/dev/null 2>&1; do
        (($(date +%s) - t0 < 60)) || { log "cannot remove the network docker_gwbridge"; return 0; }
        sleep 2
    done
    GWBRIDGE_BEFORE=removed
}

CLEANED=0
clean_up() {
    ((CLEANED)) && return 0
    CLEANED=1
    phase "clean up"
    if ((SWARM_STARTED)); then
        timeout 60 docker stack rm "$STACK" >/dev/null 2>&1 || log "docker stack rm failed"
        local t0; t0=$(date +%s)
        until stack_gone || (($(date +%s) - t0 > 90)); do sleep 2; done
        stack_gone || log "the stack's containers or networks are still there"
        timeout 60 docker volume rm "${STACK}_minio-data" >/dev/null 2>&1 || true
        timeout 60 docker swarm leave --force >/dev/null || log "docker swarm leave --force failed"
    fi
    remove_gwbridge
    remove_images
    run_cleanups
}
on_exit() {
    local rc=$?
    trap - EXIT
    if ((rc != 0 && SWARM_STARTED && !CLEANED)); then
        log "diagnostics (the run failed):"
        docker stack ps --no-trunc "$STACK" 2>&1 | head -30 || true
        local s
        for s in trainer worker evaluator minio redis; do
            echo "--- $s"
            timeout 30 docker service logs --tail 15 "${STACK}_$s" 2>&1 | grep -v SIM_TRACE_LOG | tail -15 || true
        done
    fi
    finish "$rc"
}
trap on_exit EXIT
trap 'exit 130' INT TERM

# --- 0. what this machine has ---------------------------------------------------------------------------------------
phase "prerequisites"
need_docker
command -v python3 >/dev/null || fail "python3 is needed on the host"
state=$(docker info --format '{{.Swarm.LocalNodeState}}')
[[ $state == inactive ]] || fail "this Docker node is already in a swarm ($state): not touching it"
pick_racer
figure "racer on the host" "${RACER_HOST[*]}"
figure docker "$(docker version --format 'client {{.Client.Version}}, server {{.Server.Version}}')"

# --- 1. images ------------------------------------------------------------------------------------------------------
phase "build images"
build_images
write_env
# docker stack deploy takes depends_on as a list only (compose's conditions are a schema error there); nothing
# else in docker-compose.yml needs changing. The file keeps one condition per line for this (tests/test_compose.py).
STACK_FILE=$(mktemp --suffix .yml)
CLEANUPS+=("rm -f '$STACK_FILE'")
sed -E 's/^( +)([A-Za-z0-9_.-]+): \{condition: [a-z_]+\}$/\1- \2/' "$ROOT/docker-compose.yml" >"$STACK_FILE"
! grep -q 'condition: service_' "$STACK_FILE" || fail "a depends_on condition is not in its one-line form"

# --- 2. swarm, stack ------------------------------------------------------------------------------------------------
phase "swarm init, stack deploy (WORKERS=3) until 2 checkpoints"
GWBRIDGE_BEFORE=$(docker network ls -q --filter name=^docker_gwbridge$)
timeout 60 docker swarm init --advertise-addr 127.0.0.1 --listen-addr 127.0.0.1:2377 >/dev/null
SWARM_STARTED=1
timeout 120 docker stack deploy --resolve-image never -c "$STACK_FILE" -c "$ROOT/deploy/cluster/compose.test.yml" \
    -c "$ROOT/deploy/cluster/swarm.test.yml" "$STACK" || fail "docker stack deploy failed"
wait_until "checkpoint version 2 in s3://$RACER_BUCKET" 300 checkpoints_at_least 2
wait_until "3 live workers in racer status" 120 workers_exactly 3
figure "checkpoints after deploy" "$(checkpoint_versions)"

# --- 3. scale ---------------------------------------------------------------------------------------------------------
phase "docker service scale worker=5"
timeout 120 docker service scale --detach "${STACK}_worker=5" >/dev/null || fail "docker service scale failed"
wait_until "5 live workers in racer status" 180 workers_exactly 5
v=$(policy_version)
wait_until "training to go on (policy version >= $((v + 2)))" 180 policy_at_least $((v + 2))
figure "replicas" "$(docker service ls --filter "name=${STACK}_worker" --format '{{.Name}} {{.Replicas}}')"
# No depends_on in Swarm: a trainer that started before the bucket existed failed and was restarted; say so.
figure "trainer tasks" "$(docker service ps --no-trunc --format '{{.CurrentState}}|{{.Error}}' "${STACK}_trainer" \
    | awk -F'|' '{ split($1, s, " "); print s[1] ($2 == "" ? "" : " (" $2 ")") }' | sort | uniq -c \
    | sed 's/^ *//' | paste -sd ';' -)"
figure "checkpoints listed" "$(checkpoint_versions)"

# --- 4. stack rm, swarm leave ---------------------------------------------------------------------------------------
phase "stack rm, swarm leave"
timeout 60 docker stack rm "$STACK" >/dev/null || fail "docker stack rm failed"
wait_until "the stack's containers and networks to go" 120 stack_gone
timeout 60 docker volume rm "${STACK}_minio-data" >/dev/null || fail "cannot remove the volume ${STACK}_minio-data"
timeout 60 docker swarm leave --force >/dev/null || fail "docker swarm leave --force failed"
SWARM_STARTED=0
[[ $(docker info --format '{{.Swarm.LocalNodeState}}') == inactive ]] || fail "still in a swarm after leaving"
remove_gwbridge

clean_up
