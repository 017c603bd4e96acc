//! Light calibration: each light source's power and colour, measured with a white reference.
//!
//! A calibration plan ([`LightPlan`], `rig-configs/plans/calibration-light.toml`, format in
//! `docs/light.md`) puts a white reference tile of known reflectance (spectrally flat,
//! Lambertian, e.g. a sintered-PTFE tile) on the holder in place of the sample and photographs
//! it at a few (light, view) pairs. Per capture, `btfrig_imaging::light::lambertian_signal` reduces
//! the tile's pixels to `W_c`: the camera-RGB signal rate (e-/s per photosite at gain 1) of a
//! white Lambertian reflector lit along its normal from the nominal lamp distance, dividing
//! out the tile's albedo, the lamp's incidence and distance at every point, the vignetting and
//! the dark current. The holder plate's white area in the same frames gives the plate's albedo
//! RELATIVE to the tile (a real plate's albedo is not known absolutely): the reference the
//! pipeline measures the lamp's drift against in every frame of a run.
//!
//! The result ([`LightCalibrationFile`], TOML) is keyed by light id: `"lamp"` for the
//! gonioreflectometer's lamp; a dome's LEDs will add one entry each.
//!
//! [`calibrate_light`] is the procedure on frames a [`TileCamera`] takes; the simulated rig's
//! camera and the comparison with the simulator's truth are `btfrig_sim_calibration::light`.

use std::collections::BTreeMap;

use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::light::{lambertian_signal, plate_patch_points, rate_radiometry, square_points, PatchOptions};
use btfrig_imaging::{LinearImage, Radiometry};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Version of the light calibration plan and file formats.
pub const LIGHT_FORMAT_VERSION: u32 = 1;

/// The default plan, embedded (`rig-configs/plans/calibration-light.toml`).
pub const DEFAULT_LIGHT_PLAN: &str = include_str!("../../../rig-configs/plans/calibration-light.toml");

/// The light id of a gonioreflectometer's lamp.
pub const LAMP: &str = "lamp";

/// One calibration capture: lamp and camera directions in the sample (tile) frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightCapture {
    /// Lamp polar angle from the tile normal, degrees (0..=60).
    pub light_theta_deg: f64,
    /// Lamp azimuth, degrees.
    #[serde(default)]
    pub light_phi_deg: f64,
    /// Camera polar angle, degrees (0..=60).
    pub view_theta_deg: f64,
    /// Camera azimuth, degrees.
    #[serde(default)]
    pub view_phi_deg: f64,
}

/// A light calibration plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightPlan {
    /// Format version ([`LIGHT_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Name, for reports and the calibration file's source.
    pub name: String,
    /// Light id the captures calibrate ([`LAMP`] for the gonioreflectometer).
    #[serde(default = "LightPlan::default_light")]
    pub light: String,
    /// Reflectance of the white reference tile (spectrally flat, Lambertian), (0, 1].
    pub reference_albedo: f64,
    /// Clearance from the tile's edge, metres (its edge and the plate blur together).
    #[serde(default = "LightPlan::default_tile_margin_m")]
    pub tile_margin_m: f64,
    /// Grid step of the measured points on tile and plate, metres.
    #[serde(default = "LightPlan::default_step_m")]
    pub step_m: f64,
    /// Exposure: a white reflector facing the lamp reaches this fraction of full scale.
    #[serde(default = "LightPlan::default_exposure_fraction")]
    pub exposure_fraction: f64,
    /// Frames per capture (noise averages down).
    #[serde(default = "LightPlan::default_repeats")]
    pub repeats: u32,
    /// The captures.
    pub captures: Vec<LightCapture>,
}

impl LightPlan {
    fn default_light() -> String {
        LAMP.into()
    }
    fn default_tile_margin_m() -> f64 {
        0.004
    }
    fn default_step_m() -> f64 {
        0.001
    }
    fn default_exposure_fraction() -> f64 {
        0.6
    }
    fn default_repeats() -> u32 {
        1
    }

    /// The embedded default plan.
    pub fn default_plan() -> LightPlan {
        Self::from_toml(DEFAULT_LIGHT_PLAN, "<embedded rig-configs/plans/calibration-light.toml>")
            .expect("the embedded light calibration plan is valid")
    }

