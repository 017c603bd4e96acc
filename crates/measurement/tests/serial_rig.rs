//! The same plan and seed on the simulated rig directly and through the real serial and
//! PTP backends talking to emulated firmware on pseudo-terminals (rig-configs/
//! bonn-gonio-serial.toml): identical textures, and what the serial path added in time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest, RunSummary};

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
    // The manifest keeps the embedded rig's text (so a dataset says what measured it).
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dataset").join("manifest.json")).unwrap()).unwrap();
    let builtin = btfrig_core::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == rig).unwrap().1;
    assert_eq!(manifest["rig"]["config_toml"].as_str(), Some(builtin), "manifest rig: {}", manifest["rig"]);
    let t = textures(&dir.join("dataset"));
    (s, t)
}

#[test]
fn serial_path_gives_the_direct_path_textures() {
    btfrig_sim_backend::install();
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

    // The report itself says what the links added: every emulated device, bytes both ways,
    // and wall time that is part of the run's own wall time.
    assert!(direct.links.is_empty() && direct.link_added_wall_s.is_none(), "{:?}", direct.links);
    let roles: Vec<&str> = serial.links.iter().map(|l| l.role).collect();
    assert_eq!(roles, ["robot", "rail", "lamp", "camera"], "{:?}", serial.links);
    for l in &serial.links {
        println!(
            "  {:<6} {:>5} exchanges, {:>9} B out, {:>9} B in, wall {:.3} s, wire at nominal baud {}",
            l.role,
            l.exchanges,
            l.bytes_out,
            l.bytes_in,
            l.wall_s,
            l.wire_s.map_or("-".into(), |w| format!("{w:.3} s"))
        );
        assert!(l.exchanges > 0 && l.bytes_out > 0 && l.bytes_in > 0, "{l:?}");
        assert!(l.wall_s > 0.0, "{l:?}");
    }
    // 12 frames came over PTP: at least their pixels (2 bytes a photosite).
    let camera = serial.links.iter().find(|l| l.role == "camera").unwrap();
    assert!(camera.bytes_in >= 12 * 2 * 1600 * 1200, "{camera:?}");
    let added = serial.link_added_wall_s.unwrap();
    // Through the links the engine waits on moves in wall time, by less than the links'
    // exchanges took in all (they overlap the camera's work). (The in-process devices move in
    // rig time only; their wall-clock wait is printed above but not asserted: on a shared
    // machine any wall figure is load, not a property of the code.)
    let sum: f64 = serial.links.iter().map(|l| l.wall_s).sum();
    println!(
        "motion wait: direct {:.3} s, serial {:.3} s; links busy {sum:.3} s in all",
        direct.motion_wait_wall_s, serial.motion_wait_wall_s
    );
    assert!(added > 0.0 && added <= sum, "{added} not in (0, {sum}]");
    println!("link_added_wall_s {added:.3} (measured difference in wall time {:+.2} s)", serial.wall_s - direct.wall_s);
    assert!(added < serial.wall_s, "links added {added} s of a {} s run", serial.wall_s);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(serial.dataset.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["links"].as_array().map(Vec::len), Some(4), "{report}");
    assert!((report["link_added_wall_s"].as_f64().unwrap() - added).abs() < 1e-9);
}
