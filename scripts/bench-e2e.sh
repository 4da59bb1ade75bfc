#!/usr/bin/env bash
# End-to-end benchmark: realistic-noise synthetic scenes, `grounder serve` with the oracle
# detector (or DETECTOR), `grounder oracle-vlm` as the VLM, `grounder eval` over every query.
# Configurations: VLM error rate 0 / depth segmenter, error 0.2 / depth, error 0 / box
# segmenter (ablation). Writes one report per scene family and split; the data stays under
# $BENCH_DIR.
#
# Scene families and the split (docs/benchmark-e2e.md): FAMILY picks the generator
# (`grounder synth --family rooms|props`), SPLIT picks fixed seeds. Tuning looks at dev
# seeds only; published figures come from test seeds, which no tuning decision looked at.
#   rooms: dev 100..  test 300..     props: dev 500..  test 700..
# (SCENES scenes from the first seed of the split.)
#
# Environment (defaults in brackets): FAMILY [rooms], SPLIT [dev], SCENES [5],
# BENCH_DIR [target/bench-e2e/$FAMILY-$SPLIT], FRAMES [60], COLOR_SIZE [1296x968],
# DEPTH_SIZE [640x480], NOISE [realistic], JOBS [2], WORKERS [2],
# DETECTOR [oracle; e.g. centernet for the default detector],
# GROUNDER_BIN [built with cargo build --release],
# REPORT [docs/benchmark-e2e-$FAMILY-$SPLIT.md, or ...-$DETECTOR.md for another detector],
# REPORT_ONLY [unset; 1 = only rewrite the report from the runs already in $BENCH_DIR],
# ONLY [unset; e.g. "0 depth:edges=on" = run and report that one configuration alone;
# set REPORT elsewhere then], SEED [unset; a first seed outside the split, for experiments:
# the report then says "custom seeds", not dev or test].
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FAMILY=${FAMILY:-rooms}
SPLIT=${SPLIT:-dev}
DETECTOR=${DETECTOR:-oracle}
case "$FAMILY:$SPLIT" in
    rooms:dev) SPLIT_SEED=100 ;;
    rooms:test) SPLIT_SEED=300 ;;
    props:dev) SPLIT_SEED=500 ;;
    props:test) SPLIT_SEED=700 ;;
    *) echo "error: FAMILY must be rooms or props and SPLIT dev or test (got $FAMILY, $SPLIT)" >&2; exit 1 ;;
esac
SCENES=${SCENES:-5}
if [[ -n "${SEED:-}" ]]; then
    SPLIT_NAME="custom seeds"
    TAG=$FAMILY-seed$SEED
else
    SEED=$SPLIT_SEED
    SPLIT_NAME=$SPLIT
    TAG=$FAMILY-$SPLIT
fi
(( SCENES >= 1 && SCENES <= 200 )) || { echo "error: SCENES must be 1..200 (the splits are 200 seeds apart)" >&2; exit 1; }
if [[ "$DETECTOR" != oracle ]]; then TAG=$TAG-$DETECTOR; fi
BENCH_DIR=${BENCH_DIR:-$ROOT/target/bench-e2e/$TAG}
FRAMES=${FRAMES:-60}
COLOR_SIZE=${COLOR_SIZE:-1296x968}
DEPTH_SIZE=${DEPTH_SIZE:-640x480}
NOISE=${NOISE:-realistic}
JOBS=${JOBS:-2}
WORKERS=${WORKERS:-2}
REPORT=${REPORT:-$ROOT/docs/benchmark-e2e-$TAG.md}

command -v jq >/dev/null || { echo "error: jq is required" >&2; exit 1; }

if [[ -z "${GROUNDER_BIN:-}" ]]; then
    (cd "$ROOT" && cargo build --release --bin grounder)
    GROUNDER_BIN=${CARGO_TARGET_DIR:-$ROOT/target}/release/grounder
fi
BIN=$GROUNDER_BIN

PIDS=()
cleanup() {
    for p in "${PIDS[@]:-}"; do
        if [[ -n "$p" ]]; then
            kill "$p" 2>/dev/null || true
            wait "$p" 2>/dev/null || true
        fi
    done
    PIDS=()
}
trap cleanup EXIT

# start_server NAME LOGDIR ARGS... : runs the binary in the background, waits for its
# "listening on http://ADDR" line and sets URL.
start_server() {
    local name=$1 dir=$2
    shift 2
    # Created here: the background process opens them only once it runs, and reading
    # before that would end the script (set -e).
    : >"$dir/$name.out"
    : >"$dir/$name.err"
    "$BIN" "$@" >"$dir/$name.out" 2>"$dir/$name.err" &
    PIDS+=($!)
    for _ in $(seq 1 300); do
        URL=$(sed -n 's/^listening on //p' "$dir/$name.out" | head -n1)
        [[ -n "$URL" ]] && return 0
        kill -0 "${PIDS[-1]}" 2>/dev/null || { cat "$dir/$name.err" >&2; echo "error: $name exited" >&2; exit 1; }
        sleep 0.2
    done
    echo "error: $name did not report its address" >&2
    exit 1
}

