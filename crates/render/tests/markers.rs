//! Independent check of the marker plate: OpenCV's ArUco detector (Python, opencv-python-
//! headless) must find every marker id of a rendered plate, with corners within about a
//! pixel of the projected true corners. OpenCV comes from the venv `tests/install-deps.sh`
//! makes (`target/pydeps/opencv`); the test FAILS (no silent skip) without it.

use std::path::{Path, PathBuf};
use std::process::Command;

use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::{Pinhole, PixelRays, RenderOptions, Renderer};
use nalgebra::Vector3;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").canonicalize().unwrap()
}

fn resolver(name: &str) -> Result<([f64; 3], [f64; 3]), String> {
    let x = name.strip_prefix("flat:").and_then(|v| v.parse().ok()).unwrap_or(0.4);
    Ok(([x; 3], [x; 3]))
}

/// The python of the OpenCV venv that `tests/install-deps.sh` makes (`$CARGO_TARGET_DIR` or
/// `target/`, then `pydeps/opencv`; versions pinned with hashes in
/// `tests/requirements/opencv.txt`). Never a system `cv2`: its version would decide the check.
fn python_with_opencv() -> Command {
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| repo_root().join("target"));
    let python = target.join("pydeps/opencv/bin/python");
    assert!(
        python.exists(),
        "the marker check needs the OpenCV venv at {}: run tests/install-deps.sh",
        python.display()
    );
    let o = Command::new(&python).args(["-c", "import cv2"]).output().expect("the venv's python runs");
    assert!(o.status.success(), "{} cannot import cv2: {}", python.display(), String::from_utf8_lossy(&o.stderr));
    Command::new(python)
}

fn check_pose(r: &Renderer, cam: &Pinhole, pose: &ScenePose, label: &str, python: &mut Command) -> f64 {
    let img = r.render(pose, cam, &RenderOptions::default());
    // Expose for the plate, not for the glaze's highlight: the 90th percentile maps to 200.
    let mut g: Vec<f32> = img.data.iter().map(|p| p[1]).filter(|v| *v > 0.0).collect();
    g.sort_by(f32::total_cmp);
    let max = g[g.len() * 9 / 10] as f64 * 230.0 / 200.0;
    let gray: Vec<u8> =
        img.data.iter().map(|p| ((p[1] as f64 / max) * 230.0).round().clamp(0.0, 255.0) as u8).collect();
    let dir = repo_root().join("target/marker-check");
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join(format!("{label}.png"));
    image::GrayImage::from_raw(cam.width as u32, cam.height as u32, gray).unwrap().save(&png).unwrap();

    let script = repo_root().join("tests/markers/detect_aruco.py");
    let out =
        python.arg(&script).arg(&png).arg(r.scene().layout.dictionary_name()).output().expect("run detect_aruco.py");
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{label}: detector failed: {}", String::from_utf8_lossy(&out.stderr));
    eprintln!("{label}: {}", text.lines().last().unwrap_or(""));

    // Project the true corners: sample frame -> camera frame -> pixels.
    let cam_from_sample = pose.camera_to_world.inverse() * pose.sample_to_world;
    let mut worst: f64 = 0.0;
    let (mut sum_dx, mut sum_dy, mut n) = (0.0, 0.0, 0.0);
    let found: Vec<(u32, Vec<f64>)> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (v[0] as u32, v[1..].to_vec())
        })
        .collect();
    for m in r.scene().layout.markers() {
        let det = found
            .iter()
            .find(|(id, _)| *id == m.id)
            .unwrap_or_else(|| panic!("{label}: marker {} not found; found {found:?}", m.id));
        for (k, c) in m.corners_sample_m.iter().enumerate() {
            let p = cam_from_sample * nalgebra::Point3::new(c.x, c.y, 0.0);
            let [u, v] = cam.project(&Vector3::new(p.x, p.y, p.z)).unwrap();
            let e = ((det.1[2 * k] - u).powi(2) + (det.1[2 * k + 1] - v).powi(2)).sqrt();
            worst = worst.max(e);
            sum_dx += det.1[2 * k] - u;
            sum_dy += det.1[2 * k + 1] - v;
            n += 1.0;
            assert!(
                e < 1.0,
                "{label}: marker {} corner {k}: detected ({}, {}) vs true ({u:.3}, {v:.3})",
                m.id,
                det.1[2 * k],
                det.1[2 * k + 1]
            );
        }
    }
    assert_eq!(found.len(), r.scene().layout.markers().len(), "{label}: unexpected extra detections {found:?}");
    // The pixel-centre convention: OpenCV, like btfrig, puts integer coordinates at pixel
    // centres (AprilTag-family detectors at pixel corners). A convention mismatch would show as
    // a mean offset of half a pixel on both axes; the individual errors scatter around zero.
    let (mx, my) = (sum_dx / n, sum_dy / n);
    eprintln!("{label}: mean signed corner offset OpenCV - truth: ({mx:+.3}, {my:+.3}) px");
    assert!(mx.abs() < 0.15 && my.abs() < 0.15, "{label}: OpenCV corners offset by ({mx:.3}, {my:.3}) px on average");
    worst
}

#[test]
fn opencv_aruco_detector_reads_every_marker_at_the_true_corners() {
    let r = Renderer::new(&PlateConfig::default(), &MaterialSpec::builtin("glazed-tile").unwrap(), 1000.0, &resolver)
        .unwrap();
    let cam = Pinhole { width: 1600, height: 1200, fx: 8000.0, fy: 8000.0, cx: 799.5, cy: 599.5 };
    let light = Direction::from_degrees(20.0, 60.0);
    for (label, view) in [("frontal", (0.0, 0.0)), ("oblique-45", (45.0, 30.0)), ("oblique-60", (60.0, 200.0))] {
        let pose = ScenePose::looking_at(light, Direction::from_degrees(view.0, view.1), 1.5, 2.0);
        let mut py = python_with_opencv();
        let worst = check_pose(&r, &cam, &pose, label, &mut py);
        eprintln!("{label}: all 12 markers found, worst corner error {worst:.3} px");
    }
}
