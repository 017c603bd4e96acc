//! Calibration procedures on a rig, from frames: a calibration plan ([`CalibrationPlan`],
//! `rig-configs/plans/calibration-*.toml`) says where the rig photographs a [`TargetBoard`]
//! mounted on the holder ([`plan_captures`]: the joint values of each view);
//! [`calibrate_captures`] detects the board's markers in the green channel of the captured
//! frames, pairs their corners with the board and calibrates; [`processing_camera`] is the
//! camera model the pipeline processes frames with (the calibrated one when the rig config
//! points to a calibration file). The colour ([`color`]), light ([`light`]) and dark/flat
//! ([`dark_flat`]) procedures work the same way.
//!
//! Everything here is a function of frames, the rig config and the plan: whoever took the
//! frames. The simulated rig's side (rendering the frames, comparing with the simulator's
//! truth) is `btfrig-sim-calibration`; this crate does not depend on the simulator. The
//! numerics are in `btfrig-intrinsics` (which knows nothing of rigs, renderers or files); this
//! crate is the procedure around them, and does I/O in one place only: [`processing_camera`]
//! reads the calibration file a rig config names.
#![warn(missing_docs)]

// The files, one job each:
// - lib:       the geometric calibration procedure (plan, board detection, calibrate) and processing_camera
// - color:     colour calibration from charts photographed in the sample region; processing_color
// - dark_flat: dark frames and master flats (radiometric calibration); processing_dark_flat
// - emva:      sensor characterisation after EMVA 1288 (gain, noise, dark current, DSNU, PRNU, ...)
// - light:     each light's power and colour from a white reference tile; the light calibration file
// - rig_geometry: joint zero offsets from registered marker poses; processing_joint_offsets
// - leds:      a dome's LED (or a camera array's flash) calibration; processing_leds

pub mod color;
pub mod dark_flat;
pub mod emva;
pub mod leds;
pub mod light;
pub mod rig_geometry;

use std::path::{Path, PathBuf};
use std::time::Instant;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::MarkerPlacement;
pub use btfrig_core::config::target::TargetBoard;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_markers::{detect, DetectParams, Detection, Dictionary, GrayImage};
use nalgebra::Point2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use btfrig_intrinsics::{
    calibrate, CalibError, Calibration, CalibrationFile, Correspondence, Options, View, MIN_POINTS_PER_VIEW,
};

/// Version of the calibration plan format.
pub const PLAN_FORMAT_VERSION: u32 = 1;

/// The default plan, embedded (`rig-configs/plans/calibration-geometry.toml`).
pub const DEFAULT_PLAN: &str = include_str!("../../../rig-configs/plans/calibration-geometry.toml");

/// Calibration files embedded in the binary, for `[camera] calibration = "builtin:NAME"`.
pub const BUILTIN_CALIBRATIONS: &[(&str, &str)] =
    &[("bonn-gonio-sim-geometry", include_str!("../../../calibration/bonn-gonio-sim-geometry.toml"))];

/// One ring of views: `count` view directions at polar angle `theta_deg`, evenly spread in
/// azimuth starting at `phi_offset_deg` (a ring at theta 0 is `count` frontal views whose
/// in-plane rotation steps instead).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ring {
    /// View polar angle from the board normal, degrees (0..=70).
    pub theta_deg: f64,
    /// Views on the ring (1..=72).
    pub count: usize,
    /// Azimuth of the first view, degrees.
    #[serde(default)]
    pub phi_offset_deg: f64,
}

