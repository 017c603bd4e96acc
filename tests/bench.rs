//! `btfrig bench registration` on a tiny configuration, as a person runs it: the real binary,
//! one rendered frame with positioning error, the table it prints. And the 12-megapixel rig
//! config the benchmark is documented with validates.

mod support;

use btfrig_core::config::RigConfig;
use support::{btfrig, ok, repo};

/// The figures of one row of the totals table: (setting, filter) -> (texel mean, rel_area).
fn row(stdout: &str, setting: &str, filter: &str) -> (f64, f64) {
    let line = stdout
        .lines()
        .find(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            w.len() == 13 && w[0] == setting && w[1] == filter
        })
        .unwrap_or_else(|| panic!("no totals row {setting} {filter} in:\n{stdout}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    (w[6].parse().unwrap(), w[10].parse().unwrap())
}

#[test]
fn bench_registration_runs_and_registration_beats_the_nominal_pose() {
    let stdout = ok(btfrig().args(["bench", "registration", "--views", "45,90", "--size", "32", "--repeat", "1"]));
    let (nominal_tx, _) = row(&stdout, "nominal", "bilinear");
    let (true_tx, _) = row(&stdout, "true", "bilinear");
    assert!(true_tx < 1e-9, "the true pose has no texel error: {true_tx}");
    assert!(nominal_tx > 0.01, "the seeded positioning error must show: {nominal_tx}");
    for setting in ["dlt", "lm", "lm+prior"] {
        let (tx, _) = row(&stdout, setting, "bilinear");
        assert!(tx < nominal_tx / 3.0, "{setting}: {tx} texel vs nominal {nominal_tx}\n{stdout}");
    }
    // Every filter has a row for every setting.
    for filter in ["bilinear", "supersample2", "supersample4", "footprint4", "ewa"] {
        let (_, rel) = row(&stdout, "lm", filter);
        assert!(rel > 0.0 && rel < 0.5, "lm {filter}: rel_area {rel}");
    }
    assert!(stdout.contains("opencv = not run"), "{stdout}");
}

#[test]
fn bench_registration_refuses_bad_arguments() {
    let out = btfrig().args(["bench", "registration", "--size", "2"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--size 2"));
    let out = btfrig().args(["bench", "registration", "--views", "95,0"]).output().unwrap();
    assert!(!out.status.success());
}

#[test]
fn twelve_megapixel_rig_validates_and_images_the_same_field_of_view() {
    let text = std::fs::read_to_string(repo("rig-configs/bonn-gonio-sim-12mp.toml")).unwrap();
    let big = RigConfig::from_toml(&text, "bonn-gonio-sim-12mp.toml").unwrap();
    big.validate().unwrap();
    let text = std::fs::read_to_string(repo("rig-configs/bonn-gonio-sim.toml")).unwrap();
    let base = RigConfig::from_toml(&text, "bonn-gonio-sim.toml").unwrap();
    assert_eq!(big.camera.width_px * big.camera.height_px, 12_000_000);
    let (cb, cs) = (big.camera.to_model().unwrap(), base.camera.to_model().unwrap());
    // Same ray through the same relative image position: pixel x of the default maps to
    // 2.5 (x + 0.5) - 0.5 of the 12 MP camera (pixel centres at integers).
    for (x, y) in [(0.0, 0.0), (1599.0, 1199.0), (300.0, 900.0)] {
        let a = cs.pixel_ray(nalgebra::Point2::new(x, y));
        let b = cb.pixel_ray(nalgebra::Point2::new(2.5 * (x + 0.5) - 0.5, 2.5 * (y + 0.5) - 0.5));
        assert!((a - b).norm() < 1e-12, "{a} vs {b}");
    }
    // The sensor is as wide: pitch x width unchanged.
    let w = |c: &RigConfig| c.sensor.pixel_pitch_um * c.camera.width_px as f64;
    assert!((w(&big) - w(&base)).abs() < 1e-9);
}

/// The first number after `key` on the line that contains it.
fn figure_after(stdout: &str, key: &str) -> f64 {
    let line = stdout.lines().find(|l| l.contains(key)).unwrap_or_else(|| panic!("no {key:?} in:\n{stdout}"));
    let rest = &line[line.find(key).unwrap() + key.len()..];
    rest.split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .find(|t| !t.is_empty())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no number after {key:?} in {line:?}"))
}

/// `btfrig bench pipeline` on one view of the default rig: every stage has its row, the frame
/// registers in the predicted windows to a small error against the truth, and the fast HDR
/// merge uses the same exposures as the reference merge and gives the same rates.
#[test]
fn bench_pipeline_runs_and_reports_stages_errors_and_the_hdr_merge() {
    let stdout = ok(btfrig().args(["bench", "pipeline", "--views", "45,90", "--size", "32", "--repeat", "1"]));
    for stage in ["demosaic", "marker detection", "registration / homography", "rectification", "total"] {
        assert!(stdout.lines().any(|l| l.starts_with(stage)), "no {stage:?} row:\n{stdout}");
    }
    assert!(stdout.contains("1 of 1 frame(s) searched in predicted windows (0 fell back"), "{stdout}");
    let texel = figure_after(&stdout, "against the truth: btfrig texel ");
    let corner = figure_after(&stdout, "corner RMS ");
    assert!(texel < 0.005 && corner < 0.07, "texel {texel}, corner RMS {corner} px:\n{stdout}");
    assert!(stdout.contains("same exposures used true"), "{stdout}");
    let diff = figure_after(&stdout, "largest relative difference ");
    assert!(diff < 1e-6, "the fast HDR merge differs from the reference by {diff}:\n{stdout}");
}
