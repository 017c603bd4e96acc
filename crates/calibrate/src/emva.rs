//! Sensor characterisation after EMVA 1288 (release 4.0, the linear camera model): system
//! gain, read noise, dark current, DSNU, PRNU, saturation capacity and linearity error, each
//! with a standard uncertainty, from frame averages of a photon-transfer series. No I/O and no
//! devices: `btfrig_measurement::captured_calibration` takes the frames (docs/emva1288.md).
//!
//! The model, per photosite, in DN: `μ_y = μ_y.dark + K·μ_e` and
//! `σ_y² = σ_y.dark² + K²·μ_e` (shot noise), with `σ_y.dark² = K²·σ_d² + σ_q²`, `σ_q² = 1/12`.
//!
//! - **K** (DN/e⁻) is the slope of the photon transfer curve `σ_y² − σ_y.dark²` against
//!   `μ_y − μ_y.dark`, through the origin, over the points below 70 % of saturation
//!   ([`PTC_MAX_FRACTION`]). Temporal variances are the mean per-photosite sample variance of
//!   N ≥ 2 frames, so fixed patterns do not enter.
//! - **Read noise** `σ_d = sqrt(σ_y.dark²(0) − 1/12) / K`, the dark variance extrapolated to
//!   zero exposure by a line through the dark series.
//! - **Dark current** `μ_I = (dμ_y.dark / dt) / K`, e⁻/s, the slope of the dark mean.
//! - **DSNU** `sqrt(s²_y.dark − σ²_y.dark / L) / K` (e⁻): the spatial standard deviation of an
//!   average of L dark frames, less what its temporal noise adds. Photosites hotter than the
//!   plan's threshold are left out (they are flagged as defects by the dark model).
//! - **PRNU** (%): the spatial standard deviation of the dark-subtracted bright average relative
//!   to the mean of its same-colour neighbours (a high-pass that removes vignetting and the
//!   illumination's slope), less the temporal part, divided by `sqrt(1 + 1/k)` for the k
//!   neighbours' own non-uniformity.
//! - **Saturation capacity** `μ_e.sat = (μ_y.sat − μ_y.dark) / K` at the plateau every photosite
//!   of the region reaches (EMVA 4.0 takes the mean at the variance maximum, a little lower;
//!   the plateau is what a pipeline clips at).
//! - **Linearity error** `LE = (max δ − min δ) / 2` (%), `δ` the relative deviation of
//!   `μ_y − μ_y.dark` from a straight line in exposure time between 5 % and 95 % of saturation.
//!
//! Uncertainties: a regression's standard error from its residuals, floored by what the
//! points' own sampling errors give (so that few, nearly perfect points do not claim too
//! little), and K's relative uncertainty carried into every figure divided by K.

use btfrig_imaging::dark_flat::FrameAverage;
use serde::{Deserialize, Serialize};

/// Photon-transfer points above this fraction of the saturation signal are left out of K.
pub const PTC_MAX_FRACTION: f64 = 0.7;
/// The linearity range: fractions of the saturation signal.
pub const LINEARITY_RANGE: (f64, f64) = (0.05, 0.95);
/// Quantisation noise variance, DN².
pub const QUANTISATION_VAR: f64 = 1.0 / 12.0;

/// Errors of the sensor characterisation.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum EmvaError {
    /// A series has too few usable points.
    #[error("{what}: {got} usable point(s), at least {need} needed; {hint}")]
    TooFewPoints {
        /// Which series.
        what: &'static str,
        /// Usable points.
        got: usize,
        /// Needed.
        need: usize,
        /// What to change.
        hint: &'static str,
    },
    /// A figure came out unphysical.
    #[error("{what} = {value}: {hint}")]
    Unphysical {
        /// Which figure.
        what: &'static str,
        /// Its value.
        value: f64,
        /// Why this happens.
        hint: &'static str,
    },
    /// The averages do not fit together.
    #[error("{0}")]
    Mismatch(String),
}

/// A figure and its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Its standard uncertainty (1 sigma).
    pub sigma: f64,
}

impl Estimate {
    /// `|value - truth| / sigma`.
    pub fn z(&self, truth: f64) -> f64 {
        (self.value - truth).abs() / self.sigma.max(f64::MIN_POSITIVE)
    }
}

