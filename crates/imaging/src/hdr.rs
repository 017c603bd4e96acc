//! Noise-optimal merge of an exposure bracket into linear signal rate, per photosite.
//!
//! A bracket is several raw frames of the same scene and pose at different exposure times
//! (and gains). Per photosite `(x, y)`, exposure `i` with time `t_i`, conversion gain `k_i`
//! (DN per electron) and reading `DN_i`:
//!
//! ```text
//! rate_i = (DN_i - black_i(x, y)) / (k_i · t_i · flat(x, y))                     [e-/s]
//! var_i  = (rate · flat · t_i + dark_e_i + σ_read² + 1 / (12 k_i²)) / (flat · t_i)²
//! rate   = Σ w_i rate_i / Σ w_i,   w_i = α_i / var_i,   var(rate) = Σ w_i² var_i / (Σ w_i)²
//! ```
//!
//! `black_i` is the expected dark reading (black level plus dark signal) and `flat` the
//! photosite's relative sensitivity; both come from a [`PhotositeCalibration`], by default
//! the sensor's nominal black level and dark current with a flat of 1 ([`NominalCalibration`]),
//! later measured dark and flat frames. `α_i` is 1 except near saturation (below). The variance is the sensor model's: Poisson shot
//! noise of signal and dark electrons, read noise, and the ADC's quantisation step. It is
//! evaluated at the *merged* estimate (two passes), not at each noisy sample, because
//! weights built from a sample's own value favour the samples that came out low.
//!
//! Saturation: exposures are visited from the shortest. The shortest is usable when its
//! reading is below `saturation_fraction` of the frame's full scale. For each longer one, the
//! estimate from the shorter ones predicts its reading `p`; its share of the merged mean is
//! its full inverse-variance share times `f = clamp((limit - p) / (0.25 limit), 0, 1)`,
//! fading out linearly over the last quarter of the usable range, and a clipped reading is
//! never used. Deciding from the shorter samples rather than the sample itself, and fading
//! the share linearly rather than switching, keeps photosites near the limit almost
//! unbiased: the bias is about `share' · σ²` of the deciding estimate, where a hard switch on
//! either sample gives about half a sigma of the
//! deciding sample (measured 0.5 % on the default sensor at a 1:8 bracket; with the
//! fade, see `docs/hdr.md`). When even the shortest exposure is saturated, the photosite gets that
//! exposure's clipped value as a lower bound and is flagged ([`MergedFrame::used`] = 0).
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

/// A merged bracket: signal rate per photosite (the Bayer mosaic is kept). The default is
/// empty (planes for [`merge_bracket_into`] to fill).
#[derive(Debug, Clone, Default, PartialEq)]
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
///
/// The same formula as [`merge_bracket_reference`] rearranged to divide less: a sample's
/// weight `α s² / V` and its variance term `α² s² / V` share one reciprocal of `V`, two
/// samples share one division for both, the sums one reciprocal, rates multiply by per-frame
/// reciprocals; the fade's share `ρ` is formed only inside the fade band, where it matters;
/// constants are hoisted and the samples live on the stack. Rates and variances agree with the
/// reference to a few f64 ulps before the conversion to `f32` (the test allows 2 ulps of
/// `f32`; `used` is identical). Speed before and after: `btfrig bench hdr`.
pub fn merge_bracket(
    frames: &[&RawFrame],
    calibration: &impl PhotositeCalibration,
    noise: &NoiseModel,
    options: &MergeOptions,
) -> Result<MergedFrame, HdrError> {
    let mut out = MergedFrame::default();
    merge_bracket_into(frames, calibration, noise, options, &mut out)?;
    Ok(out)
}

