//! The raw image sensor: photo-electron rates in, a noisy, quantised [`RawFrame`] out.
//!
//! Per photosite at column `x`, row `y` with colour channel `c` (from the Bayer pattern; a
//! monochrome sensor uses channel 1, green) and exposure `t`:
//!
//! ```text
//! λ  = rate_c(x, y) · prnu(x, y) · t + dark(x, y) · t            mean electrons
//! n  = min(Poisson(λ), full_well)                                 shot noise, saturation
//! v  = n + N(0, read_noise²)                                      read noise, electrons
//! DN = clamp(round(v · gain / electrons_per_dn + col(x)) + black_level, 0, white_level)
//! white_level = min(2^bits - 1, black_level + floor((full_well - 4 read_noise) · gain / electrons_per_dn))
//! ```
//!
//! Poisson sampling is exact for `λ < 10` (inversion) and `10 <= λ < 1000` (Hörmann's PTRS
//! transformed rejection); above 1000 it is the Gaussian `λ + sqrt(λ) z`, whose mean and
//! variance are exact and whose skewness (`1/sqrt(λ) < 0.032`) is the only thing lost.
//! Where shot noise is Gaussian and the well is more than 5 sigma away, shot and read noise are
//! drawn as one Gaussian of summed variance (identical distribution, one draw instead of two).
//! `prnu(x, y) = max(0, 1 + prnu_rms · z)` is a fixed pattern hashed from the config's
//! `fixed_pattern_seed` and the photosite position ([`SensorModel::prnu_gain`]), the same in
//! every frame. So are the dark current `dark(x, y)` ([`SensorModel::dark_current_at`]:
//! `dark_current · max(0, 1 + dsnu_rms · z)`, or for the `hot_pixel_fraction` of hot
//! photosites `hot_pixel_dark_e_per_s · 10^u`, u uniform in [0, 1)) and the column offset
//! `col(x) = column_offset_rms_dn · z` ([`SensorModel::column_offset_dn`]), hashed with other
//! salts from the same seed.
//!
//! Determinism: rows are processed in parallel (rayon), each with its own ChaCha8 stream
//! derived from `(seed, row)`, so a frame is bit-identical for a given seed whatever the
//! number of threads. Units and reasons for the defaults: `docs/sensor-model.md`.

use btfrig_core::config::camera::CameraConfig;
use btfrig_core::config::lamp::LampConfig;
use btfrig_core::config::sensor::SensorConfig;
use btfrig_core::frame::{BayerPattern, FrameMeta, RawFrame};
use btfrig_core::ConfigError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;

pub use crate::radiance::RadianceImage;

/// Errors of the sensor model: a bad configuration or capture setting.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SensorError {
    /// The `[sensor]` section is invalid.
    #[error("invalid sensor config: {0}")]
    Config(#[from] ConfigError),
    /// A capture setting is out of range.
    #[error("{what} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// The setting.
        what: &'static str,
        /// The offending value.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// The input image has the wrong number of pixels.
    #[error("radiance image {width}x{height} holds {len} pixels, expected {}", width * height)]
    SizeMismatch {
        /// Declared width.
        width: usize,
        /// Declared height.
        height: usize,
        /// Length of the data.
        len: usize,
    },
    /// A rate is negative or not a number (a renderer bug, never silently clipped).
    #[error("radiance image pixel ({x}, {y}) channel {channel} has rate {value}: must be finite and >= 0")]
    BadRate {
        /// Column.
        x: usize,
        /// Row.
        y: usize,
        /// Channel.
        channel: usize,
        /// The value.
        value: f32,
    },
}

/// The sensor described by a `[sensor]` config section.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorModel {
    /// Colour filter array, `None` for monochrome.
    pub bayer: Option<BayerPattern>,
    /// ADC bits.
    pub bit_depth: u8,
    /// Electrons per DN at analogue gain 1.
    pub electrons_per_dn: f64,
    /// Largest analogue gain.
    pub max_analogue_gain: f64,
    /// Full-well capacity, electrons.
    pub full_well_e: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
    /// Black level, DN.
    pub black_level_dn: u16,
    /// Dark current, e-/s.
    pub dark_current_e_per_s: f64,
    /// Relative RMS of the fixed PRNU pattern.
    pub prnu_rms: f64,
    /// Seed of the PRNU pattern.
    pub fixed_pattern_seed: u64,
    /// Relative RMS of the per-photosite dark-current multiplier.
    pub dsnu_rms: f64,
    /// Fraction of hot photosites.
    pub hot_pixel_fraction: f64,
    /// Smallest dark current of a hot photosite, e-/s.
    pub hot_pixel_dark_e_per_s: f64,
    /// RMS of the per-column black-level offset, DN.
    pub column_offset_rms_dn: f64,
}

