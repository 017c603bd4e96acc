//! Schemathesis (a PyPI package, pinned with hashes in `tests/requirements/schemathesis.txt`, installed by `tests/install-deps.sh`) against
//! the OpenAPI document the real `btfrig serve` serves at `/api/v1/openapi.json`:
//! `tests/api/schemathesis.sh` starts the daemon on a loopback port (temporary data directory,
//! tokens of `tests/api/auth.toml`), starts a long run, then runs `st run` with the admin
//! token, all four phases (examples, coverage, fuzzing, stateful along the document's links)
//! and every check, a fixed seed; afterwards it aborts every run still going and stops the
//! server. The script installs schemathesis into the venv target/pydeps/schemathesis when it
//! is missing, and FAILS if it cannot.
//!
//! Issue 24: the test did not check that cases ran. It now reads the run report's summary
//! line and asserts the number of cases, every phase run, and no failure or error.

mod support;

use std::process::Command;
use support::repo;

/// Fewer cases than this means a phase or operations were skipped (seed 6 runs 2,176).
const MIN_CASES: u64 = 1800;

#[test]
fn schemathesis_all_phases_find_no_server_error_and_no_conformance_failure() {
    let out = Command::new("bash")
        .arg(repo("tests/api/schemathesis.sh"))
        .arg(env!("CARGO_BIN_EXE_btfrig"))
        .env("ST_MIN_CASES", MIN_CASES.to_string())
        .output()
        .expect("bash runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    eprintln!("{text}");
    let summary = text
        .lines()
        .find_map(|l| l.strip_prefix("# schemathesis: "))
        .unwrap_or_else(|| panic!("no '# schemathesis:' summary line:\n{text}"));
    let field = |name: &str| -> &str {
        summary
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix(name).and_then(|v| v.strip_prefix('=')))
            .unwrap_or_else(|| panic!("no {name}= in {summary:?}"))
    };
    let number = |name: &str| -> u64 { field(name).parse().unwrap_or_else(|e| panic!("{name}: {e} in {summary:?}")) };
    assert!(text.contains("# seed: run r1 running"), "a run is going when Schemathesis starts:\n{text}");
    assert!(number("cases") >= MIN_CASES, "only {} cases ran (at least {MIN_CASES}): {summary}", number("cases"));
    assert_eq!((number("failures"), number("errors")), (0, 0), "{summary}");
    for phase in ["examples", "coverage", "fuzzing", "stateful"] {
        let status = field("phases").split(',').find_map(|p| p.strip_prefix(phase).and_then(|s| s.strip_prefix(':')));
        assert!(matches!(status, Some("success")), "phase {phase}: {status:?} in {summary}");
    }
    assert!(out.status.success(), "schemathesis failed ({:?}):\n{text}", out.status);
}
