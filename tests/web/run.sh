#!/usr/bin/env bash
# Browser test of the operator page and the viewer: starts `btfrig serve` on a loopback port
# (temporary data directory, tokens of tests/api/auth.toml), drives the operator page in
# Debian's headless Chromium with playwright-core (tests/web/ui.test.mjs, saves
# target/web/screenshot.png), meanwhile makes the demo's dataset with `btfrig demo` (its FMF
# model included), then writes its report (`btfrig dataset report`) and a render
# (`btfrig dataset render`) and drives the viewer (tests/web/viewer.test.mjs, screenshots
# target/web/viewer-*.png, report.png).
#
# usage: tests/web/run.sh [PATH/TO/btfrig]
#   binary: the argument, else $BTFRIG_BIN, else target/release/btfrig
#   BTFRIG_WEB_FAKE=1: the operator page against tests/web/fake-server.mjs instead (working
#     on the page only; no viewer test)
#   BTFRIG_WEB_EXTRA=DIR: copied into the data directory before the viewer test (tests/web.rs
#     puts the synthetic 256 x 256, 81 x 81 FMF model of the frame-rate figure there)
#   BTFRIG_WEB_ONLY=viewer|operator: run one of the two page tests
#
# Needs Debian's chromium and playwright-core (version pinned in tests/web/package.json and
# package-lock.json) in target/webdeps: tests/install-deps.sh installs both (never a browser
# download: the Debian package is driven); without them this script fails naming that script.
# Exit status: 0 when every check passed.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
webdeps="$target/webdeps"
out="$target/web"
mkdir -p "$out" "$webdeps"

# ---- what tests/install-deps.sh installs ----
[ -x /usr/bin/chromium ] || { echo "no /usr/bin/chromium: run tests/install-deps.sh" >&2; exit 1; }
want="$(node -p "require('$here/package.json').dependencies['playwright-core']")"
have="$(node -p "try { require('$webdeps/node_modules/playwright-core/package.json').version } catch (e) { '' }")"
if [ "$have" != "$want" ] || ! cmp -s "$here/package-lock.json" "$webdeps/package-lock.json"; then
    echo "playwright-core@$want is not in $webdeps (found '${have}'): run tests/install-deps.sh" >&2
    exit 1
fi

# ---- the server ----
data="$(mktemp -d "${TMPDIR:-/tmp}/btfrig-web-data.XXXXXX")"
log="$out/server.log"
pid=""
demo_pid=""
cleanup() {
    if [ -n "$demo_pid" ] && kill -0 "$demo_pid" 2>/dev/null; then
        kill -TERM "$demo_pid" 2>/dev/null || true
        wait "$demo_pid" 2>/dev/null || true
    fi
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
        kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$pid" 2>/dev/null || true
        wait "$pid" 2>/dev/null || true
    fi
    rm -rf "$data"
}
trap cleanup EXIT

only="${BTFRIG_WEB_ONLY:-}"
if [ "${BTFRIG_WEB_FAKE:-}" = 1 ]; then
    node "$here/fake-server.mjs" 0 >"$log" 2>&1 &
    pid=$!
    only=operator
else
    bin="${1:-${BTFRIG_BIN:-$target/release/btfrig}}"
    [ -x "$bin" ] || { echo "no btfrig binary at $bin (cargo build --release -p btfrig-cli)" >&2; exit 1; }
    if [ "$only" != operator ]; then
        # The demo's dataset for the viewer, made while the operator page is tested.
        "$bin" demo --out "$data/demo" >"$out/demo.log" 2>&1 &
        demo_pid=$!
    fi
    "$bin" serve --listen 127.0.0.1:0 --data "$data" --auth "$root/tests/api/auth.toml" >"$log" 2>&1 &
    pid=$!
fi

# The first line the server prints: `listening on http://127.0.0.1:PORT`.
url=""
for _ in $(seq 300); do
    url="$(sed -n '1s/^listening on \(http:\/\/[^ ]*\).*/\1/p' "$log" 2>/dev/null || true)"
    [ -n "$url" ] && break
    kill -0 "$pid" 2>/dev/null || { echo "the server exited:" >&2; cat "$log" >&2; exit 1; }
    sleep 0.1
done
[ -n "$url" ] || { echo "the server printed no 'listening on' line in 30 s:" >&2; cat "$log" >&2; exit 1; }
url="${url%/}"
echo "# server at $url (log $log)" >&2

status=0
if [ "$only" != viewer ]; then
    BTFRIG_WEBDEPS="$webdeps" node "$here/ui.test.mjs" "$url" "$out/screenshot.png" || status=$?
fi
if [ "$only" != operator ]; then
    rm -f "$out/report.html" "$out/render-cli.png"
    if ! wait "$demo_pid"; then
        echo "btfrig demo failed:" >&2
        tail -n 20 "$out/demo.log" >&2
        exit 1
    fi
    demo_pid=""
    tail -n 4 "$out/demo.log" | sed 's/^/# /'
    # The other two models, in the other two colour models, so every decoding path is compared.
    "$bin" compress "$data/demo" --method pcmf --color ylog-uv --no-eval | sed 's/^/# /'
    "$bin" compress "$data/demo" --method pvmf --color rgb --no-eval | sed 's/^/# /'
    "$bin" dataset report "$data/demo" --out "$out/report.html" | sed 's/^/# /'
    "$bin" dataset render "$data/demo" --model fmf --light 25,40 --view 10,200 --out "$out/render-cli.png" | sed 's/^/# /'
    if [ -n "${BTFRIG_WEB_EXTRA:-}" ]; then cp -r "$BTFRIG_WEB_EXTRA"/. "$data"/; fi
    BTFRIG_WEBDEPS="$webdeps" node "$here/viewer.test.mjs" "$url" "$out" || status=$?
fi
if [ "$status" != 0 ]; then
    echo "--- server log (last 40 lines)" >&2
    tail -n 40 "$log" >&2
fi
exit "$status"