    /// Parses and validates a plan; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<LightPlan, LightCalibError> {
        let p: LightPlan = toml::from_str(text)
            .map_err(|e| LightCalibError::Plan { origin: origin.into(), message: e.to_string() })?;
        let problems = p.problems();
        if !problems.is_empty() {
            return Err(LightCalibError::Plan { origin: origin.into(), message: problems.join("; ") });
        }
        Ok(p)
    }

    /// Every invalid value, as messages naming the field.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.format_version != LIGHT_FORMAT_VERSION {
            out.push(format!(
                "format_version = {} is not supported (this build reads {LIGHT_FORMAT_VERSION})",
                self.format_version
            ));
        }
        if self.light.trim().is_empty() {
            out.push("light: a light id is needed (\"lamp\" for the gonioreflectometer)".into());
        }
        if !(self.reference_albedo > 0.0 && self.reference_albedo <= 1.0) {
            out.push(format!("reference_albedo = {}: allowed (0, 1]", self.reference_albedo));
        }
        if !(self.tile_margin_m.is_finite() && (0.0..=0.02).contains(&self.tile_margin_m)) {
            out.push(format!("tile_margin_m = {}: allowed 0..=0.02 metres", self.tile_margin_m));
        }
        if !(self.step_m.is_finite() && (1e-4..=0.01).contains(&self.step_m)) {
            out.push(format!("step_m = {}: allowed 1e-4..=0.01 metres", self.step_m));
        }
        if !(self.exposure_fraction > 0.0 && self.exposure_fraction <= 0.9) {
            out.push(format!(
                "exposure_fraction = {}: allowed (0, 0.9] (a saturated tile measures nothing)",
                self.exposure_fraction
            ));
        }
        if !(1..=64).contains(&self.repeats) {
            out.push(format!("repeats = {}: allowed 1..=64", self.repeats));
        }
        if self.captures.is_empty() {
            out.push("captures: at least one capture is needed".into());
        }
        for (i, c) in self.captures.iter().enumerate() {
            for (name, v) in [("light_theta_deg", c.light_theta_deg), ("view_theta_deg", c.view_theta_deg)] {
                if !(v.is_finite() && (0.0..=60.0).contains(&v)) {
                    out.push(format!("captures[{i}].{name} = {v}: allowed 0..=60"));
                }
            }
            for (name, v) in [("light_phi_deg", c.light_phi_deg), ("view_phi_deg", c.view_phi_deg)] {
                if !v.is_finite() {
                    out.push(format!("captures[{i}].{name} = {v}: must be finite"));
                }
            }
        }
        out
    }
}

/// Why a light calibration failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LightCalibError {
    /// The plan file is invalid.
    #[error("light calibration plan {origin}: {message}")]
    Plan {
        /// File name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// The calibration file is invalid.
    #[error("light calibration file {origin}: {message}")]
    File {
        /// File name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// The rig cannot take a capture of the plan or cannot be simulated.
    #[error("light calibration: {0}")]
    Rig(String),
    /// A capture could not be measured.
    #[error("light calibration: capture {index} (light {light_deg:?} deg, view {view_deg:?} deg): {source}")]
    Measure {
        /// Capture index in the plan.
        index: usize,
        /// Lamp direction (theta, phi), degrees.
        light_deg: [f64; 2],
        /// Camera direction (theta, phi), degrees.
        view_deg: [f64; 2],
        /// The measurement's error.
        source: btfrig_imaging::light::LightError,
    },
}

/// One light's calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightEntry {
    /// `W_c`: camera-RGB signal rate of a white Lambertian reflector lit along its normal from
    /// the nominal lamp distance, e-/s per photosite at gain 1, (R, G, B).
    pub white_rate_e_per_s: [f64; 3],
    /// Standard error of `white_rate_e_per_s`: the frames' noise, or their scatter when
    /// larger ([`calibrate_light`]).
    pub white_rate_sigma: [f64; 3],
    /// White balance the rate implies: `W_g / W_c` (the white reflector's camera RGB to (1, 1, 1)).
    pub white_balance: [f64; 3],
    /// The holder plate's albedo relative to the reference tile, per camera channel (the drift
    /// reference of every run frame).
    pub plate_albedo: [f64; 3],
    /// Standard error of `plate_albedo`.
    pub plate_albedo_sigma: [f64; 3],
    /// Reflectance of the tile the rates were divided by.
    pub reference_albedo: f64,
    /// Frames measured.
    pub frames: usize,
}