/// A geometric calibration plan: the board and where to photograph it. Format in
/// `docs/camera-calibration.md`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationPlan {
    /// Format version ([`PLAN_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Name, for reports and the calibration file's source.
    pub name: String,
    /// The board mounted in place of the holder plate.
    #[serde(default)]
    pub target: TargetBoard,
    /// Polar angle of the lamp from the board normal, degrees; its azimuth is opposite the
    /// camera's (so lamp and camera stay apart and the matte board is evenly lit).
    #[serde(default = "CalibrationPlan::default_light_theta_deg")]
    pub light_theta_deg: f64,
    /// Exposure: a white reflector facing the lamp reaches this fraction of full scale.
    #[serde(default = "CalibrationPlan::default_exposure_fraction")]
    pub exposure_fraction: f64,
    /// The renderer's marker-edge supersampling (rays per pixel side) for these captures.
    #[serde(default = "CalibrationPlan::default_marker_supersampling")]
    pub marker_supersampling: u32,
    /// Detection passes: the first fits straight marker edges in the distorted image; each
    /// further pass re-detects with the previous pass's calibrated lens (edges undistorted
    /// before the line fits) and calibrates again.
    #[serde(default = "CalibrationPlan::default_passes")]
    pub passes: u32,
    /// Estimate k3 (else held at 0).
    #[serde(default = "CalibrationPlan::default_true")]
    pub estimate_k3: bool,
    /// Estimate the tangential terms p1, p2 (else held at 0).
    #[serde(default = "CalibrationPlan::default_true")]
    pub estimate_tangential: bool,
    /// The views, ring by ring.
    pub rings: Vec<Ring>,
}

impl CalibrationPlan {
    fn default_light_theta_deg() -> f64 {
        30.0
    }
    fn default_exposure_fraction() -> f64 {
        0.5
    }
    fn default_marker_supersampling() -> u32 {
        4
    }
    fn default_passes() -> u32 {
        2
    }
    fn default_true() -> bool {
        true
    }

    /// The embedded default plan.
    pub fn default_plan() -> CalibrationPlan {
        Self::from_toml(DEFAULT_PLAN, "<embedded rig-configs/plans/calibration-geometry.toml>")
            .expect("the embedded calibration plan is valid")
    }

    /// Parses and validates a plan; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<CalibrationPlan, RigCalibError> {
        let p: CalibrationPlan =
            toml::from_str(text).map_err(|e| RigCalibError::Plan { origin: origin.into(), message: e.to_string() })?;
        let problems = p.problems();
        if !problems.is_empty() {
            return Err(RigCalibError::Plan { origin: origin.into(), message: problems.join("; ") });
        }
        Ok(p)
    }

    /// Every invalid value, as messages naming the field.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.format_version != PLAN_FORMAT_VERSION {
            out.push(format!(
                "format_version = {} is not supported (this build reads {PLAN_FORMAT_VERSION})",
                self.format_version
            ));
        }
        if let Err(e) = self.target.validate() {
            out.push(e.to_string());
        }
        if !(self.light_theta_deg.is_finite() && (0.0..=80.0).contains(&self.light_theta_deg)) {
            out.push(format!("light_theta_deg = {}: allowed 0..=80", self.light_theta_deg));
        }
        if !(self.exposure_fraction > 0.0 && self.exposure_fraction <= 1.0) {
            out.push(format!("exposure_fraction = {}: allowed (0, 1]", self.exposure_fraction));
        }
        if !(1..=32).contains(&self.marker_supersampling) {
            out.push(format!("marker_supersampling = {}: allowed 1..=32", self.marker_supersampling));
        }
        if !(1..=4).contains(&self.passes) {
            out.push(format!("passes = {}: allowed 1..=4", self.passes));
        }
        if self.rings.is_empty() {
            out.push("rings: at least one ring of views is needed".into());
        }
        for (i, r) in self.rings.iter().enumerate() {
            if !(r.theta_deg.is_finite() && (0.0..=70.0).contains(&r.theta_deg)) {
                out.push(format!("rings[{i}].theta_deg = {}: allowed 0..=70", r.theta_deg));
            }
            if !(1..=72).contains(&r.count) {
                out.push(format!("rings[{i}].count = {}: allowed 1..=72", r.count));
            }
            if !r.phi_offset_deg.is_finite() {
                out.push(format!("rings[{i}].phi_offset_deg = {}: must be finite", r.phi_offset_deg));
            }
        }
        out
    }

    /// The view directions (board frame), in plan order.
    pub fn views(&self) -> Vec<Direction> {
        let mut v = Vec::new();
        for r in &self.rings {
            for k in 0..r.count {
                let phi = r.phi_offset_deg + 360.0 * k as f64 / r.count as f64;
                v.push(Direction::from_degrees(r.theta_deg, phi));
            }
        }
        v
    }

    /// The lamp direction that goes with a view: `light_theta_deg`, opposite azimuth (for a
    /// frontal view the azimuth is the view's, which steps the board's in-plane rotation).
    pub fn light_for(&self, view: Direction) -> Direction {
        Direction::new(self.light_theta_deg.to_radians(), view.phi + std::f64::consts::PI)
    }
}

