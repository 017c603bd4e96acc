//! LED calibration of a dome (and flash calibration of a camera array, whose flashes are its
//! lights): each light's power and colour, measured with a white reference tile.
//!
//! The procedure: a white reference tile of known albedo (spectrally flat, Lambertian) lies on
//! the turntable in place of the sample; one camera photographs it lit by one light at a time
//! ([`LedShot`]). Per frame, `btfrig_imaging::light::lambertian_signal` reduces the tile's pixels
//! to `W_c`: the camera-RGB signal rate (e-/s per photosite at gain 1; e- per flash for a
//! flash) of a white Lambertian reflector lit along its normal by that light from the nominal
//! light distance, dividing out the tile's albedo, each point's incidence and distance, the
//! vignetting and the dark signal ([`fit_leds`]).
//!
//! The file ([`LedCalibrationFile`], TOML, `docs/rig-config.md`, "LED calibration") states a
//! reference `W` (the mean green `W_G` over the lights) and per light its power relative to it
//! (`W_G / reference`) and its colour as camera-RGB ratios (`W_c / W_G`, green = 1: the
//! light's white balance, its spectrum's tint in the camera included), each with its standard
//! uncertainty. The dome pipeline divides every single-light image by exactly these, so a
//! texture is a radiance factor in white-balanced camera RGB.
//!
//! The simulated side (rendering the tile frames on the simulated dome) is in
//! `btfrig-sim-calibration`; this module never sees a simulator type.

use std::path::{Path, PathBuf};

use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_imaging::demosaic::demosaic_bilinear_values;
use btfrig_imaging::light::{lambertian_signal, square_points};
use btfrig_imaging::{LinearImage, Radiometry};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Version of the LED calibration file format.
pub const LED_FORMAT_VERSION: u32 = 1;

/// LED calibration files embedded in the binary, for `[dome] led_calibration = "builtin:NAME"`.
pub const BUILTIN_LED_CALIBRATIONS: &[(&str, &str)] = &[
    ("bonn-dome-sim-leds", include_str!("../../../calibration/bonn-dome-sim-leds.toml")),
    ("bonn-camera-array-sim-flashes", include_str!("../../../calibration/bonn-camera-array-sim-flashes.toml")),
];

/// A problem with an LED calibration or its measurement.
#[derive(Debug, thiserror::Error)]
pub enum LedCalibError {
    /// The rig config's `[dome] led_calibration` cannot be used (missing, unreadable, invalid,
    /// or made for another rig).
    #[error("[dome] led_calibration = {reference:?}: {message}")]
    Reference {
        /// The field's value.
        reference: String,
        /// What is wrong.
        message: String,
    },
    /// The file is not valid (names the field).
    #[error("LED calibration {origin}: {message}")]
    File {
        /// Where the text came from.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// A frame could not be measured.
    #[error("LED calibration, light {light} (camera {camera}): {message}")]
    Measure {
        /// Light index.
        light: usize,
        /// Camera index.
        camera: usize,
        /// What went wrong.
        message: String,
    },
    /// The rig is not a dome or camera array, or its config is invalid.
    #[error("LED calibration: {0}")]
    Rig(String),
}

/// How the file was made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedSource {
    /// The rig it calibrates (`[rig] name`).
    pub rig: String,
    /// The method, in words.
    pub method: String,
    /// When it was measured (a date), or `"simulated"`.
    pub date: String,
    /// The noise seed of a simulated measurement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Albedo of the white reference tile.
    pub reference_albedo: f64,
    /// Frames measured per light.
    pub frames_per_light: usize,
    /// Per channel, how much larger the scatter between repeated frames of a light was than
    /// the frames' stated errors; every light's sigma is scaled by it ([`fit_leds`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatter_inflation: Option<[f64; 3]>,
}

