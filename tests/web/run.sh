#!/usr/bin/env bash
# Browser test of the operator page: starts `btfrig serve` on a loopback port (temporary data
# directory, tokens of tests/api/auth.toml), drives the page in Debian's headless Chromium
# with playwright-core (tests/web/ui.test.mjs) and saves target/web/screenshot.png.
#
# usage: tests/web/run.sh [PATH/TO/btfrig]
#   binary: the argument, else $BTFRIG_BIN, else target/release/btfrig
#   BTFRIG_WEB_FAKE=1: against tests/web/fake-server.mjs instead (working on the page only)
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
cleanup() {
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
        kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$pid" 2>/dev/null || true
        wait "$pid" 2>/dev/null || true
    fi
    rm -rf "$data"
}
trap cleanup EXIT

if [ "${BTFRIG_WEB_FAKE:-}" = 1 ]; then
    node "$here/fake-server.mjs" 0 >"$log" 2>&1 &
    pid=$!
else
    bin="${1:-${BTFRIG_BIN:-$target/release/btfrig}}"
    [ -x "$bin" ] || { echo "no btfrig binary at $bin (cargo build --release -p btfrig-cli)" >&2; exit 1; }
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
BTFRIG_WEBDEPS="$webdeps" node "$here/ui.test.mjs" "$url" "$out/screenshot.png" || status=$?
if [ "$status" != 0 ]; then
    echo "--- server log (last 40 lines)" >&2
    tail -n 40 "$log" >&2
fi
exit "$status"