DATA=$BENCH_DIR/data
mkdir -p "$BENCH_DIR"
SYNTH_ARGS="--family $FAMILY --seed $SEED --scenes $SCENES --frames $FRAMES --color-size $COLOR_SIZE --depth-size $DEPTH_SIZE --noise $NOISE"
# Regenerate when the data is missing or was made with other settings.
if [[ ! -f "$DATA/ds/queries.jsonl" || "$(cat "$DATA/synth_args" 2>/dev/null)" != "$SYNTH_ARGS" ]]; then
    rm -rf "$DATA"
    t0=$(date +%s)
    # shellcheck disable=SC2086 # word splitting of the argument list is intended
    "$BIN" synth --out "$DATA/scenes" $SYNTH_ARGS --dataset "$DATA/ds"
    echo "$SYNTH_ARGS" >"$DATA/synth_args"
    echo "generated $SCENES scenes in $(( $(date +%s) - t0 )) s"
fi
NQ=$(wc -l <"$DATA/ds/queries.jsonl")

CONFIGS=("0 depth" "0.2 depth" "0 box")
[[ -n "${ONLY:-}" ]] && CONFIGS=("$ONLY")
for c in "${CONFIGS[@]}"; do
    [[ "${REPORT_ONLY:-}" == 1 ]] && break
    read -r err seg <<<"$c"
    run=$BENCH_DIR/run-err$err-$seg
    rm -rf "$run"
    mkdir -p "$run"
    start_server oracle "$run" oracle-vlm --addr 127.0.0.1:0 --dataset "$DATA/ds" --scenes "$DATA/scenes" \
        --seed "$SEED" --error-rate "$err"
    oracle=$URL
    GROUNDER_DETECTOR=$DETECTOR GROUNDER_SEGMENTER=$seg GROUNDER_VLM_BASE_URL=$oracle/v1 \
        GROUNDER_VLM_MODEL=grounder-oracle GROUNDER_VLM_API_KEY=x GROUNDER_WORKERS=$WORKERS \
        start_server serve "$run" serve --addr 127.0.0.1:0 --data-dir "$run/service"
    t0=$(date +%s)
    "$BIN" eval --dataset "$DATA/ds" --scenes "$DATA/scenes" --server "$URL" --jobs "$JOBS" \
        --out "$run/report" 2>"$run/eval.err"
    echo "$(( $(date +%s) - t0 ))" >"$run/wall_s"
    cleanup
done

pct() { jq -r "$1 | if . == null then \"–\" else (. * 1000 | round / 10 | tostring) + \" %\" end" "$2"; }
num() { jq -r "$1 | if . == null then \"–\" else (. * 100 | round / 100 | tostring) end" "$2"; }
rate() { jq -r "$1 | if . == null then \"–\" else ((.rate * 1000 | round / 10 | tostring) + \" % (\" + (.k|tostring) + \"/\" + (.n|tostring) + \")\") end" "$2"; }

