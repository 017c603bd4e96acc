//! The OpenCV peer of the registration benchmark: `tests/markers/bench_opencv.py` run on the
//! same frames, its result measured with our truth.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context;
use nalgebra::{Matrix3, Point2};

use crate::registration::{Bench, Frame, SettingResult};

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The python of the OpenCV venv that `tests/install-deps.sh` makes
/// (`$CARGO_TARGET_DIR` or `target/`, then `pydeps/opencv`; opencv-python-headless and numpy
/// pinned with hashes in `tests/requirements/opencv.txt`), or why there is none. A system
/// `cv2` is never used: its version would decide the comparison.
pub fn python_with_opencv() -> Result<Command, String> {
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| repo_root().join("target"));
    let python = target.join("pydeps/opencv/bin/python");
    if !python.exists() {
        return Err(format!("no OpenCV venv at {}: run tests/install-deps.sh", python.display()));
    }
    let works = Command::new(&python).args(["-c", "import cv2, numpy"]).output().map(|o| o.status.success());
    if works.unwrap_or(false) {
        Ok(Command::new(python))
    } else {
        Err(format!("{} cannot import cv2: run tests/install-deps.sh again", python.display()))
    }
}

pub fn write_f32(path: &Path, values: impl Iterator<Item = f32>) -> anyhow::Result<()> {
    let bytes: Vec<u8> = values.flat_map(f32::to_le_bytes).collect();
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Runs OpenCV on `frame` (files in a fresh temp dir, removed afterwards) and measures its
/// result with our truth. With `pipeline`, OpenCV also demosaics the raw frame
/// (`cv2.cvtColor`) and warps its own RGB; the demosaic time comes back as the third value
/// (seconds; 0 otherwise).
pub fn run_opencv(
    python: &mut Command,
    b: &Bench,
    frame: &Frame,
    repeat: usize,
    index: usize,
    pipeline: bool,
) -> anyhow::Result<(SettingResult, String, f64)> {
    let dir = std::env::temp_dir().join(format!("btfrig-bench-opencv-{}-{index}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let result = (|| {
        let cam = b.camera();
        let d = &cam.distortion;
        let plate: Vec<serde_json::Value> = b
            .registrar
            .markers()
            .iter()
            .map(|m| serde_json::json!({"id": m.id, "corners": m.corners_sample_m.iter().map(|c| [c.x, c.y]).collect::<Vec<_>>()}))
            .collect();
        let r = b.region;
        let job = serde_json::json!({
            "width": cam.width, "height": cam.height,
            "K": [[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]],
            "dist": [d.k1, d.k2, d.p1, d.p2, d.k3],
            "dictionary": b.cfg.plate.marker_dictionary,
            "size": b.size, "region": [r.x_min, r.x_max, r.y_min, r.y_max],
            "plate": plate, "repeat": repeat,
            "pipeline": pipeline,
            "bayer": frame.raw.meta.bayer.map(|p| format!("{p:?}").to_uppercase()),
            "black": frame.raw.meta.black_level, "white": frame.raw.meta.white_level,
        });
        if pipeline {
            let bytes: Vec<u8> = frame.raw.data.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(dir.join("raw.u16"), bytes)?;
        }
        std::fs::write(dir.join("job.json"), job.to_string())?;
        write_f32(&dir.join("green.f32"), frame.green.iter().copied())?;
        write_f32(&dir.join("rgb.f32"), frame.rgb.data.iter().flat_map(|p| *p))?;
        write_f32(&dir.join("clean.f32"), frame.clean.0.data.iter().flat_map(|p| *p))?;
        let script = repo_root().join("tests/markers/bench_opencv.py");
        let out = python.arg(&script).arg(&dir).output().with_context(|| format!("cannot run {}", script.display()))?;
        anyhow::ensure!(out.status.success(), "bench_opencv.py failed: {}", String::from_utf8_lossy(&out.stderr));
        let res: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("result.json"))?)?;
        let version = res["opencv"].as_str().unwrap_or("?").to_string();
        let check = res["pixel_centre_check"].as_f64().unwrap_or(f64::NAN);
        anyhow::ensure!(
            (check - 10.25).abs() < 1.0 / 32.0,
            "OpenCV's warp does not put pixel centres at integers: {check}"
        );
        let detections: Vec<(u32, [Point2<f64>; 4])> = res["markers"]
            .as_array()
            .context("markers")?
            .iter()
            .map(|m| {
                let c = &m["corners"];
                let p =
                    |k: usize| Point2::new(c[k][0].as_f64().unwrap_or(f64::NAN), c[k][1].as_f64().unwrap_or(f64::NAN));
                (m["id"].as_u64().unwrap_or(u64::MAX) as u32, [p(0), p(1), p(2), p(3)])
            })
            .collect();
        let t = &res["times"];
        let ts = |k: &str| t[k].as_f64().unwrap_or(0.0);
        let demosaic_s = ts("demosaic_s");
        if res["H"].is_null() {
            let why = res["error"].as_str().unwrap_or("no homography").to_string();
            return Ok((
                SettingResult {
                    setting: "opencv".into(),
                    detect_s: ts("detect_s"),
                    register_s: 0.0,
                    markers: detections.len(),
                    corner_rms_px: None,
                    corner_bias_px: None,
                    texel: (f64::NAN, f64::NAN),
                    filters: Vec::new(),
                    error: Some(why),
                },
                version,
                demosaic_s,
            ));
        }
        let hv = &res["H"];
        let h = Matrix3::from_fn(|i, j| hv[i][j].as_f64().unwrap_or(f64::NAN));
        let read = |name: &str| -> anyhow::Result<Vec<[f32; 3]>> {
            let bytes = std::fs::read(dir.join(name)).with_context(|| format!("OpenCV's {name}"))?;
            let vals: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            Ok(vals.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        };
        let times =
            (ts("detect_s"), ts("undistort_points_s") + ts("homography_s"), ts("undistort_image_s") + ts("warp_s"));
        let textures = (read("texture.f32")?, read("texture_clean.f32")?);
        let s = b.evaluate_homography(frame, "opencv", "linear", &detections, &h, textures, times)?;
        Ok((s, version, demosaic_s))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}
