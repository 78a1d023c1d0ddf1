# shellcheck shell=bash
# Shared by deploy/cluster/check-compose.sh and deploy/cluster/check-swarm.sh (sourced, not run): options, images, ports,
# waiting, racer from the host, figures and cleanup. Bash; the caller has `set -euo pipefail`.

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
SCRIPT=$(basename "$0")
T0=$(date +%s)
PHASES=()     # "name seconds"
FIGURES=()    # "name: value"
CLEANUPS=()   # commands run by cleanup, last first
KEEP_IMAGES=0
KEEP_BASE=0
REUSE_IMAGES=0
TAG=${RACER_TEST_TAG:-check-$$}
BASE=${RACER_TEST_BASE:-racer-base:bookworm}
BASE_CREATED=0
DANGLING_BEFORE=""

usage_common() {
    cat <<EOF
  --keep-images   keep the images it built (racer-test:TAG, the stand-ins, the base it made)
  --keep-base     keep only the Debian base image it made (${BASE}), a cache for the next run
  --reuse-images  build only the images that are missing (with --tag of an earlier --keep-images run)
  --tag TAG       image tag (default check-<pid>)
Environment:
  TORCH_INDEX_URL   else a torch 2.13.0 CPU wheel pip finds on this machine, served on loopback, else
                    download.pytorch.org
  RACER_TEST_BASE   a Debian bookworm image to build the stand-ins from (racer-base:bookworm); when missing,
                    tagged from a pulled debian:bookworm-slim, else made with debootstrap
  DEBIAN_MIRROR     the Debian archive debootstrap reads (default: the first one this machine's apt sources name)
  RACER_COMPOSE     "docker compose" or "docker-compose" (default: whichever works)
  RACER_CLI         racer on the host (default: racer on PATH, ./.venv/bin/racer, else the image)
EOF
}

parse_common() {
    while (($#)); do
        case $1 in
            --keep-images) KEEP_IMAGES=1 ;;
            --keep-base) KEEP_BASE=1 ;;
            --reuse-images) REUSE_IMAGES=1 ;;
            --tag) TAG=$2; shift ;;
            -h | --help) usage; exit 0 ;;
            *) echo "$SCRIPT: unknown option $1" >&2; usage >&2; exit 2 ;;
        esac
        shift
    done
}

log() { printf '%s [%s] %s\n' "$(date +%H:%M:%S)" "$SCRIPT" "$*"; }
fail() { log "FAILED: $*" >&2; exit 1; }
figure() { FIGURES+=("$1: $2"); }

PHASE_NAME=""
PHASE_T0=0
phase() {  # phase NAME: ends the current phase (if any) and starts NAME ("" ends only)
    local now; now=$(date +%s)
    [[ -n $PHASE_NAME ]] && PHASES+=("$PHASE_NAME $((now - PHASE_T0))")
    PHASE_NAME=$1 PHASE_T0=$now
    [[ -n $1 ]] && log "== $1"
    return 0
}

print_figures() {
    echo
    echo "== $SCRIPT figures"
    local p f
    for p in "${PHASES[@]}"; do printf '  %-58s %5ss\n' "${p% *}" "${p##* }"; done
    printf '  %-58s %5ss\n' "total" "$(($(date +%s) - T0))"
    for f in "${FIGURES[@]}"; do echo "  $f"; done
}

# --- prerequisites -------------------------------------------------------------------------------------------------

need_docker() {
    command -v docker >/dev/null || fail "docker is not installed"
    timeout 20 docker info >/dev/null 2>&1 || fail "no Docker daemon answers (docker info failed)"
}

pick_compose() {
    if [[ -n ${RACER_COMPOSE:-} ]]; then
        read -r -a COMPOSE <<<"$RACER_COMPOSE"
    elif docker compose version >/dev/null 2>&1; then
        COMPOSE=(docker compose)
    elif command -v docker-compose >/dev/null; then
        COMPOSE=(docker-compose)
    else
        fail "neither 'docker compose' (v2) nor 'docker-compose' (v1) is installed"
    fi
    figure compose "${COMPOSE[*]} ($("${COMPOSE[@]}" version --short 2>/dev/null || echo '?'))"
}

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

