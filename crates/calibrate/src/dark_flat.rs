//! Radiometric calibration of the camera: dark frames and master flats captured per the plan
//! (`rig-configs/plans/calibration-radiometric.toml`), fitted with `btfrig_imaging::dark_flat`,
//! written as float OpenEXR maps with a TOML header. Format and figures: `docs/dark-flat.md`.
//!
//! [`calibrate`] runs the plan on frames a [`DarkFlatCamera`] takes. On the simulated rig
//! (`btfrig_sim_calibration::dark_flat`) they come from the rig's sensor model: dark frames
//! with zero light, flats from a uniform field through the true lens; that crate also
//! compares a calibration with the simulator's truth. The simulator's lens vignettes the same
//! at every f-number; a real lens does not, which is why there is one flat per f-number.

use std::path::Path;

use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_imaging::dark_flat::{DarkFlat, DarkFlatError, DarkModel, FlatField, FrameAverage};
use serde::{Deserialize, Serialize};

/// Version of the radiometric plan format.
pub const RADIOMETRIC_PLAN_VERSION: u32 = 1;
/// Version of the written calibration header.
pub const DARK_FLAT_FORMAT_VERSION: u32 = 1;
/// The shipped plan.
pub const DEFAULT_RADIOMETRIC_PLAN: &str = include_str!("../../../rig-configs/plans/calibration-radiometric.toml");
/// Name of the header file in a calibration directory.
pub const HEADER_FILE: &str = "dark-flat.toml";

/// Errors of the radiometric calibration.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DarkFlatCalError {
    /// The plan is invalid.
    #[error("radiometric calibration plan {origin}: {message}")]
    Plan {
        /// File name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// The rig cannot take the plan's frames (config, a capture).
    #[error("{0}")]
    Rig(String),
    /// The fit failed.
    #[error(transparent)]
    Fit(#[from] DarkFlatError),
    /// Reading or writing the calibration files failed.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
}

/// The `[dark]` section of a radiometric plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DarkPlan {
    /// Exposure times of the dark frames, s (at least 2 distinct values, each in (0, 3600]).
    pub exposures_s: Vec<f64>,
    /// Analogue gains (each in [1, the sensor's max]).
    pub gains: Vec<f64>,
    /// Frames averaged per exposure x gain (>= 2, so the spread is known).
    pub frames: usize,
    /// Dark current above which a photosite is hot, e-/s (> 0).
    pub hot_threshold_e_per_s: f64,
}

/// The `[flat]` section of a radiometric plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlatPlan {
    /// f-numbers to take a master flat at (empty: the rig's `[camera] f_number`).
    #[serde(default)]
    pub f_numbers: Vec<f64>,
    /// Brightest channel on the optical axis, as a fraction of full scale (0 < l < 1).
    pub level: f64,
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Analogue gain.
    pub gain: f64,
    /// Frames averaged per flat (>= 2).
    pub frames: usize,
    /// Size of the centre box the flat is normalised to 1 over, fraction of width and height.
    pub centre_fraction: f64,
}

/// A radiometric (dark and flat) calibration plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RadiometricPlan {
    /// Format version ([`RADIOMETRIC_PLAN_VERSION`]).
    pub format_version: u32,
    /// Name, recorded in the calibration header.
    pub name: String,
    /// Dark frames.
    pub dark: DarkPlan,
    /// Master flats.
    pub flat: FlatPlan,
}

impl RadiometricPlan {
    /// The shipped plan.
    pub fn default_plan() -> RadiometricPlan {
        Self::from_toml(DEFAULT_RADIOMETRIC_PLAN, "<embedded rig-configs/plans/calibration-radiometric.toml>")
            .expect("the shipped radiometric plan is valid")
    }