/// Why a calibration on a rig failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RigCalibError {
    /// The plan file is invalid.
    #[error("calibration plan {origin}: {message}")]
    Plan {
        /// File name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// The rig (config, kinematics, a capture) cannot take or measure the plan's captures.
    #[error("simulated rig: {0}")]
    Rig(String),
    /// Too few views had enough detected board corners.
    #[error(
        "only {usable} of {planned} calibration views show at least {min_points} board corners (need {need} views); \
         skipped: {skipped}"
    )]
    TooFewViews {
        /// Views planned.
        planned: usize,
        /// Views usable.
        usable: usize,
        /// Views needed.
        need: usize,
        /// Points a view needs.
        min_points: usize,
        /// Why each skipped view was skipped.
        skipped: String,
    },
    /// The calibration itself failed.
    #[error("calibration: {0}")]
    Calibrate(#[from] CalibError),
    /// The rig config's calibration reference cannot be used.
    #[error("[camera] calibration = {reference:?}: {message}")]
    Reference {
        /// The field's value.
        reference: String,
        /// What is wrong.
        message: String,
    },
}

/// One capture of the plan and what was detected in it.
#[derive(Debug, Clone)]
pub struct CaptureReport {
    /// View direction (board frame).
    pub view: Direction,
    /// Joint values the board was photographed at.
    pub joints: JointState,
    /// Board markers detected (last pass).
    pub markers: usize,
    /// Why the view was not used, if it was not.
    pub skipped: Option<String>,
}

/// Result of [`calibrate_captures`].
#[derive(Debug, Clone)]
pub struct RigCalibration {
    /// The calibration of the last pass (views: the used captures, in plan order).
    pub calibration: Calibration,
    /// Every planned capture.
    pub captures: Vec<CaptureReport>,
    /// Board corners detected over the used views (last pass).
    pub points_detected: usize,
    /// Seconds capturing (on the simulated rig: rendering) frames, as [`BoardCaptures`] says.
    pub render_s: f64,
    /// Seconds detecting markers (all passes).
    pub detect_s: f64,
    /// Seconds calibrating (all passes).
    pub calibrate_s: f64,
    /// Passes run.
    pub passes: u32,
    /// The correspondences of the last pass, one per used view (captures without a skip
    /// reason, in plan order).
    pub views: Vec<View>,
}

impl RigCalibration {
    /// Number of views used.
    pub fn views_used(&self) -> usize {
        self.captures.iter().filter(|c| c.skipped.is_none()).count()
    }
}

/// Detector settings for a board: the adaptive-threshold window spans about three modules
/// of the frontal board (the default 51 px is tuned for the plate's 13 px modules; a window
/// inside one large black module would see no contrast).
pub fn detect_params(board: &TargetBoard, camera_distance_m: f64, fx_px: f64) -> DetectParams {
    let module_px = fx_px * board.marker_size_m / board.modules() as f64 / camera_distance_m;
    let win = ((3.0 * module_px) as usize).clamp(51, 301) | 1;
    DetectParams { threshold_window_px: win, max_side_frac: 0.9, ..DetectParams::default() }
}

