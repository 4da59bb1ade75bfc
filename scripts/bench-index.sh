#!/usr/bin/env bash
# Scene indexing through the service: `grounder serve` (release) with the CenterNet
# detector, one synthetic ScanNet-size scene uploaded as a tar, then the time from the
# upload's 201 until the scene reads `ready` (colour decode + detection of every usable
# frame + detections written to SQLite). Needs jq and curl.
#
# Environment (defaults in brackets): GROUNDER_BIN [built with cargo build --release],
# FRAMES [100], COLOR_SIZE [1296x968], DEPTH_SIZE [640x480], PORT [18081].
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FRAMES=${FRAMES:-100}
COLOR_SIZE=${COLOR_SIZE:-1296x968}
DEPTH_SIZE=${DEPTH_SIZE:-640x480}
PORT=${PORT:-18081}
source "$ROOT/scripts/bench-common.sh"
[[ -n "${ORT_DYLIB_PATH:-}" ]] || export ORT_DYLIB_PATH="$ROOT/.ort/libonnxruntime.so.1.31.1"

"$GROUNDER_BIN" synth --out "$WORK/synth" --seed 3 --frames "$FRAMES" --color-size "$COLOR_SIZE" \
    --depth-size "$DEPTH_SIZE" --noise realistic --tar >/dev/null
# No VLM is asked while indexing; a key only satisfies the readiness check.
start_serve GROUNDER_DETECTOR=centernet GROUNDER_MODEL_DIR="$ROOT/models" GROUNDER_VLM_API_KEY=unused
[[ $(curl -s -o /dev/null -w '%{http_code}' "$BASE/readyz") == 200 ]] || { echo "error: not ready:" >&2; curl -s "$BASE/readyz" >&2; exit 1; }

TAR=$(ls "$WORK"/synth/*.tar | head -n1)
T0=$(date +%s.%N)
SCENE=$(curl -sf --data-binary @"$TAR" -H 'Content-Type: application/x-tar' "$BASE/v1/scenes" | jq -r .id)
T1=$(date +%s.%N)
while :; do
    STATUS=$(curl -sf "$BASE/v1/scenes/$SCENE" | jq -r .status)
    [[ "$STATUS" == ready || "$STATUS" == failed ]] && break
    sleep 0.05
done
T2=$(date +%s.%N)
[[ "$STATUS" == ready ]] || { echo "error: indexing failed:" >&2; curl -s "$BASE/v1/scenes/$SCENE" >&2; exit 1; }
FR=$(curl -sf "$BASE/v1/scenes/$SCENE" | jq -r .frames)
# The server's CPU time so far (user + system, upload included): less disturbed than wall
# time by other work on a shared machine.
CPU=$(sed 's/.*) //' "/proc/$SERVER/stat" | awk -v t="$(getconf CLK_TCK)" '{printf "%.1f", ($12 + $13) / t}')
echo "frames: $FR (${COLOR_SIZE} colour), upload to 201: $(echo "$T1 - $T0" | bc) s, 201 to ready: $(echo "$T2 - $T1" | bc) s, server CPU: $CPU s"
