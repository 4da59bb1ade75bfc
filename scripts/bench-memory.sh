#!/usr/bin/env bash
# Memory under concurrency (issue #26): one synthetic ScanNet-size scene (100 frames,
# 1296x968 colour, 640x480 depth), `grounder serve` with GROUNDER_WORKERS=8, the oracle
# detector and `grounder oracle-vlm` as the VLM; then bursts of 1, 4 and 8 concurrent jobs.
# For each burst: the process's peak resident memory during the burst (VmHWM, reset before
# the burst through /proc/PID/clear_refs, and the highest VmRSS sampled every 50 ms; the
# larger of the two is reported), the resident memory WAIT seconds after the burst ended,
# the jobs' mean time (created to finished, server clock), their mean non-VLM time (the
# pipeline's own `non_vlm_ms`) and the server's CPU time per job (user + system, which a
# busy shared machine disturbs less than wall time). Needs jq, curl and python3.
#
# Environment (defaults in brackets): GROUNDER_BIN [built with cargo build --release],
# FRAMES [100], COLOR_SIZE [1296x968], DEPTH_SIZE [640x480], BURSTS ["1 4 8"],
# WAIT [60; seconds after each burst before reading the resident size again],
# SETTLE [20; seconds after indexing before the idle reading: the scene's points export is
# computed in the background once the scene is ready],
# WORKERS [8], PORT [18091], EXTRA_ENV [unset; e.g. "GROUNDER_MAX_MEMORY_MB=500"],
# DATA [target/bench-memory/data; the scene is generated once and kept].
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FRAMES=${FRAMES:-100}
COLOR_SIZE=${COLOR_SIZE:-1296x968}
DEPTH_SIZE=${DEPTH_SIZE:-640x480}
BURSTS=${BURSTS:-1 4 8}
WAIT=${WAIT:-60}
SETTLE=${SETTLE:-20}
WORKERS=${WORKERS:-8}
PORT=${PORT:-18091}
DATA=${DATA:-$ROOT/target/bench-memory/data}
for tool in python3 bc; do
    command -v "$tool" >/dev/null || { echo "error: $tool is required" >&2; exit 1; }
done
source "$ROOT/scripts/bench-common.sh"

SYNTH_ARGS="--seed 11 --frames $FRAMES --color-size $COLOR_SIZE --depth-size $DEPTH_SIZE --noise realistic"
if [[ ! -f "$DATA/ds/queries.jsonl" || "$(cat "$DATA/synth_args" 2>/dev/null)" != "$SYNTH_ARGS" ]]; then
    rm -rf "$DATA"
    mkdir -p "$DATA"
    # shellcheck disable=SC2086 # word splitting of the argument list is intended
    "$GROUNDER_BIN" synth --out "$DATA/scenes" $SYNTH_ARGS --dataset "$DATA/ds" >/dev/null
    echo "$SYNTH_ARGS" >"$DATA/synth_args"
fi
SCENE_NAME=$(ls "$DATA/scenes" | head -n1)
tar -C "$DATA/scenes" -cf "$WORK/scene.tar" "$SCENE_NAME"

# The oracle VLM on its own port.
"$GROUNDER_BIN" oracle-vlm --addr 127.0.0.1:0 --dataset "$DATA/ds" --scenes "$DATA/scenes" \
    >"$WORK/oracle.out" 2>"$WORK/oracle.err" &
ORACLE=$!
trap 'kill $ORACLE 2>/dev/null; cleanup' EXIT
for _ in $(seq 300); do
    ORACLE_URL=$(sed -n 's/^listening on //p' "$WORK/oracle.out" | head -n1)
    [[ -n "$ORACLE_URL" ]] && break
    sleep 0.1
done
[[ -n "$ORACLE_URL" ]] || { echo "error: oracle-vlm did not start" >&2; cat "$WORK/oracle.err" >&2; exit 1; }

# shellcheck disable=SC2086 # EXTRA_ENV is a list of VAR=value words
start_serve GROUNDER_WORKERS="$WORKERS" GROUNDER_DETECTOR=oracle GROUNDER_VLM_BASE_URL="$ORACLE_URL/v1" \
    GROUNDER_VLM_MODEL=grounder-oracle GROUNDER_VLM_API_KEY=x ${EXTRA_ENV:-}

