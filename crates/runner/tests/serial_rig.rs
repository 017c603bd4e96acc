//! The same plan and seed on the simulated rig directly and through the real serial and
//! PTP backends talking to emulated firmware on pseudo-terminals (rig-configs/
//! bonn-gonio-serial.toml): identical textures, and what the serial path added in time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use btfrig_runner::{run, RunControl, RunOutcome, RunRequest, RunSummary};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("serial-rig-{name}"));
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

/// Every texture file's content hash, by path.
fn textures(dataset: &Path) -> BTreeMap<String, String> {
    let dir = dataset.join("textures");
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(&dir).unwrap() {
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
    assert!(btfrig_store::verify(&dir.join("dataset")).is_ok());
    let t = textures(&dir.join("dataset"));
    (s, t)
}

#[test]
fn serial_path_gives_the_direct_path_textures() {
    let (direct, direct_tex) = measure("direct", "builtin:bonn-gonio-sim");
    let (serial, serial_tex) = measure("serial", "builtin:bonn-gonio-serial");
    assert_eq!(direct_tex.len(), 12, "{direct_tex:?}");
    assert_eq!(serial_tex, direct_tex, "texture hashes differ between the serial and the direct path");
    println!(
        "direct: rig {:.6} s, wall {:.2} s; serial: rig {:.6} s (+{:.6} s), wall {:.2} s (+{:.2} s); retries {} / {}",
        direct.hardware_s,
        direct.wall_s,
        serial.hardware_s,
        serial.hardware_s - direct.hardware_s,
        serial.wall_s,
        serial.wall_s - direct.wall_s,
        direct.retries,
        serial.retries
    );
    // Polling the controllers can only add rig time.
    assert!(serial.hardware_s >= direct.hardware_s, "{} < {}", serial.hardware_s, direct.hardware_s);
}