/// The temporal statistics of one exposure over a region: per channel (R, G, B; a monochrome
/// sensor uses G) the mean DN, the mean per-photosite variance and the photosites counted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExposureStats {
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Frames averaged.
    pub frames: usize,
    /// Mean DN per channel.
    pub mean_dn: [f64; 3],
    /// Mean temporal variance per channel, DN².
    pub var_dn2: [f64; 3],
    /// Standard deviation of the per-photosite variances per channel, DN² (their mean's
    /// standard error is this over sqrt(photosites)).
    pub var_spread_dn2: [f64; 3],
    /// Photosites per channel.
    pub pixels: [usize; 3],
    /// Per channel, the fraction of its photosites that reached the white level in some frame.
    pub saturated_fraction: [f64; 3],
}

/// The centre box of `fraction` of width and height: `(x0, y0, x1, y1)`, at least 2 x 2
/// and starting on even coordinates (whole colour-filter cells).
pub fn centre_box(width: usize, height: usize, fraction: f64) -> (usize, usize, usize, usize) {
    let bw = (((width as f64) * fraction) as usize).clamp(2, width);
    let bh = (((height as f64) * fraction) as usize).clamp(2, height);
    let x0 = ((width - bw) / 2) & !1;
    let y0 = ((height - bh) / 2) & !1;
    (x0, y0, (x0 + bw).min(width), (y0 + bh).min(height))
}

impl ExposureStats {
    /// The statistics of `avg` (N >= 2 frames) over the centre box of `fraction`.
    pub fn of(avg: &FrameAverage, fraction: f64) -> Result<ExposureStats, EmvaError> {
        if avg.frames < 2 {
            return Err(EmvaError::Mismatch(format!(
                "an average of {} frame(s) at {} s has no temporal variance: at least 2 frames per exposure",
                avg.frames, avg.exposure_s
            )));
        }
        let (x0, y0, x1, y1) = centre_box(avg.width, avg.height, fraction);
        let (mut s, mut v, mut v2, mut n) = ([0.0; 3], [0.0; 3], [0.0; 3], [0usize; 3]);
        let mut sat = [0usize; 3];
        for y in y0..y1 {
            for x in x0..x1 {
                let i = y * avg.width + x;
                let c = avg.bayer.map_or(1, |b| b.channel_at(x, y));
                s[c] += avg.mean[i];
                v[c] += avg.variance[i];
                v2[c] += avg.variance[i] * avg.variance[i];
                n[c] += 1;
                sat[c] += usize::from(avg.saturated[i]);
            }
        }
        let per =
            |a: [f64; 3]| -> [f64; 3] { std::array::from_fn(|c| if n[c] > 0 { a[c] / n[c] as f64 } else { 0.0 }) };
        let (mean_dn, var_dn2, sq) = (per(s), per(v), per(v2));
        Ok(ExposureStats {
            exposure_s: avg.exposure_s,
            frames: avg.frames,
            mean_dn,
            var_dn2,
            var_spread_dn2: std::array::from_fn(|c| (sq[c] - var_dn2[c] * var_dn2[c]).max(0.0).sqrt()),
            pixels: n,
            saturated_fraction: std::array::from_fn(|c| sat[c] as f64 / n[c].max(1) as f64),
        })
    }

    /// Channels present (photosites counted).
    fn channels(&self) -> impl Iterator<Item = usize> + '_ {
        (0..3).filter(|&c| self.pixels[c] > 0)
    }

    /// Mean and variance pooled over channels (dark frames: no colour).
    fn pooled(&self) -> (f64, f64, f64, usize) {
        let n: usize = self.pixels.iter().sum();
        let w = |a: [f64; 3]| self.channels().map(|c| a[c] * self.pixels[c] as f64).sum::<f64>() / n.max(1) as f64;
        let spread = w(self.var_spread_dn2.map(|s| s * s)).sqrt();
        (w(self.mean_dn), w(self.var_dn2), spread, n)
    }
}

/// A straight line fitted by least squares, with standard errors.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Line {
    intercept: f64,
    slope: f64,
    intercept_sigma: f64,
    slope_sigma: f64,
}