impl SensorModel {
    /// Builds the sensor of a validated `[sensor]` section.
    pub fn from_config(cfg: &SensorConfig) -> Result<Self, SensorError> {
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        ConfigError::from_list(errors)?;
        Ok(SensorModel {
            bayer: cfg.cfa.bayer(),
            bit_depth: cfg.bit_depth,
            electrons_per_dn: cfg.electrons_per_dn,
            max_analogue_gain: cfg.max_analogue_gain,
            full_well_e: cfg.full_well_e,
            read_noise_e: cfg.read_noise_e,
            black_level_dn: cfg.black_level_dn,
            dark_current_e_per_s: cfg.dark_current_e_per_s,
            prnu_rms: cfg.prnu_rms,
            fixed_pattern_seed: cfg.fixed_pattern_seed,
            dsnu_rms: cfg.dsnu_rms,
            hot_pixel_fraction: cfg.hot_pixel_fraction,
            hot_pixel_dark_e_per_s: cfg.hot_pixel_dark_e_per_s,
            column_offset_rms_dn: cfg.column_offset_rms_dn,
        })
    }

    /// Conversion gain at analogue gain `gain`: DN per electron.
    pub fn dn_per_electron(&self, gain: f64) -> f64 {
        gain / self.electrons_per_dn
    }

    /// The value a saturated photosite reports at analogue gain `gain` (full well or the ADC
    /// maximum, whichever is lower), DN.
    pub fn white_level(&self, gain: f64) -> u16 {
        let adc_max = (1u32 << self.bit_depth) - 1;
        // Four read-noise sigmas below the full-well signal, so every saturated photosite reports
        // exactly the white level, as the white level of a real raw file is set below the noisy
        // saturation plateau.
        let well = f64::from(self.black_level_dn)
            + ((self.full_well_e - 4.0 * self.read_noise_e) * self.dn_per_electron(gain)).floor();
        (well.min(f64::from(adc_max))) as u16
    }

    /// The fixed PRNU gain of photosite `(x, y)`: `max(0, 1 + prnu_rms · z)`, with `z` a
    /// zero-mean, unit-variance, near-Gaussian number (Irwin–Hall sum of four uniforms, bounded
    /// at ±3.46) from a hash of `(fixed_pattern_seed, x, y)`: a property of the sensor, the
    /// same in every frame and free of any random-stream state.
    pub fn prnu_gain(&self, x: usize, y: usize) -> f64 {
        let h = splitmix64(self.fixed_pattern_seed ^ splitmix64(((y as u64) << 32) | x as u64));
        (1.0 + self.prnu_rms * unit_normal_from_hash(h)).max(0.0)
    }

    /// The fixed dark current of photosite `(x, y)`, e-/s (see the module docs): hot with
    /// probability `hot_pixel_fraction`, else `dark_current · max(0, 1 + dsnu_rms · z)`. Hashed
    /// like [`SensorModel::prnu_gain`] with other salts, so the patterns are independent.
    pub fn dark_current_at(&self, x: usize, y: usize) -> f64 {
        let key = splitmix64(((y as u64) << 32) | x as u64);
        if self.hot_pixel_fraction > 0.0 {
            let h = splitmix64(self.fixed_pattern_seed ^ key ^ HOT_SALT);
            // Two independent 32-bit uniforms: is it hot, and how hot.
            let u_hot = (h & 0xffff_ffff) as f64 / 4_294_967_296.0;
            if u_hot < self.hot_pixel_fraction {
                let u = (h >> 32) as f64 / 4_294_967_296.0;
                return self.hot_pixel_dark_e_per_s * 10f64.powf(u);
            }
        }
        if self.dsnu_rms == 0.0 {
            return self.dark_current_e_per_s;
        }
        let h = splitmix64(self.fixed_pattern_seed ^ key ^ DSNU_SALT);
        self.dark_current_e_per_s * (1.0 + self.dsnu_rms * unit_normal_from_hash(h)).max(0.0)
    }

