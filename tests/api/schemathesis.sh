#!/usr/bin/env bash
# Schemathesis (PyPI) against the OpenAPI document that `btfrig serve` serves, with all four
# phases — examples, coverage, fuzzing and stateful (chains along the document's links, e.g.
# POST /runs -> GET /runs/{id} -> pause / resume / abort) — and every check, with the admin
# token (so requests reach the handlers, not only the auth layer), while a run is going.
# Fails on any 5xx, on any response the document does not describe (status code, content
# type, headers, body schema), on valid requests refused and invalid ones accepted, and when
# fewer than ST_MIN_CASES cases ran or a phase did not run. It prints the summary
# line `# schemathesis: cases=N failures=F errors=E phases=...` (tests/schemathesis.rs reads it).
#
# usage: tests/api/schemathesis.sh [PATH/TO/btfrig]
#   binary: the argument, else $BTFRIG_BIN, else target/release/btfrig
#   ST_MAX_EXAMPLES (default 100): generated test cases per operation in the fuzzing phase
#     (the coverage phase makes every case the schema defines, whatever this says)
#   ST_MIN_CASES (default 1800): fewer cases run is a failure
#   ST_SEED (default 6): the random seed, so a failure can be replayed
#
# Needs the venv target/pydeps/schemathesis that tests/install-deps.sh builds from
# tests/requirements/schemathesis.txt (schemathesis and every dependency, pinned with hashes;
# `.ci/run`, the README's test command, runs that script first); fails naming it when the venv
# is missing or holds another version. Reports: target/api/ (JUnit XML, the JSON run report,
# the server log, a failure cache: replay a failure with `ST_CACHE_DIR=target/api/cache
# target/pydeps/schemathesis/bin/st --config-file tests/api/schemathesis.toml replay ID`).
#
# State: before Schemathesis, tests/api/rig.py starts tests/api/long-run.toml (6561 cheap
# captures) into dataset st-seed (run r1) and checks it is running; tests/api/schemathesis.toml
# mixes those identifiers into the generated path parameters and plan names into bodies, so
# requests reach the handlers' logic. The generated requests may pause, resume, abort and start
# runs (and calibrations). None outlives the script: afterwards rig.py aborts every run that is
# not over and waits for it, then the server is stopped (SIGTERM, then SIGKILL after 10 s) and
# its temporary data directory removed. The event stream is read up to its first event
# (max-stream-events in the config).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
venv="$target/pydeps/schemathesis"
out="$target/api"
mkdir -p "$out"

# ---- schemathesis ----
req="$root/tests/requirements/schemathesis.txt"
want="$(sed -n 's/^schemathesis==\([^ ]*\).*/\1/p' "$req")"
have="$("$venv/bin/python" -c 'import importlib.metadata as m; print(m.version("schemathesis"))' 2>/dev/null || true)"
if [ "$have" != "$want" ]; then
    echo "schemathesis $want (tests/requirements/schemathesis.txt) is not in $venv (found: '${have:-none}'): run bash tests/install-deps.sh" >&2
    exit 1
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

# ---- a known state: run r1 of tests/api/long-run.toml going, dataset st-seed ----
python3 "$here/rig.py" seed "$url"

# ---- the run ----
status=0
rm -f "$out/schemathesis.json"
ST_CACHE_DIR="$out/cache" "$venv/bin/st" --config-file "$here/schemathesis.toml" --no-color run "$url/api/v1/openapi.json" \
    --header "Authorization: Bearer admin-token" \
    --phases examples,coverage,fuzzing,stateful \
    --checks all \
    --mode all \
    --max-examples "${ST_MAX_EXAMPLES:-100}" \
    --seed "${ST_SEED:-6}" \
    --request-timeout 20 \
    --workers 1 \
    --generation-database none \
    --report junit,json --report-junit-path "$out/schemathesis.junit.xml" \
    --report-json-path "$out/schemathesis.json" || status=$?

# ---- what ran: cases, failures, phases (from the JSON run report) ----
python3 - "$out/schemathesis.json" "${ST_MIN_CASES:-1800}" <<'PY' || status=1
import json, sys
path, minimum = sys.argv[1], int(sys.argv[2])
try:
    r = json.load(open(path))
except (OSError, ValueError) as e:
    sys.exit(f"no Schemathesis run report at {path}: {e}")
cases = r["test_cases"]["generated"]
failures = sum(g["count"] for g in r["failures"])
errors = sum(g["count"] for g in r["errors"])
phases = {name: p["status"] for name, p in (r["phases"] or {}).items()}
for g in r["failures"]:
    print(f"# failure: {g['title']} x{g['count']} in {', '.join(g['operations'])}", file=sys.stderr)
for g in r["errors"]:
    print(f"# error: {g['title']} x{g['count']}", file=sys.stderr)
print(f"# schemathesis: cases={cases} failures={failures} errors={errors} "
      + "phases=" + ",".join(f"{k}:{v}" for k, v in sorted(phases.items())))
problems = []
if cases < minimum:
    problems.append(f"only {cases} cases ran; at least {minimum} are expected (ST_MIN_CASES)")
for want in ("examples", "coverage", "fuzzing", "stateful"):
    if phases.get(want) in (None, "skip"):
        problems.append(f"phase {want} did not run ({r['phases'].get(want) if r['phases'] else None})")
if failures or errors:
    problems.append(f"{failures} failures and {errors} errors")
if problems:
    sys.exit("schemathesis: " + "; ".join(problems))
PY

# ---- leave no run going ----
python3 "$here/rig.py" cleanup "$url" || status=1
stop_server
if grep -qi "panick" "$log"; then
    echo "the server panicked:" >&2
    grep -i -A3 "panick" "$log" >&2
    status=1
fi
exit "$status"
