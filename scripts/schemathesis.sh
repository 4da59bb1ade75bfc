#!/usr/bin/env bash
# Property-based API conformance: schemathesis (installed into .venv-schemathesis with pip
# when missing) against a live `grounder serve` (test pipeline, no detector), checking
# for server errors and for responses that break openapi.yaml (status codes, content
# types, headers, bodies). Exits non-zero on any failure.
#
# Every phase runs: examples, coverage, fuzzing and stateful (links between operations),
# bounded by MAX_TIME and MAX_EXAMPLES per operation. `positive_data_acceptance` is not
# checked: some refusals follow rules a schema cannot state (either `query` or `queries`,
# an Idempotency-Key reused with another body, a Last-Event-ID this stream never sent).
# The upload operations' binary bodies make hypothesis filter many examples; its
# filter_too_much health check is suppressed so that they are tested anyway.
# One worker (`-w 1`): with two, CPython 3.11's `ast.parse` (which hypothesis calls while
# describing a strategy) can fail across threads with "SystemError: AST constructor
# recursion depth mismatch", failing a run in which every case passed. The version is
# pinned to one that passed here, so that a new release cannot change the checks unseen.
#
# Environment (defaults in brackets): GROUNDER_BIN [target/debug/grounder, built when
# missing], PORT [18391], MAX_TIME [120] seconds of generated requests, MAX_EXAMPLES [40].
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
PORT=${PORT:-18391}
MAX_TIME=${MAX_TIME:-120}
MAX_EXAMPLES=${MAX_EXAMPLES:-40}
VENV="$ROOT/.venv-schemathesis"
if [[ ! -x "$VENV/bin/schemathesis" ]]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q --disable-pip-version-check "schemathesis==4.32.5"
fi
if [[ -z "${GROUNDER_BIN:-}" ]]; then
    (cd "$ROOT" && cargo build -q --bin grounder)
    GROUNDER_BIN=${CARGO_TARGET_DIR:-$ROOT/target}/debug/grounder
fi
WORK=$(mktemp -d)
SERVER=""
cleanup() {
    [[ -n "$SERVER" ]] && kill "$SERVER" 2>/dev/null && wait "$SERVER" 2>/dev/null
    rm -rf "$WORK"
}
trap cleanup EXIT
GROUNDER_PIPELINE=test:delay_ms=50 GROUNDER_DETECTOR=none \
    "$GROUNDER_BIN" serve --addr "127.0.0.1:$PORT" --data-dir "$WORK/data" >"$WORK/serve.log" 2>&1 &
SERVER=$!
for _ in $(seq 200); do
    grep -q "listening on" "$WORK/serve.log" && break
    sleep 0.1
done
BASE="http://127.0.0.1:$PORT"
"$VENV/bin/schemathesis" run "$BASE/openapi.yaml" --url "$BASE" -w 1 --max-time "$MAX_TIME" \
    --max-examples "$MAX_EXAMPLES" --phases examples,coverage,fuzzing,stateful \
    --suppress-health-check=filter_too_much \
    --checks not_a_server_error,status_code_conformance,content_type_conformance,response_headers_conformance,response_schema_conformance,negative_data_rejection
