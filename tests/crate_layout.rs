//! The simulator stays out of the processing crates (issue 25, docs/ARCHITECTURE.md): no
//! library crate of the workspace depends, directly or through other crates, on `btfrig-sim`
//! or `btfrig-render` in its normal (non-dev) dependencies, except the simulator's own crates.
//! Read from `cargo metadata`, so a dependency cannot creep back unnoticed. The runner and the
//! daemon reach the simulator only through the backend registry, which `btfrig-sim-backend`
//! fills (`btfrig_measurement::backend`).

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

/// The simulator's own crates: they may depend on it.
const SIMULATOR_CRATES: &[&str] = &["btfrig-sim", "btfrig-render", "btfrig-sim-backend", "btfrig-sim-calibration"];

/// Benchmark harnesses: they measure against the simulator's truth, so they may depend on it;
/// only the CLI may depend on them (`only_the_cli_uses_the_harnesses`).
const HARNESSES: &[&str] = &["btfrig-bench"];

/// What the simulator is.
const SIMULATOR: &[&str] = &["btfrig-sim", "btfrig-render"];

/// Each workspace package with a library target, and its normal dependencies inside the workspace.
fn workspace_libraries() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--no-deps", "--offline"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata runs");
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("cargo metadata prints JSON");
    let packages = meta["packages"].as_array().expect("packages");
    let names: BTreeSet<String> = packages.iter().map(|p| p["name"].as_str().unwrap().to_string()).collect();
    let mut libs = BTreeMap::new();
    for p in packages {
        let is_lib = p["targets"].as_array().unwrap().iter().any(|t| {
            t["kind"].as_array().unwrap().iter().any(|k| matches!(k.as_str(), Some("lib" | "rlib" | "proc-macro")))
        });
        let deps: BTreeSet<String> = p["dependencies"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["kind"].is_null())
            .map(|d| d["name"].as_str().unwrap().to_string())
            .filter(|n| names.contains(n))
            .collect();
        if is_lib {
            libs.insert(p["name"].as_str().unwrap().to_string(), deps);
        } else {
            // Binaries may depend on anything, but their dependencies are still walked.
            libs.entry(p["name"].as_str().unwrap().to_string()).or_insert(deps);
        }
    }
    libs
}

/// The workspace crates `name` depends on, directly or not, through normal dependencies.
fn closure(graph: &BTreeMap<String, BTreeSet<String>>, name: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![name.to_string()];
    while let Some(n) = stack.pop() {
        for d in graph.get(&n).into_iter().flatten() {
            if seen.insert(d.clone()) {
                stack.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn no_library_outside_the_simulator_depends_on_it() {
    let graph = workspace_libraries();
    assert!(graph.contains_key("btfrig-process") && graph.contains_key("btfrig-sim"), "{graph:?}");
    let mut offenders = BTreeMap::new();
    for name in graph.keys() {
        if SIMULATOR_CRATES.contains(&name.as_str()) || HARNESSES.contains(&name.as_str()) || name == "btfrig-cli" {
            continue;
        }
        let reached: Vec<String> =
            closure(&graph, name).into_iter().filter(|d| SIMULATOR.contains(&d.as_str())).collect();
        if !reached.is_empty() {
            offenders.insert(name.clone(), reached);
        }
    }
    let found: Vec<String> = offenders.iter().map(|(n, d)| format!("{n} -> {}", d.join(", "))).collect();
    assert!(
        found.is_empty(),
        "library crates depend on the simulator in [dependencies]: {found:?}; allowed: only {SIMULATOR_CRATES:?} \
         (and the CLI binary). Open devices and truth through btfrig_measurement::backend, or make it a dev-dependency"
    );
}

#[test]
fn the_processing_crates_never_depend_on_the_simulator() {
    let graph = workspace_libraries();
    for name in [
        "btfrig-process",
        "btfrig-imaging",
        "btfrig-imageio",
        "btfrig-registration",
        "btfrig-markers",
        "btfrig-acquire",
        "btfrig-store",
        "btfrig-compress",
        "btfrig-color",
        "btfrig-mux",
    ] {
        let reached: Vec<String> =
            closure(&graph, name).into_iter().filter(|d| SIMULATOR.contains(&d.as_str())).collect();
        assert!(reached.is_empty(), "{name} depends on {reached:?}");
    }
}

#[test]
fn only_the_cli_uses_the_harnesses() {
    let graph = workspace_libraries();
    assert!(graph.contains_key("btfrig-bench"), "{graph:?}");
    let users: Vec<&String> = graph
        .keys()
        .filter(|n| n.as_str() != "btfrig-cli" && !HARNESSES.contains(&n.as_str()))
        .filter(|n| closure(&graph, n).iter().any(|d| HARNESSES.contains(&d.as_str())))
        .collect();
    assert!(users.is_empty(), "only btfrig-cli may depend on {HARNESSES:?}; these do too: {users:?}");
}

/// Aravis (a C library from a Debian package) is linked only where GenICam cameras are
/// asked for: `btfrig-genicam` wraps it, `btfrig-genicam-backend` puts it in the registry,
/// and only the CLI (behind its `genicam` feature) installs that; the simulated rig's
/// registry (`btfrig-sim-backend`) and every other library stay free of it.
#[test]
fn only_the_genicam_crates_link_aravis() {
    let graph = workspace_libraries();
    assert!(graph.contains_key("btfrig-genicam") && graph.contains_key("btfrig-genicam-backend"), "{graph:?}");
    let allowed = ["btfrig-cli", "btfrig-genicam", "btfrig-genicam-backend"];
    let users: Vec<&String> = graph
        .keys()
        .filter(|n| !allowed.contains(&n.as_str()))
        .filter(|n| closure(&graph, n).contains("btfrig-genicam"))
        .collect();
    assert!(users.is_empty(), "only {allowed:?} may depend on btfrig-genicam; these do too: {users:?}");
}

/// Dependencies point one way (issue 25): the stage pipeline reads captures (plain data in
/// `btfrig_core::capture`), never the device-owning engine that produces them; the run of a
/// measurement opens devices through the backend registry, so device transports (serial
/// ports, PTP cameras) stay in the backends.
#[test]
fn dependencies_point_one_way() {
    let graph = workspace_libraries();
    for (crate_, forbidden) in
        [("btfrig-process", &["btfrig-acquire"][..]), ("btfrig-measurement", &["btfrig-serial", "btfrig-ptp"][..])]
    {
        assert!(graph.contains_key(crate_), "{crate_} is not a workspace library: {graph:?}");
        let reached: Vec<&str> = forbidden.iter().copied().filter(|f| closure(&graph, crate_).contains(*f)).collect();
        assert!(reached.is_empty(), "{crate_} depends on {reached:?}; it must not depend on any of {forbidden:?}");
    }
}
