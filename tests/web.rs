//! Browser test of the operator page (crates/daemon/ui): `tests/web/run.sh` starts the real
//! `btfrig serve` on a loopback port with a temporary data directory and the tokens of
//! `tests/api/auth.toml`, and drives the page in Debian's headless Chromium with
//! playwright-core: a viewer is refused Start with the daemon's message, an operator starts
//! plan "demo", sees the progress bar advance and the preview image change, pauses (the page
//! shows "paused"), saves `target/web/screenshot.png`, aborts. Chromium (Debian) and playwright-core
//! (npm, into target/webdeps) come from `tests/install-deps.sh`; without them the test FAILS
//! naming that script.

mod support;

use std::process::Command;
use support::repo;

#[test]
fn operator_page_in_headless_chromium() {
    let out = Command::new("bash")
        .arg(repo("tests/web/run.sh"))
        .arg(env!("CARGO_BIN_EXE_btfrig"))
        .output()
        .expect("bash runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "browser test failed ({:?}):\n{text}", out.status);
    eprintln!("{text}");
    assert!(text.contains(" passed, 0 failed"), "{text}");
    // The script's target folder: $CARGO_TARGET_DIR or the repository's target/.
    let target = std::env::var_os("CARGO_TARGET_DIR").map(std::path::PathBuf::from).unwrap_or_else(|| repo("target"));
    let shot = target.join("web/screenshot.png");
    assert!(shot.exists(), "no screenshot at {}", shot.display());
}
