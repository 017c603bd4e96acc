#!/usr/bin/env bash
# Schemathesis (PyPI) against the OpenAPI document that `btfrig serve` serves: every
# operation, generated valid and invalid requests, with the admin token (so requests reach
# the handlers, not only the auth layer). Fails on any 5xx and on any response the document
# does not describe (status code, content type, body schema).
#
# usage: tests/api/schemathesis.sh [PATH/TO/btfrig]
#   binary: the argument, else $BTFRIG_BIN, else target/release/btfrig
#   ST_MAX_EXAMPLES (default 40): generated test cases per operation and phase
#   ST_SEED (default 6): the random seed, so a failure can be replayed
#
# Installs schemathesis (pinned below) into the venv target/pydeps/schemathesis when it is
# missing or another version. Reports: target/api/ (JUnit XML, server log, failure cache:
# replay a failure with `ST_CACHE_DIR=target/api/cache target/pydeps/schemathesis/bin/st
# --config-file tests/api/schemathesis.toml replay ID`).
#
# State: before Schemathesis, tests/api/rig.py starts plan demo into dataset st-seed (run r1)
# and pauses it; tests/api/schemathesis.toml mixes those identifiers into the generated path
# parameters and plan names into bodies, so requests reach the handlers' logic. The generated
# requests may resume, pause, abort and start runs (and calibrations). None outlives the
# script: afterwards rig.py aborts every run that is not over and waits for it, then the server
# is stopped (SIGTERM, then SIGKILL after 10 s) and its temporary data directory removed. The
# event stream is read up to its first event (max-stream-events in the config).
set -euo pipefail

ST_VERSION=4.32.5
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
venv="$target/pydeps/schemathesis"
out="$target/api"
mkdir -p "$out"

# ---- schemathesis ----
have="$("$venv/bin/python" -c 'import importlib.metadata as m; print(m.version("schemathesis"))' 2>/dev/null || true)"
if [ "$have" != "$ST_VERSION" ]; then
    echo "# installing schemathesis==$ST_VERSION into $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "schemathesis==$ST_VERSION" >&2
fi

# ---- the server ----
bin="${1:-${BTFRIG_BIN:-$target/release/btfrig}}"
[ -x "$bin" ] || { echo "no btfrig binary at $bin (cargo build --release -p btfrig-cli)" >&2; exit 1; }
data="$(mktemp -d "${TMPDIR:-/tmp}/btfrig-st-data.XXXXXX")"
log="$out/server.log"
"$bin" serve --listen 127.0.0.1:0 --data "$data" --auth "$root/tests/api/auth.toml" >"$log" 2>&1 &
pid=$!
url=""
stop_server() {
    if kill -0 "$pid" 2>/dev/null; then
        kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$pid" 2>/dev/null || true
    fi
    wait "$pid" 2>/dev/null || true
}
cleanup() {
    stop_server
    rm -rf "$data"
}
trap cleanup EXIT

for _ in $(seq 300); do
    url="$(sed -n '1s/^listening on \(http:\/\/[^ ]*\).*/\1/p' "$log" 2>/dev/null || true)"
    [ -n "$url" ] && break
    kill -0 "$pid" 2>/dev/null || { echo "the server exited:" >&2; cat "$log" >&2; exit 1; }
    sleep 0.1
done
[ -n "$url" ] || { echo "the server printed no 'listening on' line in 30 s:" >&2; cat "$log" >&2; exit 1; }
url="${url%/}"
echo "# server at $url (log $log)" >&2

# ---- a known state: run r1 of plan demo, paused after a few captures, dataset st-seed ----
python3 "$here/rig.py" seed "$url"

# ---- the run ----
status=0
ST_CACHE_DIR="$out/cache" "$venv/bin/st" --config-file "$here/schemathesis.toml" --no-color run "$url/api/v1/openapi.json" \
    --header "Authorization: Bearer admin-token" \
    --checks not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance \
    --max-examples "${ST_MAX_EXAMPLES:-40}" \
    --seed "${ST_SEED:-6}" \
    --request-timeout 20 \
    --workers 2 \
    --generation-database none \
    --report junit --report-junit-path "$out/schemathesis.junit.xml" || status=$?

# ---- leave no run going ----
python3 "$here/rig.py" cleanup "$url" || status=1
stop_server
if grep -qi "panick" "$log"; then
    echo "the server panicked:" >&2
    grep -i -A3 "panick" "$log" >&2
    status=1
fi
exit "$status"