/// The light calibration file: one [`LightEntry`] per light id.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightCalibrationFile {
    /// Format version ([`LIGHT_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Where it came from (plan, rig, seed).
    pub source: String,
    /// The lights, by id.
    pub lights: BTreeMap<String, LightEntry>,
}

impl LightCalibrationFile {
    /// Parses and checks a file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, LightCalibError> {
        let err = |message: String| LightCalibError::File { origin: origin.into(), message };
        let f: LightCalibrationFile = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if f.format_version != LIGHT_FORMAT_VERSION {
            return Err(err(format!(
                "format_version = {} is not supported (this build reads {LIGHT_FORMAT_VERSION})",
                f.format_version
            )));
        }
        for (id, e) in &f.lights {
            let all = e.white_rate_e_per_s.iter().chain(&e.plate_albedo).chain(&e.white_balance);
            if let Some(v) = all.copied().find(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(err(format!("lights.{id}: value {v} is invalid, allowed finite and > 0")));
            }
        }
        Ok(f)
    }

    /// The file's text.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a light calibration serialises")
    }

    /// The entry of light `id`.
    pub fn light(&self, id: &str) -> Option<&LightEntry> {
        self.lights.get(id)
    }
}

/// A light calibration and its per-frame figures.
#[derive(Debug, Clone, PartialEq)]
pub struct LightCalibration {
    /// The calibration.
    pub file: LightCalibrationFile,
    /// Per frame: `W_c` estimated from it (scatter shows the geometry model holds).
    pub per_frame_white_rate: Vec<[f64; 3]>,
}

/// One frame's figures: `W_c`, its sigma, the plate albedo, its sigma.
type FrameFigures = ([f64; 3], [f64; 3], [f64; 3], [f64; 3]);

