//! The dome's and the camera array's processing from files: every view group registered from
//! the plate's markers (error against the simulator's true pose), dark/flat from the rig
//! config's `[camera] dark_flat` applied per photosite before demultiplexing.

use std::path::{Path, PathBuf};

use btfrig_measurement::dome::{run, DomeRunRequest, DomeRunSummary};

const DOME: &str = include_str!("../../../rig-configs/bonn-dome-sim.toml");
const CAMERA_ARRAY: &str = include_str!("../../../rig-configs/bonn-camera-array-sim.toml");

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("btfrig-dome-reg-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes `rig` as `rig.toml` in `dir` and runs a one-view plan on it (`dome` lines appended
/// to the plan's `[dome]`) into `dir/out`.
fn go(dir: &Path, rig: &str, dome: &str) -> Result<DomeRunSummary, btfrig_measurement::RunError> {
    std::fs::write(dir.join("rig.toml"), rig).unwrap();
    let plan = format!(
        "name = \"dome-registration-test\"\ntexture_size = 16\n[rig]\nconfig = \"rig.toml\"\nmaterial = \"leather\"\n\
         [dome]\n{dome}"
    );
    let out = dir.join("out");
    let _ = std::fs::remove_dir_all(&out);
    let req = DomeRunRequest {
        plan_text: plan,
        plan_path: dir.join("plan.toml"),
        out,
        faults: None,
        preview: false,
        compressed_model: None,
    };
    run(&req, &mut |line| eprintln!("{line}"))
}

/// The dome with its turntable landing `offset_deg` off every commanded angle.
fn dome_with_turntable_offset(offset_deg: f64) -> String {
    let old = "offset_deg = 0.0\njitter_deg = 0.0";
    assert!(DOME.contains(old));
    DOME.replace(old, &format!("offset_deg = {offset_deg}\njitter_deg = 0.0"))
}

#[test]
fn a_turntable_positioning_error_is_measured_by_registration_not_taken_from_the_nominal_pose() {
    btfrig_sim_backend::install();
    let dir = tmp("offset");
    let s = go(&dir, &dome_with_turntable_offset(1.0), "cameras = [4]\nrotations = [1]\nreference_leds = 0\n")
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{}", s.to_json());
    assert_eq!((s.registered, s.fallbacks), (1, 0), "{:?}", s.warnings);
    let (reg, nominal) = (s.registration_mean_texel_err.unwrap(), s.nominal_mean_texel_err.unwrap());
    // 1 degree about the sample centre moves the 0.1 m sample's texels by up to 1.2 mm (0.19
    // texel of 16 at the corners, 0.11 on average): the nominal pose is that far off.
    assert!(nominal > 0.08, "nominal pose error {nominal} texels");
    assert!(reg < 0.05 && reg < nominal / 5.0, "registered {reg} texels vs nominal {nominal}");
    let json = s.to_json();
    assert_eq!(json["registered"], 1);
    // The group's pattern frames were registered once, from their sum.
    assert!(s.frames > 1, "{json}");
    assert_eq!(json["registrations_reused"], s.frames - 1, "{json}");
    assert!(json["registration_mean_texel_err"].as_f64().is_some(), "{json}");
}

#[test]
fn a_camera_array_run_registers_every_camera() {
    btfrig_sim_backend::install();
    let dir = tmp("array");
    let s = go(&dir, CAMERA_ARRAY, "cameras = [0, 31]\nexposure_s = 0.01\nreference_leds = 0\n")
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{}", s.to_json());
    assert_eq!((s.registered, s.fallbacks), (2, 0), "{:?}", s.warnings);
    let reg = s.registration_mean_texel_err.unwrap();
    assert!(reg < 0.05, "registration error {reg} texels");
}

/// Copies the shipped dome dark/flat calibration into `dir/name`, with its flat multiplied by
/// `flat_error(x, y)`.
fn dark_flat_copy(dir: &Path, name: &str, flat_error: impl Fn(usize, usize) -> f32) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../calibration/bonn-dome-sim-dark-flat");
    let dst = dir.join(name);
    std::fs::create_dir_all(&dst).unwrap();
    for f in ["dark-flat.toml", "dark.exr", "dark-sigma.exr", "flat-f8.exr"] {
        std::fs::copy(src.join(f), dst.join(f)).unwrap();
    }
    let flat = dst.join("flat-f8.exr");
    let (w, h, mut data) = btfrig_imageio::read_rgb_exr(&flat).unwrap();
    for (i, p) in data.iter_mut().enumerate() {
        p[0] *= flat_error(i % w, i / w);
    }
    btfrig_imageio::write_rgb_exr(&flat, w, h, &data).unwrap();
    dst
}