    /// The fixed black-level offset of column `x`, DN (`column_offset_rms_dn · z`).
    pub fn column_offset_dn(&self, x: usize) -> f64 {
        if self.column_offset_rms_dn == 0.0 {
            return 0.0;
        }
        let h = splitmix64(self.fixed_pattern_seed ^ splitmix64(x as u64 ^ COLUMN_SALT));
        self.column_offset_rms_dn * unit_normal_from_hash(h)
    }

    /// The mean DN of photosite `(x, y)` in the dark (lamp off) for an exposure and gain,
    /// before rounding and clipping: `black + col(x) + dark(x, y) · t · gain / electrons_per_dn`.
    /// The truth a dark calibration estimates.
    pub fn dark_mean_dn(&self, x: usize, y: usize, exposure_s: f64, gain: f64) -> f64 {
        f64::from(self.black_level_dn)
            + self.column_offset_dn(x)
            + self.dark_current_at(x, y) * exposure_s * self.dn_per_electron(gain)
    }

    /// Colour channel (0 R, 1 G, 2 B) sampled at photosite `(x, y)`.
    pub fn channel_at(&self, x: usize, y: usize) -> usize {
        self.bayer.map_or(1, |b| b.channel_at(x, y))
    }

    /// Exposes the sensor to `radiance` for `exposure_s` seconds at analogue gain `gain` and
    /// reads it out with noise drawn from `seed`. Metadata fields the sensor cannot know
    /// (`sequence`, `f_number`, `timestamp_s`) are 0 / `None` for the caller to fill in.
    pub fn capture(
        &self,
        radiance: &RadianceImage,
        exposure_s: f64,
        gain: f64,
        seed: u64,
    ) -> Result<RawFrame, SensorError> {
        let (w, h) = (radiance.width, radiance.height);
        if radiance.data.len() != w * h {
            return Err(SensorError::SizeMismatch { width: w, height: h, len: radiance.data.len() });
        }
        if !(exposure_s.is_finite() && (0.0..=3600.0).contains(&exposure_s)) {
            return Err(SensorError::OutOfRange {
                what: "exposure_s",
                value: exposure_s.to_string(),
                allowed: "0..=3600 s".into(),
            });
        }
        if !(gain.is_finite() && gain >= 1.0 && gain <= self.max_analogue_gain) {
            return Err(SensorError::OutOfRange {
                what: "analogue gain",
                value: gain.to_string(),
                allowed: format!("1..={}", self.max_analogue_gain),
            });
        }
        if let Some(i) = radiance.data.iter().position(|p| p.iter().any(|v| !(v.is_finite() && *v >= 0.0))) {
            let p = radiance.data[i];
            let channel = p.iter().position(|v| !(v.is_finite() && *v >= 0.0)).unwrap_or(0);
            return Err(SensorError::BadRate { x: i % w, y: i / w, channel, value: p[channel] });
        }

        let white = self.white_level(gain);
        let k = self.dn_per_electron(gain);
        let black = f64::from(self.black_level_dn);
        let uniform_dark = self.dsnu_rms == 0.0 && self.hot_pixel_fraction == 0.0;
        let cols: Vec<f64> = (0..w).map(|x| self.column_offset_dn(x)).collect();
        let read_var = self.read_noise_e * self.read_noise_e;
        let mut data = vec![0u16; w * h];
        data.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(y as u64);
            let src = &radiance.data[y * w..(y + 1) * w];
            for (x, (out, rate)) in row.iter_mut().zip(src).enumerate() {
                let mut r = f64::from(rate[self.channel_at(x, y)]);
                if self.prnu_rms > 0.0 {
                    r *= self.prnu_gain(x, y);
                }
                let dark = if uniform_dark { self.dark_current_e_per_s } else { self.dark_current_at(x, y) };
                let mean = r * exposure_s + dark * exposure_s;
                let e = if mean >= GAUSSIAN_ABOVE && mean + 5.0 * mean.sqrt() < self.full_well_e {
                    // Shot and read noise are both Gaussian here and the well (5 sigma away)
                    // does not clip: one draw with the summed variance.
                    let z: f64 = rng.sample(StandardNormal);
                    mean + (mean + read_var).sqrt() * z
                } else {
                    let mut e = poisson(&mut rng, mean).min(self.full_well_e);
                    if self.read_noise_e > 0.0 {
                        let z: f64 = rng.sample(StandardNormal);
                        e += self.read_noise_e * z;
                    }
                    e
                };
                let dn = round_half_away(e * k + cols[x]) + black;
                *out = dn.clamp(0.0, f64::from(white)) as u16;
            }
        });
        Ok(RawFrame {
            width: w,
            height: h,
            data,
            meta: FrameMeta {
                sequence: 0,
                exposure_s,
                gain,
                f_number: None,
                black_level: self.black_level_dn,
                white_level: white,
                bit_depth: self.bit_depth,
                bayer: self.bayer,
                timestamp_s: 0.0,
                temperature_c: None,
            },
        })
    }
}