/// [`merge_bracket`] into the planes of `out` (resized to the frames; every photosite is
/// written), so that a run merging frame after frame reuses them: fresh planes of a 12 MP
/// frame are 108 MB of pages the kernel must clear on first touch, about 20 ms of a 70-75 ms
/// merge (`docs/benchmarks.md`). On an error `out` holds no meaningful values.
pub fn merge_bracket_into(
    frames: &[&RawFrame],
    calibration: &impl PhotositeCalibration,
    noise: &NoiseModel,
    options: &MergeOptions,
    out: &mut MergedFrame,
) -> Result<(), HdrError> {
    let (order, ks, limits) = prepare(frames, noise, options)?;
    let (w, h) = (order[0].width, order[0].height);
    let n = order.len();
    let rn2 = noise.read_noise_e * noise.read_noise_e;
    // Per frame: quantisation variance, fade band inverse, clip and black levels.
    let quant: Vec<f64> = ks.iter().map(|k| 1.0 / (12.0 * k * k)).collect();
    let inv_band: Vec<f64> = limits.iter().map(|l| 1.0 / (FADE * l)).collect();
    let white: Vec<f64> = order.iter().map(|f| f64::from(f.meta.white_level)).collect();
    let black: Vec<f64> = order.iter().map(|f| f64::from(f.meta.black_level)).collect();
    let inv_k_exposure: Vec<f64> = order.iter().zip(&ks).map(|(f, k)| 1.0 / (k * f.meta.exposure_s)).collect();
    // V(at) of a sample: the reading's variance in e-² at rate `at` (`NoiseModel::variance_e2`).
    let var_e2 = |at: f64, scale: f64, dark_e: f64, j: usize| (at * scale + dark_e).max(0.0) + rn2 + quant[j];

    (out.width, out.height) = (w, h);
    out.rate.resize(w * h, 0.0);
    out.variance.resize(w * h, 0.0);
    out.used.resize(w * h, 0);
    let MergedFrame { rate, variance, used, .. } = out;
    if n == 2 {
        // The usual bracket, without branches (see `merge_pair_row`).
        let c = PairConstants {
            exposure: [order[0].meta.exposure_s, order[1].meta.exposure_s],
            k: [ks[0], ks[1]],
            inv_k_exposure: [inv_k_exposure[0], inv_k_exposure[1]],
            quant: [quant[0], quant[1]],
            white: [white[0], white[1]],
            black0: black[0],
            limit: [limits[0], limits[1]],
            inv_band1: inv_band[1],
            rn2,
        };
        let rows: Vec<Result<(), HdrError>> = rate
            .par_chunks_mut(w.max(1))
            .zip(variance.par_chunks_mut(w.max(1)))
            .zip(used.par_chunks_mut(w.max(1)))
            .enumerate()
            .map(|(y, ((r_row, v_row), u_row))| {
                merge_pair_row(&c, [order[0], order[1]], calibration, y, r_row, v_row, u_row)
            })
            .collect();
        rows.into_iter().collect::<Result<Vec<()>, HdrError>>()?;
        return Ok(());
    }
    let rows: Vec<Result<(), HdrError>> = rate
        .par_chunks_mut(w.max(1))
        .zip(variance.par_chunks_mut(w.max(1)))
        .zip(used.par_chunks_mut(w.max(1)))
        .enumerate()
        .map(|(y, ((r_row, v_row), u_row))| {
            // Samples of one photosite: rate, scale, dark electrons, alpha (stack, <= 64).
            let mut sr = [0.0f64; 64];
            let mut ss = [0.0f64; 64];
            let mut sd = [0.0f64; 64];
            let mut sa = [0.0f64; 64];
            // Weighted mean and variance of the first `m` samples, variances at `at`; for two
            // samples (the usual bracket) one division gives both inverse variances.
            let weighted = |m: usize, at: f64, sr: &[f64; 64], ss: &[f64; 64], sd: &[f64; 64], sa: &[f64; 64]| {
                let at = at.max(0.0);
                let (mut sw, mut swr, mut sav) = (0.0, 0.0, 0.0);
                let mut add = |i: usize, inv_v: f64| {
                    let wi = sa[i] * ss[i] * ss[i] * inv_v;
                    sw += wi;
                    swr += wi * sr[i];
                    // w² var_i = α² s⁴ / V² · V / s² = α · w.
                    sav += sa[i] * wi;
                };
                if m == 2 {
                    let (v0, v1) = (var_e2(at, ss[0], sd[0], 0), var_e2(at, ss[1], sd[1], 1));
                    let inv = 1.0 / (v0 * v1);
                    add(0, v1 * inv);
                    add(1, v0 * inv);
                } else {
                    for i in 0..m {
                        add(i, 1.0 / var_e2(at, ss[i], sd[i], i));
                    }
                }
                let inv_sw = 1.0 / sw;
                (swr * inv_sw, sav * inv_sw * inv_sw)
            };
            for x in 0..w {
                let flat = calibration.flat(x, y);
                if !(flat.is_finite() && flat > 0.0) {
                    return Err(HdrError::OutOfRange {
                        what: format!("flat({x}, {y})"),
                        value: flat,
                        allowed: "finite and > 0",
                    });
                }
                let i = y * w + x;
                let inv_flat = 1.0 / flat;
                let mut m = 0usize;
                let mut estimate = 0.0f64;
                for j in 0..n {
                    let f = order[j];
                    let dn = f64::from(f.data[i]);
                    if dn >= white[j] {
                        // Clipped; longer exposures are brighter still.
                        break;
                    }
                    let dark_e = calibration.dark_electrons(x, y, &f.meta);
                    let scale = f.meta.exposure_s * flat;
                    let k = ks[j];
                    let alpha = if m == 0 {
                        if dn - black[j] > limits[j] {
                            0.0
                        } else {
                            1.0
                        }
                    } else {
                        // Predicted signal (DN above black) from the shorter exposures; the
                        // share fades over the band below the limit (module docs).
                        let p = (estimate * scale + dark_e) * k;
                        let fade = ((limits[j] - p) * inv_band[j]).clamp(0.0, 1.0);
                        if fade >= 1.0 {
                            1.0
                        } else if fade <= 0.0 {
                            0.0
                        } else {
                            let at = estimate.max(0.0);
                            let own = scale * scale / var_e2(at, scale, dark_e, j);
                            let shorter: f64 =
                                (0..m).map(|q| sa[q] * ss[q] * ss[q] / var_e2(at, ss[q], sd[q], q)).sum();
                            let rho = own / shorter;
                            fade / (1.0 + rho * (1.0 - fade))
                        }
                    };
                    if alpha == 0.0 {
                        break;
                    }
                    let dark_dn = calibration.dark_dn(x, y, &f.meta);
                    sr[m] = (dn - dark_dn) * inv_k_exposure[j] * inv_flat;
                    ss[m] = scale;
                    sd[m] = dark_e;
                    sa[m] = alpha;
                    m += 1;
                    estimate = if m == 1 { sr[0] } else { weighted(m, sr[m - 1], &sr, &ss, &sd, &sa).0 };
                }
                if m == 0 {
                    // Saturated even in the shortest exposure: its clipped value, flagged.
                    let f = order[0];
                    let k = ks[0];
                    let scale = f.meta.exposure_s * flat;
                    let r = (f64::from(f.data[i]) - calibration.dark_dn(x, y, &f.meta)) / (k * scale);
                    r_row[x] = r as f32;
                    let e = r * scale + calibration.dark_electrons(x, y, &f.meta);
                    v_row[x] = (noise.variance_e2(e, k) / (scale * scale)) as f32;
                    u_row[x] = 0;
                    continue;
                }
                // Second pass: weights at the merged estimate rather than the running one.
                let (r, var) = weighted(m, estimate, &sr, &ss, &sd, &sa);
                r_row[x] = r as f32;
                v_row[x] = var as f32;
                u_row[x] = m as u8;
            }
            Ok(())
        })
        .collect();
    rows.into_iter().collect::<Result<Vec<()>, HdrError>>()?;
    Ok(())
}

