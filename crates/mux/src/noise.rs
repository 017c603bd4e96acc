//! Noise theory of multiplexed illumination and the choice of capture mode.
//!
//! Model (Schechner, Nayar, Belhumeur 2003/2007; Ratner, Schechner 2007), per pixel: `n`
//! sources, frames `m = W i + ν`, per-frame noise variance `σ²(C) = κ² + C σ_p²` with `κ²` the
//! signal-independent (read, dark-shot, quantisation) variance, `σ_p²` the photon variance of
//! one source's contribution and `C` the sources lit in the frame. Demultiplexing
//! `î = W⁻¹ m` has per-source MSE `σ²(C)/n · tr[(WᵀW)⁻¹]`; single-source capture (`W = I`) has
//! `κ² + σ_p²`. The SNR gain is `G = √(MSE_single / MSE_mux)`. With `ρ = σ_p²/κ²`:
//!
//! ```text
//! S-matrix (C = (n+1)/2):   G_S = (n+1)/(2√n) · √[(1 + ρ) / (1 + (n+1)/2 · ρ)]
//! break-even:               G_S > 1  ⇔  ρ < (n−1)/(n+1)
//! C-lit design bound:       MSE ≥ σ²(C)/n · [1/C² + (n−1)²/(C (n−C))]   (equality: BIBD)
//! best C:                   C* = (√(1 + n ρ) − 1) / ρ      (→ n/2 as ρ → 0, κ√n/σ_p as ρ → ∞)
//! saturation:               exposure cut by r = t_sat/t  ⇒  G_eff ≈ r G (read-noise limit)
//! ```
//!
//! [`predict`] evaluates these for a concrete sensor (read noise, conversion gain, full well,
//! dark current) and scene (source `j`'s signal rate at a pixel = LED power × its irradiance
//! factor `g_j` × sample brightness, `g_j = cos θ_j · (d/r_j)²` for a light at polar angle `θ_j`
//! and distance `r_j` from the sample, `d` the distance its power is calibrated at) at **equal
//! total capture time**: every mode spends the time single-light
//! capture of all sources would, split over its own frames, each exposure capped by the
//! full well. The modes are single light, one S-matrix over all sources (padded to an
//! available order), and S-matrices within groups of `m` sources (fewer lit per frame, the
//! practical codes with `C < (n+1)/2`). Sources differ in `g_j` (a dome's zenith LED lights
//! the sample about twice as strongly as one at 60°), so the prediction is made per source:
//! source `j`'s demultiplexed noise comes from the frames of its own code, whose mean photon
//! variance is `C/m · Σ g_i` over that code's `m` sources (not `C` times the on-axis level),
//! its single-light noise from its own signal, and the gain is the mean of the per-source
//! gains (what a measurement over reference sources spread over the dome averages).
//! [`choose`] takes the best and says why, e.g.
//! `"multiplexing skipped: photon-noise dominated (σ_p²/κ² = 12.3), best predicted gain 0.93"`.

use crate::error::MuxError;
use crate::smatrix::{available_orders, SMatrix};

/// `G_S` of an S-matrix of order `n` with photon-to-read variance ratio `ρ = σ_p²/κ²`.
pub fn s_matrix_gain(n: usize, rho: f64) -> f64 {
    let nf = n as f64;
    (nf + 1.0) / (2.0 * nf.sqrt()) * ((1.0 + rho) / (1.0 + (nf + 1.0) / 2.0 * rho)).sqrt()
}

/// `tr[(WᵀW)⁻¹]/n` of a `C`-lit balanced design on `n` sources (the bound, reached by
/// BIBDs; exact for S-matrices and for `C = 1`): `[1/C² + (n−1)²/(C(n−C))]/n`.
pub fn design_factor(n: usize, c: f64) -> f64 {
    let nf = n as f64;
    if n == 1 {
        return 1.0 / (c * c);
    }
    (1.0 / (c * c) + (nf - 1.0) * (nf - 1.0) / (c * (nf - c))) / nf
}

/// Gain of the `C`-lit design bound over single capture at ratio `ρ`.
pub fn lit_gain(n: usize, c: f64, rho: f64) -> f64 {
    ((1.0 + rho) / ((1.0 + c * rho) * design_factor(n, c))).sqrt()
}