/// Pairs detected corners with the board: four correspondences per detection (sigma: the
/// detector's per-corner standard deviation). A board may repeat its ids; each detection is
/// paired with the instance of its id whose predicted image centre (`predict`: board point
/// to pixel, from the kinematic pose and the nominal lens) is nearest, provided that it is
/// less than a third as far as the next instance's. Ids not on the board are ignored.
pub fn correspondences(
    markers: &[MarkerPlacement],
    detections: &[Detection],
    predict: &dyn Fn(Point2<f64>) -> Option<Point2<f64>>,
) -> Vec<Correspondence> {
    let mut out = Vec::with_capacity(4 * detections.len());
    let mut used = vec![false; markers.len()];
    for d in detections {
        let seen = nalgebra::center(
            &nalgebra::center(&d.corners[0], &d.corners[1]),
            &nalgebra::center(&d.corners[2], &d.corners[3]),
        );
        let mut best: Option<(f64, usize)> = None;
        let mut second = f64::INFINITY;
        for (k, m) in markers.iter().enumerate().filter(|(_, m)| m.id == d.id) {
            let c = nalgebra::center(&m.corners_sample_m[0], &m.corners_sample_m[2]);
            let dist = predict(c).map_or(f64::INFINITY, |p| (p - seen).norm());
            match best {
                Some((b, _)) if dist >= b => second = second.min(dist),
                _ => {
                    if let Some((b, _)) = best {
                        second = second.min(b);
                    }
                    best = Some((dist, k));
                }
            }
        }
        let Some((dist, k)) = best else { continue };
        if !(dist.is_finite() && dist < second / 3.0) || used[k] {
            continue;
        }
        used[k] = true;
        for c in 0..4 {
            out.push(Correspondence {
                target: markers[k].corners_sample_m[c],
                pixel: d.corners[c],
                sigma_px: Some(d.corner_sigma_px[c]),
            });
        }
    }
    out
}

/// Detects every marker of `image` although the detector reports each id once: after each
/// round the found markers (grown by their quiet zone) are painted over with the bright
/// level and the detector runs again, until a round finds nothing new (at most `rounds`).
pub fn detect_repeated(
    width: usize,
    height: usize,
    mut image: Vec<f32>,
    dict: &Dictionary,
    params: &DetectParams,
    rounds: usize,
) -> Result<Vec<Detection>, btfrig_markers::DetectError> {
    let mut all = Vec::new();
    // The bright level: a high percentile of the frame (the board's white).
    let mut sample: Vec<f32> = image.iter().step_by(97).copied().collect();
    sample.sort_by(|a, b| a.total_cmp(b));
    let white = sample.get(sample.len() * 9 / 10).copied().unwrap_or(1.0);
    for _ in 0..rounds {
        let found = detect(&GrayImage::new(width, height, &image)?, dict, params)?;
        if found.is_empty() {
            break;
        }
        for d in &found {
            // The quad grown by 1.25 about its centre: the quiet zone (one module of six each
            // side would be 1.33), leaving neighbours two modules away untouched.
            let c = nalgebra::center(
                &nalgebra::center(&d.corners[0], &d.corners[1]),
                &nalgebra::center(&d.corners[2], &d.corners[3]),
            );
            let q: Vec<Point2<f64>> = d.corners.iter().map(|p| c + (p - c) * 1.25).collect();
            let (x0, x1) = q.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| (a.0.min(p.x), a.1.max(p.x)));
            let (y0, y1) = q.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| (a.0.min(p.y), a.1.max(p.y)));
            let (xa, xb) = (x0.floor().max(0.0) as usize, (x1.ceil().max(0.0) as usize).min(width.saturating_sub(1)));
            let (ya, yb) = (y0.floor().max(0.0) as usize, (y1.ceil().max(0.0) as usize).min(height.saturating_sub(1)));
            // Inside a convex quad: the same side of all four edges.
            let cross = |a: &Point2<f64>, b: &Point2<f64>, p: &Point2<f64>| {
                (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
            };
            for y in ya..=yb {
                for x in xa..=xb {
                    let p = Point2::new(x as f64, y as f64);
                    let s: Vec<f64> = (0..4).map(|k| cross(&q[k], &q[(k + 1) % 4], &p)).collect();
                    if s.iter().all(|&v| v >= 0.0) || s.iter().all(|&v| v <= 0.0) {
                        image[y * width + x] = white;
                    }
                }
            }
        }
        all.extend(found);
    }
    Ok(all)
}

/// The green channel of a bilinear demosaic (the detector's input, `docs/markers.md`).
pub fn green(raw: &RawFrame) -> Vec<f32> {
    demosaic_bilinear(raw).data.iter().map(|p| p[1]).collect()
}

/// The raw frames of a plan's captures (`None`: view unreachable), however they were taken.
#[derive(Debug, Clone)]
pub struct BoardCaptures {
    /// One per planned view.
    pub frames: Vec<Option<RawFrame>>,
    /// One per planned view (detection fields not yet filled), as [`plan_captures`] gives them.
    pub captures: Vec<CaptureReport>,
    /// Seconds spent capturing.
    pub render_s: f64,
}

