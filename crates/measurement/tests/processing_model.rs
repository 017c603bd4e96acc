//! The processing model comes from the rig config and its calibration files (issue 25): a
//! calibration file the config names but that is missing stops the run before anything is
//! created, naming the file and the setting; a rig with no light calibration still measures,
//! in relative units, and its report says so and has no truth figures to compare.

use std::path::{Path, PathBuf};

use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("model-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const SMALL_RIG: &str = include_str!("../../../rig-configs/bonn-gonio-sim-small.toml");
const LIGHT_LINE: &str = "calibration = \"builtin:bonn-gonio-sim-light\"";

/// The tests' small plan on the rig file `rig.toml` next to it, with `exposure`.
fn plan(exposure: &str) -> String {
    include_str!("../../../tests/data/tiny-plan.toml")
        .replace("SEED", "5")
        .replace("config = \"builtin:bonn-gonio-sim\"", "config = \"rig.toml\"")
        .replace("[exposure]\nmode = \"auto\"", exposure)
        .replace("[run]\nfault_scenario = \"FAULTS\"", "")
}

fn request(dir: &Path, rig: &str, exposure: &str) -> RunRequest {
    assert!(SMALL_RIG.contains(LIGHT_LINE), "the small rig names its light calibration");
    std::fs::write(dir.join("rig.toml"), rig).unwrap();
    RunRequest::from_text(plan(exposure), &dir.join("plan.toml"), &dir.join("dataset"))
}

#[test]
fn a_missing_calibration_file_is_named_and_nothing_is_created() {
    btfrig_sim_backend::install();
    let dir = scratch("missing");
    let rig = SMALL_RIG.replace(LIGHT_LINE, "calibration = \"lamp-light.toml\"");
    let fixed = "[exposure]\nmode = \"fixed\"\nexposure_s = 0.004";
    let e = run(&request(&dir, &rig, fixed), &RunControl::new(), &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("[lamp] calibration") && e.contains("lamp-light.toml"), "{e}");
    assert!(!dir.join("dataset").exists(), "a dataset was created: {e}");
    // Auto exposure needs the lamp's brightness: refused, naming what to do.
    let none = SMALL_RIG.replace(LIGHT_LINE, "");
    let e = run(&request(&dir, &none, "[exposure]\nmode = \"auto\""), &RunControl::new(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("no light calibration") && e.contains("exposure_s"), "{e}");
    assert!(!dir.join("dataset").exists());
}

#[test]
fn without_a_light_calibration_textures_are_relative_and_the_report_says_so() {
    btfrig_sim_backend::install();
    let fixed = "[exposure]\nmode = \"fixed\"\nexposure_s = 0.004";
    let dir = scratch("relative");
    let with = run(&request(&dir, SMALL_RIG, fixed), &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(with.outcome, RunOutcome::Finished);
    assert!(with.texture_rel_rmse.is_some_and(|e| e < 0.3), "{with:?}");
    let (_, _, absolute) = btfrig_imageio::read_rgb_exr(&first_texture(&dir)).unwrap();

    let dir = scratch("relative-none");
    let none = SMALL_RIG.replace(LIGHT_LINE, "");
    let without = run(&request(&dir, &none, fixed), &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(without.outcome, RunOutcome::Finished);
    assert_eq!(without.captures, with.captures);
    // Nothing to compare relative units with: no truth figure, and the report says why.
    assert_eq!(without.texture_rel_rmse, None);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dataset/report.json")).unwrap()).unwrap();
    let notes = report["processing"]["notes"].to_string();
    assert!(notes.contains("no light calibration: textures in relative units"), "{notes}");
    assert!(report["processing"]["sources"]["light"].as_str().unwrap().starts_with("none"), "{report}");
    // Relative units are full scales per second: the same frames give the calibrated texture
    // times W_g / full scale (the light calibration's green white rate, e-/s, over the
    // sensor's full scale, e-), to half-float rounding.
    let (_, _, relative) = btfrig_imageio::read_rgb_exr(&first_texture(&dir)).unwrap();
    let green = |t: &[[f32; 3]]| t.iter().map(|p| f64::from(p[1])).sum::<f64>();
    let k = green(&relative) / green(&absolute);
    let w_g = 4_739_615.569_731_943; // calibration/bonn-gonio-sim-light.toml
    let full_scale_e = (16383.0_f64.min(256.0 + ((40000.0_f64 - 12.0) / 2.5).floor()) - 256.0) * 2.5;
    let expected = w_g / full_scale_e;
    assert!((k / expected - 1.0).abs() < 2e-3, "relative / absolute = {k}, expected {expected}");
    assert!(relative.iter().flatten().all(|v| v.is_finite()), "a relative texel overflowed the file format");
}

fn first_texture(dir: &Path) -> PathBuf {
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(dir.join("dataset/textures")).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    files.into_iter().find(|p| p.extension().is_some_and(|e| e == "exr")).expect("a texture")
}