/// `x.round()` (halves away from zero), bit for bit, without the library call `f64::round`
/// makes on a baseline x86-64 target (a tenth of a simulated frame's readout time): below
/// 2^52 the truncation through `i64` and the fractional part `x - t` are exact.
#[inline]
fn round_half_away(x: f64) -> f64 {
    if !(x.abs() < 4_503_599_627_370_496.0) {
        return x.round();
    }
    let t = x as i64 as f64;
    let f = x - t;
    if f >= 0.5 {
        t + 1.0
    } else if f <= -0.5 {
        t - 1.0
    } else {
        t
    }
}

/// Mean above which shot noise is drawn as a Gaussian (see the module docs).
pub const GAUSSIAN_ABOVE: f64 = 1000.0;

/// Salts of the fixed patterns hashed from `fixed_pattern_seed` (PRNU uses none).
const DSNU_SALT: u64 = 0x6473_6e75_0000_0001;
const HOT_SALT: u64 = 0x686f_7470_0000_0002;
const COLUMN_SALT: u64 = 0x636f_6c6f_0000_0003;

/// A zero-mean, unit-variance, near-Gaussian number from a 64-bit hash: the Irwin–Hall sum of
/// its four 16-bit quarters as uniforms, bounded at ±3.46.
fn unit_normal_from_hash(h: u64) -> f64 {
    let sum: f64 = (0..4).map(|i| ((h >> (16 * i)) & 0xffff) as f64 / 65536.0).sum::<f64>() + 4.0 / 131072.0;
    (sum - 2.0) * 3f64.sqrt()
}

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Natural log of `k!`: a table below 10, Stirling's series above (error < 1e-10).
fn ln_factorial(k: f64) -> f64 {
    const TABLE: [f64; 10] = [
        0.0,
        0.0,
        std::f64::consts::LN_2,
        1.791_759_469_228_055,
        3.178_053_830_347_146,
        4.787_491_742_782_046,
        6.579_251_212_010_101,
        8.525_161_361_065_415,
        10.604_602_902_745_25,
        12.801_827_480_081_469,
    ];
    if k < 10.0 {
        return TABLE[k as usize];
    }
    let inv = 1.0 / k;
    let inv2 = inv * inv;
    k * k.ln() - k + 0.5 * (std::f64::consts::TAU * k).ln() + inv * (1.0 / 12.0 - inv2 * (1.0 / 360.0 - inv2 / 1260.0))
}

/// A Poisson-distributed count with mean `mean` (as f64); see the module docs for the method.
pub fn poisson<R: Rng + ?Sized>(rng: &mut R, mean: f64) -> f64 {
    if !(mean > 0.0) {
        return 0.0;
    }
    if mean < 10.0 {
        // Inversion by sequential search: at most a few dozen steps for mean < 10.
        let u: f64 = rng.gen();
        let mut p = (-mean).exp();
        let mut cdf = p;
        let mut k = 0.0;
        while u > cdf && k < 200.0 {
            k += 1.0;
            p *= mean / k;
            cdf += p;
        }
        return k;
    }
    if mean >= GAUSSIAN_ABOVE {
        let z: f64 = rng.sample(StandardNormal);
        return (mean + mean.sqrt() * z).max(0.0);
    }
    // PTRS: W. Hörmann (1993), "The transformed rejection method for generating Poisson
    // random variables", Insurance: Mathematics and Economics 12, 39-45.
    let smu = mean.sqrt();
    let b = 0.931 + 2.53 * smu;
    let a = -0.059 + 0.02483 * b;
    let inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
    let v_r = 0.9277 - 3.6224 / (b - 2.0);
    loop {
        let u: f64 = rng.gen::<f64>() - 0.5;
        let v: f64 = rng.gen();
        let us = 0.5 - u.abs();
        let k = ((2.0 * a / us + b) * u + mean + 0.43).floor();
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if k < 0.0 || (us < 0.013 && v > us) {
            continue;
        }
        // Acceptance test of the paper, its three logarithms folded into one on the left.
        if (v * inv_alpha / (a / (us * us) + b)).ln() <= -mean + k * mean.ln() - ln_factorial(k) {
            return k;
        }
    }
}