/// The captures of a valid `plan` on the rig `cfg`: per view the joint values from the rig's
/// nominal kinematics, or why the view is unreachable (then it is skipped, not an error).
pub fn plan_captures(cfg: &RigConfig, plan: &CalibrationPlan) -> Result<Vec<CaptureReport>, RigCalibError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(RigCalibError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let gonio = Gonio::new(cfg.geometry.clone()).map_err(|e| RigCalibError::Rig(e.to_string()))?;
    Ok(plan
        .views()
        .into_iter()
        .map(|view| match gonio.ik(plan.light_for(view), view) {
            Ok(joints) => CaptureReport { view, joints, markers: 0, skipped: None },
            Err(e) => CaptureReport {
                view,
                joints: JointState::default(),
                markers: 0,
                skipped: Some(format!("unreachable: {e}")),
            },
        })
        .collect())
}

/// Detects the board in captured frames and calibrates (`plan` supplies the board, passes
/// and estimated parameters; `shots` the frames of [`plan_captures`], `plan.passes` times,
/// see [`CalibrationPlan::passes`]). `progress` receives one line per pass.
pub fn calibrate_captures(
    cfg: &RigConfig,
    plan: &CalibrationPlan,
    shots: &BoardCaptures,
    mut progress: impl FnMut(&str),
) -> Result<RigCalibration, RigCalibError> {
    let gonio = Gonio::new(cfg.geometry.clone()).map_err(|e| RigCalibError::Rig(e.to_string()))?;
    // The lens the rig config states (for a real rig its nominal lens): only used to predict
    // roughly where each board marker appears.
    let nominal = cfg.camera.to_model().map_err(|e| RigCalibError::Rig(format!("[camera]: {e}")))?;
    if shots.frames.len() != shots.captures.len() {
        return Err(RigCalibError::Rig(format!(
            "{} frames for {} planned captures",
            shots.frames.len(),
            shots.captures.len()
        )));
    }
    let dict = Dictionary::by_name(&plan.target.dictionary).ok_or_else(|| {
        RigCalibError::Rig(format!("target.dictionary {:?} unknown to the detector", plan.target.dictionary))
    })?;
    let markers = plan.target.markers();
    let mut params = detect_params(&plan.target, cfg.geometry.rail_radius_m, cfg.camera.fx_px);
    let frames = &shots.frames;
    let mut captures = shots.captures.clone();
    let render_s = shots.render_s;

    let mut opts_cal = Options::new(nominal.width, nominal.height);
    opts_cal.estimate_k3 = plan.estimate_k3;
    opts_cal.estimate_tangential = plan.estimate_tangential;
    let (mut detect_s, mut calibrate_s) = (0.0, 0.0);
    let mut result = None;
    for pass in 0..plan.passes {
        // 2. Detect (with the previous pass's lens from the second pass on).
        let t = Instant::now();
        let mut views = Vec::new();
        let detected: Vec<Option<Result<Vec<Detection>, btfrig_markers::DetectError>>> = frames
            .par_iter()
            .map(|f| f.as_ref().map(|raw| detect_repeated(raw.width, raw.height, green(raw), &dict, &params, 4)))
            .collect();
        for (det, cap) in detected.into_iter().zip(captures.iter_mut()) {
            let Some(det) = det else { continue };
            let det = det.map_err(|e| RigCalibError::Rig(format!("detector: {e}")))?;
            // Where the kinematics and the nominal lens put each board point.
            let pose = gonio.scene_pose(&cap.joints);
            let s2c = pose.camera_to_world.inverse() * pose.sample_to_world;
            let predict = |p: Point2<f64>| nominal.project(&(s2c * nalgebra::Point3::new(p.x, p.y, 0.0)));
            let corr = correspondences(&markers, &det, &predict);
            cap.markers = corr.len() / 4;
            if corr.len() < MIN_POINTS_PER_VIEW.max(12) {
                cap.skipped = Some(format!("{} board markers detected and paired, need 3", corr.len() / 4));
            } else {
                cap.skipped = None;
                views.push(View { points: corr });
            }
        }
        detect_s += t.elapsed().as_secs_f64();
        let need = btfrig_intrinsics::MIN_VIEWS.max(4);
        if views.len() < need {
            let skipped = captures
                .iter()
                .enumerate()
                .filter_map(|(i, c)| {
                    c.skipped.as_ref().map(|s| {
                        let (th, ph) = c.view.to_degrees();
                        format!("view {i} (theta {th:.0}, phi {ph:.0}): {s}")
                    })
                })
                .collect::<Vec<_>>()
                .join(", ");
            return Err(RigCalibError::TooFewViews {
                planned: captures.len(),
                usable: views.len(),
                need,
                min_points: MIN_POINTS_PER_VIEW.max(12),
                skipped,
            });
        }
        let points: usize = views.iter().map(|v| v.points.len()).sum();
        // 3. Calibrate.
        let t = Instant::now();
        let cal = calibrate(&views, &opts_cal)?;
        calibrate_s += t.elapsed().as_secs_f64();
        progress(&format!(
            "pass {}: {} views, {points} corners, rms {:.4} px, fx {:.2} cx {:.2} cy {:.2}",
            pass + 1,
            views.len(),
            cal.rms_px,
            cal.camera.fx,
            cal.camera.cx,
            cal.camera.cy
        ));
        params.camera = Some(cal.camera.clone());
        result = Some((cal, points, views));
    }
    let (calibration, points_detected, views) = result.expect("at least one pass");
    Ok(RigCalibration {
        calibration,
        captures,
        points_detected,
        render_s,
        detect_s,
        calibrate_s,
        passes: plan.passes,
        views,
    })
}