mkdir -p "$(dirname "$REPORT")"
{
    echo "# End-to-end benchmark: $FAMILY family, $SPLIT_NAME seeds (oracle VLM, $DETECTOR detector)"
    echo
    echo "Generated by \`scripts/bench-e2e.sh\` on $(date -u +%Y-%m-%d) at commit $(cd "$ROOT" && git rev-parse --short HEAD)."
    echo
    echo "- Data: $SCENES synthetic scenes of the $FAMILY family, $SPLIT_NAME seeds $SEED..$(( SEED + SCENES - 1 )) (\`grounder synth --family $FAMILY --seed $SEED --scenes $SCENES --frames $FRAMES"
    echo "  --color-size $COLOR_SIZE --depth-size $DEPTH_SIZE --noise $NOISE\`), $NQ queries."
    echo "- Service: \`grounder serve\` with GROUNDER_DETECTOR=$DETECTOR (oracle = ground-truth 2D boxes),"
    echo "  $WORKERS workers; VLM: \`grounder oracle-vlm\` (answers from ground truth, wrong with"
    echo "  probability = error rate); \`grounder eval --jobs $JOBS\` over HTTP."
    echo "- The oracle removes the VLM's and the detector's judgement; what is measured is the"
    echo "  rest of the pipeline (prompts, parsing, pre-selection, stitching, feedback,"
    echo "  segmentation, multi-view projection) on noisy depth and poses."
    echo
    echo "## Accuracy (ScanRefer metric: 3D IoU with the target box)"
    echo
    echo "| VLM error rate | segmenter | n | Acc@0.25 | Acc@0.5 | unique @0.25 | unique @0.5 | multiple @0.25 | multiple @0.5 | Nr3D-style |"
    echo "|---|---|---|---|---|---|---|---|---|---|"
    for c in "${CONFIGS[@]}"; do
        read -r err seg <<<"$c"
        s=$BENCH_DIR/run-err$err-$seg/report/summary.json
        echo "| $err | $seg | $(jq .n_queries "$s") | $(pct .scanrefer.overall.acc_025 "$s") | $(pct .scanrefer.overall.acc_05 "$s") | $(pct .scanrefer.unique.acc_025 "$s") | $(pct .scanrefer.unique.acc_05 "$s") | $(pct .scanrefer.multiple.acc_025 "$s") | $(pct .scanrefer.multiple.acc_05 "$s") | $(pct .nr3d.overall.rate "$s") |"
    done
    echo
    echo "95 % intervals of the overall accuracies (bootstrap over the target objects, each with"
    echo "all its queries; \`grounder compare\` gives the interval of a difference between two runs):"
    echo
    for c in "${CONFIGS[@]}"; do
        read -r err seg <<<"$c"
        s=$BENCH_DIR/run-err$err-$seg/report/summary.json
        echo "- err $err, $seg: $(jq -r '.scanrefer.overall_interval | if . == null then "–" else "Acc@0.25 \(.acc_025.lo * 1000 | round / 10)–\(.acc_025.hi * 1000 | round / 10) %, Acc@0.5 \(.acc_05.lo * 1000 | round / 10)–\(.acc_05.hi * 1000 | round / 10) % (\(.objects) objects)" end' "$s")"
    done
    echo
    echo "## Where the first configuration loses (per target class)"
    echo
    s=$BENCH_DIR/run-err${CONFIGS[0]// /-}/report/summary.json
    if [[ $(jq '.by_class // [] | length' "$s") -gt 0 ]]; then
        echo "The 12 classes that lose the most queries (\`by_class\` in \`summary.json\` has them all):"
        echo
        echo "| class | n | Acc@0.25 | Acc@0.5 | mean IoU |"
        echo "|---|---|---|---|---|"
        jq -r '.by_class[:12][] | "| \(.label | gsub("\\|"; "\\|")) | \(.n) | \(.acc_025 * 1000 | round / 10) % | \(.acc_05 * 1000 | round / 10) % | \(.mean_iou * 100 | round / 100) |"' "$s"
    else
        echo "Not in this run's summary (written by an older \`grounder eval\`)."
    fi
    echo
    echo "## Per-stage success rates"
    echo
    echo "| stage | $(for c in "${CONFIGS[@]}"; do read -r e g <<<"$c"; printf 'err %s, %s | ' "$e" "$g"; done)"
    echo "|---|$(for _ in "${CONFIGS[@]}"; do printf -- '---|'; done)"
    for st in preselection_contains_target image_choice_correct detection_present instance_choice_correct mask_iou_ge_05 box_iou_ge_05; do
        row="| $st |"
        for c in "${CONFIGS[@]}"; do
            read -r err seg <<<"$c"
            row+=" $(rate ".stages.$st" "$BENCH_DIR/run-err$err-$seg/report/summary.json") |"
        done
        echo "$row"
    done
    row="| mean mask IoU |"
    for c in "${CONFIGS[@]}"; do
        read -r err seg <<<"$c"
        row+=" $(num .stages.mask_iou_mean "$BENCH_DIR/run-err$err-$seg/report/summary.json") |"
    done
    echo "$row"
    echo
    echo "## First failing stage (queries)"
    echo
    for c in "${CONFIGS[@]}"; do
        read -r err seg <<<"$c"
        echo "- err $err, $seg: $(jq -r '.failure_stages | to_entries | map("\(.key) \(.value)") | join(", ") | if . == "" then "none" else . end' "$BENCH_DIR/run-err$err-$seg/report/summary.json")"
    done
    echo
    echo "## Cost and latency"
    echo
    echo "| VLM error rate | segmenter | mean VLM calls | mean tokens | latency p50 / p90 / p99 (ms) | wall time (s) |"
    echo "|---|---|---|---|---|---|"
    for c in "${CONFIGS[@]}"; do
        read -r err seg <<<"$c"
        run=$BENCH_DIR/run-err$err-$seg
        s=$run/report/summary.json
        echo "| $err | $seg | $(num .mean_vlm_calls "$s") | $(jq -r '.mean_tokens | round' "$s") | $(jq -r '[.latency_ms.p50, .latency_ms.p90, .latency_ms.p99] | map(round | tostring) | join(" / ")' "$s") | $(cat "$run/wall_s") |"
    done
    echo
    echo "Latency is per job (submit to finished, oracle VLM answers in about a millisecond), with"
    echo "$JOBS concurrent jobs on a shared 2-core machine; scene import is not included."
} >"$REPORT"
echo "wrote $REPORT"