/// Photo-electron rate scale of the radiometric chain lamp → surface → lens → photosite.
///
/// For a surface point lit by the lamp from distance `d` (metres) at incidence cosine
/// `cos_i`, whose BRDF is `ρ(λ) · φ` (φ in 1/sr carries the geometry, e.g. `1/π` for a
/// Lambertian surface, and ρ its spectral reflectance), seen by the pixel at `px`, the
/// photosite's rate in channel `c` is
///
/// ```text
/// rate_c = K · camera_rgb_c(ρ) · φ · cos_i / d² · vignetting(px)        [e-/s]
/// K = E₁ · A_pix · T · π / (4 N²) · R_peak · g_lamp                    [e-/s per (W/m² ... )]
/// ```
///
/// with `E₁` the lamp's irradiance at 1 m (W/m²), `A_pix` the photosite area, `T` the lens
/// transmittance, `N` the f-number (`π / (4 N²)` turns scene radiance into image-plane
/// irradiance on the axis), `R_peak = QE_peak · λ_peak / (h c)` electrons per joule at the
/// most sensitive channel's peak, and `g_lamp` = [`crate::colour::ColourSystem::lamp_green_efficiency`]
/// (the lamp-weighted green response relative to the peak). `camera_rgb` is normalised so a
/// perfect white gives green 1, which is why `K` carries `g_lamp`.
pub fn electrons_per_second_scale(
    camera: &CameraConfig,
    sensor: &SensorConfig,
    lamp: &LampConfig,
    colour: &crate::colour::ColourSystem,
) -> f64 {
    const H: f64 = 6.626_070_15e-34; // Planck, J s
    const C: f64 = 299_792_458.0; // m/s
    let pitch = sensor.pixel_pitch_um * 1e-6;
    let area = pitch * pitch;
    let optics = camera.lens_transmittance * std::f64::consts::PI / (4.0 * camera.f_number * camera.f_number);
    let peak_wavelength_m = colour.camera_peak_wavelength_nm() * 1e-9;
    let r_peak = sensor.peak_quantum_efficiency * peak_wavelength_m / (H * C);
    lamp.irradiance_at_1m_w_m2 * area * optics * r_peak * colour.lamp_green_efficiency()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Equal as numbers (a negative value rounding to zero gives +0, not -0: the same DN).
    #[test]
    fn round_half_away_is_f64_round() {
        let mut v = vec![0.5, -0.5, 1.5, -1.5, 2.5, 0.49999999999999994, -0.49999999999999994, 4503599627370495.5];
        v.extend([1e300, -1e300, f64::INFINITY, 0.0, -0.0, 16383.499999, 16383.5, 123456.7]);
        v.extend((0..100_000).map(|i| (i as f64 - 50_000.0) * 0.037 + 0.5));
        for x in v {
            assert_eq!(round_half_away(x), x.round(), "{x}");
        }
        assert!(round_half_away(f64::NAN).is_nan());
    }

    fn model(cfg: SensorConfig) -> SensorModel {
        SensorModel::from_config(&cfg).unwrap()
    }

    fn mean_var(v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
        let n = v.clone().count() as f64;
        let m = v.clone().sum::<f64>() / n;
        (m, v.map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0))
    }

    #[test]
    fn poisson_moments_in_every_regime() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for mean in [0.3, 4.0, 9.9, 10.0, 37.5, 250.0, 999.0, 1000.0, 20000.0] {
            let n = 100_000;
            let draws: Vec<f64> = (0..n).map(|_| poisson(&mut rng, mean)).collect();
            let (m, v) = mean_var(draws.iter().copied());
            // Standard errors: mean sqrt(λ/n); variance about λ sqrt(2/n).
            let se_m = (mean / n as f64).sqrt();
            assert!((m - mean).abs() < 5.0 * se_m, "mean {mean}: got {m}");
            assert!((v / mean - 1.0).abs() < 5.0 * (2.0 / n as f64).sqrt() + 0.005, "mean {mean}: var {v}");
            if mean < 1000.0 {
                assert!(draws.iter().all(|d| d.fract() == 0.0 && *d >= 0.0));
            }
        }
        // Exact probabilities for a small mean: P(0) = e^-λ.
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let zeros = (0..200_000).filter(|_| poisson(&mut rng, 1.5) == 0.0).count() as f64 / 200_000.0;
        assert!((zeros - (-1.5f64).exp()).abs() < 0.004, "{zeros}");
        // PTRS regime: P(k = λ) for λ = 50 is 0.05633.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let hits = (0..200_000).filter(|_| poisson(&mut rng, 50.0) == 50.0).count() as f64 / 200_000.0;
        assert!((hits - 0.056_325).abs() < 0.002, "{hits}");
    }

    #[test]
    fn ln_factorial_matches_products() {
        let mut acc = 0.0f64;
        for k in 1..200u32 {
            acc += f64::from(k).ln();
            assert!((ln_factorial(f64::from(k)) - acc).abs() < 1e-9 * acc.max(1.0), "{k}");
        }
    }

    /// Photon transfer: variance (from frame pairs, which cancels PRNU) against mean signal,
    /// above black. The slope is the conversion gain in DN per electron.
    fn ptc_slope(sensor: &SensorModel, gain: f64) -> f64 {
        let (w, h) = (256, 128);
        let mut means = Vec::new();
        let mut vars = Vec::new();
        for (i, rate) in [2_000.0f32, 10_000.0, 40_000.0, 120_000.0, 250_000.0].iter().enumerate() {
            let img = RadianceImage::filled(w, h, [*rate; 3]);
            let a = sensor.capture(&img, 0.1 / gain, gain, 100 + 2 * i as u64).unwrap();
            let b = sensor.capture(&img, 0.1 / gain, gain, 101 + 2 * i as u64).unwrap();
            assert!(a.data.iter().all(|&d| d < a.meta.white_level), "no saturation in the PTC");
            let black = f64::from(a.meta.black_level);
            let (m, _) = mean_var(a.data.iter().map(|&d| f64::from(d) - black));
            let (_, vd) = mean_var(a.data.iter().zip(&b.data).map(|(&p, &q)| f64::from(p) - f64::from(q)));
            means.push(m);
            vars.push(vd / 2.0);
        }
        // Least-squares line.
        let n = means.len() as f64;
        let mx = means.iter().sum::<f64>() / n;
        let my = vars.iter().sum::<f64>() / n;
        let sxy: f64 = means.iter().zip(&vars).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = means.iter().map(|x| (x - mx) * (x - mx)).sum();
        sxy / sxx
    }

    #[test]
    fn photon_transfer_slope_equals_configured_gain() {
        for (cfa, gain) in
            [(btfrig_core::config::sensor::Cfa::Rggb, 1.0), (btfrig_core::config::sensor::Cfa::Mono, 2.0)]
        {
            let s = model(SensorConfig { cfa, ..Default::default() });
            let slope = ptc_slope(&s, gain);
            let expect = s.dn_per_electron(gain);
            assert!((slope / expect - 1.0).abs() < 0.05, "{cfa:?} gain {gain}: slope {slope} vs {expect}");
            assert!((slope / expect - 1.0).abs() < 0.02, "tighter than needed: {slope} vs {expect}");
        }
    }

    #[test]
    fn same_seed_is_bit_identical_different_seed_is_not_and_threads_do_not_matter() {
        let s = model(SensorConfig::default());
        let img = RadianceImage {
            width: 160,
            height: 120,
            data: (0..160 * 120).map(|i| [(i % 997) as f32 * 50.0, 3.0 * i as f32, 100.0]).collect(),
        };
        let a = s.capture(&img, 0.01, 1.0, 42).unwrap();
        let b = s.capture(&img, 0.01, 1.0, 42).unwrap();
        assert_eq!(a, b);
        let c = s.capture(&img, 0.01, 1.0, 43).unwrap();
        let differing = a.data.iter().zip(&c.data).filter(|(p, q)| p != q).count();
        assert!(differing > a.data.len() / 2, "{differing}");
        let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let d = one_thread.install(|| s.capture(&img, 0.01, 1.0, 42).unwrap());
        assert_eq!(a, d);
    }

    #[test]
    fn saturation_clips_at_white_level_and_black_level_is_honoured() {
        let s = model(SensorConfig::default());
        let bright = RadianceImage::filled(64, 64, [1e9; 3]);
        let f = s.capture(&bright, 0.01, 1.0, 1).unwrap();
        assert_eq!(f.meta.white_level, 256 + 15995); // floor((40000 - 4 * 3) / 2.5)
        assert!(f.data.iter().all(|&d| d == f.meta.white_level));
        // At gain 8 the ADC clips first.
        let f = s.capture(&bright, 0.01, 8.0, 1).unwrap();
        assert_eq!(f.meta.white_level, 16383);
        assert!(f.data.iter().all(|&d| d == 16383));
        // Dark frame: mean at the black level, spread = read noise in DN.
        let dark = RadianceImage::filled(256, 256, [0.0; 3]);
        let f = s.capture(&dark, 0.001, 1.0, 2).unwrap();
        let (m, v) = mean_var(f.data.iter().map(|&d| f64::from(d)));
        assert!((m - 256.0).abs() < 0.02, "{m}");
        let expect = (3.0f64 / 2.5).powi(2) + 1.0 / 12.0;
        assert!((v / expect - 1.0).abs() < 0.05, "{v} vs {expect}");
        assert_eq!(f.meta.black_level, 256);
        // Without read noise, zero light reads exactly black.
        let quiet = model(SensorConfig { read_noise_e: 0.0, dark_current_e_per_s: 0.0, ..Default::default() });
        assert!(quiet.capture(&dark, 0.01, 1.0, 3).unwrap().data.iter().all(|&d| d == 256));
    }

    #[test]
    fn bayer_channels_and_mono_sample_the_right_rates() {
        let quiet = SensorConfig { read_noise_e: 0.0, dark_current_e_per_s: 0.0, prnu_rms: 0.0, ..Default::default() };
        let img = RadianceImage::filled(8, 8, [10_000.0, 50_000.0, 200_000.0]);
        let s = model(quiet.clone());
        let f = s.capture(&img, 0.1, 1.0, 5).unwrap();
        // RGGB at (0,0) is red: 1000 e- -> 400 DN; (1,0) green 5000 e- -> 2000; (1,1) blue 20000 e- -> 8000.
        let near = |v: u16, e: f64| (f64::from(v) - 256.0 - e / 2.5).abs() < 6.0 * e.sqrt() / 2.5;
        assert!(near(f.at(0, 0), 1000.0) && near(f.at(1, 0), 5000.0) && near(f.at(1, 1), 20000.0));
        assert_eq!(f.meta.bayer, Some(BayerPattern::Rggb));
        let mono = model(SensorConfig { cfa: btfrig_core::config::sensor::Cfa::Mono, ..quiet });
        let f = mono.capture(&img, 0.1, 1.0, 5).unwrap();
        assert_eq!(f.meta.bayer, None);
        assert!((0..8).all(|y| (0..8).all(|x| near(f.at(x, y), 5000.0))));
    }

    #[test]
    fn prnu_is_a_fixed_pattern() {
        let s = model(SensorConfig { prnu_rms: 0.02, read_noise_e: 0.0, ..Default::default() });
        let img = RadianceImage::filled(128, 128, [200_000.0; 3]);
        // Averaging many frames leaves the fixed pattern: relative spread ~ prnu_rms.
        let n = 16;
        let mut sum = vec![0.0f64; 128 * 128];
        for seed in 0..n {
            let f = s.capture(&img, 0.1, 1.0, seed).unwrap();
            for (a, &d) in sum.iter_mut().zip(&f.data) {
                *a += f64::from(d) - 256.0;
            }
        }
        let (m, v) = mean_var(sum.iter().map(|a| a / n as f64));
        // Shot noise left after averaging: 20000 e- -> var(DN) = 8000/2.5/n; PRNU: (0.02 m)².
        let expect = (0.02 * m).powi(2) + 20000.0 / 2.5f64.powi(2) / n as f64;
        assert!((v / expect - 1.0).abs() < 0.1, "{v} vs {expect}");
    }

    #[test]
    fn bad_inputs_are_errors_naming_the_problem() {
        let s = model(SensorConfig::default());
        let mut img = RadianceImage::filled(4, 4, [1.0; 3]);
        assert!(s.capture(&img, -1.0, 1.0, 0).unwrap_err().to_string().contains("exposure_s"));
        assert!(s.capture(&img, 0.1, 100.0, 0).unwrap_err().to_string().contains("gain"));
        img.data[6][2] = f32::NAN;
        let e = s.capture(&img, 0.1, 1.0, 0).unwrap_err().to_string();
        assert!(e.contains("(2, 1) channel 2"), "{e}");
        img.data.pop();
        assert!(matches!(s.capture(&img, 0.1, 1.0, 0), Err(SensorError::SizeMismatch { .. })));
        let bad = SensorConfig { bit_depth: 3, ..Default::default() };
        assert!(SensorModel::from_config(&bad).unwrap_err().to_string().contains("bit_depth"));
    }

    #[test]
    fn dark_signal_non_uniformity_hot_pixels_and_column_offsets_are_fixed_patterns() {
        let cfg = SensorConfig {
            dark_current_e_per_s: 20.0,
            dsnu_rms: 0.3,
            hot_pixel_fraction: 0.005,
            hot_pixel_dark_e_per_s: 1000.0,
            column_offset_rms_dn: 2.0,
            ..Default::default()
        };
        let s = model(cfg);
        let (w, h) = (128, 128);
        // Pattern statistics: hot fraction, DSNU spread of the rest, column offset RMS.
        let dark: Vec<f64> =
            (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| s.dark_current_at(x, y)).collect();
        let hot = dark.iter().filter(|&&d| d >= 1000.0).count();
        assert!((40..=125).contains(&hot), "{hot} hot of {}", w * h); // expect 82
        let (m, v) = mean_var(dark.iter().copied().filter(|&d| d < 1000.0));
        assert!((m / 20.0 - 1.0).abs() < 0.02 && (v.sqrt() / m - 0.3).abs() < 0.02, "{m} {}", v.sqrt());
        let (cm, cv) = mean_var((0..4096).map(|x| s.column_offset_dn(x)));
        assert!(cm.abs() < 0.1 && (cv.sqrt() - 2.0).abs() < 0.1, "{cm} {}", cv.sqrt());
        // The average of dark frames converges to dark_mean_dn per photosite.
        let img = RadianceImage::filled(w, h, [0.0; 3]);
        let n = 24;
        let mut sum = vec![0.0f64; w * h];
        for seed in 0..n {
            let f = s.capture(&img, 0.5, 1.0, seed).unwrap();
            sum.iter_mut().zip(&f.data).for_each(|(a, &d)| *a += f64::from(d));
        }
        let z2: f64 = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let truth = s.dark_mean_dn(x, y, 0.5, 1.0);
                // Per frame: read noise, dark shot noise (DN^2), rounding.
                let var = (9.0 + s.dark_current_at(x, y) * 0.5) / 6.25 + 1.0 / 12.0;
                (sum[i] / n as f64 - truth).powi(2) / (var / n as f64)
            })
            .sum::<f64>()
            / (w * h) as f64;
        assert!((z2 - 1.0).abs() < 0.1, "mean squared z = {z2}");
    }

    #[test]
    fn full_frame_mean_levels_and_speed() {
        // A full 1600 x 1200 frame mixing all three noise regimes; the time is printed for the
        // report (not asserted: the machine is shared), the mean levels are checked.
        let s = model(SensorConfig::default());
        let img = RadianceImage {
            width: 1600,
            height: 1200,
            data: (0..1600 * 1200).map(|i| [(i % 4000) as f32 * 100.0, 5e5, 2e4]).collect(),
        };
        let t = std::time::Instant::now();
        let f = s.capture(&img, 0.01, 1.0, 9).unwrap();
        eprintln!("sensor capture 1600x1200: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
        let mean_of = |c: usize| {
            let v: Vec<f64> = (0..1200)
                .flat_map(|y| (0..1600).map(move |x| (x, y)))
                .filter(|&(x, y)| s.channel_at(x, y) == c)
                .map(|(x, y)| f64::from(f.at(x, y)) - 256.0)
                .collect();
            v.iter().sum::<f64>() / v.len() as f64
        };
        // Green 5000 e- (+0.005 dark) -> 2000 DN; blue 200 e- -> 80 DN; red mean 2000 e- -> 800.
        assert!((mean_of(1) - 2000.0).abs() < 0.5, "{}", mean_of(1));
        assert!((mean_of(2) - 80.0).abs() < 0.1, "{}", mean_of(2));
        assert!((mean_of(0) - 799.8).abs() < 1.0, "{}", mean_of(0));
    }
}
