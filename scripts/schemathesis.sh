#!/usr/bin/env bash
# Property-based API conformance: schemathesis (installed into .venv-schemathesis with pip
# when missing) against a live `grounder serve` (test pipeline, no detector), checking
# for server errors and for responses that break openapi.yaml (status codes, content
# types, headers, bodies). Exits non-zero on any failure.
#
# Environment (defaults in brackets): GROUNDER_BIN [target/debug/grounder, built when
# missing], PORT [18391], MAX_TIME [60] seconds of generated requests.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
PORT=${PORT:-18391}
MAX_TIME=${MAX_TIME:-60}
VENV="$ROOT/.venv-schemathesis"
if [[ ! -x "$VENV/bin/schemathesis" ]]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q schemathesis
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
"$VENV/bin/schemathesis" run "$BASE/openapi.yaml" --url "$BASE" -w 2 --max-time "$MAX_TIME" \
    --checks not_a_server_error,status_code_conformance,content_type_conformance,response_headers_conformance,response_schema_conformance
