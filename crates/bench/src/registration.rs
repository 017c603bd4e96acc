//! The measurement behind `btfrig bench registration`, free of I/O: render a frame of the
//! simulated rig at a TRUE joint state off the commanded one, estimate the sample pose in
//! several ways, rectify with every filter, and measure each result against the simulator's
//! truth (texel position error of the pose, texture error against the ground truth).
//!
//! The CLI's `bench_cmd.rs` does the printing; the OpenCV peer ([`crate::opencv`]) passes its
//! images and results through [`Bench::evaluate_homography`]. [`Agg`] totals the results of
//! one (setting, filter) for the tables.

use std::time::Instant;

use anyhow::Context;
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::homography::{decompose, dlt};
use btfrig_core::kinematics::JointState;
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::{rectify, to_radiance_factor, vignetting_map, Filter, LinearImage, Radiometry, Region};
use btfrig_markers::{detect, Detection, Dictionary, GrayImage};
use btfrig_registration::{
    back_project, register, sample_to_camera, texel_position_error, PlateRegistrar, RegisterOptions,
};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::options::{SimAxisOptions, SimRobotOptions};
use nalgebra::{Matrix3, Point2, Point3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// The filters every pose is rectified with.
pub const FILTERS: [Filter; 5] = [
    Filter::Bilinear,
    Filter::Supersample { n: 2 },
    Filter::Supersample { n: 4 },
    Filter::Footprint { max: 4 },
    Filter::Ewa,
];

/// Point samples per texel axis of the area-averaged ground truth.
pub const BOX_SAMPLES: usize = 4;

/// Weak Gaussian prior of the `lm+prior` setting: (rotation deg, translation m) per component,
/// about the rig's combined joint offset and jitter (docs/registration.md).
pub const PRIOR_SIGMA: (f64, f64) = (0.08, 0.0005);

/// Short name of a filter for tables.
pub fn filter_name(f: Filter) -> String {
    match f {
        Filter::Bilinear => "bilinear".into(),
        Filter::Supersample { n } => format!("supersample{n}"),
        Filter::Footprint { max } => format!("footprint{max}"),
        Filter::Ewa => "ewa".into(),
    }
}

/// Positioning error of the simulated devices (degrees), from the rig's `[devices]` options
/// (the simulator's defaults where the file is silent): a move lands at
/// `target + offset + jitter * N(0, 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositioningError {
    /// Robot joint offsets, degrees.
    pub robot_offset: [f64; 3],
    /// Robot joint jitter (standard deviation), degrees.
    pub robot_jitter: [f64; 3],
    /// Rail offset, degrees.
    pub rail_offset: f64,
    /// Rail jitter, degrees.
    pub rail_jitter: f64,
}

impl PositioningError {
    /// Reads the sim robot's and rail's `offset_deg` / `jitter_deg`.
    pub fn from_config(cfg: &RigConfig) -> anyhow::Result<Self> {
        let robot = SimRobotOptions::default();
        let rail = SimAxisOptions::rail();
        let ro = &cfg.devices.robot.options;
        let ra = &cfg.devices.rail.options;
        let arr3 = |t: &toml::Table, key: &str, default: [f64; 3]| -> anyhow::Result<[f64; 3]> {
            match t.get(key) {
                None => Ok(default),
                Some(v) => {
                    let a = v.as_array().filter(|a| a.len() == 3).with_context(|| format!("{key}: need 3 numbers"))?;
                    let num = |x: &toml::Value| x.as_float().or(x.as_integer().map(|i| i as f64));
                    let mut out = [0.0; 3];
                    for (k, o) in out.iter_mut().enumerate() {
                        *o = num(&a[k]).with_context(|| format!("{key}[{k}]: not a number"))?;
                    }
                    Ok(out)
                }
            }
        };
        let num = |t: &toml::Table, key: &str, default: f64| -> anyhow::Result<f64> {
            match t.get(key) {
                None => Ok(default),
                Some(v) => {
                    v.as_float().or(v.as_integer().map(|i| i as f64)).with_context(|| format!("{key}: not a number"))
                }
            }
        };
        Ok(PositioningError {
            robot_offset: arr3(ro, "offset_deg", robot.offset_deg).context("devices.robot")?,
            robot_jitter: arr3(ro, "jitter_deg", robot.jitter_deg).context("devices.robot")?,
            rail_offset: num(ra, "offset_deg", rail.offset_deg).context("devices.rail")?,
            rail_jitter: num(ra, "jitter_deg", rail.jitter_deg).context("devices.rail")?,
        })
    }