/// Per-frame constants of a two-frame merge (frame 0 the shorter signal scale).
struct PairConstants {
    exposure: [f64; 2],
    k: [f64; 2],
    inv_k_exposure: [f64; 2],
    quant: [f64; 2],
    white: [f64; 2],
    black0: f64,
    limit: [f64; 2],
    inv_band1: f64,
    rn2: f64,
}

/// One row of a two-frame merge, every photosite through the same arithmetic (no branches,
/// so photosites overlap in the pipeline): the usable-sample count `m` only selects. With
/// `m = 1` the long sample's fade share is set to 0, which reduces the two-sample formulas to
/// the one-sample ones exactly; the fade share `α = f / (1 + ρ (1 - f))` with
/// `ρ = s₁² V₀ / (s₀² V₁)` is written with one division, `f s₀² V₁ / (s₀² V₁ + s₁² V₀ (1 - f))`.
#[allow(clippy::too_many_arguments)]
fn merge_pair_row(
    c: &PairConstants,
    frames: [&RawFrame; 2],
    calibration: &impl PhotositeCalibration,
    y: usize,
    r_row: &mut [f32],
    v_row: &mut [f32],
    u_row: &mut [u8],
) -> Result<(), HdrError> {
    let w = r_row.len();
    let (d0, d1) = (&frames[0].data[y * w..(y + 1) * w], &frames[1].data[y * w..(y + 1) * w]);
    let (m0, m1) = (&frames[0].meta, &frames[1].meta);
    let var_e2 = |at: f64, scale: f64, dark_e: f64, j: usize| (at * scale + dark_e).max(0.0) + c.rn2 + c.quant[j];
    for x in 0..w {
        let flat = calibration.flat(x, y);
        if !(flat.is_finite() && flat > 0.0) {
            return Err(HdrError::OutOfRange {
                what: format!("flat({x}, {y})"),
                value: flat,
                allowed: "finite and > 0",
            });
        }
        let inv_flat = 1.0 / flat;
        let (dn0, dn1) = (f64::from(d0[x]), f64::from(d1[x]));
        let (de0, de1) = (calibration.dark_electrons(x, y, m0), calibration.dark_electrons(x, y, m1));
        let (dd0, dd1) = (calibration.dark_dn(x, y, m0), calibration.dark_dn(x, y, m1));
        let (s0, s1) = (c.exposure[0] * flat, c.exposure[1] * flat);
        let r0 = (dn0 - dd0) * c.inv_k_exposure[0] * inv_flat;
        let r1 = (dn1 - dd1) * c.inv_k_exposure[1] * inv_flat;
        let usable0 = dn0 < c.white[0] && dn0 - c.black0 <= c.limit[0];
        // The long sample's share, judged from the short one (module docs).
        let at = r0.max(0.0);
        let p = (r0 * s1 + de1) * c.k[1];
        let fade = ((c.limit[1] - p) * c.inv_band1).clamp(0.0, 1.0);
        let a = s0 * s0 * var_e2(at, s1, de1, 1);
        let b = s1 * s1 * var_e2(at, s0, de0, 0);
        let alpha = fade * a / (a + b * (1.0 - fade));
        let use1 = usable0 && dn1 < c.white[1] && alpha > 0.0;
        let alpha1 = if use1 { alpha } else { 0.0 };
        // Two passes: variances at the long sample's rate, then at the merged estimate. With
        // weights w_i = α_i s_i² / V_i, multiplied through by V₀ V₁: one division per pass.
        let pass = |at: f64| {
            let at = at.max(0.0);
            let (v0, v1) = (var_e2(at, s0, de0, 0), var_e2(at, s1, de1, 1));
            let (u0, u1) = (s0 * s0 * v1, alpha1 * s1 * s1 * v0);
            let inv_d = 1.0 / (u0 + u1);
            ((u0 * r0 + u1 * r1) * inv_d, (u0 + alpha1 * u1) * v0 * v1 * inv_d * inv_d)
        };
        let first = if use1 { pass(r1).0 } else { r0 };
        let (r, var) = pass(first);
        // Saturated even in the short exposure: its clipped value, flagged.
        let clipped_var = var_e2(0.0, 0.0, r0 * s0 + de0, 0) / (s0 * s0);
        (r_row[x], v_row[x], u_row[x]) =
            if usable0 { (r as f32, var as f32, 1 + u8::from(use1)) } else { (r0 as f32, clipped_var as f32, 0) };
    }
    Ok(())
}

