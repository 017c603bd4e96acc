//! `btfrig calibrate geometry` on small cases: the real binary, its exit status, its output
//! and the file it writes.

use std::path::PathBuf;
use std::process::Command;

use btfrig_intrinsics::CalibrationFile;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("btfrig-calibrate-test-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A quick plan: the default board, 9 views at three tilts.
const SMALL_PLAN: &str = r#"
format_version = 1
name = "small"
passes = 1
estimate_k3 = false
[target]
[[rings]]
theta_deg = 0.0
count = 1
phi_offset_deg = 10.0
[[rings]]
theta_deg = 25.0
count = 4
phi_offset_deg = 10.0
[[rings]]
theta_deg = 50.0
count = 4
phi_offset_deg = 55.0
"#;

#[test]
fn small_plan_calibrates_and_writes_a_file_that_parses() {
    let dir = tmp("ok");
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, SMALL_PLAN).unwrap();
    let out = dir.join("cal.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_btfrig"))
        .args(["calibrate", "geometry", "--plan"])
        .arg(&plan)
        .arg("--out")
        .arg(&out)
        .args(["--seed", "7"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    for needle in
        ["fx_px", "cy_px", "p2", "RMS reprojection error", "views used 9 of 9", "principal point error", "wrote"]
    {
        assert!(stdout.contains(needle), "missing {needle:?} in\n{stdout}");
    }
    let text = std::fs::read_to_string(&out).unwrap();
    let f = CalibrationFile::from_toml(&text, "cal.toml").unwrap();
    assert_eq!((f.camera.width_px, f.camera.height_px), (1600, 1200));
    assert_eq!(f.fit.views, 9);
    assert!(f.fit.points > 9 * 150, "{}", f.fit.points);
    assert!(f.fit.rms_px > 0.0 && f.fit.rms_px < 0.3, "{}", f.fit.rms_px);
    // 9 views, k3 held: a rough but sane camera (a single tilt of 35 degrees gave 1.4 %).
    assert!((f.camera.fx_px / 4800.0 - 1.0).abs() < 0.01, "{}", f.camera.fx_px);
    assert!(f.fit.source.contains("--seed 7"), "{}", f.fit.source);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_board_out_of_view_fails_with_a_clear_message() {
    let dir = tmp("fail");
    let plan = dir.join("plan.toml");
    // Four markers 0.5 m apart: all outside the 0.4 x 0.3 m field.
    std::fs::write(
        &plan,
        "format_version = 1\nname = \"away\"\n[target]\nmarkers_per_side = 2\nmarker_size_m = 0.05\npitch_m = 0.5\n\
         [[rings]]\ntheta_deg = 20.0\ncount = 4\n",
    )
    .unwrap();
    let out = dir.join("cal.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_btfrig"))
        .args(["calibrate", "geometry", "--plan"])
        .arg(&plan)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("only 0 of 4 calibration views"), "{stderr}");
    assert!(!out.exists());
    // A bad plan is named.
    std::fs::write(
        &plan,
        "format_version = 1\nname = \"bad\"\nlight_theta_deg = 95.0\n[[rings]]\ntheta_deg = 0.0\ncount = 0\n",
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_btfrig"))
        .args(["calibrate", "geometry", "--plan"])
        .arg(&plan)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("light_theta_deg") && stderr.contains("rings[0].count"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}
