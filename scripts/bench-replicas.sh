#!/usr/bin/env bash
# Replicas on one PostgreSQL (issue 22): jobs/minute with 1, 2 and 3 worker replicas behind
# one API replica, then status polling (wrk on GET /v1/jobs/{id}) through one replica on
# PostgreSQL and on SQLite. Everything on this machine, so the job figure measures the
# queue's coordination overhead, not a speed-up. By default jobs run the test pipeline (a
# fixed delay per job) so that the figure is about the queue alone; VLM=oracle runs the
# whole method instead (`grounder oracle-vlm` as the VLM, the oracle detector).
#
# Starts its own throwaway PostgreSQL (initdb + pg_ctl from the Debian package
# `postgresql`, as the postgres user when run as root) and removes it on exit.
# Needs curl, jq, wrk.
#
# Environment (defaults in brackets; JOBS at most 500): GROUNDER_BIN [target/debug/grounder, built if
# missing], VLM [test: the test pipeline; oracle: the method with the oracle VLM],
# JOBS [120], JOB_MS [200] (test pipeline), WORKERS [2] (per worker replica), DURATION [10s],
# CONNECTIONS [32], PORT [18300] (first port; the replicas take the next ones).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
JOBS=${JOBS:-120}
JOB_MS=${JOB_MS:-200}
VLM=${VLM:-test}
[[ $VLM == test || $VLM == oracle ]] || { echo "error: VLM must be test or oracle (got $VLM)" >&2; exit 1; }
WORKERS=${WORKERS:-2}
DURATION=${DURATION:-10s}
CONNECTIONS=${CONNECTIONS:-32}
PORT=${PORT:-18300}
for tool in curl jq wrk; do
    command -v "$tool" >/dev/null || { echo "error: $tool is required" >&2; exit 1; }
done
PGBIN=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1)
[[ -x "$PGBIN/initdb" ]] || { echo "error: PostgreSQL is not installed (Debian package postgresql)" >&2; exit 1; }
if [[ -z "${GROUNDER_BIN:-}" ]]; then
    (cd "$ROOT" && cargo build --bin grounder)
    GROUNDER_BIN=${CARGO_TARGET_DIR:-$ROOT/target}/debug/grounder
fi

WORK=$(mktemp -d)
chmod 755 "$WORK"   # the postgres user must reach its cluster inside
PIDS=()
AS_PG=()
[[ $(id -u) == 0 ]] && AS_PG=(runuser -u postgres --)
cleanup() {
    for p in "${PIDS[@]}" ${ORACLE_PID:-}; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    [[ -d "$WORK/pg/data" ]] && "${AS_PG[@]}" "$PGBIN/pg_ctl" -D "$WORK/pg/data" stop -m immediate >/dev/null 2>&1 || true
    rm -rf "$WORK"
}
trap cleanup EXIT

mkdir -p "$WORK/pg"
[[ $(id -u) == 0 ]] && chown postgres "$WORK/pg"
PGPORT=$((PORT + 99))
"${AS_PG[@]}" "$PGBIN/initdb" -D "$WORK/pg/data" -A trust -U postgres --no-sync >/dev/null
"${AS_PG[@]}" "$PGBIN/pg_ctl" -D "$WORK/pg/data" -l "$WORK/pg/log" -w start \
    -o "-p $PGPORT -k $WORK/pg -c listen_addresses=127.0.0.1 -c max_connections=200" >/dev/null
PG="postgres://postgres@127.0.0.1:$PGPORT"
createdb() { "$PGBIN/psql" -q "$PG/postgres" -c "CREATE DATABASE $1" >/dev/null; echo "$PG/$1"; }

# serve PORT DATA_DIR VAR=value...: start a replica, wait for it to listen.
serve() {
    local port=$1 data=$2
    shift 2
    env "${METHOD_ENV[@]}" GROUNDER_LOG=warn "$@" \
        "$GROUNDER_BIN" serve --addr "127.0.0.1:$port" --data-dir "$data" >"$WORK/serve-$port.log" 2>&1 &
    PIDS+=($!)
    for _ in $(seq 300); do
        grep -q "listening on" "$WORK/serve-$port.log" && return 0
        sleep 0.1
    done
    echo "error: replica on $port did not start" >&2; cat "$WORK/serve-$port.log" >&2; exit 1
}
stop_all() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    for p in "${PIDS[@]}"; do wait "$p" 2>/dev/null || true; done
    PIDS=()
}