/// The checks every merge makes, the frames in order of signal scale (shortest first), their
/// conversion gains `k` (DN/e-) and usable DN above the dark level.
#[allow(clippy::type_complexity)]
fn prepare<'a>(
    frames: &[&'a RawFrame],
    noise: &NoiseModel,
    options: &MergeOptions,
) -> Result<(Vec<&'a RawFrame>, Vec<f64>, Vec<f64>), HdrError> {
    let first = frames.first().ok_or(HdrError::Empty)?;
    let (w, h) = (first.width, first.height);
    let sf = options.saturation_fraction;
    if !(sf > 0.0 && sf <= 1.0) {
        return Err(HdrError::OutOfRange { what: "saturation_fraction".into(), value: sf, allowed: "(0, 1]" });
    }
    check_noise(noise)?;
    if frames.len() > 64 {
        return Err(HdrError::OutOfRange {
            what: "bracket length".into(),
            value: frames.len() as f64,
            allowed: "1 ..= 64 frames",
        });
    }
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
    Ok((order, ks, limits))
}

/// [`merge_bracket`] photosite by photosite as the module documentation writes it: the form
/// the fast merge is tested against, kept callable for `btfrig bench hdr` (before and after
/// in one run).
pub fn merge_bracket_reference(
    frames: &[&RawFrame],
    calibration: &impl PhotositeCalibration,
    noise: &NoiseModel,
    options: &MergeOptions,
) -> Result<MergedFrame, HdrError> {
    let (order, ks, limits) = prepare(frames, noise, options)?;
    let (w, h) = (order[0].width, order[0].height);

    let mut rate = vec![0.0f32; w * h];
    let mut variance = vec![0.0f32; w * h];
    let mut used = vec![0u8; w * h];
    let rows: Vec<Result<(), HdrError>> = rate
        .par_chunks_mut(w.max(1))
        .zip(variance.par_chunks_mut(w.max(1)))
        .zip(used.par_chunks_mut(w.max(1)))
        .enumerate()
        .map(|(y, ((r_row, v_row), u_row))| {
            let mut samples: Vec<Sample> = Vec::with_capacity(order.len());
            for x in 0..w {
                let flat = calibration.flat(x, y);
                if !(flat.is_finite() && flat > 0.0) {
                    // A dead photosite in the flat: an error naming it, never a NaN rate.
                    return Err(HdrError::OutOfRange {
                        what: format!("flat({x}, {y})"),
                        value: flat,
                        allowed: "finite and > 0",
                    });
                }
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
                    // With a prediction, the weight fades out over a band below the limit,
                    // decided from the shorter samples only (see the module docs).
                    let alpha = match (predicted, estimate) {
                        (Some(p), Some(r)) => {
                            let f = ((limits[j] - p) / (FADE * limits[j])).clamp(0.0, 1.0);
                            // rho: this sample's full weight over the shorter ones' at the
                            // estimate; alpha makes its share of the mean fall linearly with f.
                            let var = noise.variance_e2(r.max(0.0) * scale + dark_e, k) / (scale * scale);
                            let rho = (1.0 / var) / weight_sum(&samples, noise, r);
                            f / (1.0 + rho * (1.0 - f))
                        }
                        _ if dn - black > limits[j] => 0.0,
                        _ => 1.0,
                    };
                    if clipped || alpha == 0.0 {
                        // Longer exposures are brighter still.
                        break;
                    }
                    samples.push(Sample { rate: (dn - dark_dn) / (k * scale), scale, dark_e, k, alpha });
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
            Ok(())
        })
        .collect();
    // The first bad photosite in row order, if any.
    rows.into_iter().collect::<Result<Vec<()>, HdrError>>()?;
    Ok(MergedFrame { width: w, height: h, rate, variance, used })
}

/// Share of the usable range below the limit over which a longer exposure's weight fades
/// from full to zero.
const FADE: f64 = 0.25;

/// One usable reading of a photosite.
struct Sample {
    /// Its rate estimate, e-/s.
    rate: f64,
    /// Exposure time times flat.
    scale: f64,
    /// Dark electrons.
    dark_e: f64,
    /// Conversion gain, DN/e-.
    k: f64,
    /// Fade factor of its weight, `(0, 1]`.
    alpha: f64,
}

/// Sum of the weights `alpha / var` of the samples, variances at rate `at`.
fn weight_sum(samples: &[Sample], noise: &NoiseModel, at: f64) -> f64 {
    samples.iter().map(|s| s.alpha * s.scale * s.scale / noise.variance_e2(at.max(0.0) * s.scale + s.dark_e, s.k)).sum()
}

/// Weighted mean of the samples with weights `alpha / var` and its variance; the variances
/// are evaluated at `at` (default: the longest sample's own rate, the least noisy).
fn weighted(samples: &[Sample], noise: &NoiseModel, at: Option<f64>) -> (f64, f64) {
    let at = at.unwrap_or_else(|| samples.last().map_or(0.0, |s| s.rate)).max(0.0);
    let (mut sw, mut swr, mut sw2v) = (0.0, 0.0, 0.0);
    for s in samples {
        let var = noise.variance_e2(at * s.scale + s.dark_e, s.k) / (s.scale * s.scale);
        let w = s.alpha / var;
        sw += w;
        swr += w * s.rate;
        sw2v += w * w * var;
    }
    (swr / sw, sw2v / (sw * sw))
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

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::frame::BayerPattern;

    const NOISE: NoiseModel = NoiseModel { electrons_per_dn: 2.5, read_noise_e: 3.0 };
    const NOMINAL: NominalCalibration = NominalCalibration { dark_current_e_per_s: 0.0, electrons_per_dn: 2.5 };

    /// A noise-free frame of constant `rate` (e-/s): DN = round(rate t k) + 256, clipped at 16251.
    fn frame(rates: &[f64], exposure_s: f64, gain: f64) -> RawFrame {
        let k = gain / 2.5;
        let data = rates.iter().map(|r| ((r * exposure_s * k).round() + 256.0).min(16251.0) as u16).collect();
        RawFrame {
            width: rates.len(),
            height: 1,
            data,
            meta: FrameMeta {
                sequence: 0,
                exposure_s,
                gain,
                f_number: None,
                black_level: 256,
                white_level: 16251,
                bit_depth: 14,
                bayer: Some(BayerPattern::Rggb),
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn noise_free_bracket_recovers_rates_across_the_range() {
        // Rates from 1e2 to 1e8 e-/s; exposures 1 ms, 8 ms, 64 ms: full scale is 40 000 e-.
        let rates: Vec<f64> = (0..61).map(|i| 10f64.powf(2.0 + i as f64 / 10.0)).collect();
        let frames = [frame(&rates, 0.064, 1.0), frame(&rates, 0.001, 1.0), frame(&rates, 0.008, 2.0)];
        let refs: Vec<&RawFrame> = frames.iter().collect();
        let m = merge_bracket(&refs, &NOMINAL, &NOISE, &MergeOptions::default()).unwrap();
        for (i, r) in rates.iter().enumerate() {
            let got = f64::from(m.rate[i]);
            // Saturated even at 1 ms: above 0.95 * 39975 e- / 1 ms = 3.8e7 e-/s.
            if *r * 0.001 > 0.95 * 15995.0 * 2.5 {
                assert_eq!(m.used[i], 0, "rate {r}");
                assert!(got < *r, "clipped value is a lower bound: {got} vs {r}");
                continue;
            }
            assert!(m.used[i] >= 1);
            // Rounding (±0.5 DN) is the only error. Without read noise the weights would be
            // proportional to t, bounding the error by Σ 0.5/k / Σ t over the usable
            // exposures; read noise moves them a little (factor 1.5). In a fade band (the last
            // quarter below a longer exposure's limit) the shorter exposure's rounding counts.
            let exps = [(0.001, 0.4), (0.008, 0.8), (0.064, 0.4)];
            let limit = 0.95 * 15995.0;
            let usable: Vec<&(f64, f64)> = exps.iter().filter(|(t, k)| r * t * k < limit).collect();
            let fading = exps.iter().any(|(t, k)| (0.75 * limit..limit + 1.0).contains(&(r * t * k)));
            let tol = if fading {
                usable.iter().map(|(t, k)| 0.5 / (k * t)).fold(0.0, f64::max)
            } else {
                1.5 * usable.iter().map(|(_, k)| 0.5 / k).sum::<f64>() / usable.iter().map(|(t, _)| t).sum::<f64>()
            } + 1e-6 * r;
            assert!((got - r).abs() <= tol, "rate {r}: got {got}, tolerance {tol}");
        }
        assert_eq!(m.saturated_everywhere(), rates.iter().filter(|r| **r * 0.001 > 0.95 * 39987.5).count());
        // The darkest rates use all three exposures, the brightest usable ones only the shortest.
        assert_eq!(m.used[0], 3);
        assert_eq!(m.used[55], 1, "rate {}", rates[55]);
    }

    #[test]
    fn weights_are_inverse_variance() {
        // Two exposures of a 1e5 e-/s photosite reading 5 % high in the short and exact in the
        // long one: the merge lies where the inverse variances put it.
        let r: f64 = 1e5;
        let (t1, t2) = (0.01, 0.1);
        let mut a = frame(&[r * 1.05], t1, 1.0);
        let b = frame(&[r], t2, 1.0);
        a.data[0] = (r * 1.05 * t1 / 2.5).round() as u16 + 256;
        let m = merge_bracket(&[&a, &b], &NOMINAL, &NOISE, &MergeOptions::default()).unwrap();
        let r1 = (f64::from(a.data[0]) - 256.0) * 2.5 / t1;
        let r2 = (f64::from(b.data[0]) - 256.0) * 2.5 / t2;
        let var = |t: f64| NOISE.variance_e2(f64::from(m.rate[0]) * t, 0.4) / (t * t);
        let (w1, w2) = (1.0 / var(t1), 1.0 / var(t2));
        let expect = (w1 * r1 + w2 * r2) / (w1 + w2);
        assert!((f64::from(m.rate[0]) - expect).abs() < 1e-3 * expect, "{} vs {expect}", m.rate[0]);
        assert!((f64::from(m.variance[0]) * (w1 + w2) - 1.0).abs() < 1e-4);
        // The long exposure dominates: about t2/t1 = 10 times the weight.
        assert!(w2 / w1 > 9.0 && w2 / w1 < 11.0, "{}", w2 / w1);
    }

    struct Flat(Vec<f64>);
    impl PhotositeCalibration for Flat {
        fn dark_dn(&self, _x: usize, _y: usize, meta: &FrameMeta) -> f64 {
            f64::from(meta.black_level) + 4.0
        }
        fn dark_electrons(&self, _x: usize, _y: usize, _meta: &FrameMeta) -> f64 {
            10.0
        }
        fn flat(&self, x: usize, _y: usize) -> f64 {
            self.0[x]
        }
    }

    #[test]
    fn a_measured_dark_level_and_flat_plug_in() {
        // Photosites of sensitivity 0.8 and 1.25 with a dark offset of 4 DN (10 e-).
        let flat = Flat(vec![0.8, 1.25]);
        let truth = [2e5, 2e5];
        let seen: Vec<f64> = truth.iter().zip(&flat.0).map(|(r, f)| r * f).collect();
        let mut f = frame(&seen, 0.1, 1.0);
        for d in &mut f.data {
            *d += 4;
        }
        let m = merge_bracket(&[&f], &flat, &NOISE, &MergeOptions::default()).unwrap();
        for (got, want) in m.rate.iter().zip(truth) {
            assert!((f64::from(*got) / want - 1.0).abs() < 1e-3, "{got} vs {want}");
        }
    }

    #[test]
    fn extreme_readings_stay_finite() {
        // Below black (read noise on a dark photosite), exactly black, clipped at the ADC:
        // finite rates and variances, never NaN, with or without read noise.
        let mut f = frame(&[0.0, 0.0, 1e12], 0.01, 1.0);
        f.data[0] = 0;
        for noise in [NOISE, NoiseModel { electrons_per_dn: 2.5, read_noise_e: 0.0 }] {
            let m = merge_bracket(&[&f, &frame(&[0.0, 0.0, 1e12], 0.1, 8.0)], &NOMINAL, &noise, &Default::default())
                .unwrap();
            assert!(m.rate.iter().chain(&m.variance).all(|v| v.is_finite()), "{m:?}");
            assert!(m.rate[0] < 0.0 && m.rate[1] == 0.0 && m.used[2] == 0);
        }
    }

    #[test]
    fn bad_inputs_are_named_errors() {
        let opts = MergeOptions::default();
        assert_eq!(merge_bracket(&[], &NOMINAL, &NOISE, &opts), Err(HdrError::Empty));
        let a = frame(&[1.0, 2.0], 0.1, 1.0);
        let b = frame(&[1.0], 0.1, 1.0);
        let e = merge_bracket(&[&a, &b], &NOMINAL, &NOISE, &opts).unwrap_err().to_string();
        assert!(e.contains("frame 1 is 1x1"), "{e}");
        let mut c = frame(&[1.0, 2.0], 0.1, 1.0);
        c.meta.exposure_s = 0.0;
        let e = merge_bracket(&[&a, &c], &NOMINAL, &NOISE, &opts).unwrap_err().to_string();
        assert!(e.contains("frame 1 exposure_s = 0"), "{e}");
        let e = merge_bracket(&[&a], &NOMINAL, &NOISE, &MergeOptions { saturation_fraction: 1.5 }).unwrap_err();
        assert!(e.to_string().contains("saturation_fraction = 1.5"), "{e}");
        let dead = Flat(vec![1.0, 0.0]);
        let e = merge_bracket(&[&a], &dead, &NOISE, &opts).unwrap_err().to_string();
        assert!(e.contains("flat(1, 0) = 0"), "{e}");
        let bad = NoiseModel { electrons_per_dn: f64::NAN, read_noise_e: 1.0 };
        assert!(merge_bracket(&[&a], &NOMINAL, &bad, &opts).unwrap_err().to_string().contains("electrons_per_dn"));
    }

    /// A per-photosite flat and dark level that vary (as a measured calibration does).
    struct Varying {
        flat: Vec<f64>,
        dark: Vec<f64>,
        width: usize,
    }
    impl PhotositeCalibration for Varying {
        fn dark_dn(&self, x: usize, y: usize, meta: &FrameMeta) -> f64 {
            f64::from(meta.black_level) + self.dark[y * self.width + x] * meta.exposure_s * meta.gain / 2.5
        }
        fn dark_electrons(&self, x: usize, y: usize, meta: &FrameMeta) -> f64 {
            self.dark[y * self.width + x] * meta.exposure_s
        }
        fn flat(&self, x: usize, y: usize) -> f64 {
            self.flat[y * self.width + x]
        }
    }

    #[test]
    fn the_fast_merge_agrees_with_the_reference() {
        // Seeded noisy brackets over 7 decades of rate (below black, in every fade band,
        // clipped), 1 to 3 exposures, nominal and varying calibrations: the same photosites
        // used, rates and variances within 2 ulps of f32 (the f64 arithmetic is rearranged,
        // not changed).
        let (w, h) = (97, 41);
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let rates: Vec<f64> = (0..w * h).map(|_| 10f64.powf(1.0 + 7.0 * rnd())).collect();
        let cal = Varying {
            flat: (0..w * h).map(|_| 0.7 + 0.6 * rnd()).collect(),
            dark: (0..w * h).map(|_| 50.0 * rnd()).collect(),
            width: w,
        };
        let mut noisy = |t: f64, g: f64| {
            let mut f = frame(&rates, t, g);
            f.width = w;
            f.height = h;
            for (i, d) in f.data.iter_mut().enumerate() {
                let v = f64::from(*d) * cal.flat[i] + 8.0 * (rnd() - 0.5);
                *d = v.round().clamp(0.0, 16251.0) as u16;
            }
            f
        };
        let frames = [noisy(0.001, 1.0), noisy(0.008, 1.0), noisy(0.03, 2.0)];
        let close = |a: f32, b: f32| a == b || (a - b).abs() <= 2.0 * f32::EPSILON * a.abs().max(b.abs());
        for set in [vec![0usize], vec![1, 0], vec![0, 2], vec![2, 1, 0]] {
            let refs: Vec<&RawFrame> = set.iter().map(|&k| &frames[k]).collect();
            for noise in [NOISE, NoiseModel { electrons_per_dn: 2.5, read_noise_e: 0.0 }] {
                let fast = merge_bracket(&refs, &cal, &noise, &MergeOptions::default()).unwrap();
                let slow = merge_bracket_reference(&refs, &cal, &noise, &MergeOptions::default()).unwrap();
                assert_eq!(fast.used, slow.used, "frames {set:?}");
                for i in 0..w * h {
                    assert!(
                        close(fast.rate[i], slow.rate[i]),
                        "{set:?} rate {i}: {} vs {}",
                        fast.rate[i],
                        slow.rate[i]
                    );
                    assert!(
                        close(fast.variance[i], slow.variance[i]),
                        "{set:?} var {i}: {} vs {}",
                        fast.variance[i],
                        slow.variance[i]
                    );
                }
                let nominal = merge_bracket(&refs, &NOMINAL, &noise, &MergeOptions::default()).unwrap();
                let nominal_ref = merge_bracket_reference(&refs, &NOMINAL, &noise, &MergeOptions::default()).unwrap();
                assert_eq!(nominal.used, nominal_ref.used);
                assert!(nominal.rate.iter().zip(&nominal_ref.rate).all(|(a, b)| close(*a, *b)));
            }
        }
    }
}