secret() { python3 -c 'import secrets; print(secrets.token_hex(16))'; }

# racer on the host (racer status, racer models ls); without one, the image on the host's network.
RACER_HOST=()
pick_racer() {
    if [[ -n ${RACER_CLI:-} ]]; then
        read -r -a RACER_HOST <<<"$RACER_CLI"
    elif command -v racer >/dev/null; then
        RACER_HOST=(racer)
    elif [[ -x $ROOT/.venv/bin/racer ]]; then
        RACER_HOST=("$ROOT/.venv/bin/racer")
    else
        RACER_HOST=(docker run --rm --network host -e RACER_RUN_ID -e AWS_ACCESS_KEY_ID -e AWS_SECRET_ACCESS_KEY
            -e AWS_DEFAULT_REGION "racer-test:$TAG")
    fi
}
racer_host() { timeout 120 "${RACER_HOST[@]}" "$@"; }

# JSON from stdin, a Python expression of d.
json_get() { python3 -c "import json, sys; d = json.load(sys.stdin); print($1)"; }

# wait_until DESCRIPTION SECONDS COMMAND...: run COMMAND every 2 s until it succeeds.
wait_until() {
    local what=$1 limit=$2 t0; t0=$(date +%s)
    shift 2
    log "waiting (at most ${limit}s) for $what"
    until "$@" 2>/dev/null; do
        (($(date +%s) - t0 < limit)) || fail "timed out after ${limit}s waiting for $what"
        sleep 2
    done
    log "  ok after $(($(date +%s) - t0))s: $what"
}

# --- the run's state, from the host -------------------------------------------------------------------------------

status_json() { racer_host status --redis "$HOST_REDIS_URL" --run-id "$RACER_RUN_ID" --json - 2>/dev/null; }
live_workers() { status_json | json_get 'len(d["workers"])'; }
policy_version() { status_json | json_get '(d["policy"] or {}).get("version", -1)'; }
checkpoint_versions() {  # the whole checkpoints in the bucket, oldest first (3 tries; the last error on stderr)
    local out i err; err=$(mktemp)
    for i in 1 2 3; do
        if out=$(racer_host models ls --store "s3://$RACER_BUCKET/" --s3-endpoint "$HOST_S3_URL" \
            --run-id "$RACER_RUN_ID" --json - 2>"$err"); then
            rm -f "$err"
            json_get '" ".join(str(m["version"]) for m in d)' <<<"$out"
            return $?
        fi
        sleep 1
    done
    echo "racer models ls: $(tail -1 "$err")" >&2
    rm -f "$err"
    return 1
}
newest_checkpoint() { local v; v=$(checkpoint_versions) || return 1; echo "${v##* }"; }
checkpoints_at_least() {  # newest checkpoint version >= $1
    local v; v=$(newest_checkpoint 2>/dev/null) && [[ -n $v ]] && ((v >= $1))
}
workers_exactly() { local n; n=$(live_workers 2>/dev/null) && [[ $n == "$1" ]]; }
policy_at_least() { local v; v=$(policy_version 2>/dev/null) && ((v >= $1)); }

# --- images --------------------------------------------------------------------------------------------------------

image_exists() { docker image inspect "$1" >/dev/null 2>&1; }

legacy_builder() { ! docker buildx version >/dev/null 2>&1; }

