//! Noise-optimal merge of an exposure bracket into linear signal rate, per photosite.
//!
//! A bracket is several raw frames of the same scene and pose at different exposure times
//! (and gains). Per photosite `(x, y)`, exposure `i` with time `t_i`, conversion gain `k_i`
//! (DN per electron) and reading `DN_i`:
//!
//! ```text
//! rate_i = (DN_i - black_i(x, y)) / (k_i · t_i · flat(x, y))                     [e-/s]
//! var_i  = (rate · flat · t_i + dark_e_i + σ_read² + 1 / (12 k_i²)) / (flat · t_i)²
//! rate   = Σ w_i rate_i / Σ w_i,   w_i = 1 / var_i,   var(rate) = 1 / Σ w_i
//! ```
//!
//! `black_i` is the expected dark reading (black level plus dark signal) and `flat` the
//! photosite's relative sensitivity; both come from a [`PhotositeCalibration`], by default
//! the sensor's nominal black level and dark current with a flat of 1 ([`NominalCalibration`]),
//! later measured dark and flat frames. The variance is the sensor model's: Poisson shot
//! noise of signal and dark electrons, read noise, and the ADC's quantisation step. It is
//! evaluated at the *merged* estimate (two passes), not at each noisy sample, because
//! weights built from a sample's own value favour the samples that came out low.
//!
//! Saturation: exposures are visited from the shortest. The shortest is usable when its
//! reading is below `saturation_fraction` of the frame's full scale; each longer one when the
//! estimate from the shorter ones predicts it below that level (and it is not clipped).
//! Deciding from the independent shorter samples instead of the sample itself keeps
//! photosites near the threshold from being included only when their noise came out low (a
//! bias of about half a sigma). When even the shortest exposure is saturated, the photosite
//! gets that exposure's clipped value as a lower bound and is flagged
//! ([`MergedFrame::used`] = 0).
//!
//! No exposure is dropped for being dark: with variances from the model, a dark sample's
//! weight is already what its noise deserves, and dropping it would bias faint photosites.
//! Numerics only (no I/O); the method is documented with measured figures in `docs/hdr.md`.

use btfrig_core::frame::{FrameMeta, RawFrame};
use rayon::prelude::*;

/// Why a bracket could not be merged.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum HdrError {
    /// No frames were given.
    #[error("the bracket is empty: at least one frame is needed")]
    Empty,
    /// A frame's size differs from the first frame's.
    #[error("bracket frame {index} is {width}x{height}, the first frame is {expect_width}x{expect_height}")]
    SizeMismatch {
        /// Index of the frame in the bracket.
        index: usize,
        /// Its width.
        width: usize,
        /// Its height.
        height: usize,
        /// The first frame's width.
        expect_width: usize,
        /// The first frame's height.
        expect_height: usize,
    },
    /// A frame's data length disagrees with its size.
    #[error("bracket frame {index} holds {len} photosites, its size says {expect}")]
    DataLength {
        /// Index of the frame.
        index: usize,
        /// Length of the data.
        len: usize,
        /// `width * height`.
        expect: usize,
    },
    /// A frame's metadata or a merge setting is out of range.
    #[error("{what} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// The field, e.g. `frame 1 exposure_s`.
        what: String,
        /// The offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
}

/// Per-photosite dark level and sensitivity: where measured dark and flat frames plug in.
pub trait PhotositeCalibration: Sync {
    /// Expected reading of photosite `(x, y)` with no light for a frame taken as `meta`
    /// (black level plus dark signal), DN.
    fn dark_dn(&self, x: usize, y: usize, meta: &FrameMeta) -> f64;
    /// Dark electrons of photosite `(x, y)` in that frame (their shot noise counts in the
    /// variance).
    fn dark_electrons(&self, x: usize, y: usize, meta: &FrameMeta) -> f64;
    /// Relative sensitivity of photosite `(x, y)` (a normalised flat field), > 0.
    fn flat(&self, _x: usize, _y: usize) -> f64 {
        1.0
    }
}

/// The sensor's nominal black level and a uniform dark current; flat 1 everywhere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalCalibration {
    /// Dark current, electrons per second per photosite.
    pub dark_current_e_per_s: f64,
    /// Electrons per DN at analogue gain 1.
    pub electrons_per_dn: f64,
}

impl PhotositeCalibration for NominalCalibration {
    fn dark_dn(&self, _x: usize, _y: usize, meta: &FrameMeta) -> f64 {
        f64::from(meta.black_level) + self.dark_current_e_per_s * meta.exposure_s * meta.gain / self.electrons_per_dn
    }
    fn dark_electrons(&self, _x: usize, _y: usize, meta: &FrameMeta) -> f64 {
        self.dark_current_e_per_s * meta.exposure_s
    }
}

