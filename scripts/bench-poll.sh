#!/usr/bin/env bash
# Polling throughput from a second process: `grounder serve` (release) with the test
# pipeline, one small synthetic scene, one finished job, then `wrk` polling
# GET /v1/jobs/{id} with 32 keep-alive connections, first plainly (200 with the job), then
# with `If-None-Match: <its ETag>` (304, no body). Needs wrk (Debian package `wrk`) and jq.
#
# Environment (defaults in brackets): GROUNDER_BIN [built with cargo build --release],
# PORT [18080], DURATION [10s], CONNECTIONS [32], THREADS [1].
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
PORT=${PORT:-18080}
DURATION=${DURATION:-10s}
CONNECTIONS=${CONNECTIONS:-32}
THREADS=${THREADS:-1}
command -v wrk >/dev/null || { echo "error: wrk is required" >&2; exit 1; }
source "$ROOT/scripts/bench-common.sh"

start_serve GROUNDER_PIPELINE=test:delay_ms=1 GROUNDER_DETECTOR=none

"$GROUNDER_BIN" synth --out "$WORK/synth" --frames 4 --color-size 320x240 --depth-size 160x120 --tar >/dev/null
SCENE=$(curl -sf --data-binary @"$WORK/synth/scene_synth_0000.tar" -H 'Content-Type: application/x-tar' "$BASE/v1/scenes" | jq -r .id)
JOB=$(curl -sf -H 'Content-Type: application/json' -d "{\"scene_id\":\"$SCENE\",\"query\":\"the chair\"}" "$BASE/v1/jobs" | jq -r .id)
for _ in $(seq 100); do
    [[ $(curl -sf "$BASE/v1/jobs/$JOB" | jq -r .status) == succeeded ]] && break
    sleep 0.1
done
ETAG=$(curl -sfD - -o /dev/null "$BASE/v1/jobs/$JOB" | tr -d '\r' | sed -n 's/^etag: //Ip')
[[ $(curl -s -o /dev/null -w '%{http_code}' -H "If-None-Match: $ETAG" "$BASE/v1/jobs/$JOB") == 304 ]] \
    || { echo "error: If-None-Match did not give 304" >&2; exit 1; }
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "== plain polling (200 + body)"
wrk -t"$THREADS" -c"$CONNECTIONS" -d"$DURATION" "$BASE/v1/jobs/$JOB"
echo "== conditional polling (If-None-Match: $ETAG -> 304)"
wrk -t"$THREADS" -c"$CONNECTIONS" -d"$DURATION" -H "If-None-Match: $ETAG" "$BASE/v1/jobs/$JOB"