# apt_debian_mirror [ROOT]: the Debian archive that the apt sources under ROOT (default /) name first: one-line entries
# in etc/apt/sources.list and etc/apt/sources.list.d/*.list, deb822 stanzas in etc/apt/sources.list.d/*.sources, in
# apt's order. An entry counts when its type is deb (not deb-src), it is enabled, its URI is http(s):// or file:/ and
# its suite is a Debian release's own (a codename or stable, testing, ...): -security, -updates and -backports
# suites are other archives, and a third party's (nodistro, cloud-sdk-bookworm) is not Debian. Prints the URI
# without a trailing slash; fails, printing nothing, when no entry counts.
apt_debian_mirror() {
    local root=${1:-} file files=() uri
    [[ -f $root/etc/apt/sources.list ]] && files+=("$root/etc/apt/sources.list")
    for file in "$root"/etc/apt/sources.list.d/*; do
        [[ -f $file && ($file == *.list || $file == *.sources) ]] && files+=("$file")
    done
    for file in "${files[@]}"; do
        uri=$(awk -v deb822="$([[ $file == *.sources ]] && echo 1 || echo 0)" '
            function debian(suite) {
                return suite ~ /^(oldoldstable|oldstable|stable|testing|unstable|experimental|sid|buster|bullseye|bookworm|trixie|forky|duke)$/
            }
            function usable(uri) { return uri ~ /^(https?:\/\/|file:\/)/ }
            function found(uri) { sub(/\/+$/, "", uri); print uri; done = 1; exit }
            function stanza(   i, j, n, m, types, uris, suites, deb) {  # the deb822 stanza read so far
                if (tolower(field["enabled"]) != "no") {
                    n = split(field["types"], types, /[ \t]+/)
                    for (i = 1; i <= n; i++) deb = deb || types[i] == "deb"
                    n = split(field["uris"], uris, /[ \t]+/)
                    m = split(field["suites"], suites, /[ \t]+/)
                    for (i = 1; deb && i <= n; i++)
                        for (j = 1; j <= m; j++)
                            if (usable(uris[i]) && debian(suites[j])) found(uris[i])
                }
                delete field
                name = ""
            }
            deb822 && /^[ \t]*#/ { next }
            deb822 && /^[ \t]*$/ { stanza(); next }
            deb822 && /^[ \t]/ { if (name != "") field[name] = field[name] " " $0; next }
            deb822 {
                name = tolower(substr($0, 1, index($0, ":") - 1))
                field[name] = substr($0, index($0, ":") + 1)
                gsub(/^[ \t]+|[ \t]+$/, "", field[name])
                next
            }
            {  # one-line: deb [ options ] uri suite [component...]  (# starts a comment)
                sub(/#.*/, "")
                if ($1 != "deb") next
                i = 2
                if ($2 ~ /^\[/) { while (i < NF && $i !~ /\]$/) i++; i++ }
                if (usable($i) && debian($(i + 1))) found($i)
            }
            END { if (deb822 && !done) stanza() }
        ' "$file") || continue
        [[ -n $uri ]] && { echo "$uri"; return 0; }
    done
    return 1
}

