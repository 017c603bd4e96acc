//! Schemathesis (a PyPI package) against the OpenAPI document the real `btfrig serve` serves
//! at `/api/v1/openapi.json`: `tests/api/schemathesis.sh` starts the daemon on a loopback
//! port (temporary data directory, tokens of `tests/api/auth.toml`), runs `st run` with the
//! admin token and the checks not_a_server_error, status_code_conformance,
//! content_type_conformance and response_schema_conformance, a fixed seed and 40 examples per
//! operation, then aborts every run still going and stops the server. Any failure fails the
//! test. The script installs schemathesis (pinned) into the venv target/pydeps/schemathesis
//! when it is missing, and FAILS if it cannot.

mod support;

use std::process::Command;
use support::repo;

#[test]
fn schemathesis_finds_no_server_error_and_no_schema_violation() {
    let out = Command::new("bash")
        .arg(repo("tests/api/schemathesis.sh"))
        .arg(env!("CARGO_BIN_EXE_btfrig"))
        .output()
        .expect("bash runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "schemathesis failed ({:?}):\n{text}", out.status);
    eprintln!("{text}");
}