"$GROUNDER_BIN" synth --out "$WORK/synth" --frames 4 --color-size 320x240 --depth-size 160x120 --tar \
    --dataset "$WORK/ds" >/dev/null
TAR="$WORK/synth/scene_synth_0000.tar"
QUERY=$(head -1 "$WORK/ds/queries.jsonl" | jq -r .text)
if [[ $VLM == oracle ]]; then
    "$GROUNDER_BIN" oracle-vlm --addr "127.0.0.1:$((PORT + 98))" --dataset "$WORK/ds" --scenes "$WORK/synth" \
        >"$WORK/oracle.log" 2>&1 &
    ORACLE_PID=$!
    for _ in $(seq 300); do grep -q "listening on" "$WORK/oracle.log" && break; sleep 0.1; done
    METHOD_ENV=(GROUNDER_DETECTOR=oracle GROUNDER_VLM_BASE_URL="http://127.0.0.1:$((PORT + 98))/v1"
        GROUNDER_VLM_MODEL=grounder-oracle GROUNDER_VLM_API_KEY=bench)
    JOB_WHAT="the method with the oracle VLM"
else
    METHOD_ENV=(GROUNDER_PIPELINE="test:delay_ms=$JOB_MS" GROUNDER_DETECTOR=none)
    JOB_WHAT="test jobs of $JOB_MS ms"
fi
upload() { curl -sf --data-binary @"$TAR" -H 'Content-Type: application/x-tar' "$1/v1/scenes" | jq -r .id; }
submit() { jq -n --arg s "$2" --arg q "$QUERY" '{scene_id: $s, query: $q}' | curl -sf -H 'Content-Type: application/json' -d @- "$1/v1/jobs" | jq -r .id; }
wait_ready() {
    for _ in $(seq 300); do
        [[ $(curl -sf "$1/v1/scenes/$2" | jq -r .status) == ready ]] && return 0
        sleep 0.1
    done
    echo "error: scene not ready" >&2; exit 1
}

echo "== jobs/minute: $JOBS $JOB_WHAT, $WORKERS workers per worker replica, one API replica (debug build unless GROUNDER_BIN says otherwise)"
for n in 1 2 3; do
    url=$(createdb "jobs_$n")
    data="$WORK/data-$n"
    serve "$PORT" "$data" GROUNDER_DATABASE_URL="$url" GROUNDER_ROLE=api
    api="http://127.0.0.1:$PORT"
    scene=$(upload "$api")
    wait_ready "$api" "$scene"
    for i in $(seq "$n"); do
        serve $((PORT + i)) "$data" GROUNDER_DATABASE_URL="$url" GROUNDER_ROLE=worker GROUNDER_WORKERS="$WORKERS"
    done
    start=$(date +%s.%N)
    for _ in $(seq "$JOBS"); do submit "$api" "$scene" >/dev/null; done
    while :; do
        done_n=$(curl -sf "$api/v1/jobs?status=succeeded&limit=500" | jq '.jobs | length')
        [[ "$done_n" -ge "$JOBS" ]] && break
        sleep 0.2
    done
    end=$(date +%s.%N)
    awk -v n="$n" -v j="$JOBS" -v s="$start" -v e="$end" -v w="$WORKERS" -v ms="$JOB_MS" 'BEGIN {
        t = e - s; printf "%d worker replica(s): %d jobs in %.1f s = %.0f jobs/min\n", n, j, t, j * 60 / t }'
    stop_all
done

echo "== status polling through one replica: wrk -c$CONNECTIONS -d$DURATION GET /v1/jobs/{id}"
for backend in postgres sqlite; do
    data="$WORK/poll-$backend"
    if [[ $backend == postgres ]]; then
        serve "$PORT" "$data" GROUNDER_DATABASE_URL="$(createdb poll)"
    else
        serve "$PORT" "$data"
    fi
    base="http://127.0.0.1:$PORT"
    scene=$(upload "$base")
    wait_ready "$base" "$scene"
    job=$(submit "$base" "$scene")
    for _ in $(seq 300); do
        [[ $(curl -sf "$base/v1/jobs/$job" | jq -r .status) == succeeded ]] && break
        sleep 0.1
    done
    printf '%s: ' "$backend"
    wrk -t1 -c"$CONNECTIONS" -d"$DURATION" "$base/v1/jobs/$job" | grep -E "Requests/sec|Latency"  | tr -s ' ' | tr '\n' ' '
    echo
    stop_all
done