/// Fits `y = a + b x` to points `(x, y, sigma_y)`: ordinary least squares; the standard
/// errors are the larger of the residuals' and the points' own sigmas'.
fn fit_line(points: &[(f64, f64, f64)]) -> Line {
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let rss: f64 = points.iter().map(|p| (p.1 - intercept - slope * p.0).powi(2)).sum();
    let s2_res = if points.len() > 2 { rss / (n - 2.0) } else { 0.0 };
    let s2_pts = points.iter().map(|p| p.2 * p.2).sum::<f64>() / n;
    let s2 = s2_res.max(s2_pts);
    let sumx2: f64 = points.iter().map(|p| p.0 * p.0).sum();
    Line { intercept, slope, slope_sigma: (s2 / sxx).sqrt(), intercept_sigma: (s2 * sumx2 / (n * sxx)).sqrt() }
}

/// What [`characterise`] measures from.
#[derive(Debug, Clone, Copy)]
pub struct EmvaInput<'a> {
    /// The dark series at long exposures (dark current, read noise): statistics of N >= 2
    /// frames each, at >= 2 distinct exposures.
    pub dark_series: &'a [ExposureStats],
    /// The photon-transfer series: per exposure the lit statistics and the dark ones at the
    /// same exposure; the last ones saturated.
    pub ptc: &'a [(ExposureStats, ExposureStats)],
    /// An average of L dark frames (DSNU), over the whole sensor.
    pub dsnu_dark: &'a FrameAverage,
    /// An average of lit frames near half of saturation and one of dark frames at the same
    /// exposure (PRNU), over the whole sensor.
    pub prnu: (&'a FrameAverage, &'a FrameAverage),
    /// Photosites whose dark current is above this are left out of DSNU and PRNU, e⁻/s.
    pub hot_threshold_e_per_s: f64,
    /// Half-width of the PRNU high-pass in same-colour photosites (the neighbourhood is
    /// (2r + 1)² - 1 of them).
    pub prnu_radius: usize,
}

/// The characterisation: the EMVA 1288 figures with their uncertainties.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EmvaResult {
    /// Overall system gain K, DN/e⁻ (at the series' analogue gain).
    pub system_gain_dn_per_e: Estimate,
    /// Temporal dark noise σ_d, e⁻.
    pub read_noise_e: Estimate,
    /// Mean dark current, e⁻/s.
    pub dark_current_e_per_s: Estimate,
    /// Dark-signal non-uniformity (spatial standard deviation at `dsnu_exposure_s`), e⁻.
    pub dsnu_e: Estimate,
    /// The exposure the DSNU holds at, s.
    pub dsnu_exposure_s: f64,
    /// Photo-response non-uniformity, %.
    pub prnu_pct: Estimate,
    /// Saturation capacity, e⁻.
    pub saturation_capacity_e: Estimate,
    /// Linearity error, %.
    pub linearity_error_pct: Estimate,
    /// Photon-transfer points used for K.
    pub ptc_points: usize,
    /// Photosites left out of DSNU and PRNU as hot.
    pub hot_pixels: usize,
}