    /// True joints for `commanded`, drawn like the simulated devices draw them (radians).
    pub fn apply(&self, commanded: &JointState, rng: &mut ChaCha8Rng) -> JointState {
        let mut j = *commanded;
        for k in 0..3 {
            let n: f64 = rng.sample(StandardNormal);
            j.robot[k] += (self.robot_offset[k] + self.robot_jitter[k] * n).to_radians();
        }
        let n: f64 = rng.sample(StandardNormal);
        j.rail += (self.rail_offset + self.rail_jitter * n).to_radians();
        j
    }
}

/// One rendered frame and its truth.
pub struct Frame {
    /// View direction, degrees (theta, phi).
    pub view_deg: (f64, f64),
    /// Joints the rig was told to reach.
    pub commanded: JointState,
    /// Joints it really reached (the frame is rendered there).
    pub truth: JointState,
    /// Demosaiced camera RGB, fractions of the white level above black.
    pub rgb: LinearImage,
    /// Its green channel (what the detectors see).
    pub green: Vec<f32>,
    /// The raw frame it was demosaiced from.
    pub raw: btfrig_core::frame::RawFrame,
    /// Conversion of `rgb` to the ground truth's units.
    pub radiometry: Radiometry,
    /// Point-sampled ground truth (the renderer's definition), `size²` texels.
    pub gt_point: Vec<[f32; 3]>,
    /// Area-averaged ground truth ([`BOX_SAMPLES`]² points per texel).
    pub gt_box: Vec<[f32; 3]>,
    /// The noise-free camera-RGB rate image (e-/s, no sensor, no demosaic) of the same true
    /// state and its conversion: separates resampling and geometry from sensor noise.
    pub clean: (LinearImage, Radiometry),
}

/// Texture error of one filter.
#[derive(Debug, Clone)]
pub struct FilterResult {
    /// Filter name ([`filter_name`], or the peer's interpolation).
    pub filter: String,
    /// Rectification time, seconds (median of the repeats).
    pub rectify_s: f64,
    /// Sums over texels and channels of (texture - truth)² and truth², point-sampled truth.
    pub point: (f64, f64),
    /// The same against the area-averaged truth.
    pub area: (f64, f64),
    /// The same for the noise-free image against the area-averaged truth.
    pub clean_area: (f64, f64),
}

impl FilterResult {
    /// `rel_rmse` against the point-sampled truth.
    pub fn rel_point(&self) -> f64 {
        (self.point.0 / self.point.1).sqrt()
    }
    /// `rel_rmse` against the area-averaged truth.
    pub fn rel_area(&self) -> f64 {
        (self.area.0 / self.area.1).sqrt()
    }
    /// `rel_rmse` of the noise-free image against the area-averaged truth.
    pub fn rel_clean(&self) -> f64 {
        (self.clean_area.0 / self.clean_area.1).sqrt()
    }
}

/// One pose-estimation setting on one frame.
#[derive(Debug, Clone)]
pub struct SettingResult {
    /// Setting name: `nominal`, `dlt`, `lm`, `lm+prior`, `opencv`.
    pub setting: String,
    /// Marker detection time, seconds (0 for `nominal`).
    pub detect_s: f64,
    /// Pose / homography estimation time, seconds.
    pub register_s: f64,
    /// Plate markers detected.
    pub markers: usize,
    /// RMS distance (radial) of the detected corners from the projected true corners, pixels.
    pub corner_rms_px: Option<f64>,
    /// Mean offset (x, y) of the detected corners from the true ones, pixels: a half-pixel
    /// convention mismatch would show here as about (±0.5, ±0.5).
    pub corner_bias_px: Option<(f64, f64)>,
    /// Texel position error of the image mapping, mean and max, texels.
    pub texel: (f64, f64),
    /// Per filter.
    pub filters: Vec<FilterResult>,
    /// Why the setting gave no pose (then `texel` and `filters` are empty / NaN).
    pub error: Option<String>,
}

