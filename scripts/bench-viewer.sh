#!/usr/bin/env bash
# Time to load the viewer page of a finished job on a 100-frame scene: every request the
# page makes (HTML, scripts, job and scene JSON, scene and object points, grids, frames,
# masks), one after another over one connection, as curl sees them. The first load after
# indexing reads the scene's points from the cache indexing filled.
# Usage: scripts/bench-viewer.sh [path/to/grounder]   (default: target/release/grounder)
set -euo pipefail
BIN=${1:-target/release/grounder}
FRAMES=${FRAMES:-100}
DIR=$(mktemp -d)
trap 'kill $PID 2>/dev/null; wait $PID 2>/dev/null; rm -rf "$DIR"' EXIT
GROUNDER_LOG=warn "$BIN" demo --addr 127.0.0.1:0 --frames "$FRAMES" --data-dir "$DIR/demo" >"$DIR/log" 2>&1 &
PID=$!
for _ in $(seq 600); do grep -q "^serving on" "$DIR/log" && break; sleep 1; done
grep -q "^serving on" "$DIR/log" || { cat "$DIR/log"; exit 1; }
BASE=$(grep -m1 "^listening on" "$DIR/log" | awk '{print $3}')
JOB=$(grep -m1 "view: .*/v1/jobs/" "$DIR/log" | sed 's#.*/v1/jobs/##; s#/view##')
SCENE=$(curl -s "$BASE/v1/jobs/$JOB" | python3 -c 'import json,sys; print(json.load(sys.stdin)["scene_id"])')
urls() {
  echo "$BASE/v1/jobs/$JOB/view"
  for f in viewer.css common.js points3d.js job.js three.module.min.js OrbitControls.js; do echo "$BASE/v1/viewer/$f"; done
  echo "$BASE/v1/jobs/$JOB"; echo "$BASE/v1/scenes/$SCENE"
  echo "$BASE/v1/scenes/$SCENE/points.ply?voxel=0.05"; echo "$BASE/v1/jobs/$JOB/object.ply"
  curl -s "$BASE/v1/jobs/$JOB" | python3 -c '
import json, sys
j = json.load(sys.stdin); base, job, scene = sys.argv[1], j["id"], j["scene_id"]
t = {s["step"]: s for s in j["trace"]}
for g in t["stitching"]["outputs"]["grids"]: print(base + g["url"])
ids = [t["segmentation"]["outputs"]["image_id"]] + [v["image_id"] for v in t["projection"]["outputs"]["views"] if v["kept"]]
for i in ids: print(f"{base}/v1/scenes/{scene}/frames/{i}.jpg"); print(f"{base}/v1/jobs/{job}/masks/{i}.png")
' "$BASE"
}
mapfile -t U < <(urls)
for run in 1 2 3; do
  args=(); for u in "${U[@]}"; do args+=(-o /dev/null "$u"); done
  start=$(date +%s.%N)
  curl -s -w '%{http_code} %{size_download}\n' "${args[@]}" >"$DIR/codes"
  end=$(date +%s.%N)
  bad=$(grep -vc '^200 ' "$DIR/codes" || true)
  bytes=$(awk '{s+=$2} END {print s}' "$DIR/codes")
  printf 'load %d: %d requests, %d bytes, %s failed, %.0f ms\n' "$run" "${#U[@]}" "$bytes" "$bad" \
    "$(echo "($end - $start) * 1000" | bc)"
done