    /// Parses and validates a plan; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<RadiometricPlan, DarkFlatCalError> {
        let p: RadiometricPlan = toml::from_str(text)
            .map_err(|e| DarkFlatCalError::Plan { origin: origin.into(), message: e.to_string() })?;
        let problems = p.problems();
        if !problems.is_empty() {
            return Err(DarkFlatCalError::Plan { origin: origin.into(), message: problems.join("; ") });
        }
        Ok(p)
    }

    /// Every invalid value, as messages naming the field and what is allowed.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.format_version != RADIOMETRIC_PLAN_VERSION {
            out.push(format!("format_version = {}: allowed {RADIOMETRIC_PLAN_VERSION}", self.format_version));
        }
        let d = &self.dark;
        for (i, &t) in d.exposures_s.iter().enumerate() {
            if !(t > 0.0 && t <= 3600.0) {
                out.push(format!("dark.exposures_s[{i}] = {t}: allowed 0 < t <= 3600"));
            }
        }
        for (i, &g) in d.gains.iter().enumerate() {
            if !(g >= 1.0 && g.is_finite()) {
                out.push(format!("dark.gains[{i}] = {g}: allowed >= 1"));
            }
        }
        let mut products: Vec<f64> = d.exposures_s.iter().flat_map(|t| d.gains.iter().map(move |g| t * g)).collect();
        products.sort_by(f64::total_cmp);
        products.dedup();
        if products.len() < 2 {
            out.push(format!(
                "dark: {} distinct exposure x gain value(s): need at least 2 to separate bias and dark current",
                products.len()
            ));
        }
        if d.frames < 2 {
            out.push(format!("dark.frames = {}: allowed >= 2", d.frames));
        }
        if !(d.hot_threshold_e_per_s > 0.0 && d.hot_threshold_e_per_s.is_finite()) {
            out.push(format!("dark.hot_threshold_e_per_s = {}: allowed > 0", d.hot_threshold_e_per_s));
        }
        let f = &self.flat;
        for (i, &n) in f.f_numbers.iter().enumerate() {
            if !(n > 0.0 && n.is_finite()) {
                out.push(format!("flat.f_numbers[{i}] = {n}: allowed > 0"));
            }
        }
        if !(f.level > 0.0 && f.level < 1.0) {
            out.push(format!("flat.level = {}: allowed 0 < level < 1", f.level));
        }
        if !(f.exposure_s > 0.0 && f.exposure_s <= 3600.0) {
            out.push(format!("flat.exposure_s = {}: allowed 0 < t <= 3600", f.exposure_s));
        }
        if !(f.gain >= 1.0 && f.gain.is_finite()) {
            out.push(format!("flat.gain = {}: allowed >= 1", f.gain));
        }
        if f.frames < 2 {
            out.push(format!("flat.frames = {}: allowed >= 2", f.frames));
        }
        if !(f.centre_fraction > 0.0 && f.centre_fraction <= 1.0) {
            out.push(format!("flat.centre_fraction = {}: allowed 0 < f <= 1", f.centre_fraction));
        }
        out
    }
}

/// Summary figures of a calibration (written in the header, printed by the CLI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DarkFlatStats {
    /// Median bias over photosites, DN.
    pub bias_median_dn: f64,
    /// RMS standard error of the bias, DN.
    pub bias_sigma_rms_dn: f64,
    /// Median dark current, e-/s.
    pub rate_median_e_per_s: f64,
    /// RMS standard error of the dark current, e-/s.
    pub rate_sigma_rms_e_per_s: f64,
    /// Photosites flagged as defects (hot or unfittable).
    pub defects: usize,
    /// Per flat: f-number, RMS relative standard error, and min / max relative gain.
    pub flats: Vec<FlatStats>,
}

/// Figures of one master flat.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatStats {
    /// f-number.
    pub f_number: f64,
    /// Frames averaged.
    pub frames: usize,
    /// RMS relative standard error of the per-photosite gain.
    pub sigma_rms: f64,
    /// Smallest relative gain (strongest vignetting).
    pub min: f64,
    /// Largest relative gain.
    pub max: f64,
    /// Centre level per channel, DN above dark.
    pub centre_level_dn: [f64; 3],
    /// The EXR file of the flat.
    pub file: String,
}