make_base_image() {
    if image_exists "$BASE"; then
        log "base image $BASE exists"
        return 0
    fi
    if timeout 180 docker pull -q debian:bookworm-slim >/dev/null 2>&1; then  # a registry answers: the plain way
        docker tag debian:bookworm-slim "$BASE"
        BASE_CREATED=1
        figure "base image" "$BASE = debian:bookworm-slim, pulled"
        return 0
    fi
    command -v debootstrap >/dev/null || fail "$BASE is missing, no registry answers and debootstrap is not installed"
    [[ $(id -u) == 0 ]] || fail "$BASE is missing and making it with debootstrap needs root"
    local mirror=${DEBIAN_MIRROR:-}
    [[ -n $mirror ]] || mirror=$(apt_debian_mirror) ||
        fail "no Debian archive in this machine's apt sources (/etc/apt/sources.list{,.d/}): set DEBIAN_MIRROR to one"
    local dir t0; dir=$(mktemp -d /var/tmp/racer-base.XXXXXX) t0=$(date +%s)
    CLEANUPS+=("rm -rf '$dir'")
    log "making $BASE with debootstrap (Debian bookworm, minbase, from $mirror)"
    timeout 900 debootstrap --variant=minbase bookworm "$dir" "$mirror" \
        >"$dir.log" 2>&1 || { tail -20 "$dir.log" >&2; fail "debootstrap failed (log above)"; }
    rm -f "$dir.log"
    rm -rf "$dir"/var/cache/apt/*.bin "$dir"/var/cache/apt/archives/*.deb "$dir"/var/lib/apt/lists/*
    # Trust what this machine trusts (a TLS-inspecting proxy's CA, say): pip and apt inside the builds need it.
    if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
        mkdir -p "$dir/usr/local/share/ca-certificates"
        cp /usr/local/share/ca-certificates/*.crt "$dir/usr/local/share/ca-certificates/"
    fi
    tar -C "$dir" -c . | timeout 300 docker import - "$BASE" >/dev/null
    rm -rf "$dir"
    BASE_CREATED=1
    figure "base image" "$BASE made with debootstrap in $(($(date +%s) - t0))s, $(image_size "$BASE")"
}

image_size() { docker image inspect -f '{{.Size}}' "$1" | awk '{printf "%.2f GB (%d MB)", $1 / 1e9, $1 / 1e6}'; }

# A PEP 503 folder on loopback holding the torch wheel pip finds on this machine (its find-links / local index),
# so that the image gets torch through TORCH_INDEX_URL like any other index. No wheel: the default index.
serve_torch_wheel() {
    [[ -n ${TORCH_INDEX_URL:-} ]] && { log "torch from TORCH_INDEX_URL=$TORCH_INDEX_URL"; return 0; }
    local pip=(python3 -m pip) dir port
    [[ -x $ROOT/.venv/bin/python ]] && pip=("$ROOT/.venv/bin/python" -m pip)
    dir=$(mktemp -d)
    CLEANUPS+=("rm -rf '$dir'")
    mkdir -p "$dir/simple/torch"
    if ! timeout 300 "${pip[@]}" download -q --no-deps --no-index --only-binary=:all: --python-version 3.11 \
        -d "$dir/simple/torch" "torch==2.13.0" >/dev/null 2>&1; then
        log "no local torch wheel: the image takes torch from the Dockerfile's default index"
        return 0
    fi
    port=$(free_port)
    python3 -m http.server --bind 127.0.0.1 --directory "$dir" "$port" >/dev/null 2>&1 &
    local pid=$!
    CLEANUPS+=("kill $pid 2>/dev/null || true")
    export TORCH_INDEX_URL="http://127.0.0.1:$port/simple"
    wait_until "the local wheel server" 30 \
        python3 -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=2)" "$TORCH_INDEX_URL/torch/"
    log "torch from $(ls "$dir/simple/torch"), served at $TORCH_INDEX_URL"
}

remember_dangling() { DANGLING_BEFORE=$(docker images -q --filter dangling=true | sort -u); }

# build IMAGE DOCKERFILE CONTEXT [docker build options]
build_image() {
    local image=$1 file=$2 context=$3 t0; t0=$(date +%s)
    shift 3
    if ((REUSE_IMAGES)) && image_exists "$image"; then
        log "reusing $image"
        return 0
    fi
    log "building $image"
    local flags=() out; legacy_builder && flags=(--force-rm)
    out=$(mktemp)
    if ! timeout 1500 docker build "${flags[@]}" -t "$image" -f "$file" "$@" "$context" >"$out" 2>&1; then
        tail -25 "$out" >&2
        rm -f "$out"
        fail "docker build of $image failed (its last lines above)"
    fi
    rm -f "$out"
    figure "build $image" "$(($(date +%s) - t0))s, $(image_size "$image")"
}

# The stand-ins and the racer image: racer-standin-{python,redis,s3}:TAG and racer-test:TAG.
build_images() {
    remember_dangling
    make_base_image
    serve_torch_wheel
    build_image "racer-standin-python:$TAG" "$ROOT/deploy/cluster/standins/python.Dockerfile" "$ROOT/deploy/cluster/standins" \
        --build-arg "BASE_IMAGE=$BASE"
    build_image "racer-standin-redis:$TAG" "$ROOT/deploy/cluster/standins/redis.Dockerfile" "$ROOT/deploy/cluster/standins" \
        --build-arg "BASE_IMAGE=$BASE"
    build_image "racer-standin-s3:$TAG" "$ROOT/deploy/cluster/standins/s3.Dockerfile" "$ROOT/deploy/cluster/standins" \
        --build-arg "PYTHON_IMAGE=racer-standin-python:$TAG"
    build_image "racer-test:$TAG" "$ROOT/Dockerfile" "$ROOT" --network host \
        --build-arg "BASE_IMAGE=racer-standin-python:$TAG" \
        ${TORCH_INDEX_URL:+--build-arg "TORCH_INDEX_URL=$TORCH_INDEX_URL"}
    figure "racer image size" "$(image_size "racer-test:$TAG") (docker image ls: $(docker image ls --format '{{.Size}}' "racer-test:$TAG"))"
}

remove_images() {
    if ((KEEP_IMAGES)); then
        log "keeping the images (--keep-images): racer-test:$TAG racer-standin-{python,redis,s3}:$TAG $BASE"
        return 0
    fi
    local image
    for image in "racer-test:$TAG" "racer-standin-s3:$TAG" "racer-standin-redis:$TAG" "racer-standin-python:$TAG"; do
        image_exists "$image" && docker image rm -f "$image" >/dev/null
    done
    if ((BASE_CREATED && !KEEP_BASE)); then
        docker image rm -f "$BASE" >/dev/null 2>&1 || true
    fi
    # What failed builds left behind (a legacy build keeps the steps it finished): images dangling now, not before.
    local id
    for id in $(comm -13 <(echo "$DANGLING_BEFORE") <(docker images -q --filter dangling=true | sort -u)); do
        docker image rm -f "$id" >/dev/null 2>&1 || true
    done
}

run_cleanups() {
    local i
    for ((i = ${#CLEANUPS[@]} - 1; i >= 0; i--)); do eval "${CLEANUPS[i]}" || true; done
    CLEANUPS=()
}

# The variables docker-compose.yml and deploy/cluster/compose.test.yml read, in an env file so that a .env in the checkout
# plays no part, and exported (the shell's variables win over an env file).
write_env() {
    ENV_FILE=$(mktemp)
    CLEANUPS+=("rm -f '$ENV_FILE'")
    RACER_TEST_REDIS_PORT=$(free_port)
    RACER_TEST_S3_PORT=$(free_port)
    while [[ $RACER_TEST_S3_PORT == "$RACER_TEST_REDIS_PORT" ]]; do RACER_TEST_S3_PORT=$(free_port); done
    cat >"$ENV_FILE" <<EOF
RACER_RUN_ID=$SCRIPT_RUN_ID
RACER_BUCKET=racer-check
RACER_IMAGE=racer-test:$TAG
RACER_TEST_TAG=$TAG
RACER_TEST_ROOT=$ROOT
RACER_TEST_BASE=$BASE
RACER_TEST_REDIS_PORT=$RACER_TEST_REDIS_PORT
RACER_TEST_S3_PORT=$RACER_TEST_S3_PORT
REDIS_PASSWORD=$(secret)
MINIO_ROOT_USER=racer-check
MINIO_ROOT_PASSWORD=$(secret)
RACER_TRACK=racer_straight
RACER_TRAINER_THREADS=1
RACER_EVAL_EPISODES=1
RACER_EVAL_NICE=10
WORKERS=3
TORCH_INDEX_URL=${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}
EOF
    set -a
    # shellcheck disable=SC1090
    . "$ENV_FILE"
    set +a
    export AWS_ACCESS_KEY_ID=$MINIO_ROOT_USER AWS_SECRET_ACCESS_KEY=$MINIO_ROOT_PASSWORD AWS_DEFAULT_REGION=us-east-1
    HOST_REDIS_URL="redis://:$REDIS_PASSWORD@127.0.0.1:$RACER_TEST_REDIS_PORT/0"
    HOST_S3_URL="http://127.0.0.1:$RACER_TEST_S3_PORT"
    figure ports "Redis 127.0.0.1:$RACER_TEST_REDIS_PORT, S3 127.0.0.1:$RACER_TEST_S3_PORT"
}

finish() {  # finish RC: the script's last words on any exit: clean up (the script's clean_up), figures, verdict
    local rc=$1
    clean_up
    phase ""
    print_figures
    ((rc == 0)) && echo "$SCRIPT: all checks passed" || echo "$SCRIPT: FAILED (exit $rc)"
    exit "$rc"
}
