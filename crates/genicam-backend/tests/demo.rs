//! The same plan and seed on the simulated rig directly and with its camera seen through a
//! real GenICam stream (rig-configs/bonn-gonio-genicam.toml: Aravis's GigE Vision fake camera
//! served by this process on 127.0.0.1, fed with the simulated frames): identical textures,
//! and what the GenICam path cost. Runs in a loopback-only network namespace of its own.

#[path = "../../genicam/tests/support/mod.rs"]
mod support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use btfrig_genicam_backend::GenicamBackend;
use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest, RunSummary};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("genicam-demo-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn plan(rig: &str) -> String {
    include_str!("../../../tests/data/tiny-plan.toml")
        .replace("SEED", "5")
        .replace("FAULTS", "none")
        .replace("builtin:bonn-gonio-sim", rig)
}

fn textures(dataset: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dataset.join("textures")).unwrap() {
        let p = e.unwrap().path();
        out.insert(
            p.file_name().unwrap().to_string_lossy().into_owned(),
            btfrig_store::content_hash(&std::fs::read(&p).unwrap()),
        );
    }
    out
}

fn measure(name: &str, rig: &str) -> (RunSummary, BTreeMap<String, String>) {
    let dir = scratch(name);
    let req = RunRequest::from_text(plan(rig), &dir.join("plan.toml"), &dir.join("dataset"));
    let s = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
    assert_eq!(s.captures, 12);
    let t = textures(&dir.join("dataset"));
    (s, t)
}

#[test]
fn genicam_path_gives_the_direct_path_textures() {
    if !support::in_netns("genicam_path_gives_the_direct_path_textures") {
        return;
    }
    support::assert_loopback_only();
    let sim = btfrig_sim_backend::registry();
    btfrig_measurement::backend::install(sim.clone().with(Arc::new(GenicamBackend::new(sim))));
    let (direct, direct_tex) = measure("direct", "builtin:bonn-gonio-sim");
    let (genicam, genicam_tex) = measure("genicam", "builtin:bonn-gonio-genicam");
    assert_eq!(direct_tex.len(), 12, "{direct_tex:?}");
    assert_eq!(genicam_tex, direct_tex, "texture hashes differ between the GenICam and the direct path");
    let camera = genicam.links.iter().find(|l| l.role == "camera").expect("the GenICam camera's link");
    println!(
        "direct: wall {:.2} s; genicam: wall {:.2} s (+{:.2} s); camera link: {} frames, {} B in, {:.3} s in GenICam calls, {:?} dropped buffers; retries {} / {}",
        direct.wall_s,
        genicam.wall_s,
        genicam.wall_s - direct.wall_s,
        camera.exchanges,
        camera.bytes_in,
        camera.wall_s,
        camera.dropped_buffers,
        direct.retries,
        genicam.retries
    );
    assert!(camera.exchanges >= 12 && camera.bytes_in >= 12 * 2 * 1600 * 1200, "{camera:?}");
    assert_eq!(camera.dropped_buffers, Some(0), "{camera:?}");
    assert!(camera.target.contains("BTFRIG-SIM"), "{}", camera.target);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(genicam.dataset.join("report.json")).unwrap()).unwrap();
    let links = report["links"].as_array().unwrap();
    assert!(links.iter().any(|l| l["role"] == "camera" && l["dropped_buffers"] == 0), "{report}");
}