/// The header of a written calibration (`dark-flat.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DarkFlatHeader {
    /// [`DARK_FLAT_FORMAT_VERSION`].
    pub format_version: u32,
    /// The rig's name.
    pub rig: String,
    /// The plan's name.
    pub plan: String,
    /// Seed of the simulated captures.
    pub seed: u64,
    /// Sensor width, photosites.
    pub width: usize,
    /// Sensor height, photosites.
    pub height: usize,
    /// Electrons per DN at gain 1 the dark model is expressed in.
    pub electrons_per_dn: f64,
    /// Hot threshold, e-/s.
    pub hot_threshold_e_per_s: f64,
    /// Dark exposures, s.
    pub dark_exposures_s: Vec<f64>,
    /// Dark gains.
    pub dark_gains: Vec<f64>,
    /// Frames per dark average.
    pub dark_frames: usize,
    /// The dark map file: R bias (DN), G dark current (e-/s), B defect (0 or 1).
    pub dark_file: String,
    /// The dark map's standard errors: R bias (DN), G dark current (e-/s), B 0.
    pub dark_sigma_file: String,
    /// Statistics, flats included (each names its file: R gain, G standard error, B 0).
    pub stats: DarkFlatStats,
}

/// A calibration and its figures.
#[derive(Debug, Clone)]
pub struct DarkFlatResult {
    /// The calibration.
    pub cal: DarkFlat,
    /// Its figures.
    pub stats: DarkFlatStats,
}

fn rms(v: &[f32]) -> f64 {
    let finite: Vec<f64> = v.iter().map(|&x| f64::from(x)).filter(|x| x.is_finite()).collect();
    (finite.iter().map(|x| x * x).sum::<f64>() / finite.len().max(1) as f64).sqrt()
}

fn median(v: &[f32]) -> f64 {
    let mut s: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f32::total_cmp);
    s.get(s.len() / 2).map_or(f64::NAN, |&x| f64::from(x))
}

/// The figures of a calibration.
pub fn stats_of(cal: &DarkFlat) -> DarkFlatStats {
    let d = &cal.dark;
    DarkFlatStats {
        bias_median_dn: median(&d.bias_dn),
        bias_sigma_rms_dn: rms(&d.bias_sigma_dn),
        rate_median_e_per_s: median(&d.rate_e_per_s),
        rate_sigma_rms_e_per_s: rms(&d.rate_sigma_e_per_s),
        defects: d.defects(),
        flats: cal
            .flats
            .iter()
            .map(|f| {
                let ok = || f.gain.iter().map(|&g| f64::from(g)).filter(|g| g.is_finite());
                FlatStats {
                    f_number: f.f_number,
                    frames: f.frames,
                    sigma_rms: f.rms_sigma(),
                    min: ok().fold(f64::INFINITY, f64::min),
                    max: ok().fold(f64::NEG_INFINITY, f64::max),
                    centre_level_dn: f.centre_level_dn,
                    file: flat_file_name(f.f_number),
                }
            })
            .collect(),
    }
}

/// One frame [`calibrate`] asks a [`DarkFlatCamera`] for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DarkFlatShot {
    /// A flat (a uniform field filling the lens, the brightest channel on the optical axis at
    /// the plan's `flat.level` of full scale) or, if false, a dark frame (no light).
    pub flat: bool,
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Analogue gain.
    pub gain: f64,
    /// The lens's f-number (recorded in the frame's metadata).
    pub f_number: f64,
    /// Capture group: one per exposure x gain of the darks, then one per flat f-number.
    pub group: u64,
    /// Frame index within the group.
    pub frame: u64,
}

/// The rig side of a dark and flat calibration: takes the plan's frames.
pub trait DarkFlatCamera {
    /// Takes `shot`.
    fn capture(&mut self, shot: &DarkFlatShot) -> Result<RawFrame, String>;
}

