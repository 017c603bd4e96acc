//! The dry run of a dome plan against the run it predicts: same mode, frames and textures,
//! and a rig-time estimate that bounds the measured rig time from below and comes close.

use std::path::PathBuf;

use btfrig_measurement::dome::{run, DomeRunRequest};
use btfrig_measurement::dome_dry_run::{dry_run, is_dome_plan};

fn check(plan: &str, name: &str) {
    let file = PathBuf::from("<test>");
    let d = dry_run(plan, &file).unwrap_or_else(|e| panic!("{e}"));
    let out = std::env::temp_dir().join(format!("btfrig-dome-dry-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let req = DomeRunRequest {
        plan_text: plan.into(),
        plan_path: file.clone(),
        out: out.clone(),
        faults: None,
        preview: false,
        compressed_model: None,
    };
    let s = run(&req, &mut |line| eprintln!("{line}")).unwrap_or_else(|e| panic!("{e}"));
    for l in d.lines(&file) {
        eprintln!("{l}");
    }
    eprintln!("measured rig time {:.2} s, estimated {:.2} s", s.hardware_s, d.rig_time_s);
    assert_eq!(d.schedule.mode.describe(), s.mode);
    assert_eq!((d.frames as u64, d.textures as u64), (s.frames, s.textures));
    assert!((d.schedule.predicted_gain - s.multiplex_gain_predicted).abs() < 1e-12);
    // A lower bound (the serial round trips are left out), within 5 % of the run (measured: 1 %).
    assert!(d.rig_time_s <= s.hardware_s * (1.0 + 1e-9), "estimate {} above the run's {}", d.rig_time_s, s.hardware_s);
    assert!(d.rig_time_s >= 0.95 * s.hardware_s, "estimate {} far below the run's {}", d.rig_time_s, s.hardware_s);
    // The raw pattern frames a plan keeps: counted, and their disk use within 2 % of the files'.
    let raw: Vec<u64> = std::fs::read_dir(out.join(btfrig_store::RAW_DIR))
        .map(|d| d.map(|e| e.unwrap().metadata().unwrap().len()).collect())
        .unwrap_or_default();
    match d.raw_frames {
        Some((n, bytes)) => {
            let on_disk: u64 = raw.iter().sum();
            eprintln!("raw frames: {n} estimated {bytes} bytes, {} written {on_disk} bytes", raw.len());
            assert_eq!(n, raw.len());
            assert!((bytes as f64 / on_disk as f64 - 1.0).abs() < 0.02, "estimated {bytes}, on disk {on_disk}");
        }
        None => assert!(raw.is_empty(), "{} raw frames kept without raw_frames", raw.len()),
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_led_dome_dry_run_predicts_the_run() {
    btfrig_sim_backend::install();
    let plan = "name = \"dry\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\nmaterial = \"leather\"\n\
                [dome]\ncameras = [4]\nrotations = [1, 5]\n";
    assert!(is_dome_plan(plan));
    check(plan, "led");
}

#[test]
fn a_camera_array_dry_run_predicts_the_run() {
    btfrig_sim_backend::install();
    let plan =
        "name = \"dry\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-camera-array-sim\"\nmaterial = \"leather\"\n\
                [dome]\ncameras = [0, 31]\n[outputs]\nraw_frames = true\n";
    check(plan, "array");
}

#[test]
fn a_gonio_plan_is_no_dome_plan() {
    btfrig_sim_backend::install();
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../rig-configs/plans/demo.toml")).unwrap();
    assert!(!is_dome_plan(&text));
    assert!(!is_dome_plan("not toml ["));
}

/// A material file in a dome plan is found next to the plan, wherever the command runs from
/// (as in a gonio plan), and a missing one is named with its resolved path.
#[test]
fn a_dome_plan_material_file_resolves_against_the_plan() {
    btfrig_sim_backend::install();
    let dir = std::env::temp_dir().join(format!("btfrig-dome-material-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("plans")).unwrap();
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../sim/materials/corduroy.toml"),
        dir.join("plans/mat.toml"),
    )
    .unwrap();
    let plan = |material: &str| {
        format!(
            "name = \"dry\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\nmaterial = \"{material}\"\n\
             [dome]\ncameras = [4]\nrotations = [1]\n"
        )
    };
    let file = dir.join("plans/dome.toml");
    // The test runs in the crate's directory, where no mat.toml is.
    assert!(!std::path::Path::new("mat.toml").exists());
    dry_run(&plan("mat.toml"), &file).unwrap_or_else(|e| panic!("{e}"));
    let e = dry_run(&plan("missing.toml"), &file).unwrap_err().to_string();
    assert!(e.contains(&dir.join("plans/missing.toml").display().to_string()), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