/// Characterises the sensor from `input` (see the module docs for each figure's method).
pub fn characterise(input: &EmvaInput<'_>) -> Result<EmvaResult, EmvaError> {
    // Dark mean and variance against exposure time: dark current and read noise.
    let mut dark_mean = Vec::new();
    let mut dark_var = Vec::new();
    for s in input.dark_series {
        let (m, v, spread, n) = s.pooled();
        let nn = n.max(1) as f64;
        dark_mean.push((s.exposure_s, m, (v / (nn * s.frames as f64)).sqrt()));
        dark_var.push((s.exposure_s, v, spread / nn.sqrt()));
    }
    let distinct = {
        let mut t: Vec<f64> = input.dark_series.iter().map(|s| s.exposure_s).collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t.len()
    };
    if distinct < 2 {
        return Err(EmvaError::TooFewPoints {
            what: "dark series",
            got: distinct,
            need: 2,
            hint: "take dark frames at two or more exposure times",
        });
    }
    let dark_mean_line = fit_line(&dark_mean);
    let dark_var_line = fit_line(&dark_var);

    // The photon transfer curve, per channel, against the dark frames of the same exposure.
    // Saturation: the first exposure at which a channel's every photosite clips (the
    // brightest channel of the field first); the plateau is the same DN in every channel.
    let full = |b: &ExposureStats| b.channels().filter(|&c| b.saturated_fraction[c] >= 0.999).collect::<Vec<_>>();
    let sat =
        input.ptc.iter().filter(|(b, _)| !full(b).is_empty()).min_by(|a, b| a.0.exposure_s.total_cmp(&b.0.exposure_s));
    let Some((sat_b, sat_d)) = sat else {
        return Err(EmvaError::TooFewPoints {
            what: "saturated photon-transfer points",
            got: 0,
            need: 1,
            hint: "the series must end beyond saturation: raise its longest exposure",
        });
    };
    let sat_chans = full(sat_b);
    let sat_signal =
        sat_chans.iter().map(|&c| sat_b.mean_dn[c] - sat_d.mean_dn[c]).sum::<f64>() / sat_chans.len() as f64;
    let mut ptc = Vec::new();
    for (b, d) in input.ptc {
        for c in b.channels() {
            let x = b.mean_dn[c] - d.mean_dn[c];
            if b.saturated_fraction[c] > 0.0 || x <= 0.0 || x > PTC_MAX_FRACTION * sat_signal {
                continue;
            }
            let y = b.var_dn2[c] - d.var_dn2[c];
            let n = b.pixels[c] as f64;
            let sy = (b.var_spread_dn2[c].powi(2) + d.var_spread_dn2[c].powi(2)).sqrt() / n.sqrt();
            ptc.push((x, y, sy));
        }
    }
    if ptc.len() < 3 {
        return Err(EmvaError::TooFewPoints {
            what: "photon-transfer points below 70 % of saturation",
            got: ptc.len(),
            need: 3,
            hint: "take more exposures between dark and saturation",
        });
    }
    // Through the origin: K = Σxy / Σx².
    let sxx: f64 = ptc.iter().map(|p| p.0 * p.0).sum();
    let k = ptc.iter().map(|p| p.0 * p.1).sum::<f64>() / sxx;
    let rss: f64 = ptc.iter().map(|p| (p.1 - k * p.0).powi(2)).sum();
    let s2 = (rss / (ptc.len() - 1) as f64).max(ptc.iter().map(|p| p.2 * p.2).sum::<f64>() / ptc.len() as f64);
    let k_sigma = (s2 / sxx).sqrt();
    if !(k > 0.0 && k.is_finite()) {
        return Err(EmvaError::Unphysical {
            what: "system gain K",
            value: k,
            hint: "the lit frames' noise does not grow with their signal: is the field lit and the lens uncapped?",
        });
    }
    let rel_k = k_sigma / k;

    // Read noise from the dark variance at zero exposure.
    let dark_var0 = dark_var_line.intercept - QUANTISATION_VAR;
    if dark_var0 <= 0.0 {
        return Err(EmvaError::Unphysical {
            what: "dark temporal variance less quantisation, DN²",
            value: dark_var0,
            hint: "below the quantisation noise: the camera's read noise is under 0.3 DN, raise the gain",
        });
    }
    let read = dark_var0.sqrt() / k;
    let read_sigma = read * ((dark_var_line.intercept_sigma / (2.0 * dark_var0)).powi(2) + rel_k * rel_k).sqrt();
    let dark_current = dark_mean_line.slope / k;
    let dark_current_sigma = ((dark_mean_line.slope_sigma / k).powi(2) + (dark_current * rel_k).powi(2)).sqrt();

    // Saturation capacity: the plateau above dark.
    let chans: Vec<usize> = sat_b.channels().collect();
    let sat_e = sat_signal / k;

    // Linearity: per channel, signal against exposure in the range; the worst channel.
    let mut le = 0.0f64;
    let mut le_sigma = 0.0f64;
    for &c in &chans {
        let pts: Vec<(f64, f64, f64)> = input
            .ptc
            .iter()
            .filter(|(b, _)| b.saturated_fraction[c] == 0.0)
            .filter_map(|(b, d)| {
                let x = b.mean_dn[c] - d.mean_dn[c];
                let f = x / sat_signal;
                let n = b.pixels[c] as f64 * b.frames as f64;
                let sx = ((b.var_dn2[c] + d.var_dn2[c]) / n).sqrt();
                (LINEARITY_RANGE.0..=LINEARITY_RANGE.1).contains(&f).then_some((b.exposure_s, x, sx))
            })
            .collect();
        if pts.len() < 3 {
            return Err(EmvaError::TooFewPoints {
                what: "photon-transfer points between 5 % and 95 % of saturation",
                got: pts.len(),
                need: 3,
                hint: "take more exposures between dark and saturation",
            });
        }
        let line = fit_line(&pts);
        let dev: Vec<f64> = pts.iter().map(|p| 100.0 * (p.1 / (line.intercept + line.slope * p.0) - 1.0)).collect();
        let max = dev.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let min = dev.iter().copied().fold(f64::INFINITY, f64::min);
        le = le.max((max - min) / 2.0);
        // What noise alone gives: the half-range of the points' relative errors.
        let worst = pts.iter().map(|p| 100.0 * p.2 / p.1).fold(0.0, f64::max);
        le_sigma = le_sigma.max(worst);
    }

    // DSNU and PRNU over the whole sensor, hot photosites left out.
    let dd = input.dsnu_dark;
    let (pb, pd) = input.prnu;
    if (pb.width, pb.height) != (dd.width, dd.height) || (pd.width, pd.height) != (dd.width, dd.height) {
        return Err(EmvaError::Mismatch("the DSNU and PRNU averages differ in size".into()));
    }
    let (w, h) = (dd.width, dd.height);
    let median = {
        let mut v: Vec<f64> = dd.mean.clone();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    // Hot: dark signal more than the threshold's worth above the median (the median photosite
    // is not hot); saturated photosites go with them.
    let hot_dn = input.hot_threshold_e_per_s * dd.exposure_s * k;
    let hot: Vec<bool> =
        (0..w * h).map(|i| dd.mean[i] - median > hot_dn || dd.saturated[i] || pb.saturated[i]).collect();
    let hot_pixels = hot.iter().filter(|&&x| x).count();
    let ok: Vec<usize> = (0..w * h).filter(|&i| !hot[i]).collect();
    let m = ok.len() as f64;
    let mean = ok.iter().map(|&i| dd.mean[i]).sum::<f64>() / m;
    let s2 = ok.iter().map(|&i| (dd.mean[i] - mean).powi(2)).sum::<f64>() / (m - 1.0);
    let temporal = ok.iter().map(|&i| dd.variance[i]).sum::<f64>() / m / dd.frames as f64;
    let dsnu2 = s2 - temporal;
    if dsnu2 <= 0.0 {
        return Err(EmvaError::Unphysical {
            what: "DSNU², DN²",
            value: dsnu2,
            hint: "the dark average's spatial variance is below its temporal noise: average more dark frames",
        });
    }
    let dsnu_dn = dsnu2.sqrt();
    let var_s2 = 2.0 * temporal * temporal / m + 4.0 * dsnu2 * temporal / m;
    let dsnu = dsnu_dn / k;
    let dsnu_sigma = dsnu * ((var_s2.sqrt() / (2.0 * dsnu2)).powi(2) + rel_k * rel_k).sqrt();

    let prnu = prnu(pb, pd, &hot, input.prnu_radius)?;

    Ok(EmvaResult {
        system_gain_dn_per_e: Estimate { value: k, sigma: k_sigma },
        read_noise_e: Estimate { value: read, sigma: read_sigma },
        dark_current_e_per_s: Estimate { value: dark_current, sigma: dark_current_sigma },
        dsnu_e: Estimate { value: dsnu, sigma: dsnu_sigma },
        dsnu_exposure_s: dd.exposure_s,
        prnu_pct: prnu,
        saturation_capacity_e: Estimate { value: sat_e, sigma: sat_e * rel_k },
        linearity_error_pct: Estimate { value: le, sigma: le_sigma },
        ptc_points: ptc.len(),
        hot_pixels,
    })
}

/// PRNU (%) from a lit and a dark average at the same exposure (see the module docs).
fn prnu(lit: &FrameAverage, dark: &FrameAverage, hot: &[bool], radius: usize) -> Result<Estimate, EmvaError> {
    let (w, h) = (lit.width, lit.height);
    // Same-colour neighbours are 2 photosites apart on a Bayer sensor, 1 on a monochrome one.
    let step = if lit.bayer.is_some() { 2 } else { 1 };
    let r = radius.max(1) as isize;
    let reach = r as usize * step;
    let signal: Vec<f64> = (0..w * h).map(|i| lit.mean[i] - dark.mean[i]).collect();
    let (mut sum, mut sum2, mut temporal, mut n, mut k_used) = (0.0, 0.0, 0.0, 0usize, 0.0);
    for y in reach..h.saturating_sub(reach) {
        for x in reach..w.saturating_sub(reach) {
            let i = y * w + x;
            if hot[i] || signal[i] <= 0.0 {
                continue;
            }
            let (mut s, mut k) = (0.0, 0usize);
            for dy in -r..=r {
                for dx in -r..=r {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let j =
                        ((y as isize + dy * step as isize) as usize) * w + (x as isize + dx * step as isize) as usize;
                    if !hot[j] {
                        s += signal[j];
                        k += 1;
                    }
                }
            }
            if k == 0 {
                continue;
            }
            let local = s / k as f64;
            let ratio = signal[i] / local;
            sum += ratio;
            sum2 += ratio * ratio;
            temporal += (lit.variance[i] / lit.frames as f64 + dark.variance[i] / dark.frames as f64) / (local * local);
            k_used += k as f64;
            n += 1;
        }
    }
    if n < 100 {
        return Err(EmvaError::TooFewPoints {
            what: "photosites for the PRNU",
            got: n,
            need: 100,
            hint: "the sensor is too small for the high-pass, or nearly every photosite is hot or dark",
        });
    }
    let nn = n as f64;
    let mean = sum / nn;
    let var = (sum2 / nn - mean * mean) * nn / (nn - 1.0);
    let temporal = temporal / nn;
    let k = k_used / nn;
    let prnu2 = (var - temporal * (1.0 + 1.0 / k)) / (1.0 + 1.0 / k);
    if prnu2 <= 0.0 {
        return Err(EmvaError::Unphysical {
            what: "PRNU²",
            value: prnu2,
            hint: "the lit average's spatial variance is below its temporal noise: average more lit frames",
        });
    }
    let p = prnu2.sqrt();
    let var_s2 = 2.0 * temporal * temporal / nn + 4.0 * prnu2 * temporal / nn;
    Ok(Estimate { value: 100.0 * p, sigma: 100.0 * var_s2.sqrt() / (2.0 * p) })
}

/// Version of the sensor plan and file formats.
pub const SENSOR_FORMAT_VERSION: u32 = 1;
/// The shipped plan.
pub const DEFAULT_SENSOR_PLAN: &str = include_str!("../../../rig-configs/plans/calibration-sensor.toml");

/// The photon-transfer series of a sensor plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtcPlan {
    /// Exposures, evenly spaced from the first step up to `max_fraction` of full scale
    /// (metered on the field's centre first) (>= 6).
    pub steps: usize,
    /// The longest exposure's signal, fraction of full scale (> 1, so the last points saturate).
    pub max_fraction: f64,
    /// Frames per exposure, lit and dark each (>= 2).
    pub frames: usize,
    /// The region of the temporal statistics, fraction of width and height (0 < f <= 1).
    pub centre_fraction: f64,
}

