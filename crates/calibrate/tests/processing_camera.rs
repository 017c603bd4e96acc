//! `processing_camera`: which camera model the pipeline processes frames with, and plan
//! parsing. No rendering here (see `rig_calibration.rs`).

use btfrig_calibrate::{processing_camera, CalibrationPlan, RigCalibError};
use btfrig_core::config::RigConfig;
use btfrig_intrinsics::CalibrationFile;

fn rig() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap()
}

#[test]
fn without_a_calibration_the_configs_own_camera_is_used() {
    let mut cfg = rig();
    // The default rig names the shipped calibration; without it the lens itself is used.
    assert_eq!(cfg.camera.calibration.as_deref(), Some("builtin:bonn-gonio-sim-geometry"));
    cfg.camera.calibration = None;
    assert_eq!(processing_camera(&cfg, None).unwrap(), cfg.camera.to_model().unwrap());
}

#[test]
fn a_builtin_calibration_replaces_the_geometry_and_keeps_the_rest() {
    let mut cfg = rig();
    cfg.camera.calibration = Some("builtin:bonn-gonio-sim-geometry".into());
    cfg.validate().unwrap();
    let cam = processing_camera(&cfg, None).unwrap();
    let file =
        CalibrationFile::from_toml(include_str!("../../../calibration/bonn-gonio-sim-geometry.toml"), "x").unwrap();
    assert_eq!(cam.fx, file.camera.fx_px);
    assert_eq!(cam.cy, file.camera.cy_px);
    assert_eq!(cam.distortion.k2, file.camera.k2);
    assert_eq!(cam.vignetting, cfg.camera.to_model().unwrap().vignetting);
    // The truth (what the renderer images with) is untouched.
    assert_eq!(cfg.camera.fx_px, 4800.0);
}

#[test]
fn a_file_is_found_relative_to_the_rig_file() {
    let dir = std::env::temp_dir().join(format!("btfrig-camcal-pc-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("cal")).unwrap();
    let mut file =
        CalibrationFile::from_toml(include_str!("../../../calibration/bonn-gonio-sim-geometry.toml"), "x").unwrap();
    file.camera.fx_px = 4810.0;
    std::fs::write(dir.join("cal/mine.toml"), file.to_toml()).unwrap();
    let mut cfg = rig();
    cfg.camera.calibration = Some("cal/mine.toml".into());
    let cam = processing_camera(&cfg, Some(&dir.join("rig.toml"))).unwrap();
    assert_eq!(cam.fx, 4810.0);
    // Another image size is refused, naming both sizes.
    file.camera.width_px = 800;
    std::fs::write(dir.join("cal/mine.toml"), file.to_toml()).unwrap();
    let e = processing_camera(&cfg, Some(&dir.join("rig.toml"))).unwrap_err().to_string();
    assert!(e.contains("800 x 1200") && e.contains("1600 x 1200"), "{e}");
    // A missing file names the path it looked at.
    cfg.camera.calibration = Some("cal/none.toml".into());
    let e = processing_camera(&cfg, Some(&dir.join("rig.toml"))).unwrap_err();
    assert!(matches!(e, RigCalibError::Reference { .. }));
    assert!(e.to_string().contains("cal/none.toml"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_unknown_builtin_lists_the_known_ones() {
    let mut cfg = rig();
    cfg.camera.calibration = Some("builtin:nope".into());
    let e = processing_camera(&cfg, None).unwrap_err().to_string();
    assert!(e.contains("nope") && e.contains("bonn-gonio-sim-geometry"), "{e}");
}

#[test]
fn the_default_plan_parses_and_bad_plans_name_fields() {
    let p = CalibrationPlan::default_plan();
    assert!(p.views().len() >= 20);
    // Every view reachable on the default rig, lamp and camera apart.
    let g = btfrig_core::kinematics::Gonio::new(rig().geometry).unwrap();
    for v in p.views() {
        g.ik(p.light_for(v), v).unwrap();
    }
    let e =
        CalibrationPlan::from_toml("format_version = 2\nname = \"x\"\nrings = []\n", "p.toml").unwrap_err().to_string();
    assert!(e.contains("p.toml") && e.contains("format_version") && e.contains("rings"), "{e}");
    let e = CalibrationPlan::from_toml("format_version = 1\nname = \"x\"\nzoom = 2\nrings = []\n", "p.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("zoom"), "{e}");
}
