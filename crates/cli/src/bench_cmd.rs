//! `btfrig bench render`: frame render time with and without the renderer's skips, side by
//! side, with the difference between the two images (the skips must not change the image).
//!
//! `btfrig bench registration`: display of [`crate::bench_registration`]'s measurements, and
//! the OpenCV peer run through `tests/markers/bench_opencv.py` on the same frames.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use nalgebra::{Matrix3, Point2};

use crate::args::BenchRegistrationArgs;
use crate::bench_registration::{Bench, Frame, SettingResult, FILTERS};

/// A timed pose: (name, light (theta, phi), view (theta, phi)), angles in degrees.
type Pose = (&'static str, (f64, f64), (f64, f64));

/// The poses every material is timed at.
const POSES: [Pose; 3] = [
    ("frontal", (45.0, 0.0), (0.0, 0.0)),
    ("oblique", (30.0, 120.0), (45.0, 0.0)),
    ("grazing", (75.0, 90.0), (75.0, 270.0)),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs the benchmark and prints one row per (material, pose).
pub fn render(rig: Option<&std::path::Path>, materials: &[String], texels: usize, repeat: usize) -> anyhow::Result<()> {
    anyhow::ensure!((2..=4096).contains(&texels), "--texels {texels}: allowed 2..=4096");
    anyhow::ensure!((1..=100).contains(&repeat), "--repeat {repeat}: allowed 1..=100");
    let cfg = crate::rig::load(rig)?;
    let names: Vec<String> = if materials.is_empty() {
        crate::material::names().iter().map(|s| s.to_string()).collect()
    } else {
        materials.to_vec()
    };
    println!(
        "render benchmark: {}x{} frame, {texels}x{texels}-texel sample, {} rayon threads, median of {repeat}",
        cfg.camera.width_px,
        cfg.camera.height_px,
        rayon::current_num_threads()
    );
    println!(
        "{:<16} {:<8} {:>10} {:>10} {:>6} {:>10} {:>10} {:>12} {:>12} {:>10}",
        "material",
        "pose",
        "skips (s)",
        "none (s)",
        "ratio",
        "max diff",
        "traced %",
        "shadow rays",
        "skipped rays",
        "sensor (s)"
    );
    for name in &names {
        let material = crate::material::load(Some(name))?.with_texels(texels);
        let scene = RigScene::new(&cfg, &material)?;
        for (pose_name, (lt, lp), (vt, vp)) in POSES {
            let joints = scene
                .gonio()
                .ik(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp))
                .map_err(|r| anyhow::anyhow!("bench pose {pose_name} unreachable: {r}"))?;
            let on = RenderOptions::with_skips(true);
            let off = RenderOptions::with_skips(false);
            // One untimed render of each warms caches and gives the images to compare.
            let (img_on, st_on) = scene.radiance(&joints, 1.0, &on);
            let (img_off, _) = scene.radiance(&joints, 1.0, &off);
            let mut t_on = Vec::new();
            let mut t_off = Vec::new();
            for _ in 0..repeat {
                // Interleaved, so a load change on this noisy machine hits both alike.
                let t = Instant::now();
                std::hint::black_box(scene.radiance(&joints, 1.0, &on));
                t_on.push(t.elapsed().as_secs_f64());
                let t = Instant::now();
                std::hint::black_box(scene.radiance(&joints, 1.0, &off));
                t_off.push(t.elapsed().as_secs_f64());
            }
            let peak = img_off.max_value().max(f32::MIN_POSITIVE);
            let diff = img_on
                .data
                .iter()
                .zip(&img_off.data)
                .flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs()))
                .fold(0.0f32, f32::max)
                / peak;
            let exposure = scene.exposure_for_white(0.6, 1e-4, 30.0);
            let t = Instant::now();
            std::hint::black_box(scene.sensor().capture(&img_on, exposure, 1.0, 1)?);
            let sensor_s = t.elapsed().as_secs_f64();
            let (m_on, m_off) = (median(t_on), median(t_off));
            println!(
                "{:<16} {:<8} {:>10.3} {:>10.3} {:>6.2} {:>10.1e} {:>10.1} {:>12} {:>12} {:>10.3}",
                name,
                pose_name,
                m_on,
                m_off,
                m_off / m_on,
                diff,
                100.0 * st_on.pixels_traced as f64 / st_on.pixels.max(1) as f64,
                st_on.shadow_rays,
                st_on.shadow_rays_skipped,
                sensor_s
            );
        }
    }
    println!("max diff: largest |skips - none| over all pixels and channels, relative to the image's peak");
    Ok(())
}