/// The long dark series of a sensor plan (dark current, read noise, DSNU).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DarkSeriesPlan {
    /// Exposures, s (>= 2 distinct; the longest is the DSNU's).
    pub exposures_s: Vec<f64>,
    /// Frames per exposure (>= 2; the DSNU average is the longest exposure's).
    pub frames: usize,
    /// Photosites with more dark current than this are hot, e⁻/s (> 0).
    pub hot_threshold_e_per_s: f64,
}

/// The spatial (PRNU) average of a sensor plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialPlan {
    /// Frames averaged, lit and dark each (>= 2).
    pub frames: usize,
    /// Signal on the field's centre, fraction of full scale (0.2..=0.8).
    pub level: f64,
    /// Half-width of the high-pass, same-colour photosites (1..=8).
    pub radius: usize,
}

/// A sensor characterisation plan (`rig-configs/plans/calibration-sensor.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorPlan {
    /// [`SENSOR_FORMAT_VERSION`].
    pub format_version: u32,
    /// Name, recorded in the file.
    pub name: String,
    /// Analogue gain of every frame (K is at this gain).
    pub gain: f64,
    /// The photon-transfer series on the uniform field.
    pub photon_transfer: PtcPlan,
    /// The dark series, lens capped.
    pub dark: DarkSeriesPlan,
    /// The PRNU average.
    pub spatial: SpatialPlan,
}

