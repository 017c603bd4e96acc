#!/usr/bin/env bash
# Installs what the test suite needs beyond the Rust toolchain, pinned, and nothing when it is
# all there already (idempotent; `.ci/run` calls it before `cargo test`). As root: apt-get.
#
#   Debian packages (apt-get; the version below when Debian still has it, else its candidate,
#   with a warning naming both):
#     chromium         the operator page's browser test (tests/web.rs drives it headless)
#     g++              builds btf-extractor's C++ extension from its source package
#     python3-venv     the Python venvs below (when python3 is Debian's)
#     nodejs, npm      only if `node` / `npm` are missing (playwright-core below)
#     libaravis-dev    the GenICam camera backend (crates/genicam, the `aravis` crate links
#                      Debian's Aravis 0.8 through pkg-config; cargo feature btfrig-cli/genicam)
#     libusb-1.0-0-dev aravis-0.8.pc names libusb-1.0 in Requires.private, and libaravis-dev
#                      does not pull it in: without it pkg-config, hence the build, fails
#     pkg-config       how aravis-sys's build script finds Aravis
#     aravis-tools     arv-fake-gv-camera-0.8, the fake GigE Vision camera the GenICam tests
#                      start on 127.0.0.1 (pulls GTK3, already here through chromium)
#     aravis-tools-cli arv-tool-0.8, to look at a camera's features by hand (docs/genicam.md)
#   Python venvs under $CARGO_TARGET_DIR (default target/)/pydeps, from tests/requirements/*.txt
#   (exact versions with sha256 hashes, `pip install --require-hashes --no-deps`):
#     schemathesis/    tests/schemathesis.rs (tests/api/schemathesis.sh; the version it pins)
#     btf/             tests/compress_extractor.rs (btf-extractor reads our Bonn exports)
#     opencv/          crates/render/tests/markers.rs, `btfrig bench registration --opencv`
#   node: playwright-core (tests/web/package.json, package-lock.json) into target/webdeps by
#   `npm ci` (integrity hashes in the lockfile); it drives Debian's chromium, no browser download.
#
# A venv is rebuilt when its requirement files change (their hash is kept in the venv).
# usage: tests/install-deps.sh        Exit status 0: everything is in place.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
req="$here/requirements"
mkdir -p "$target/pydeps"
t0=$SECONDS
say() { echo "# install-deps: $*" >&2; }

# ---- Debian packages ----
declare -A APT_PIN=(
    [chromium]="156.0.8078.114-1~deb12u1"
    [g++]="4:12.2.0-3"
    [python3-venv]="3.11.2-1+b1"
    [libaravis-dev]="0.8.26-1"
    [aravis-tools]="0.8.26-1"
    [aravis-tools-cli]="0.8.26-1"
    [libusb-1.0-0-dev]="2:1.0.26-1"
    [pkg-config]="1.8.1-1"
)
missing=()
for pkg in chromium g++ python3-venv libaravis-dev aravis-tools aravis-tools-cli libusb-1.0-0-dev pkg-config; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
command -v node >/dev/null || missing+=(nodejs)
command -v npm >/dev/null || missing+=(npm)
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" != 0 ]; then
        say "missing Debian packages ${missing[*]}, and this is not root: sudo apt-get install ${missing[*]}"
        exit 1
    fi
    export DEBIAN_FRONTEND=noninteractive
    say "apt-get update, then install ${missing[*]}"
    apt-get -o DPkg::Lock::Timeout=600 update -q >&2
    want=()
    for pkg in "${missing[@]}"; do
        pin="${APT_PIN[$pkg]:-}"
        candidate="$(apt-cache policy "$pkg" | sed -n 's/^ *Candidate: //p')"
        if [ -n "$pin" ] && apt-cache madison "$pkg" | awk -F'|' '{gsub(/ /, "", $2); print $2}' | grep -qxF "$pin"; then
            want+=("$pkg=$pin")
        else
            [ -n "$pin" ] && say "WARNING: Debian no longer has $pkg=$pin; installing its candidate $candidate (update the pin in $0)"
            want+=("$pkg")
        fi
    done
    apt-get -o DPkg::Lock::Timeout=600 install -y -q --no-install-recommends "${want[@]}" >&2
fi

# ---- Python venvs ----
# venv NAME [--no-build-isolation] REQ...: target/pydeps/NAME from the requirement files in
# order (each a separate pip run, so a later file can build against an earlier one's packages).
venv() {
    local name="$1"
    shift
    local flags=()
    if [ "$1" = --no-build-isolation ]; then
        flags+=(--no-build-isolation)
        shift
    fi
    local dir="$target/pydeps/$name"
    local stamp
    stamp="$(cd "$req" && cat "$@" | sha256sum | cut -d' ' -f1) $(python3 --version 2>&1)"
    if [ -x "$dir/bin/python" ] && [ "$(cat "$dir/.requirements-hash" 2>/dev/null)" = "$stamp" ]; then
        return
    fi
    say "venv $dir from $*"
    rm -rf "$dir"
    python3 -m venv "$dir"
    for f in "$@"; do
        "$dir/bin/python" -m pip install --quiet --disable-pip-version-check --require-hashes --no-deps \
            "${flags[@]}" -r "$req/$f" >&2
    done
    echo "$stamp" >"$dir/.requirements-hash"
}

venv schemathesis schemathesis.txt
# btf-extractor's sdist pins numpy<1.20 for its build, which does not build on Python 3.11:
# its build dependencies go in first, then it builds against them without isolation.
venv btf --no-build-isolation btf-extractor-build.txt btf-extractor.txt
venv opencv opencv.txt

# ---- node: playwright-core ----
webdeps="$target/webdeps"
mkdir -p "$webdeps"
wantpw="$(node -p "require('$here/web/package.json').dependencies['playwright-core']")"
havepw="$(node -p "try { require('$webdeps/node_modules/playwright-core/package.json').version } catch (e) { '' }")"
if [ "$havepw" != "$wantpw" ] || ! cmp -s "$here/web/package-lock.json" "$webdeps/package-lock.json"; then
    say "playwright-core@$wantpw into $webdeps (npm ci)"
    cp "$here/web/package.json" "$here/web/package-lock.json" "$webdeps/"
    (cd "$webdeps" && npm ci --no-audit --no-fund --loglevel=error) >&2
fi

say "all in place ($((SECONDS - t0)) s)"