/// One light's calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedEntry {
    /// Output relative to the file's reference (green channel).
    pub power: f64,
    /// Standard uncertainty of `power` (from the scatter over the tile of the light's frames'
    /// mean, scaled to the scatter between repeated frames of the same light: [`fit_leds`]).
    pub power_sigma: f64,
    /// Camera-RGB ratios of the light on a white reflector, green = 1.
    pub colour: [f64; 3],
    /// Standard uncertainty of each of `colour`.
    pub colour_sigma: [f64; 3],
}

/// An LED (or flash) calibration file (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedCalibrationFile {
    /// [`LED_FORMAT_VERSION`].
    pub format_version: u32,
    /// What a light is: `"LED"` or `"flash"`.
    pub light: String,
    /// The reference the powers are relative to, in words.
    pub reference: String,
    /// The reference's green signal: e-/s per photosite at gain 1 (e- per flash for flashes)
    /// of a white Lambertian reflector lit along its normal from the nominal light distance.
    pub reference_rate: f64,
    /// How it was made.
    pub source: LedSource,
    /// One entry per light, in the rig's light order.
    pub leds: Vec<LedEntry>,
}

impl LedCalibrationFile {
    /// Parses and validates a file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<LedCalibrationFile, LedCalibError> {
        let err = |message: String| LedCalibError::File { origin: origin.into(), message };
        let f: LedCalibrationFile = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if f.format_version != LED_FORMAT_VERSION {
            return Err(err(format!(
                "format_version = {} is not supported (this build reads {LED_FORMAT_VERSION})",
                f.format_version
            )));
        }
        if !(f.reference_rate.is_finite() && f.reference_rate > 0.0) {
            return Err(err(format!("reference_rate = {}: must be finite and > 0", f.reference_rate)));
        }
        for (j, l) in f.leds.iter().enumerate() {
            if !(l.power.is_finite() && l.power > 0.0) {
                return Err(err(format!("leds[{j}].power = {}: must be finite and > 0", l.power)));
            }
            if let Some((c, v)) = l.colour.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
                return Err(err(format!("leds[{j}].colour[{c}] = {v}: must be finite and > 0")));
            }
        }
        Ok(f)
    }

    /// The file as TOML, with a header saying what it is.
    pub fn to_toml(&self) -> String {
        format!(
            "# LED calibration (format: docs/rig-config.md, \"LED calibration\"), written by `btfrig calibrate leds`.\n\
             # Light j's white-reflector signal (camera RGB, e-/s per photosite) = reference_rate * power * colour.\n{}",
            toml::to_string(self).expect("an LED calibration serialises")
        )
    }

    /// Per light, its power relative to the reference.
    pub fn powers(&self) -> Vec<f64> {
        self.leds.iter().map(|l| l.power).collect()
    }

    /// Per light, its camera-RGB colour (green = 1).
    pub fn colours(&self) -> Vec<[f64; 3]> {
        self.leds.iter().map(|l| l.colour).collect()
    }
}

/// The LED calibration a dome run processes with: the file the rig config's `[dome]
/// led_calibration` names (`builtin:NAME` or a path relative to the rig file's directory),
/// checked against the rig (one entry per light), or `None` when it names none.
pub fn processing_leds(rig: &RigConfig, rig_path: Option<&Path>) -> Result<Option<LedCalibrationFile>, LedCalibError> {
    let Some(dome) = rig.dome.as_ref() else { return Ok(None) };
    let Some(reference) = dome.led_calibration.as_deref() else { return Ok(None) };
    let err = |message: String| LedCalibError::Reference { reference: reference.into(), message };
    let (text, origin) = if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, text) = BUILTIN_LED_CALIBRATIONS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_LED_CALIBRATIONS.iter().map(|(n, _)| *n).collect();
            err(format!("no built-in LED calibration {name:?} (built in: {})", known.join(", ")))
        })?;
        (text.to_string(), format!("<embedded calibration/{name}.toml>"))
    } else {
        let base: PathBuf = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
        let path = base.join(reference);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            err(format!(
                "cannot read the LED calibration file {}: {e} (make one with `btfrig calibrate leds`, or remove the key \
                 to process in relative units)",
                path.display()
            ))
        })?;
        (text, path.display().to_string())
    };
    let file = LedCalibrationFile::from_toml(&text, &origin).map_err(|e| err(e.to_string()))?;
    if file.leds.len() != dome.led_count() {
        return Err(err(format!(
            "{origin} calibrates {} lights, the rig {} has {}",
            file.leds.len(),
            rig.rig.name,
            dome.led_count()
        )));
    }
    Ok(Some(file))
}