/// The `C` minimising the design bound (small `1/C²` term ignored):
/// `C* = (√(1 + n ρ) − 1)/ρ`, `n/2` at `ρ = 0`.
pub fn optimal_lit(n: usize, rho: f64) -> f64 {
    let nf = n as f64;
    if rho <= 1e-12 {
        return nf / 2.0;
    }
    ((1.0 + nf * rho).sqrt() - 1.0) / rho
}

/// The photon-to-read variance ratio below which an S-matrix of order `n` gains:
/// `(n−1)/(n+1)`.
pub fn break_even_ratio(n: usize) -> f64 {
    (n as f64 - 1.0) / (n as f64 + 1.0)
}

/// The sensor as the noise prediction sees it (electrons; the same model as
/// `btfrig-render`'s sensor: Poisson shot noise, Gaussian read noise, quantisation, full well).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorNoise {
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
    /// Conversion gain, DN per electron (quantisation adds `1/(12 k²)` e²).
    pub dn_per_e: f64,
    /// Full-well capacity, electrons.
    pub full_well_e: f64,
    /// Dark current, e-/s (its shot noise is signal-independent).
    pub dark_current_e_per_s: f64,
}

impl SensorNoise {
    /// Signal-independent variance of one frame of exposure `t`, e².
    pub fn kappa2(&self, t: f64) -> f64 {
        self.read_noise_e * self.read_noise_e + self.dark_current_e_per_s * t + 1.0 / (12.0 * self.dn_per_e.powi(2))
    }
}

/// What one pixel receives.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneLight {
    /// Per source (LED), in capture order, the irradiance it gives the sample relative to a
    /// light of the same power facing the sample at the calibration distance: `cos θ · (d/r)²`
    /// (module docs). Its length is the number of sources.
    pub irradiance: Vec<f64>,
    /// Electrons per second one LED facing the sample at the calibration distance puts into a
    /// pixel of a white (albedo 1) Lambertian sample.
    pub led_e_per_s: f64,
    /// Typical sample brightness relative to a white Lambertian sample lit by the same source
    /// (sets the SNR that is compared).
    pub brightness: f64,
    /// Brightest single-LED brightness in the region, on the same scale (sets saturation),
    /// `>= brightness`.
    pub brightness_max: f64,
    /// Exposure single-light capture would use per frame, s (the time budget is
    /// `sources × exposure_s`).
    pub exposure_s: f64,
    /// Fraction of the full well a frame may fill.
    pub well_fraction: f64,
}

/// A capture mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// One source per frame.
    Single,
    /// One S-matrix over all sources (the order may exceed the sources: always-off slots).
    SMatrix {
        /// The order.
        order: usize,
    },
    /// Sources split into groups, each multiplexed by an S-matrix of order `order`.
    Grouped {
        /// Order of each group's S-matrix.
        order: usize,
        /// Number of groups.
        groups: usize,
    },
}

impl Mode {
    /// Short description, e.g. `s-matrix 199`, `groups 7 x 31`.
    pub fn describe(&self) -> String {
        match self {
            Mode::Single => "single-light".into(),
            Mode::SMatrix { order } => format!("s-matrix {order}"),
            Mode::Grouped { order, groups } => format!("groups {groups} x {order}"),
        }
    }
}

/// The prediction for one mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    /// The mode.
    pub mode: Mode,
    /// Frames captured.
    pub frames: usize,
    /// Physical sources lit per frame (mean).
    pub lit: f64,
    /// Exposure per frame, s.
    pub exposure_s: f64,
    /// Exposure cut by saturation: `exposure / (time budget / frames)`, 1 if none.
    pub saturation_factor: f64,
    /// Photon-to-signal-independent variance ratio `ρ = σ_p²/κ²` at this exposure.
    pub rho: f64,
    /// SNR of a demultiplexed (or single) image at the typical brightness.
    pub snr: f64,
    /// `snr` over the single-light SNR.
    pub gain: f64,
}

/// The chosen mode with the reason.
#[derive(Debug, Clone, PartialEq)]
pub struct Choice {
    /// The winner.
    pub best: Prediction,
    /// Its gain over single light.
    pub predicted_gain: f64,
    /// Why, in one sentence.
    pub reason: String,
    /// Every mode evaluated, single light first.
    pub candidates: Vec<Prediction>,
}