/// Runs the plan on a rig: `rig` takes every dark and flat frame; the dark model and the
/// flats are fitted (the rig config's sensor constants: electrons per DN, the gain limit);
/// `progress` gets one line per capture group.
pub fn calibrate(
    cfg: &RigConfig,
    plan: &RadiometricPlan,
    rig: &mut dyn DarkFlatCamera,
    mut progress: impl FnMut(&str),
) -> Result<DarkFlatResult, DarkFlatCalError> {
    let rig_err = |e: &dyn std::fmt::Display| DarkFlatCalError::Rig(e.to_string());
    cfg.validate().map_err(|e| rig_err(&e))?;
    let sensor = &cfg.sensor;
    let problems: Vec<String> = plan
        .dark
        .gains
        .iter()
        .chain([&plan.flat.gain])
        .filter(|&&g| g > sensor.max_analogue_gain)
        .map(|g| format!("gain {g} above the sensor's max_analogue_gain {}", sensor.max_analogue_gain))
        .collect();
    if !problems.is_empty() {
        return Err(DarkFlatCalError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let mut capture = |shot: DarkFlatShot| rig.capture(&shot).map_err(|e| rig_err(&e));

    let mut averages = Vec::new();
    let mut group = 0u64;
    for &gain in &plan.dark.gains {
        for &t in &plan.dark.exposures_s {
            let frames = (0..plan.dark.frames as u64)
                .map(|frame| {
                    capture(DarkFlatShot {
                        flat: false,
                        exposure_s: t,
                        gain,
                        f_number: cfg.camera.f_number,
                        group,
                        frame,
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            averages.push(FrameAverage::of(&frames, "dark frames")?);
            progress(&format!("dark: {} frames at {t} s, gain {gain}", plan.dark.frames));
            group += 1;
        }
    }
    let dark = DarkModel::fit(&averages, sensor.electrons_per_dn, plan.dark.hot_threshold_e_per_s)?;
    drop(averages);

    let f_numbers =
        if plan.flat.f_numbers.is_empty() { vec![cfg.camera.f_number] } else { plan.flat.f_numbers.clone() };
    let mut flats = Vec::new();
    for &n in &f_numbers {
        let (t, g) = (plan.flat.exposure_s, plan.flat.gain);
        let frames = (0..plan.flat.frames as u64)
            .map(|frame| capture(DarkFlatShot { flat: true, exposure_s: t, gain: g, f_number: n, group, frame }))
            .collect::<Result<Vec<_>, _>>()?;
        let avg = FrameAverage::of(&frames, "flat frames")?;
        drop(frames);
        let saturated = avg.saturated.iter().filter(|&&s| s).count();
        flats.push(FlatField::fit(&avg, &dark, n, plan.flat.centre_fraction)?);
        progress(&format!(
            "flat: {} frames at f/{n}, {t} s, gain {g} ({saturated} photosites saturated in some frame)",
            plan.flat.frames
        ));
        group += 1;
    }
    let cal = DarkFlat { dark, flats };
    let stats = stats_of(&cal);
    Ok(DarkFlatResult { cal, stats })
}

/// File name of the flat at `f_number`.
pub fn flat_file_name(f_number: f64) -> String {
    format!("flat-f{f_number}.exr")
}

fn file_err(path: &Path, e: impl std::fmt::Display) -> DarkFlatCalError {
    DarkFlatCalError::File { path: path.display().to_string(), message: e.to_string() }
}

/// Writes `res` into `dir` (created if missing): `dark.exr`, `dark-sigma.exr`, one
/// `flat-f<N>.exr` per flat, and the header `dark-flat.toml`. Returns the header.
pub fn write_calibration(
    dir: &Path,
    res: &DarkFlatResult,
    rig: &str,
    plan: &RadiometricPlan,
    seed: u64,
) -> Result<DarkFlatHeader, DarkFlatCalError> {
    std::fs::create_dir_all(dir).map_err(|e| file_err(dir, e))?;
    let d = &res.cal.dark;
    let (w, h) = (d.width, d.height);
    let dark: Vec<[f32; 3]> =
        (0..w * h).map(|i| [d.bias_dn[i], d.rate_e_per_s[i], if d.defect[i] { 1.0 } else { 0.0 }]).collect();
    let sigma: Vec<[f32; 3]> = (0..w * h).map(|i| [d.bias_sigma_dn[i], d.rate_sigma_e_per_s[i], 0.0]).collect();
    let write = |name: &str, data: &[[f32; 3]]| {
        let p = dir.join(name);
        btfrig_imageio::write_rgb_exr(&p, w, h, data).map_err(|e| file_err(&p, e))
    };
    write("dark.exr", &dark)?;
    write("dark-sigma.exr", &sigma)?;
    for f in &res.cal.flats {
        let data: Vec<[f32; 3]> = f.gain.iter().zip(&f.sigma).map(|(&g, &s)| [g, s, 0.0]).collect();
        write(&flat_file_name(f.f_number), &data)?;
    }
    let header = DarkFlatHeader {
        format_version: DARK_FLAT_FORMAT_VERSION,
        rig: rig.to_string(),
        plan: plan.name.clone(),
        seed,
        width: w,
        height: h,
        electrons_per_dn: d.electrons_per_dn,
        hot_threshold_e_per_s: d.hot_threshold_e_per_s,
        dark_exposures_s: plan.dark.exposures_s.clone(),
        dark_gains: plan.dark.gains.clone(),
        dark_frames: plan.dark.frames,
        dark_file: "dark.exr".into(),
        dark_sigma_file: "dark-sigma.exr".into(),
        stats: res.stats.clone(),
    };
    let p = dir.join(HEADER_FILE);
    let text = toml::to_string_pretty(&header).map_err(|e| file_err(&p, e))?;
    std::fs::write(&p, format!("# Dark and flat field calibration (format: docs/dark-flat.md)\n{text}"))
        .map_err(|e| file_err(&p, e))?;
    Ok(header)
}

/// One embedded dark/flat calibration directory: its name and its files (name, bytes).
type EmbeddedDarkFlat = (&'static str, &'static [(&'static str, &'static [u8])]);

/// Dark/flat calibrations embedded in the binary, for `[camera] dark_flat = "builtin:NAME"`
/// (the directories `btfrig calibrate radiometric` wrote into `calibration/`).
pub const BUILTIN_DARK_FLATS: &[EmbeddedDarkFlat] = &[
    (
        "bonn-dome-sim-dark-flat",
        &[
            (HEADER_FILE, include_bytes!("../../../calibration/bonn-dome-sim-dark-flat/dark-flat.toml")),
            ("dark.exr", include_bytes!("../../../calibration/bonn-dome-sim-dark-flat/dark.exr")),
            ("dark-sigma.exr", include_bytes!("../../../calibration/bonn-dome-sim-dark-flat/dark-sigma.exr")),
            ("flat-f8.exr", include_bytes!("../../../calibration/bonn-dome-sim-dark-flat/flat-f8.exr")),
        ],
    ),
    (
        "bonn-camera-array-sim-dark-flat",
        &[
            (HEADER_FILE, include_bytes!("../../../calibration/bonn-camera-array-sim-dark-flat/dark-flat.toml")),
            ("dark.exr", include_bytes!("../../../calibration/bonn-camera-array-sim-dark-flat/dark.exr")),
            ("dark-sigma.exr", include_bytes!("../../../calibration/bonn-camera-array-sim-dark-flat/dark-sigma.exr")),
            ("flat-f8.exr", include_bytes!("../../../calibration/bonn-camera-array-sim-dark-flat/flat-f8.exr")),
        ],
    ),
];

/// The dark/flat calibration the rig config names (`[camera] dark_flat`: a directory relative
/// to the rig config's directory, or `builtin:NAME`), checked against the config's sensor
/// size, with where it came from; `None` when the config names none.
pub fn processing_dark_flat(
    rig: &RigConfig,
    rig_path: Option<&Path>,
) -> Result<Option<(DarkFlat, String)>, DarkFlatCalError> {
    let Some(reference) = rig.camera.dark_flat.as_deref() else { return Ok(None) };
    let key = format!("[camera] dark_flat = {reference:?}");
    let (header, cal, origin) = if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, files) = BUILTIN_DARK_FLATS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_DARK_FLATS.iter().map(|(n, _)| *n).collect();
            file_err(
                Path::new(&key),
                format!("no built-in dark/flat calibration {name:?} (built in: {})", known.join(", ")),
            )
        })?;
        let dir = Path::new("<embedded calibration>").join(name);
        let (header, cal) = read_calibration_with(&dir, |p| {
            let file = p.file_name().and_then(|f| f.to_str()).unwrap_or_default();
            files.iter().find(|(n, _)| *n == file).map(|(_, b)| b.to_vec()).ok_or_else(|| "not embedded".to_string())
        })?;
        (header, cal, format!("<embedded calibration/{name}>"))
    } else {
        let base = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
        let dir = base.join(reference);
        let (header, cal) = read_calibration(&dir).map_err(|e| {
            file_err(
                Path::new(&key),
                format!("{e} (make one with `btfrig calibrate radiometric --out DIR`, or remove the key)"),
            )
        })?;
        (header, cal, dir.display().to_string())
    };
    let (w, h) = (rig.camera.width_px, rig.camera.height_px);
    if (header.width, header.height) != (w, h) {
        return Err(file_err(
            Path::new(&key),
            format!("{origin} is {}x{} photosites, the rig's camera {w}x{h}", header.width, header.height),
        ));
    }
    Ok(Some((cal, origin)))
}

/// Reads a calibration written by [`write_calibration`] from `dir`.
pub fn read_calibration(dir: &Path) -> Result<(DarkFlatHeader, DarkFlat), DarkFlatCalError> {
    read_calibration_with(dir, |p| std::fs::read(p).map_err(|e| e.to_string()))
}

/// Reads a calibration like [`read_calibration`] with `read` fetching each file's bytes by
/// its path under `dir` (e.g. from files embedded in the binary; `dir` then only names them).
pub fn read_calibration_with(
    dir: &Path,
    read: impl Fn(&Path) -> Result<Vec<u8>, String>,
) -> Result<(DarkFlatHeader, DarkFlat), DarkFlatCalError> {
    let p = dir.join(HEADER_FILE);
    let bytes = read(&p).map_err(|e| file_err(&p, e))?;
    let text = String::from_utf8(bytes).map_err(|e| file_err(&p, e))?;
    let header: DarkFlatHeader = toml::from_str(&text).map_err(|e| file_err(&p, e))?;
    if header.format_version != DARK_FLAT_FORMAT_VERSION {
        return Err(file_err(
            &p,
            format!("format_version {}: allowed {DARK_FLAT_FORMAT_VERSION}", header.format_version),
        ));
    }
    let (w, h) = (header.width, header.height);
    let read = |name: &str| -> Result<Vec<[f32; 3]>, DarkFlatCalError> {
        let p = dir.join(name);
        let bytes = read(&p).map_err(|e| file_err(&p, e))?;
        let (rw, rh, data) = btfrig_imageio::decode_rgb_exr(&p, &bytes).map_err(|e| file_err(&p, e))?;
        if (rw, rh) != (w, h) {
            return Err(file_err(&p, format!("{rw}x{rh}, the header says {w}x{h}")));
        }
        Ok(data)
    };
    let dark = read(&header.dark_file)?;
    let sigma = read(&header.dark_sigma_file)?;
    let model = DarkModel {
        width: w,
        height: h,
        electrons_per_dn: header.electrons_per_dn,
        bias_dn: dark.iter().map(|p| p[0]).collect(),
        rate_e_per_s: dark.iter().map(|p| p[1]).collect(),
        bias_sigma_dn: sigma.iter().map(|p| p[0]).collect(),
        rate_sigma_e_per_s: sigma.iter().map(|p| p[1]).collect(),
        defect: dark.iter().map(|p| p[2] > 0.5).collect(),
        hot_threshold_e_per_s: header.hot_threshold_e_per_s,
    };
    let mut flats = Vec::new();
    for s in &header.stats.flats {
        let data = read(&s.file)?;
        flats.push(FlatField {
            width: w,
            height: h,
            f_number: s.f_number,
            gain: data.iter().map(|p| p[0]).collect(),
            sigma: data.iter().map(|p| p[1]).collect(),
            centre_level_dn: s.centre_level_dn,
            frames: s.frames,
        });
    }
    Ok((header, DarkFlat { dark: model, flats }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_plan_is_valid_and_bad_plans_name_every_problem() {
        let p = RadiometricPlan::default_plan();
        assert!(p.dark.exposures_s.len() >= 2 && p.flat.frames >= 2);
        let text = DEFAULT_RADIOMETRIC_PLAN
            .replace("exposures_s = [0.001, 0.5, 2.0]", "exposures_s = [0.5]")
            .replace("gains = [1.0, 4.0]", "gains = [1.0]")
            .replace("level = 0.6", "level = 1.5");
        let e = RadiometricPlan::from_toml(&text, "x.toml").unwrap_err().to_string();
        assert!(e.contains("1 distinct exposure x gain") && e.contains("flat.level = 1.5"), "{e}");
    }
}