/// One calibration frame: the white tile lit by light `light` alone, seen by camera `camera`
/// with the turntable at `turntable_rad`.
#[derive(Debug, Clone)]
pub struct LedShot {
    /// Light index.
    pub light: usize,
    /// Camera index.
    pub camera: usize,
    /// Turntable angle, radians.
    pub turntable_rad: f64,
    /// The raw frame.
    pub frame: RawFrame,
}

/// What [`fit_leds`] needs besides the frames.
#[derive(Debug, Clone)]
pub struct LedFitOptions {
    /// Albedo of the white reference tile.
    pub reference_albedo: f64,
    /// Margin inside the tile (sample square) edge left out, metres.
    pub tile_margin_m: f64,
    /// Grid step of the measured points, metres.
    pub step_m: f64,
    /// The method, in words (for the file).
    pub method: String,
    /// When (a date) or `"simulated"`.
    pub date: String,
    /// The noise seed of a simulated measurement.
    pub seed: Option<u64>,
}

impl Default for LedFitOptions {
    fn default() -> Self {
        LedFitOptions {
            reference_albedo: 0.99,
            tile_margin_m: 0.01,
            step_m: 0.002,
            method: "white reference tile lit by one light at a time".into(),
            date: "simulated".into(),
            seed: None,
        }
    }
}

/// One light's white signal, measured by [`measure_leds`].
#[derive(Debug, Clone, PartialEq)]
pub struct LightSignal {
    /// `W_c` over the tile's albedo: the mean of the light's frames.
    pub white: [f64; 3],
    /// Its standard error before the scatter inflation: the scatter over the tile of the mean
    /// of the light's frames (what the frames share, the photosites' fixed pattern and the
    /// tile, stays in it at full size; their independent noise averages down).
    pub sigma: [f64; 3],
    /// Frames measured.
    pub frames: usize,
}

impl LightSignal {
    /// The light's file entry, its sigma scaled by `inflation`, its power relative to
    /// `reference_rate`.
    pub fn entry(&self, inflation: [f64; 3], reference_rate: f64) -> LedEntry {
        let (w, s) = (self.white, std::array::from_fn::<f64, 3, _>(|c| self.sigma[c] * inflation[c]));
        let rel = |c: usize| s[c] / w[c];
        LedEntry {
            power: w[1] / reference_rate,
            power_sigma: w[1] / reference_rate * rel(1),
            colour: [w[0] / w[1], 1.0, w[2] / w[1]],
            colour_sigma: [w[0] / w[1] * rel(0).hypot(rel(1)), 0.0, w[2] / w[1] * rel(2).hypot(rel(1))],
        }
    }
}