/// The rig side of a light calibration: photographs the white reference tile on the holder.
/// Frames are taken in parallel, so it is `Sync`.
pub trait TileCamera: Sync {
    /// Exposure, seconds, at which a white reflector facing the lamp reaches `fraction` of
    /// full scale at gain 1.
    fn exposure_for_white(&self, fraction: f64) -> f64;
    /// Frame `frame` of the plan (capture by capture, repeats adjacent) with the goniometer at
    /// `joints`, lamp at its settled output, exposure `exposure_s` at gain 1.
    fn capture(&self, frame: usize, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String>;
}

/// Runs `plan` on a rig: `rig` photographs the tile at every capture of the plan (joint values
/// from the rig config's nominal kinematics); per frame `W_c` and the plate albedo are
/// measured (the rig config's lens, sensor constants and lamp distance), then averaged.
/// `source` is the file's provenance line.
pub fn calibrate_light(
    cfg: &RigConfig,
    plan: &LightPlan,
    rig: &dyn TileCamera,
    source: String,
) -> Result<LightCalibration, LightCalibError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(LightCalibError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let gonio = Gonio::new(cfg.geometry.clone()).map_err(|e| LightCalibError::Rig(e.to_string()))?;
    let camera = cfg.camera.to_model().map_err(|e| LightCalibError::Rig(format!("[camera]: {e}")))?;
    let exposure = rig.exposure_for_white(plan.exposure_fraction);
    let sensor = &cfg.sensor;
    let lamp_distance = cfg.geometry.lamp_distance_m;
    let tile_pts = square_points(cfg.plate.sample_side_m - 2.0 * plan.tile_margin_m, plan.step_m);
    let patch = PatchOptions { sample_margin_m: plan.tile_margin_m, step_m: plan.step_m, ..PatchOptions::default() };
    let plate_pts = plate_patch_points(&cfg.plate, &patch);

    let mut jobs = Vec::new();
    for (i, c) in plan.captures.iter().enumerate() {
        let light = Direction::from_degrees(c.light_theta_deg, c.light_phi_deg);
        let view = Direction::from_degrees(c.view_theta_deg, c.view_phi_deg);
        let joints = gonio
            .ik(light, view)
            .map_err(|e| LightCalibError::Rig(format!("capture {i} of the plan is unreachable: {e:?}")))?;
        let deg = ([c.light_theta_deg, c.light_phi_deg], [c.view_theta_deg, c.view_phi_deg]);
        for r in 0..plan.repeats {
            jobs.push((i, deg.0, deg.1, joints, r));
        }
    }
    // Frames are independent: measured in parallel.
    let measured: Vec<Result<FrameFigures, LightCalibError>> = jobs
        .par_iter()
        .enumerate()
        .map(|(k, &(index, light_deg, view_deg, joints, _))| {
            let frame = rig.capture(k, &joints, exposure).map_err(LightCalibError::Rig)?;
            let dm = demosaic_bilinear(&frame);
            let image = LinearImage { width: dm.width, height: dm.height, data: dm.data };
            let r = Radiometry {
                dn_range: (f64::from(frame.meta.white_level) - f64::from(frame.meta.black_level)).max(1.0),
                exposure_s: frame.meta.exposure_s,
                dn_per_electron: frame.meta.gain.max(1.0) / sensor.electrons_per_dn,
                dark_e_per_s: sensor.dark_current_e_per_s,
                nominal_irradiance: 1.0,
                white_balance: [1.0; 3],
                matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            };
            let to_rate = rate_radiometry(&r);
            let pose = gonio.scene_pose(&joints);
            let measure = |pts| {
                lambertian_signal(&image, &camera, &pose, lamp_distance, &to_rate, pts)
                    .map_err(|source| LightCalibError::Measure { index, light_deg, view_deg, source })
            };
            let tile = measure(&tile_pts)?;
            let plate = measure(&plate_pts)?;
            let w: [f64; 3] = std::array::from_fn(|c| tile.mean[c] / plan.reference_albedo);
            let ws: [f64; 3] = std::array::from_fn(|c| tile.sigma[c] / plan.reference_albedo);
            let p: [f64; 3] = std::array::from_fn(|c| plate.mean[c] / w[c]);
            let ps: [f64; 3] = std::array::from_fn(|c| p[c] * ((plate.sigma[c] / plate.mean[c]).hypot(ws[c] / w[c])));
            Ok((w, ws, p, ps))
        })
        .collect();
    let measured = measured.into_iter().collect::<Result<Vec<_>, _>>()?;
    let n = measured.len() as f64;
    let mean = |f: &dyn Fn(&FrameFigures) -> [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|c| measured.iter().map(|m| f(m)[c]).sum::<f64>() / n)
    };
    // The mean's error, per channel the larger of two figures. Each frame states its error
    // from the scatter of its points; the frames see the tile through mostly the same
    // photosites (the camera aims at the sample's centre), so that scatter's fixed-pattern
    // part (the photosites' response) is common to them and does not average down: the
    // frames' stated errors are taken at their root mean square, not divided by sqrt(n).
    // The frames also differ by what a frame's scatter cannot see (the pose each was taken at,
    // spatially correlated structure): the scatter between them over sqrt(n), their standard
    // error as independent measurements (with one frame, its stated error alone).
    let sigma = |value: &dyn Fn(&FrameFigures) -> [f64; 3], error: &dyn Fn(&FrameFigures) -> [f64; 3]| -> [f64; 3] {
        let m = mean(value);
        std::array::from_fn(|c| {
            let stated = (measured.iter().map(|f| error(f)[c].powi(2)).sum::<f64>() / n).sqrt();
            if measured.len() < 2 {
                return stated;
            }
            let scatter = measured.iter().map(|f| (value(f)[c] - m[c]).powi(2)).sum::<f64>() / (n - 1.0);
            stated.max((scatter / n).sqrt())
        })
    };
    let w = mean(&|m| m.0);
    let entry = LightEntry {
        white_rate_e_per_s: w,
        white_rate_sigma: sigma(&|m| m.0, &|m| m.1),
        white_balance: std::array::from_fn(|c| w[1] / w[c]),
        plate_albedo: mean(&|m| m.2),
        plate_albedo_sigma: sigma(&|m| m.2, &|m| m.3),
        reference_albedo: plan.reference_albedo,
        frames: measured.len(),
    };
    let file = LightCalibrationFile {
        format_version: LIGHT_FORMAT_VERSION,
        source,
        lights: BTreeMap::from([(plan.light.clone(), entry)]),
    };
    Ok(LightCalibration { file, per_frame_white_rate: measured.iter().map(|m| m.0).collect() })
}