impl SensorPlan {
    /// The shipped plan.
    pub fn default_plan() -> SensorPlan {
        Self::from_toml(DEFAULT_SENSOR_PLAN, "<embedded rig-configs/plans/calibration-sensor.toml>")
            .expect("the shipped sensor plan is valid")
    }

    /// Parses and validates a plan; `origin` names the file in errors (every problem at once).
    pub fn from_toml(text: &str, origin: &str) -> Result<SensorPlan, String> {
        let plan: SensorPlan = toml::from_str(text).map_err(|e| format!("sensor plan {origin}: {e}"))?;
        let p = plan.problems();
        if p.is_empty() {
            Ok(plan)
        } else {
            Err(format!("sensor plan {origin}: {}", p.join("; ")))
        }
    }

    /// Everything wrong with the plan, each naming the field, the value and what is allowed.
    pub fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        let mut check = |ok: bool, field: &str, value: String, allowed: &str| {
            if !ok {
                p.push(format!("{field} = {value}: allowed {allowed}"));
            }
        };
        check(self.format_version == SENSOR_FORMAT_VERSION, "format_version", self.format_version.to_string(), "1");
        check(self.gain.is_finite() && self.gain >= 1.0, "gain", self.gain.to_string(), ">= 1");
        let t = &self.photon_transfer;
        check(t.steps >= 6 && t.steps <= 200, "photon_transfer.steps", t.steps.to_string(), "6..=200");
        check(
            t.max_fraction > 1.0 && t.max_fraction <= 3.0,
            "photon_transfer.max_fraction",
            t.max_fraction.to_string(),
            "(1, 3]",
        );
        check(t.frames >= 2, "photon_transfer.frames", t.frames.to_string(), ">= 2");
        check(
            t.centre_fraction > 0.0 && t.centre_fraction <= 1.0,
            "photon_transfer.centre_fraction",
            t.centre_fraction.to_string(),
            "(0, 1]",
        );
        let d = &self.dark;
        let mut ts = d.exposures_s.clone();
        ts.sort_by(f64::total_cmp);
        ts.dedup();
        check(
            ts.len() >= 2 && ts.iter().all(|&x| x > 0.0 && x <= 3600.0),
            "dark.exposures_s",
            format!("{:?}", d.exposures_s),
            ">= 2 distinct values in (0, 3600] s",
        );
        check(d.frames >= 2, "dark.frames", d.frames.to_string(), ">= 2");
        check(d.hot_threshold_e_per_s > 0.0, "dark.hot_threshold_e_per_s", d.hot_threshold_e_per_s.to_string(), "> 0");
        let s = &self.spatial;
        check(s.frames >= 2, "spatial.frames", s.frames.to_string(), ">= 2");
        check((0.2..=0.8).contains(&s.level), "spatial.level", s.level.to_string(), "0.2..=0.8");
        check((1..=8).contains(&s.radius), "spatial.radius", s.radius.to_string(), "1..=8");
        p
    }
}