/// The lights of `shots` measured (processing with `camera`): per light of the rig its
/// signal (`None` without a frame), and per channel the scatter inflation (how much larger
/// the scatter between repeated frames of a light is than their stated errors: neighbouring
/// points share photosites through the demosaic, so the points' scatter understates the
/// noise). Each light's signal depends on its own frames only.
pub fn measure_leds(
    rig: &RigConfig,
    camera: &CameraModel,
    shots: &[LedShot],
    opts: &LedFitOptions,
) -> Result<(Vec<Option<LightSignal>>, [f64; 3]), LedCalibError> {
    let dome = rig.dome.as_ref().ok_or_else(|| {
        LedCalibError::Rig(format!(
            "rig {} is a {}, not an LED dome or camera array",
            rig.rig.name,
            rig.rig.kind.as_str()
        ))
    })?;
    if !(opts.reference_albedo.is_finite() && opts.reference_albedo > 0.0 && opts.reference_albedo <= 1.0) {
        return Err(LedCalibError::Rig(format!("reference_albedo = {}: allowed (0, 1]", opts.reference_albedo)));
    }
    let n = dome.led_count();
    let points = square_points(rig.plate.sample_side_m - 2.0 * opts.tile_margin_m, opts.step_m);
    let (e_per_dn, dark) = (rig.sensor.electrons_per_dn, rig.sensor.dark_current_e_per_s);
    // DN above black and mean dark signal, as the dome pipeline reads a frame.
    let above_dark = |f: &RawFrame| -> Vec<f32> {
        let dark_dn = (dark * f.meta.exposure_s * f.meta.gain / e_per_dn) as f32;
        let black = f32::from(f.meta.black_level);
        f.data.iter().map(|&v| f32::from(v) - black - dark_dn).collect()
    };
    // `W_c` (over the tile's albedo) and its standard error from the scatter over the tile, of
    // `values` (DN above dark, the layout of `f`) of light `s.light` seen as in shot `s`.
    let signal = |s: &LedShot, values: &[f32]| -> Result<([f64; 3], [f64; 3]), LedCalibError> {
        let f = &s.frame;
        let rgb = demosaic_bilinear_values(f.width, f.height, f.meta.bayer, values);
        let image = LinearImage { width: f.width, height: f.height, data: rgb.data };
        let to_rate = Radiometry {
            dn_range: 1.0,
            exposure_s: dome.light_units(f.meta.exposure_s),
            dn_per_electron: f.meta.gain / e_per_dn,
            dark_e_per_s: 0.0,
            nominal_irradiance: 1.0,
            white_balance: [1.0; 3],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let pose = dome.scene_pose(s.camera, s.turntable_rad, s.light);
        let w = lambertian_signal(&image, camera, &pose, dome.light_distance_m(), &to_rate, &points)
            .map_err(|e| LedCalibError::Measure { light: s.light, camera: s.camera, message: e.to_string() })?;
        let a = opts.reference_albedo;
        Ok((w.mean.map(|v| v / a), w.sigma.map(|v| v / a)))
    };
    let measured: Vec<(usize, [f64; 3], [f64; 3])> = shots
        .par_iter()
        .map(|s| {
            let bad = |message: String| LedCalibError::Measure { light: s.light, camera: s.camera, message };
            if s.light >= n {
                return Err(bad(format!("the rig has {n} lights")));
            }
            let f = &s.frame;
            if (f.width, f.height) != (camera.width, camera.height) {
                return Err(bad(format!(
                    "a {}x{} frame, the camera is {}x{}",
                    f.width, f.height, camera.width, camera.height
                )));
            }
            let (w, sigma) = signal(s, &above_dark(f))?;
            Ok((s.light, w, sigma))
        })
        .collect::<Result<_, _>>()?;
    let n_frames = |j: usize| measured.iter().filter(|m| m.0 == j).count();
    let mut sum = vec![[0.0f64; 3]; n];
    for (j, w, _) in &measured {
        for c in 0..3 {
            sum[*j][c] += w[c];
        }
    }
    let mean: Vec<[f64; 3]> = sum.iter().enumerate().map(|(j, w)| w.map(|x| x / n_frames(j).max(1) as f64)).collect();
    let inflation = scatter_inflation(&measured, &mean);
    let signals = (0..n)
        .into_par_iter()
        .map(|j| {
            let mine: Vec<&LedShot> = shots.iter().filter(|s| s.light == j).collect();
            let Some(first) = mine.first().copied() else { return Ok(None) };
            let one_view = mine.iter().all(|s| s.camera == first.camera && s.turntable_rad == first.turntable_rad);
            let k = mine.len() as f64;
            let sigma = if one_view {
                let mut acc = vec![0.0f64; first.frame.data.len()];
                for s in &mine {
                    for (a, v) in acc.iter_mut().zip(above_dark(&s.frame)) {
                        *a += f64::from(v);
                    }
                }
                let avg: Vec<f32> = acc.iter().map(|a| (a / k) as f32).collect();
                signal(first, &avg)?.1
            } else {
                // Frames from several views share no fixed pattern: the root-sum-square of
                // their stated errors over their number.
                let mine: Vec<_> = measured.iter().filter(|m| m.0 == j).collect();
                std::array::from_fn(|c| mine.iter().map(|m| m.2[c].powi(2)).sum::<f64>().sqrt() / k)
            };
            Ok(Some(LightSignal { white: mean[j], sigma, frames: mine.len() }))
        })
        .collect::<Result<Vec<_>, LedCalibError>>()?;
    Ok((signals, inflation))
}

/// Fits the LED calibration of `rig` from `shots` (every light at least once; several frames
/// of one light are averaged), processing with `camera` (the processing camera).
pub fn fit_leds(
    rig: &RigConfig,
    camera: &CameraModel,
    shots: &[LedShot],
    opts: &LedFitOptions,
) -> Result<LedCalibrationFile, LedCalibError> {
    let (signals, inflation) = measure_leds(rig, camera, shots, opts)?;
    let dome = rig.dome.as_ref().expect("measure_leds checked the rig is a dome");
    let n = signals.len();
    let per: Vec<&LightSignal> = signals
        .iter()
        .enumerate()
        .map(|(j, s)| {
            s.as_ref().ok_or_else(|| {
                LedCalibError::Rig(format!("light {j} has no calibration frame (every one of the {n} needs one)"))
            })
        })
        .collect::<Result<_, _>>()?;
    let frames = per.iter().map(|s| s.frames).min().unwrap_or(0);
    let reference_rate = per.iter().map(|s| s.white[1]).sum::<f64>() / n as f64;
    let leds = per.iter().map(|s| s.entry(inflation, reference_rate)).collect();
    let light = if dome.is_flash() { "flash" } else { "LED" };
    Ok(LedCalibrationFile {
        format_version: LED_FORMAT_VERSION,
        light: light.into(),
        reference: format!(
            "the mean over the rig's {n} {light}s of the green signal of a white Lambertian reflector lit along its \
             normal from {} m",
            dome.light_distance_m()
        ),
        reference_rate,
        source: LedSource {
            rig: rig.rig.name.clone(),
            method: opts.method.clone(),
            date: opts.date.clone(),
            seed: opts.seed,
            reference_albedo: opts.reference_albedo,
            frames_per_light: frames,
            scatter_inflation: Some(inflation),
        },
        leds,
    })
}

/// Per channel, how much larger the frame-to-frame scatter of the lights' measurements is than
/// the standard errors `lambertian_signal` states (a lower bound: neighbouring points share
/// photosites through the demosaic): the root of the mean, over the lights measured more than
/// once, of their frames' sample variance over their mean squared stated error. At least 1; 1
/// when no light has two frames.
fn scatter_inflation(measured: &[(usize, [f64; 3], [f64; 3])], mean: &[[f64; 3]]) -> [f64; 3] {
    let n = mean.len();
    let mut dev = vec![([0.0f64; 3], [0.0f64; 3], 0usize); n];
    for (j, w, s) in measured {
        for c in 0..3 {
            dev[*j].0[c] += (w[c] - mean[*j][c]).powi(2);
            dev[*j].1[c] += s[c] * s[c];
        }
        dev[*j].2 += 1;
    }
    let used: Vec<_> = dev.iter().filter(|d| d.2 >= 2).collect();
    if used.is_empty() {
        return [1.0; 3];
    }
    std::array::from_fn(|c| {
        let ratio = used
            .iter()
            .map(|(d, v, k)| {
                let k = *k as f64;
                let stated = v[c] / k;
                if stated > 0.0 {
                    d[c] / (k - 1.0) / stated
                } else {
                    1.0
                }
            })
            .sum::<f64>()
            / used.len() as f64;
        ratio.sqrt().max(1.0)
    })
}