// ---- `btfrig bench registration` ----

/// Views of the benchmark when none are given (theta, phi in degrees; light at 45, 0).
const DEFAULT_VIEWS: [(f64, f64); 6] =
    [(0.0, 0.0), (45.0, 90.0), (45.0, 270.0), (75.0, 90.0), (75.0, 270.0), (80.0, 90.0)];

/// Order of the settings in the tables.
const SETTINGS: [&str; 6] = ["nominal", "true", "dlt", "lm", "lm+prior", "opencv"];

/// Totals of one (setting, filter) over the frames of one rig.
#[derive(Default)]
struct Agg {
    detect_s: Vec<f64>,
    register_s: Vec<f64>,
    rectify_s: Vec<f64>,
    texel_mean: Vec<f64>,
    texel_max: f64,
    corner_sq: f64,
    corner_n: usize,
    point: (f64, f64),
    area: (f64, f64),
    clean: (f64, f64),
    failed: usize,
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

impl Agg {
    fn add(&mut self, s: &SettingResult, f: Option<&crate::bench_registration::FilterResult>) {
        if s.error.is_some() {
            self.failed += 1;
            return;
        }
        self.detect_s.push(s.detect_s);
        self.register_s.push(s.register_s);
        self.texel_mean.push(s.texel.0);
        self.texel_max = self.texel_max.max(s.texel.1);
        if let Some(c) = s.corner_rms_px {
            self.corner_sq += c * c;
            self.corner_n += 1;
        }
        if let Some(f) = f {
            self.rectify_s.push(f.rectify_s);
            self.point = (self.point.0 + f.point.0, self.point.1 + f.point.1);
            self.area = (self.area.0 + f.area.0, self.area.1 + f.area.1);
            self.clean = (self.clean.0 + f.clean_area.0, self.clean.1 + f.clean_area.1);
        }
    }
    fn total_ms(&self) -> f64 {
        1e3 * (mean(&self.detect_s) + mean(&self.register_s) + mean(&self.rectify_s))
    }
    fn rel(p: (f64, f64)) -> f64 {
        (p.0 / p.1).sqrt()
    }
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The python of the OpenCV venv that `tests/install-deps.sh` makes
/// (`$CARGO_TARGET_DIR` or `target/`, then `pydeps/opencv`; opencv-python-headless and numpy
/// pinned with hashes in `tests/requirements/opencv.txt`), or why there is none. A system
/// `cv2` is never used: its version would decide the comparison.
fn python_with_opencv() -> Result<Command, String> {
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

fn write_f32(path: &Path, values: impl Iterator<Item = f32>) -> anyhow::Result<()> {
    let bytes: Vec<u8> = values.flat_map(f32::to_le_bytes).collect();
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Runs OpenCV on `frame` (files in a fresh temp dir, removed afterwards) and measures its
/// result with our truth.
fn run_opencv(
    python: &mut Command,
    b: &Bench,
    frame: &Frame,
    repeat: usize,
    index: usize,
) -> anyhow::Result<(SettingResult, String)> {
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
        });
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
        Ok((s, version))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn fmt(v: f64, prec: usize) -> String {
    if v.is_finite() {
        format!("{v:.prec$}")
    } else {
        "-".into()
    }
}

/// Runs the benchmark and prints the tables.
pub fn registration(a: &BenchRegistrationArgs) -> anyhow::Result<()> {
    anyhow::ensure!((1..=100).contains(&a.repeat), "--repeat {}: allowed 1..=100", a.repeat);
    let views: Vec<(f64, f64)> = if a.views.is_empty() {
        DEFAULT_VIEWS.to_vec()
    } else {
        a.views.iter().map(|d| (d.theta.to_degrees(), d.phi.to_degrees())).collect()
    };
    let rigs: Vec<(String, RigConfig)> = if a.rig.is_empty() {
        vec![("bonn-gonio-sim (embedded)".into(), crate::rig::load(None)?)]
    } else {
        a.rig
            .iter()
            .map(|p| Ok((p.display().to_string(), crate::rig::load(Some(p))?)))
            .collect::<anyhow::Result<_>>()?
    };
    let material = crate::material::load(Some(&a.material))?;
    let mut python = if a.opencv {
        match python_with_opencv() {
            Ok(p) => Some(p),
            Err(why) => {
                println!("OpenCV not available ({why}); running without it");
                None
            }
        }
    } else {
        None
    };
    let mut opencv_version = None;
    println!(
        "registration benchmark: {} view(s) {:?} (light 45,0), {}x{} texels over the sample, material {}, seed {}, \
         median of {} repeat(s), {} rayon threads",
        views.len(),
        views,
        a.size,
        a.size,
        a.material,
        a.seed,
        a.repeat,
        rayon::current_num_threads()
    );
    // (rig label, image size, totals per (setting, filter)).
    type RigTotals = (String, String, BTreeMap<(usize, usize), Agg>);
    let mut all: Vec<RigTotals> = Vec::new();
    for (label, cfg) in rigs {
        let b = Bench::new(cfg, &material, a.size).with_context(|| format!("rig {label}"))?;
        let res = format!("{}x{}", b.camera().width, b.camera().height);
        println!("\n== rig {label}: {res} ==");
        let mut aggs: BTreeMap<(usize, usize), Agg> = BTreeMap::new();
        if a.per_view {
            println!(
                "{:<8} {:<9} {:>4} {:>9} {:>9} {:>8} {:>8} {:>8} {:>15} {:>9} {:>9} {:>9}",
                "view",
                "setting",
                "mk",
                "detect",
                "register",
                "tx mean",
                "tx max",
                "corner",
                "bias x,y",
                "pt bil",
                "area bil",
                "clean bil"
            );
        }
        for (k, &view) in views.iter().enumerate() {
            let frame = b.frame(view, a.seed + k as u64).with_context(|| format!("view {view:?}"))?;
            let mut results = b.run_ours(&frame, a.repeat)?;
            if let Some(py) = python.as_mut() {
                let mut cmd = Command::new(py.get_program());
                for (key, val) in py.get_envs() {
                    if let Some(v) = val {
                        cmd.env(key, v);
                    }
                }
                match run_opencv(&mut cmd, &b, &frame, a.repeat, k) {
                    Ok((s, v)) => {
                        opencv_version = Some(v);
                        results.push(s);
                    }
                    Err(e) => println!("OpenCV run failed on view {view:?}: {e:#}"),
                }
            }
            for s in &results {
                let si = SETTINGS.iter().position(|n| *n == s.setting).unwrap_or(SETTINGS.len());
                if s.filters.is_empty() {
                    aggs.entry((si, 0)).or_default().add(s, None);
                }
                for f in &s.filters {
                    let fi = FILTERS
                        .iter()
                        .position(|g| crate::bench_registration::filter_name(*g) == f.filter)
                        .unwrap_or(0);
                    aggs.entry((si, fi)).or_default().add(s, Some(f));
                }
                if a.per_view {
                    let bias = s.corner_bias_px.map_or("-".into(), |(x, y)| format!("{x:+.3},{y:+.3}"));
                    let f0 = s.filters.first();
                    let pick = |g: fn(&crate::bench_registration::FilterResult) -> f64| f0.map_or(f64::NAN, g);
                    println!(
                        "{:<8} {:<9} {:>4} {:>9} {:>9} {:>8} {:>8} {:>8} {:>15} {:>9} {:>9} {:>9}{}",
                        format!("{},{}", frame.view_deg.0, frame.view_deg.1),
                        s.setting,
                        s.markers,
                        fmt(s.detect_s * 1e3, 1),
                        fmt(s.register_s * 1e3, 2),
                        fmt(s.texel.0, 4),
                        fmt(s.texel.1, 3),
                        s.corner_rms_px.map_or("-".into(), |c| fmt(c, 3)),
                        bias,
                        fmt(pick(|f| f.rel_point()), 4),
                        fmt(pick(|f| f.rel_area()), 4),
                        fmt(pick(|f| f.rel_clean()), 4),
                        s.error.as_ref().map_or(String::new(), |e| format!("  FAILED: {e}"))
                    );
                }
            }
        }
        println!(
            "{:<9} {:<13} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>5}",
            "setting",
            "filter",
            "detect",
            "register",
            "rectify",
            "total ms",
            "tx mean",
            "tx max",
            "corner",
            "rel_pt",
            "rel_area",
            "clean",
            "fail"
        );
        for ((si, _fi), g) in &aggs {
            let setting = SETTINGS.get(*si).copied().unwrap_or("?");
            let filter = if setting == "opencv" {
                "linear".to_string()
            } else {
                crate::bench_registration::filter_name(FILTERS[*_fi])
            };
            println!(
                "{:<9} {:<13} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>5}",
                setting,
                filter,
                fmt(1e3 * mean(&g.detect_s), 1),
                fmt(1e3 * mean(&g.register_s), 2),
                fmt(1e3 * mean(&g.rectify_s), 1),
                fmt(g.total_ms(), 1),
                fmt(mean(&g.texel_mean), 4),
                fmt(g.texel_max, 3),
                fmt(if g.corner_n > 0 { (g.corner_sq / g.corner_n as f64).sqrt() } else { f64::NAN }, 3),
                fmt(Agg::rel(g.point), 4),
                fmt(Agg::rel(g.area), 4),
                fmt(Agg::rel(g.clean), 4),
                g.failed
            );
        }
        all.push((label, res, aggs));
    }
    if all.len() > 1 {
        println!("\n== side by side: total ms per frame | texel mean / max | rel_rmse area-averaged truth ==");
        print!("{:<9} {:<13}", "setting", "filter");
        for (_, res, _) in &all {
            print!(" | {:^32}", res);
        }
        println!();
        let keys: std::collections::BTreeSet<(usize, usize)> =
            all.iter().flat_map(|(_, _, m)| m.keys().copied()).collect();
        for key in keys {
            let setting = SETTINGS.get(key.0).copied().unwrap_or("?");
            let filter = if setting == "opencv" {
                "linear".to_string()
            } else {
                crate::bench_registration::filter_name(FILTERS[key.1])
            };
            print!("{setting:<9} {filter:<13}");
            for (_, _, m) in &all {
                match m.get(&key) {
                    Some(g) => print!(
                        " | {:>8} {:>7}/{:<6} {:>8}",
                        fmt(g.total_ms(), 1),
                        fmt(mean(&g.texel_mean), 4),
                        fmt(g.texel_max, 3),
                        fmt(Agg::rel(g.area), 4)
                    ),
                    None => print!(" | {:^32}", "-"),
                }
            }
            println!();
        }
    }
    println!(
        "\ndetect/register/rectify: ms per frame (median of repeats, mean over views); total = their sum. \
         tx: texel position error (mean over views of the per-frame mean; max over all). corner: RMS distance of \
         detected corners from the projected true ones, px. rel_pt / rel_area: texture rel_rmse against the \
         point-sampled / {0}x{0}-area-averaged ground truth, pooled over views; clean: the same rectification of the \
         noise-free radiance image (no sensor noise, no demosaic) against the area-averaged truth.",
        crate::bench_registration::BOX_SAMPLES
    );
    println!(
        "settings: nominal = kinematic pose; dlt = normalised DLT on all detected corners (undistorted), decomposed, \
         no LM; lm = marker-pair RANSAC + LM (PlateRegistrar::register_image); lm+prior = lm with a weak prior of \
         {:?} (deg, m); opencv = {} (aruco SUBPIX + undistortPoints + findHomography RANSAC; rectify = remap \
         undistort + warpPerspective INTER_LINEAR; times from Python's perf_counter around the cv2 calls).",
        crate::bench_registration::PRIOR_SIGMA,
        opencv_version.map_or("not run".to_string(), |v| format!("OpenCV {v}"))
    );
    Ok(())
}