#[test]
fn the_dark_flat_file_is_used_and_a_wrong_one_worsens_the_textures() {
    btfrig_sim_backend::install();
    let dir = tmp("dark-flat");
    let view = "cameras = [4]\nrotations = [1]\nreference_leds = 0\n";
    let with = |reference: &str| {
        let rig =
            DOME.replace("dark_flat = \"builtin:bonn-dome-sim-dark-flat\"", &format!("dark_flat = \"{reference}\""));
        assert_ne!(rig, DOME);
        go(&dir, &rig, view).unwrap_or_else(|e| panic!("{e}"))
    };
    let none = {
        let rig = DOME.replace("dark_flat = \"builtin:bonn-dome-sim-dark-flat\"\n", "");
        go(&dir, &rig, view).unwrap_or_else(|e| panic!("{e}"))
    };
    // The shipped calibration, read from its directory like any lab's, and the same with its
    // flat normalised 25% too high (every photosite divided by 1.25: textures 20% too dark).
    dark_flat_copy(&dir, "right", |_, _| 1.0);
    dark_flat_copy(&dir, "wrong", |_, _| 1.25);
    let right = with("right");
    let wrong = with("wrong");
    let b = |s: &DomeRunSummary| s.texture_brightness_err.unwrap();
    let e = |s: &DomeRunSummary| s.texture_rel_rmse.unwrap();
    eprintln!(
        "brightness error / texture RMSE: right dark/flat {:+.4} / {:.4}, flat 25% high {:+.4} / {:.4}, none {:+.4} / {:.4}",
        b(&right),
        e(&right),
        b(&wrong),
        e(&wrong),
        b(&none),
        e(&none)
    );
    // The wrong flat scales every texture by 1 / 1.25 (the dome's textures are about 11% too
    // bright with the right one and without: a bias of the LED/colour calibration, open).
    assert!((b(&wrong) - (0.8 * (1.0 + b(&right)) - 1.0)).abs() < 0.005, "wrong flat: {}", b(&wrong));
    assert!(b(&right).abs() < 0.15, "right dark/flat: brightness error {}", b(&right));
    assert!(none.warnings.iter().any(|l| l.starts_with("no dark/flat calibration")), "{:?}", none.warnings);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/report.json")).unwrap()).unwrap();
    assert_eq!(report["calibration"]["dark_flat"]["reference"], "wrong", "{report}");
}

#[test]
fn a_missing_dark_flat_directory_is_named_before_anything_is_written() {
    btfrig_sim_backend::install();
    let dir = tmp("missing");
    let rig = DOME.replace("dark_flat = \"builtin:bonn-dome-sim-dark-flat\"", "dark_flat = \"no-such-dark-flat\"");
    let e =
        go(&dir, &rig, "cameras = [4]\nrotations = [1]\n").expect_err("a missing dark/flat calibration").to_string();
    assert!(e.contains("[camera] dark_flat = \"no-such-dark-flat\""), "{e}");
    assert!(e.contains(&dir.join("no-such-dark-flat").join("dark-flat.toml").display().to_string()), "{e}");
    assert!(!dir.join("out").exists());
}