/// The sensor's temporal noise, as in `btfrig_render::sensor` (see `docs/sensor-model.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Electrons per DN at analogue gain 1 (conversion gain `k = gain / electrons_per_dn`).
    pub electrons_per_dn: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
}

impl NoiseModel {
    /// Variance (e-²) of one reading holding `electrons` of signal plus dark, at conversion
    /// gain `k` DN/e-: shot noise, read noise and the quantisation step (1 DN, uniform).
    pub fn variance_e2(&self, electrons: f64, k: f64) -> f64 {
        electrons.max(0.0) + self.read_noise_e * self.read_noise_e + 1.0 / (12.0 * k * k)
    }
}

/// Settings of the merge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeOptions {
    /// A sample is usable below this fraction of its frame's full scale `white - black`
    /// (`(0, 1]`, default 0.95: about ten shot-noise sigmas below the clip of the default
    /// sensor, so the clip never biases a usable sample).
    pub saturation_fraction: f64,
}

impl Default for MergeOptions {
    fn default() -> Self {
        MergeOptions { saturation_fraction: 0.95 }
    }
}

/// A merged bracket: signal rate per photosite (the Bayer mosaic is kept).
#[derive(Debug, Clone, PartialEq)]
pub struct MergedFrame {
    /// Width in photosites.
    pub width: usize,
    /// Height in photosites.
    pub height: usize,
    /// Signal rate, electrons per second, flat removed (row-major). Where every exposure is
    /// saturated, the shortest exposure's clipped value (a lower bound).
    pub rate: Vec<f32>,
    /// Variance of `rate` from the noise model, (e-/s)²; for all-saturated photosites the
    /// variance the clipped value would have.
    pub variance: Vec<f32>,
    /// Number of exposures that entered each photosite's rate; 0 = saturated in all.
    pub used: Vec<u8>,
}

impl MergedFrame {
    /// Photosites saturated in every exposure of the bracket.
    pub fn saturated_everywhere(&self) -> usize {
        self.used.iter().filter(|&&u| u == 0).count()
    }
}

/// Merges a bracket of raw frames (any order) into signal rate per photosite. See the module
/// documentation for the formula.
pub fn merge_bracket(
    frames: &[&RawFrame],
    calibration: &impl PhotositeCalibration,
    noise: &NoiseModel,
    options: &MergeOptions,
) -> Result<MergedFrame, HdrError> {
    let first = frames.first().ok_or(HdrError::Empty)?;
    let (w, h) = (first.width, first.height);
    let sf = options.saturation_fraction;
    if !(sf > 0.0 && sf <= 1.0) {
        return Err(HdrError::OutOfRange { what: "saturation_fraction".into(), value: sf, allowed: "(0, 1]" });
    }
    check_noise(noise)?;
    for (i, f) in frames.iter().enumerate() {
        if (f.width, f.height) != (w, h) {
            return Err(HdrError::SizeMismatch {
                index: i,
                width: f.width,
                height: f.height,
                expect_width: w,
                expect_height: h,
            });
        }
        if f.data.len() != w * h {
            return Err(HdrError::DataLength { index: i, len: f.data.len(), expect: w * h });
        }
        check_meta(i, &f.meta)?;
    }
    // Shortest signal scale first: each longer exposure is judged from the shorter ones.
    let mut order: Vec<&RawFrame> = frames.to_vec();
    order.sort_by(|a, b| (a.meta.exposure_s * a.meta.gain).total_cmp(&(b.meta.exposure_s * b.meta.gain)));
    let ks: Vec<f64> = order.iter().map(|f| f.meta.gain / noise.electrons_per_dn).collect();
    // Usable DN above the dark level: `saturation_fraction` of the full scale, but never the
    // clip itself.
    let limits: Vec<f64> = order
        .iter()
        .map(|f| {
            let full = f64::from(f.meta.white_level) - f64::from(f.meta.black_level);
            (sf * full).min(full - 1.0)
        })
        .collect();

    let mut rate = vec![0.0f32; w * h];
    let mut variance = vec![0.0f32; w * h];
    let mut used = vec![0u8; w * h];
    rate.par_chunks_mut(w.max(1))
        .zip(variance.par_chunks_mut(w.max(1)))
        .zip(used.par_chunks_mut(w.max(1)))
        .enumerate()
        .for_each(|(y, ((r_row, v_row), u_row))| {
            // Per photosite: (rate_i, t_i·flat, dark electrons, k_i) of the usable samples.
            let mut samples: Vec<(f64, f64, f64, f64)> = Vec::with_capacity(order.len());
            for x in 0..w {
                let flat = calibration.flat(x, y);
                samples.clear();
                let mut estimate: Option<f64> = None;
                for (j, f) in order.iter().enumerate() {
                    let dn = f64::from(f.data[y * w + x]);
                    let dark_dn = calibration.dark_dn(x, y, &f.meta);
                    let dark_e = calibration.dark_electrons(x, y, &f.meta);
                    let black = f64::from(f.meta.black_level);
                    let scale = f.meta.exposure_s * flat;
                    let k = ks[j];
                    // Predicted signal (DN above black) from the shorter exposures.
                    let predicted = estimate.map(|r| (r * scale + dark_e) * k);
                    let clipped = dn >= f64::from(f.meta.white_level);
                    // With a prediction, the decision ignores the sample's own noise.
                    let over = match predicted {
                        Some(p) => p > limits[j],
                        None => dn - black > limits[j],
                    };
                    if clipped || over {
                        // Longer exposures are brighter still.
                        break;
                    }
                    samples.push(((dn - dark_dn) / (k * scale), scale, dark_e, k));
                    estimate = Some(weighted(&samples, noise, None).0);
                }
                if samples.is_empty() {
                    // Saturated even in the shortest exposure: its clipped value, flagged.
                    let f = order[0];
                    let k = ks[0];
                    let scale = f.meta.exposure_s * flat;
                    let r = (f64::from(f.data[y * w + x]) - calibration.dark_dn(x, y, &f.meta)) / (k * scale);
                    r_row[x] = r as f32;
                    let e = r * scale + calibration.dark_electrons(x, y, &f.meta);
                    v_row[x] = (noise.variance_e2(e, k) / (scale * scale)) as f32;
                    u_row[x] = 0;
                    continue;
                }
                // Second pass: weights at the merged estimate rather than the running one.
                let first = weighted(&samples, noise, None).0;
                let (r, var) = weighted(&samples, noise, Some(first));
                r_row[x] = r as f32;
                v_row[x] = var as f32;
                u_row[x] = samples.len() as u8;
            }
        });
    Ok(MergedFrame { width: w, height: h, rate, variance, used })
}

