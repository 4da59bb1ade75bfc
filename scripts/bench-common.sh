# Shared by the bench-*.sh scripts (sourced, not run). Needs ROOT and PORT set.
# Provides WORK (a temporary folder removed on exit), start_serve ENV... and BASE.

for tool in jq curl; do
    command -v "$tool" >/dev/null || { echo "error: $tool is required" >&2; exit 1; }
done
if [[ -z "${GROUNDER_BIN:-}" ]]; then
    (cd "$ROOT" && cargo build --release --bin grounder)
    GROUNDER_BIN=${CARGO_TARGET_DIR:-$ROOT/target}/release/grounder
fi

WORK=$(mktemp -d)
SERVER=""
cleanup() {
    [[ -n "$SERVER" ]] && kill "$SERVER" 2>/dev/null && wait "$SERVER" 2>/dev/null
    rm -rf "$WORK"
}
trap cleanup EXIT

# start_serve [VAR=value ...]: `grounder serve` on PORT with a fresh data dir under WORK and
# the given environment; returns once it prints its address (exits the script if it dies).
start_serve() {
    env "$@" "$GROUNDER_BIN" serve --addr "127.0.0.1:$PORT" --data-dir "$WORK/data" >"$WORK/serve.log" 2>&1 &
    SERVER=$!
    BASE="http://127.0.0.1:$PORT"
    for _ in $(seq 200); do
        grep -q "listening on" "$WORK/serve.log" && return 0
        sleep 0.1
    done
    echo "error: the server did not start:" >&2
    cat "$WORK/serve.log" >&2
    exit 1
}