/// The text of the calibration file a rig config's `[camera] calibration` names, with a name
/// for messages: `builtin:NAME` from [`BUILTIN_CALIBRATIONS`], else a path relative to the
/// rig file's directory (`rig_path`; the working directory when `None`).
pub fn read_calibration_reference(reference: &str, rig_path: Option<&Path>) -> Result<(String, String), RigCalibError> {
    let err = |message: String| RigCalibError::Reference { reference: reference.into(), message };
    if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, text) = BUILTIN_CALIBRATIONS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_CALIBRATIONS.iter().map(|(n, _)| *n).collect();
            err(format!("no built-in calibration {name:?} (built in: {})", known.join(", ")))
        })?;
        return Ok((text.to_string(), format!("<embedded calibration/{name}.toml>")));
    }
    let base: PathBuf = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
    let path = base.join(reference);
    let text = std::fs::read_to_string(&path).map_err(|e| err(format!("cannot read {}: {e}", path.display())))?;
    Ok((text, path.display().to_string()))
}

/// The camera model the pipeline processes frames with: the rig config's `[camera]` section
/// with its geometric fields replaced by the calibration file it names (`calibration`), or
/// the section as it is when it names none. A calibration of another image size is an error.
/// (The simulator's renderer keeps imaging with the section's own fields: the truth.)
pub fn processing_camera(rig: &RigConfig, rig_path: Option<&Path>) -> Result<CameraModel, RigCalibError> {
    let own = |e: btfrig_core::camera::CameraError| RigCalibError::Rig(format!("[camera]: {e}"));
    let Some(reference) = rig.camera.calibration.as_deref() else {
        return rig.camera.to_model().map_err(own);
    };
    let err = |message: String| RigCalibError::Reference { reference: reference.into(), message };
    let (text, origin) = read_calibration_reference(reference, rig_path)?;
    let file = CalibrationFile::from_toml(&text, &origin).map_err(|e| err(e.to_string()))?;
    let (w, h) = (file.camera.width_px, file.camera.height_px);
    if (w, h) != (rig.camera.width_px, rig.camera.height_px) {
        return Err(err(format!(
            "{origin} calibrates a {w} x {h} image, the rig's camera is {} x {}",
            rig.camera.width_px, rig.camera.height_px
        )));
    }
    let cfg = file.apply_to(&rig.camera);
    let mut errors = Vec::new();
    cfg.validate(&mut errors);
    if let Some(e) = errors.first() {
        return Err(err(format!("{origin}: {e}")));
    }
    cfg.to_model().map_err(|e| err(format!("{origin}: {e}")))
}