impl SettingResult {
    fn failed(setting: &str, detect_s: f64, markers: usize, why: String) -> Self {
        SettingResult {
            setting: setting.into(),
            detect_s,
            register_s: 0.0,
            markers,
            corner_rms_px: None,
            corner_bias_px: None,
            texel: (f64::NAN, f64::NAN),
            filters: Vec::new(),
            error: Some(why),
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Sums of squared difference and squared truth over texels and channels.
pub fn sq_sums(a: &[[f32; 3]], truth: &[[f32; 3]]) -> (f64, f64) {
    let mut se = 0.0;
    let mut st = 0.0;
    for (a, b) in a.iter().zip(truth) {
        for c in 0..3 {
            let (a, b) = (f64::from(a[c]), f64::from(b[c]));
            se += (a - b) * (a - b);
            st += b * b;
        }
    }
    (se, st)
}

/// A rig, a material, a texture size and the estimators: renders frames and measures them.
pub struct Bench {
    /// The rig.
    pub cfg: RigConfig,
    /// Its simulated scene.
    pub scene: RigScene,
    /// Detector + estimator of the `lm` setting.
    pub registrar: PlateRegistrar,
    /// Texture region (the sample square).
    pub region: Region,
    /// Texels per side.
    pub size: usize,
    /// Light direction of every frame.
    pub light: Direction,
    /// Positioning error of the devices.
    pub positioning: PositioningError,
    /// How frames are rendered (default: the renderer's; `marker_supersampling` is how
    /// finely the simulated photosites integrate the marker edges).
    pub render: RenderOptions,
    dictionary: Dictionary,
    last_windows: std::cell::Cell<Option<WindowStats>>,
}

/// How the `lm-roi` setting searched one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowStats {
    /// The windows' tolerance (degrees, metres).
    pub tolerance: (f64, f64),
    /// Windows searched.
    pub windows: usize,
    /// Pixels searched over the frame's (above 1 after a fallback).
    pub pixel_fraction: f64,
    /// Whether the windows missed and the whole frame was searched.
    pub fell_back: bool,
    /// Whether the windows gave the whole-frame detector's plate markers and corners (1e-6 px).
    pub same_as_whole_frame: bool,
}

impl Bench {
    /// Sets up the scene and the registrar. The detector's adaptive-threshold window scales
    /// with the image width (51 px at 1600 px): the same field of view on a finer grid has
    /// proportionally larger markers.
    pub fn new(cfg: RigConfig, material: &MaterialSpec, size: usize) -> anyhow::Result<Self> {
        anyhow::ensure!((8..=4096).contains(&size), "--size {size}: allowed 8..=4096");
        let scene = RigScene::new(&cfg, material)?;
        let camera = scene.camera().model().clone();
        // The rig's pose tolerance, as processing uses it (the gate, and the first windows).
        let (deg, m) = cfg.geometry.pose_tolerance();
        let mut registrar =
            PlateRegistrar::new(camera.clone(), &cfg.plate, RegisterOptions::with_pose_tolerance(deg, m))?;
        let scale = camera.width as f64 / 1600.0;
        let window = ((51.0 * scale).round() as usize).max(3) | 1;
        registrar.detect.threshold_window_px = window;
        let dictionary = Dictionary::by_name(&cfg.plate.marker_dictionary)
            .with_context(|| format!("unknown marker dictionary {}", cfg.plate.marker_dictionary))?;
        let positioning = PositioningError::from_config(&cfg)?;
        let region = Region::centred_square(cfg.plate.sample_side_m);
        Ok(Bench {
            cfg,
            scene,
            registrar,
            region,
            size,
            light: Direction::from_degrees(45.0, 0.0),
            positioning,
            render: RenderOptions::default(),
            dictionary,
            last_windows: std::cell::Cell::new(None),
        })
    }

    /// The camera model.
    pub fn camera(&self) -> &CameraModel {
        self.scene.camera().model()
    }

    /// Renders the frame of `view_deg` (theta, phi in degrees): the commanded joints by
    /// inverse kinematics with [`Bench::light`], the true joints off them by a positioning
    /// error drawn from `seed`, seeded sensor noise, bilinear demosaic; and both ground truths.
    pub fn frame(&self, view_deg: (f64, f64), seed: u64) -> anyhow::Result<Frame> {
        let view = Direction::from_degrees(view_deg.0, view_deg.1);
        let commanded = self
            .scene
            .gonio()
            .ik(self.light, view)
            .map_err(|r| anyhow::anyhow!("view {view_deg:?} with light (45, 0) unreachable: {r}"))?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = self.positioning.apply(&commanded, &mut rng);
        let exposure = self.scene.exposure_for_white(0.5, 1e-4, 30.0);
        let (raw, _) = self.scene.capture(&truth, 1.0, exposure, 1.0, seed, &self.render)?;
        let dm = demosaic_bilinear(&raw);
        let green: Vec<f32> = dm.data.iter().map(|p| p[1]).collect();
        let rgb = LinearImage { width: dm.width, height: dm.height, data: dm.data };
        let sensor = self.scene.sensor();
        let k = sensor.dn_per_electron(1.0);
        let fit = self.scene.colour().colorchecker_matrix();
        let radiometry = Radiometry {
            dn_range: f64::from(raw.meta.white_level) - f64::from(raw.meta.black_level),
            exposure_s: exposure,
            dn_per_electron: k,
            dark_e_per_s: sensor.dark_current_e_per_s,
            // RigScene keeps the nominal irradiance private; white_signal_dn(1 s, gain 1) is
            // nominal_irradiance * dn_per_electron(1).
            nominal_irradiance: self.scene.white_signal_dn(1.0, 1.0) / k,
            white_balance: fit.white_balance,
            matrix: fit.matrix,
        };
        let gt_point = self.scene.ground_truth(&truth, 1.0, self.size).data;
        let gt_box = self.scene.ground_truth(&truth, 1.0, self.size * BOX_SAMPLES).box_average(BOX_SAMPLES).data;
        let (img, _) = self.scene.radiance(&truth, 1.0, &self.render);
        // Rates in e-/s: exposure 1 s, 1 DN per electron, range 1, no dark current.
        let clean_radiometry =
            Radiometry { dn_range: 1.0, exposure_s: 1.0, dn_per_electron: 1.0, dark_e_per_s: 0.0, ..radiometry };
        let clean = (LinearImage { width: img.width, height: img.height, data: img.data }, clean_radiometry);
        Ok(Frame { view_deg, commanded, truth, rgb, green, raw, radiometry, gt_point, gt_box, clean })
    }

    /// Distance of detected corners from the projection of the true corners: (RMS radial,
    /// mean offset). `detections` are (id, corners) in OpenCV's corner order.
    pub fn corner_error(&self, frame: &Frame, detections: &[(u32, [Point2<f64>; 4])]) -> Option<(f64, (f64, f64))> {
        let t = sample_to_camera(&self.scene.pose(&frame.truth));
        let cam = self.camera();
        let (mut ss, mut sx, mut sy, mut n) = (0.0, 0.0, 0.0, 0usize);
        for (id, corners) in detections {
            let Some(m) = self.registrar.markers().iter().find(|m| m.id == *id) else { continue };
            for (c, seen) in m.corners_sample_m.iter().zip(corners) {
                let Some(p) = cam.project(&(t * Point3::new(c.x, c.y, 0.0))) else { continue };
                let d = seen - p;
                ss += d.norm_squared();
                sx += d.x;
                sy += d.y;
                n += 1;
            }
        }
        (n > 0).then(|| ((ss / n as f64).sqrt(), (sx / n as f64, sy / n as f64)))
    }

    /// Rectifies with `pose` and every filter, converts to radiance factor, compares with
    /// both truths; rectification timed `repeat` times (median).
    pub fn textures(&self, frame: &Frame, pose: &ScenePose, repeat: usize) -> anyhow::Result<Vec<FilterResult>> {
        let cam = self.camera();
        let vig = vignetting_map(cam, pose, self.region, self.size)?;
        let mut out = Vec::new();
        for f in FILTERS {
            let mut times = Vec::new();
            let mut tex = None;
            for _ in 0..repeat.max(1) {
                let t = Instant::now();
                let r = rectify(&frame.rgb, cam, pose, self.region, self.size, f)?;
                times.push(t.elapsed().as_secs_f64());
                tex = Some(r);
            }
            let tex = to_radiance_factor(&tex.expect("at least one repeat"), &vig, &frame.radiometry)?;
            let clean = rectify(&frame.clean.0, cam, pose, self.region, self.size, f)?;
            let clean = to_radiance_factor(&clean, &vig, &frame.clean.1)?;
            out.push(FilterResult {
                filter: filter_name(f),
                rectify_s: median(times),
                point: sq_sums(&tex.data, &frame.gt_point),
                area: sq_sums(&tex.data, &frame.gt_box),
                clean_area: sq_sums(&clean.data, &frame.gt_box),
            });
        }
        Ok(out)
    }

    fn pose_from_camera(&self, nominal: &ScenePose, s2c: nalgebra::Isometry3<f64>) -> ScenePose {
        ScenePose { sample_to_world: nominal.camera_to_world * s2c, ..*nominal }
    }

    fn texel_error(&self, frame: &Frame, pose: &ScenePose) -> (f64, f64) {
        texel_position_error(&self.scene.pose(&frame.truth), pose, self.camera(), self.region, self.size)
    }

    /// Our settings on `frame`: `nominal` (the kinematic pose), `dlt` (normalised DLT over
    /// every detected plate corner after undistortion, decomposed into a pose; no RANSAC, no
    /// refinement), `lm` (marker-pair RANSAC + Levenberg–Marquardt: what
    /// `PlateRegistrar::register_image` runs) and `lm+prior` (the same with the weak prior
    /// [`PRIOR_SIGMA`]). Detection and estimation are timed `repeat` times (median).
    pub fn run_ours(&self, frame: &Frame, repeat: usize) -> anyhow::Result<Vec<SettingResult>> {
        let repeat = repeat.max(1);
        let nominal = self.scene.pose(&frame.commanded);
        let mut out = Vec::new();
        out.push(SettingResult {
            setting: "nominal".into(),
            detect_s: 0.0,
            register_s: 0.0,
            markers: 0,
            corner_rms_px: None,
            corner_bias_px: None,
            texel: self.texel_error(frame, &nominal),
            filters: self.textures(frame, &nominal, repeat)?,
            error: None,
        });

        // The oracle: the true pose (what a perfect registration would give).
        let true_pose = self.scene.pose(&frame.truth);
        out.push(SettingResult {
            setting: "true".into(),
            detect_s: 0.0,
            register_s: 0.0,
            markers: 0,
            corner_rms_px: None,
            corner_bias_px: None,
            texel: self.texel_error(frame, &true_pose),
            filters: self.textures(frame, &true_pose, repeat)?,
            error: None,
        });

        let image = GrayImage::new(frame.rgb.width, frame.rgb.height, &frame.green)?;
        let mut times = Vec::new();
        let mut detections: Vec<Detection> = Vec::new();
        for _ in 0..repeat {
            let t = Instant::now();
            detections = detect(&image, &self.dictionary, &self.registrar.detect)?;
            times.push(t.elapsed().as_secs_f64());
        }
        let detect_s = median(times);
        let (corr, detected, _foreign) = self.registrar.correspondences(&detections);
        let ids: Vec<(u32, [Point2<f64>; 4])> =
            detections.iter().filter(|d| detected.contains(&d.id)).map(|d| (d.id, d.corners)).collect();
        let corners = self.corner_error(frame, &ids);
        let cam = self.camera();

        // Homography only.
        let mut times = Vec::new();
        let mut s2c = None;
        for _ in 0..repeat {
            let t = Instant::now();
            let (plane, img): (Vec<Point2<f64>>, Vec<Point2<f64>>) = corr
                .iter()
                .filter_map(|c| cam.try_pixel_ray(c.pixel).map(|r| (c.plane, Point2::new(r.x / r.z, r.y / r.z))))
                .unzip();
            s2c = dlt(&plane, &img).and_then(|h| decompose(&h));
            times.push(t.elapsed().as_secs_f64());
        }
        let register_s = median(times);
        out.push(match s2c {
            Some(s2c) => {
                let pose = self.pose_from_camera(&nominal, s2c);
                SettingResult {
                    setting: "dlt".into(),
                    detect_s,
                    register_s,
                    markers: detected.len(),
                    corner_rms_px: corners.map(|c| c.0),
                    corner_bias_px: corners.map(|c| c.1),
                    texel: self.texel_error(frame, &pose),
                    filters: self.textures(frame, &pose, repeat)?,
                    error: None,
                }
            }
            None => SettingResult::failed(
                "dlt",
                detect_s,
                detected.len(),
                format!("no homography from {} corners", corr.len()),
            ),
        });

        // `lm-roi`: what `PlateRegistrar::register_image` runs by default: the markers searched
        // only in windows predicted from the nominal pose, their tolerance learned from the
        // frames registered before (the estimator's gate for the first), the whole frame when
        // they miss; then `lm`. Bilinear only (the pose is what differs).
        let tolerance = self.registrar.learned_tolerance();
        let mut detect_times = Vec::new();
        let mut register_times = Vec::new();
        let mut roi = None;
        for _ in 0..repeat {
            let r = self.registrar.register_within(&image, &nominal, Some(tolerance));
            if let Ok(r) = &r {
                detect_times.push(r.detect_s);
                register_times.push(r.register_s);
            }
            roi = Some(r);
        }
        let roi_result = match roi.expect("at least one repeat") {
            Ok(r) => {
                self.registrar.remember(&r.registration, &nominal);
                let roi_ids: Vec<(u32, [Point2<f64>; 4])> =
                    r.detections.iter().filter(|d| r.detected.contains(&d.id)).map(|d| (d.id, d.corners)).collect();
                let roi_corners = self.corner_error(frame, &roi_ids);
                self.last_windows.set(Some(WindowStats {
                    tolerance,
                    windows: r.search.windows,
                    pixel_fraction: r.search.pixels as f64 / r.search.frame_pixels as f64,
                    fell_back: r.search.whole_frame,
                    same_as_whole_frame: ids.len() == roi_ids.len()
                        && ids
                            .iter()
                            .zip(&roi_ids)
                            .all(|(a, b)| a.0 == b.0 && a.1.iter().zip(&b.1).all(|(p, q)| (p - q).norm() < 1e-6)),
                }));
                SettingResult {
                    setting: "lm-roi".into(),
                    detect_s: median(detect_times),
                    register_s: median(register_times),
                    markers: r.detected.len(),
                    corner_rms_px: roi_corners.map(|c| c.0),
                    corner_bias_px: roi_corners.map(|c| c.1),
                    texel: self.texel_error(frame, &r.registration.pose),
                    filters: self.textures(frame, &r.registration.pose, repeat)?.into_iter().take(1).collect(),
                    error: None,
                }
            }
            Err(e) => {
                self.last_windows.set(None);
                SettingResult::failed("lm-roi", f64::NAN, 0, e.to_string())
            }
        };

        for (name, prior) in [("lm", None), ("lm+prior", Some(PRIOR_SIGMA))] {
            let options = RegisterOptions { prior_sigma: prior, ..self.registrar.options.clone() };
            let mut times = Vec::new();
            let mut result = None;
            for _ in 0..repeat {
                let t = Instant::now();
                result = Some(register(&corr, cam, &nominal, &options));
                times.push(t.elapsed().as_secs_f64());
            }
            let register_s = median(times);
            out.push(match result.expect("at least one repeat") {
                Ok(r) => SettingResult {
                    setting: name.into(),
                    detect_s,
                    register_s,
                    markers: detected.len(),
                    corner_rms_px: corners.map(|c| c.0),
                    corner_bias_px: corners.map(|c| c.1),
                    texel: self.texel_error(frame, &r.pose),
                    filters: self.textures(frame, &r.pose, repeat)?,
                    error: None,
                },
                Err(e) => SettingResult::failed(name, detect_s, detected.len(), e.to_string()),
            });
        }
        out.push(roi_result);
        Ok(out)
    }

    /// The window search of the last [`Bench::run_ours`].
    pub fn last_window_stats(&self) -> Option<WindowStats> {
        self.last_windows.get()
    }

    /// Texel position error of an image mapping given as a homography `h` from the sample
    /// plane (metres) to UNDISTORTED pixel coordinates of the camera's own matrix (what
    /// OpenCV's `findHomography` on `undistortPoints(..., P = K)` gives): each texel centre is
    /// mapped through `h`, distorted back to the pixel actually read, and cast onto the
    /// true plane.
    pub fn homography_texel_error(&self, frame: &Frame, h: &Matrix3<f64>) -> (f64, f64) {
        let cam = self.camera();
        let truth = sample_to_camera(&self.scene.pose(&frame.truth));
        let (size, r) = (self.size, self.region);
        let pitch_x = (r.x_max - r.x_min) / size as f64;
        let pitch_y = (r.y_max - r.y_min) / size as f64;
        let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
        for row in 0..size {
            for col in 0..size {
                let (x, y) = r.point(size, size, col as f64 + 0.5, row as f64 + 0.5);
                let Some(u) = btfrig_core::homography::map(h, &Point2::new(x, y)) else { continue };
                let n_pt = Point3::new((u.x - cam.cx) / cam.fx, (u.y - cam.cy) / cam.fy, 1.0);
                let Some(px) = cam.project(&n_pt) else { continue };
                let Some(q) = back_project(cam, &truth, px) else { continue };
                let d = ((q.x - x) / pitch_x).hypot((q.y - y) / pitch_y);
                sum += d;
                max = max.max(d);
                n += 1;
            }
        }
        if n == 0 {
            (f64::NAN, f64::NAN)
        } else {
            (sum / n as f64, max)
        }
    }

    /// Measures a peer's result on `frame`: its detections, its homography `h` (sample plane
    /// metres to undistorted pixels, see [`Bench::homography_texel_error`]) and its texture
    /// (camera RGB like `frame.rgb`, `size²` texels, row 0 at the `+y` edge) and its texture of
    /// `frame.clean`. The textures are converted with the vignetting of the pose decomposed
    /// from `h`.
    #[allow(clippy::too_many_arguments)]
    pub fn evaluate_homography(
        &self,
        frame: &Frame,
        setting: &str,
        filter: &str,
        detections: &[(u32, [Point2<f64>; 4])],
        h: &Matrix3<f64>,
        (texture, clean): (Vec<[f32; 3]>, Vec<[f32; 3]>),
        times_s: (f64, f64, f64),
    ) -> anyhow::Result<SettingResult> {
        let texels = self.size * self.size;
        anyhow::ensure!(texture.len() == texels && clean.len() == texels, "peer texture has {} texels", texture.len());
        let cam = self.camera();
        let k = Matrix3::new(cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0);
        let hn = k.try_inverse().expect("focal lengths are positive") * h;
        let s2c = decompose(&hn).context("peer homography does not decompose into a pose")?;
        let pose = self.pose_from_camera(&self.scene.pose(&frame.commanded), s2c);
        let vig = vignetting_map(cam, &pose, self.region, self.size)?;
        let wrap = |data| btfrig_imaging::Texture {
            width: self.size,
            height: self.size,
            region: self.region,
            data,
            texels_outside: 0,
        };
        let tex = to_radiance_factor(&wrap(texture), &vig, &frame.radiometry)?;
        let clean = to_radiance_factor(&wrap(clean), &vig, &frame.clean.1)?;
        let markers = detections.iter().filter(|(id, _)| self.registrar.markers().iter().any(|m| m.id == *id)).count();
        let corners = self.corner_error(frame, detections);
        Ok(SettingResult {
            setting: setting.into(),
            detect_s: times_s.0,
            register_s: times_s.1,
            markers,
            corner_rms_px: corners.map(|c| c.0),
            corner_bias_px: corners.map(|c| c.1),
            texel: self.homography_texel_error(frame, h),
            filters: vec![FilterResult {
                filter: filter.into(),
                rectify_s: times_s.2,
                point: sq_sums(&tex.data, &frame.gt_point),
                area: sq_sums(&tex.data, &frame.gt_box),
                clean_area: sq_sums(&clean.data, &frame.gt_box),
            }],
            error: None,
        })
    }
}

/// Totals of one (setting, filter) over the frames of one rig.
#[derive(Default)]
pub struct Agg {
    pub detect_s: Vec<f64>,
    pub register_s: Vec<f64>,
    pub rectify_s: Vec<f64>,
    pub texel_mean: Vec<f64>,
    pub texel_max: f64,
    pub corner_sq: f64,
    pub corner_n: usize,
    pub point: (f64, f64),
    pub area: (f64, f64),
    pub clean: (f64, f64),
    pub failed: usize,
}

pub fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

impl Agg {
    pub fn add(&mut self, s: &SettingResult, f: Option<&FilterResult>) {
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
    pub fn total_ms(&self) -> f64 {
        1e3 * (mean(&self.detect_s) + mean(&self.register_s) + mean(&self.rectify_s))
    }
    pub fn rel(p: (f64, f64)) -> f64 {
        (p.0 / p.1).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::plan::BUILTIN_RIGS;

    fn bench(size: usize) -> Bench {
        let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin").unwrap();
        Bench::new(cfg, &MaterialSpec::builtin("lacquered-wood").unwrap(), size).unwrap()
    }

    /// On a rendered frame with positioning error, every marker-based setting beats the
    /// nominal pose by a wide margin, and the homography path of the peer (fed our own DLT
    /// homography) measures the same texel error as the pose it decomposes into.
    #[test]
    fn registration_beats_the_nominal_pose_on_a_rendered_frame() {
        let mut b = bench(128);
        // Three times the rig's positioning error, so the nominal pose is clearly off.
        let p = &mut b.positioning;
        p.robot_jitter = p.robot_jitter.map(|j| 3.0 * j);
        p.robot_offset = p.robot_offset.map(|j| 3.0 * j);
        p.rail_jitter *= 3.0;
        p.rail_offset *= 3.0;
        let frame = b.frame((45.0, 90.0), 3).unwrap();
        let r = b.run_ours(&frame, 1).unwrap();
        let get = |n: &str| r.iter().find(|s| s.setting == n).unwrap();
        let nominal = get("nominal");
        assert!(nominal.texel.0 > 0.1, "positioning error too small to test: {:?}", nominal.texel);
        for s in ["dlt", "lm", "lm+prior"] {
            let s = get(s);
            assert!(s.error.is_none(), "{s:?}");
            assert_eq!(s.markers, 12);
            assert!(s.texel.0 < nominal.texel.0 / 3.0, "{} {:?} vs nominal {:?}", s.setting, s.texel, nominal.texel);
            // Pixel centres at integers on both sides: no half-pixel bias.
            let (bx, by) = s.corner_bias_px.unwrap();
            assert!(bx.abs() < 0.1 && by.abs() < 0.1, "corner bias {bx} {by}");
            // On the noise-free image the better pose gives the better texture (on the noisy
            // one, noise can hide a fraction of a texel).
            for f in &s.filters {
                let n = nominal.filters.iter().find(|g| g.filter == f.filter).unwrap();
                assert!(
                    f.rel_clean() < n.rel_clean(),
                    "{} {}: {} vs {}",
                    s.setting,
                    f.filter,
                    f.rel_clean(),
                    n.rel_clean()
                );
                assert!(f.rel_point() < 0.5 && f.rel_area() < 0.5);
            }
        }
        assert_eq!(get("lm").filters.len(), FILTERS.len());
    }

    /// The homography metric agrees with the pose metric for a homography that IS a pose.
    #[test]
    fn homography_metric_matches_pose_metric() {
        let b = bench(32);
        let frame = b.frame((45.0, 270.0), 5).unwrap();
        let nominal = b.scene.pose(&frame.commanded);
        let s2c = sample_to_camera(&nominal);
        let cam = b.camera();
        let k = Matrix3::new(cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0);
        let r = s2c.rotation.to_rotation_matrix();
        let m = r.matrix();
        let t = s2c.translation.vector;
        let h = k * Matrix3::from_columns(&[m.column(0).into_owned(), m.column(1).into_owned(), t]);
        let (a_mean, a_max) = b.homography_texel_error(&frame, &h);
        let (b_mean, b_max) = texel_position_error(&b.scene.pose(&frame.truth), &nominal, cam, b.region, b.size);
        assert!((a_mean - b_mean).abs() < 1e-6 && (a_max - b_max).abs() < 1e-6, "{a_mean} {a_max} vs {b_mean} {b_max}");
        assert!(a_mean > 0.01);
    }
}