/// The sensor calibration file (`btfrig calibrate sensor`; docs/emva1288.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorCalibrationFile {
    /// [`SENSOR_FORMAT_VERSION`].
    pub format_version: u32,
    /// The command and rig that made it.
    pub source: String,
    /// The plan's name.
    pub plan: String,
    /// Analogue gain of the series.
    pub gain: f64,
    /// The figures.
    pub result: EmvaResult,
}

impl SensorCalibrationFile {
    /// As TOML, with a header comment naming the command that made it.
    pub fn to_toml(&self) -> String {
        let body = toml::to_string_pretty(self).expect("a sensor calibration serialises");
        format!(
            "# Sensor characterisation after EMVA 1288 (format: docs/emva1288.md), made by:\n#   {}\n{body}",
            self.source
        )
    }

    /// Parses a file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<SensorCalibrationFile, String> {
        let f: SensorCalibrationFile = toml::from_str(text).map_err(|e| format!("sensor calibration {origin}: {e}"))?;
        if f.format_version != SENSOR_FORMAT_VERSION {
            return Err(format!("sensor calibration {origin}: format_version = {}: allowed 1", f.format_version));
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_through_exact_points_has_their_coefficients() {
        let pts: Vec<(f64, f64, f64)> = (0..5).map(|i| (i as f64, 2.0 + 3.0 * i as f64, 0.01)).collect();
        let l = fit_line(&pts);
        assert!((l.slope - 3.0).abs() < 1e-12 && (l.intercept - 2.0).abs() < 1e-12);
        // Exact points: the sigmas come from the points' own errors.
        assert!(l.slope_sigma > 0.0 && l.slope_sigma < 0.01);
    }

    #[test]
    fn the_centre_box_starts_on_whole_filter_cells() {
        let (x0, y0, x1, y1) = centre_box(101, 77, 0.25);
        assert_eq!((x0 % 2, y0 % 2), (0, 0));
        assert!(x1 > x0 + 1 && y1 > y0 + 1 && x1 <= 101 && y1 <= 77);
    }
}