/// Tuning of [`choose`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChooseParams {
    /// Multiplexing must beat single light by this factor to be chosen (default 1.05:
    /// calibration and fault risk are not free).
    pub min_gain: f64,
    /// Smallest group order tried (default 3).
    pub min_group_order: usize,
}

impl Default for ChooseParams {
    fn default() -> Self {
        ChooseParams { min_gain: 1.05, min_group_order: 3 }
    }
}

fn check(what: &'static str, v: f64, ok: bool, allowed: &'static str) -> Result<(), MuxError> {
    if ok && v.is_finite() {
        Ok(())
    } else {
        Err(MuxError::OutOfRange { what, value: v, allowed })
    }
}

fn validate(sensor: &SensorNoise, scene: &SceneLight) -> Result<(), MuxError> {
    check("read_noise_e", sensor.read_noise_e, sensor.read_noise_e >= 0.0, ">= 0")?;
    check("dn_per_e", sensor.dn_per_e, sensor.dn_per_e > 0.0, "> 0")?;
    check("full_well_e", sensor.full_well_e, sensor.full_well_e > 0.0, "> 0")?;
    check("dark_current_e_per_s", sensor.dark_current_e_per_s, sensor.dark_current_e_per_s >= 0.0, ">= 0")?;
    check("sources", scene.irradiance.len() as f64, !scene.irradiance.is_empty(), ">= 1")?;
    for &g in &scene.irradiance {
        // A light at or below the sample's horizon does not light it.
        check("irradiance", g, g > 0.0, "> 0 for every source (a light above the sample's horizon)")?;
    }
    check("led_e_per_s", scene.led_e_per_s, scene.led_e_per_s > 0.0, "> 0")?;
    check("brightness", scene.brightness, scene.brightness > 0.0, "> 0")?;
    check("brightness_max", scene.brightness_max, scene.brightness_max >= scene.brightness, ">= brightness")?;
    check("exposure_s", scene.exposure_s, scene.exposure_s > 0.0, "> 0")?;
    check("well_fraction", scene.well_fraction, scene.well_fraction > 0.0 && scene.well_fraction <= 1.0, "(0, 1]")?;
    Ok(())
}

/// Evaluates a mode: frames, lit sources, saturation-capped exposure, SNR and gain over
/// single light at the same total time.
pub fn predict(sensor: &SensorNoise, scene: &SceneLight, mode: Mode) -> Result<Prediction, MuxError> {
    validate(sensor, scene)?;
    let g = &scene.irradiance;
    let n = g.len();
    let budget = n as f64 * scene.exposure_s;
    // (frames, sources per code, lit per frame of a code, design MSE factor tr[(WᵀW)⁻¹]/n).
    let (frames, code, half, factor) = match mode {
        Mode::Single => (n, 1, 1.0, 1.0),
        Mode::SMatrix { order } => {
            if order < n {
                return Err(MuxError::OutOfRange {
                    what: "s-matrix order",
                    value: order as f64,
                    allowed: ">= the number of sources",
                });
            }
            let half = order.div_ceil(2) as f64;
            (order, order, half, design_factor(order, half))
        }
        Mode::Grouped { order, groups } => {
            if order * groups < n || order < 1 {
                return Err(MuxError::OutOfRange {
                    what: "groups x order",
                    value: (order * groups) as f64,
                    allowed: ">= the number of sources",
                });
            }
            let half = order.div_ceil(2) as f64;
            (order * groups, order, half, design_factor(order, half))
        }
    };
    let lit = half * n as f64 / frames as f64;
    let t_share = budget / frames as f64;
    // Saturation: the fullest frame lights at most `half` sources of one code, each at most at
    // the brightest level: bounded by the `half` largest irradiances of a code.
    let fullest = g.chunks(code).map(|c| top_sum(c, half as usize)).fold(0.0, f64::max);
    let t_sat = saturation_exposure(sensor, scene, fullest);
    let t = t_share.min(t_sat);
    let kappa2 = sensor.kappa2(t);
    let q = scene.led_e_per_s * scene.brightness * t;
    let (t_single, k_single) = single_exposure(sensor, scene);
    let q_single = scene.led_e_per_s * scene.brightness * t_single;
    let (mut snr_sum, mut gain_sum) = (0.0, 0.0);
    for c in g.chunks(code) {
        // A code's frames light each of its sources in `half` of its `code` frames.
        let photons = half / code as f64 * c.iter().sum::<f64>() * q;
        let mse = (kappa2 + photons) * factor;
        for &gj in c {
            let snr = gj * q / mse.sqrt();
            let single = gj * q_single / (k_single + gj * q_single).sqrt();
            snr_sum += snr;
            gain_sum += snr / single;
        }
    }
    let mean_g = g.iter().sum::<f64>() / n as f64;
    Ok(Prediction {
        mode,
        frames,
        lit,
        exposure_s: t,
        saturation_factor: t / t_share,
        rho: mean_g * q / kappa2,
        snr: snr_sum / n as f64,
        gain: gain_sum / n as f64,
    })
}