/// Inverse-variance mean of `(rate_i, scale_i, dark_e_i, k_i)` samples and its variance; the
/// variances are evaluated at `at` (default: the longest sample's own rate, the least noisy).
fn weighted(samples: &[(f64, f64, f64, f64)], noise: &NoiseModel, at: Option<f64>) -> (f64, f64) {
    let at = at.unwrap_or_else(|| samples.last().map_or(0.0, |s| s.0)).max(0.0);
    let (mut sw, mut swr) = (0.0, 0.0);
    for &(r, scale, dark_e, k) in samples {
        let var = noise.variance_e2(at * scale + dark_e, k) / (scale * scale);
        sw += 1.0 / var;
        swr += r / var;
    }
    (swr / sw, 1.0 / sw)
}

fn check_noise(noise: &NoiseModel) -> Result<(), HdrError> {
    if !(noise.electrons_per_dn.is_finite() && noise.electrons_per_dn > 0.0) {
        return Err(HdrError::OutOfRange {
            what: "noise.electrons_per_dn".into(),
            value: noise.electrons_per_dn,
            allowed: "finite and > 0",
        });
    }
    if !(noise.read_noise_e.is_finite() && noise.read_noise_e >= 0.0) {
        return Err(HdrError::OutOfRange {
            what: "noise.read_noise_e".into(),
            value: noise.read_noise_e,
            allowed: "finite and >= 0",
        });
    }
    Ok(())
}

fn check_meta(i: usize, m: &FrameMeta) -> Result<(), HdrError> {
    if !(m.exposure_s.is_finite() && m.exposure_s > 0.0) {
        return Err(HdrError::OutOfRange {
            what: format!("frame {i} exposure_s"),
            value: m.exposure_s,
            allowed: "finite and > 0",
        });
    }
    if !(m.gain.is_finite() && m.gain > 0.0) {
        return Err(HdrError::OutOfRange { what: format!("frame {i} gain"), value: m.gain, allowed: "finite and > 0" });
    }
    if m.white_level <= m.black_level.saturating_add(1) {
        return Err(HdrError::OutOfRange {
            what: format!("frame {i} white_level"),
            value: f64::from(m.white_level),
            allowed: "above black_level + 1",
        });
    }
    Ok(())
}