rss() { awk '/^VmRSS/ {print int($2 / 1024)}' "/proc/$SERVER/status"; }
hwm() { awk '/^VmHWM/ {print int($2 / 1024)}' "/proc/$SERVER/status"; }
# CPU time of the server so far, in clock ticks (utime + stime; the name may hold spaces).
ticks() { sed 's/.*) //' "/proc/$SERVER/stat" | awk '{print $12 + $13}'; }
TCK=$(getconf CLK_TCK)

SCENE=$(curl -sf --data-binary @"$WORK/scene.tar" -H 'Content-Type: application/x-tar' "$BASE/v1/scenes" | jq -r .id)
while :; do
    STATUS=$(curl -sf "$BASE/v1/scenes/$SCENE" | jq -r .status)
    [[ "$STATUS" == ready || "$STATUS" == failed ]] && break
    sleep 0.2
done
[[ "$STATUS" == ready ]] || { echo "error: indexing failed" >&2; curl -s "$BASE/v1/scenes/$SCENE" >&2; exit 1; }
sleep "$SETTLE"
INDEX_PEAK=$(hwm)
IDLE=$(rss)

mapfile -t QUERIES < <(jq -r --arg s "$SCENE_NAME" 'select(.scene_id == $s) | .text' "$DATA/ds/queries.jsonl")
echo "scene: $SCENE_NAME, $FRAMES frames ($COLOR_SIZE colour, $DEPTH_SIZE depth), $WORKERS workers"
echo "peak during upload and indexing: $INDEX_PEAK MB; idle ${SETTLE} s after indexing: $IDLE MB"
echo "| concurrent jobs | peak RSS (MB) | RSS ${WAIT} s after (MB) | mean job time (s) | mean non-VLM time (s) | CPU per job (s) | succeeded |"
echo "|---|---|---|---|---|---|---|"
OFFSET=0
for n in $BURSTS; do
    # Distinct queries per burst (cycling through the scene's queries).
    BODY=$(for i in $(seq 0 $((n - 1))); do echo "${QUERIES[$(((OFFSET + i) % ${#QUERIES[@]}))]}"; done |
        jq -R . | jq -s --arg s "$SCENE" '{scene_id: $s, queries: .}')
    OFFSET=$((OFFSET + n))
    echo 5 >"/proc/$SERVER/clear_refs" 2>/dev/null || true
    PEAK=$(rss)
    T0=$(ticks)
    IDS=$(curl -sf -H 'Content-Type: application/json' -d "$BODY" "$BASE/v1/jobs" | jq -r '.jobs[].id')
    while :; do
        r=$(rss)
        ((r > PEAK)) && PEAK=$r
        LEFT=0
        for id in $IDS; do
            s=$(curl -sf "$BASE/v1/jobs/$id" | jq -r .status)
            [[ "$s" == queued || "$s" == running ]] && LEFT=$((LEFT + 1))
        done
        ((LEFT == 0)) && break
        sleep 0.05
    done
    h=$(hwm)
    ((h > PEAK)) && PEAK=$h
    CPU=$(echo "scale=2; ($(ticks) - $T0) / $TCK / $n" | bc)
    : >"$WORK/jobs.jsonl"
    for id in $IDS; do curl -sf "$BASE/v1/jobs/$id" | jq -c '{status, created_at, finished_at, non_vlm_ms: .result.stats.non_vlm_ms}' >>"$WORK/jobs.jsonl"; done
    STATS=$(python3 - "$WORK/jobs.jsonl" <<'EOF'
import json, sys
from datetime import datetime
def t(s):
    return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
rows = [json.loads(l) for l in open(sys.argv[1])]
d = [t(r["finished_at"]) - t(r["created_at"]) for r in rows]
ok = sum(r["status"] == "succeeded" for r in rows)
nv = [r["non_vlm_ms"] / 1000 for r in rows if r.get("non_vlm_ms") is not None]
nvm = f"{sum(nv) / len(nv):.2f}" if nv else "-"
print(f"{sum(d) / len(d):.2f} {nvm} {ok}/{len(rows)}")
EOF
)
    read -r MEAN NONVLM OK <<<"$STATS"
    sleep "$WAIT"
    echo "| $n | $PEAK | $(rss) | $MEAN | $NONVLM | $CPU | $OK |"
done