/// The sum of the `k` largest of `g`.
fn top_sum(g: &[f64], k: usize) -> f64 {
    let mut v = g.to_vec();
    v.sort_by(|a, b| b.total_cmp(a));
    v.iter().take(k).sum()
}

/// The longest exposure whose frame, lit with irradiance `fullest` (summed over its sources)
/// at the brightest level, fills no more than `well_fraction` of the well.
fn saturation_exposure(sensor: &SensorNoise, scene: &SceneLight, fullest: f64) -> f64 {
    let peak = scene.led_e_per_s * scene.brightness_max * fullest;
    scene.well_fraction * sensor.full_well_e / (peak + sensor.dark_current_e_per_s)
}

/// Single-light capture's exposure (capped by its brightest source) and signal-independent
/// variance.
fn single_exposure(sensor: &SensorNoise, scene: &SceneLight) -> (f64, f64) {
    let brightest = scene.irradiance.iter().copied().fold(0.0, f64::max);
    let t = scene.exposure_s.min(saturation_exposure(sensor, scene, brightest));
    (t, sensor.kappa2(t))
}

/// Evaluates single light, the full S-matrix and every grouped S-matrix, and picks the best
/// (single light unless a multiplexed mode beats it by `params.min_gain`).
pub fn choose(sensor: &SensorNoise, scene: &SceneLight, params: &ChooseParams) -> Result<Choice, MuxError> {
    validate(sensor, scene)?;
    let n = scene.irradiance.len();
    let mut candidates = vec![predict(sensor, scene, Mode::Single)?];
    if n >= 2 {
        if let Ok(p) = SMatrix::for_sources(n) {
            candidates.push(predict(sensor, scene, Mode::SMatrix { order: p.s.order() })?);
        }
        for m in available_orders(n.saturating_sub(1)) {
            if m >= params.min_group_order.max(2) {
                let groups = n.div_ceil(m);
                if groups >= 2 {
                    candidates.push(predict(sensor, scene, Mode::Grouped { order: m, groups })?);
                }
            }
        }
    }
    let single = candidates[0];
    let best_mux =
        candidates.iter().skip(1).copied().max_by(|a, b| a.gain.total_cmp(&b.gain)).filter(|p| p.gain.is_finite());
    let (best, reason) = match best_mux {
        Some(b) if b.gain >= params.min_gain => {
            let why = if b.saturation_factor < 0.999 {
                format!(", exposure cut to {:.0}% by saturation", 100.0 * b.saturation_factor)
            } else {
                String::new()
            };
            (
                b,
                format!(
                    "multiplexing with {}: predicted gain {:.2} (σ_p²/κ² = {:.3}, {:.1} sources lit per frame{why})",
                    b.mode.describe(),
                    b.gain,
                    b.rho,
                    b.lit
                ),
            )
        }
        Some(b) => {
            let cause = if b.saturation_factor < 0.5 {
                format!("saturation-limited (exposure cut to {:.0}%)", 100.0 * b.saturation_factor)
            } else if single.rho > 1.0 {
                format!("photon-noise dominated (σ_p²/κ² = {:.2})", single.rho)
            } else {
                format!("gain below the {:.2} threshold", params.min_gain)
            };
            (
                single,
                format!("multiplexing skipped: {cause}, best predicted gain {:.2} ({})", b.gain, b.mode.describe()),
            )
        }
        None => (single, "multiplexing skipped: a single source".into()),
    };
    Ok(Choice { predicted_gain: best.gain, best, reason, candidates })
}
