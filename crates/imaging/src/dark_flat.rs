//! Dark and flat fields: the per-photosite dark model and relative gain measured from averaged
//! raw frames, and the correction of a raw frame with them (no I/O; the capture procedure is
//! `btfrig_calibrate::dark_flat`, the file format and figures `docs/dark-flat.md`).
//!
//! Dark model, fitted per photosite by weighted least squares over averaged dark frames
//! (lamp shutter closed) at several exposure times and gains:
//!
//! ```text
//! dark_dn(x, y, t, g) = bias(x, y) + rate(x, y) · t · g / electrons_per_dn      [DN]
//! ```
//!
//! `bias` holds the black level and any column offset, `rate` the photosite's dark current
//! (e-/s, hot photosites included). Because it is a model in `t · g`, it covers any exposure
//! the exposure policy picks. Photosites whose dark current exceeds a threshold are flagged as
//! defects ("hot") and replaced by their same-colour neighbours in the corrected frame, since
//! their dark shot noise stays even after the mean is subtracted.
//!
//! Master flat per f-number: the mean of N frames of a uniform-radiance field minus the dark
//! model, divided per colour channel by its mean over a centre box, so it is 1 at the centre
//! and holds vignetting × PRNU:
//!
//! ```text
//! flat(x, y) = (mean_DN(x, y) - dark_dn(x, y, t, g)) / centre_mean_c
//! ```
//!
//! Correction of a frame, and the canonical linear intermediate (what the HDR merge combines):
//!
//! ```text
//! rate(x, y) = (DN - dark_dn(x, y, t, g)) · electrons_per_dn / g / t / flat(x, y)      [e-/s]
//! ```

use btfrig_core::frame::{BayerPattern, RawFrame};
use rayon::prelude::*;

/// Why a dark/flat calibration or correction cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DarkFlatError {
    /// No frames were given where some are needed.
    #[error("{what}: no frames")]
    NoFrames {
        /// What the frames were for.
        what: &'static str,
    },
    /// A frame differs from the first in size or settings.
    #[error("{what}: frame {index} has {got}, expected {expected}")]
    Inconsistent {
        /// What the frames were for.
        what: &'static str,
        /// Index of the offending frame.
        index: usize,
        /// What it has.
        got: String,
        /// What the first frame has.
        expected: String,
    },
    /// The dark fit needs at least two distinct values of `exposure · gain`.
    #[error("dark model: {distinct} distinct exposure x gain value(s) ({settings}); need at least 2")]
    TooFewSettings {
        /// Distinct `t · g` values found.
        distinct: usize,
        /// The settings given.
        settings: String,
    },
    /// A frame and the calibration disagree in size.
    #[error("frame is {got_w}x{got_h} photosites, the calibration {cal_w}x{cal_h}")]
    SizeMismatch {
        /// Frame width.
        got_w: usize,
        /// Frame height.
        got_h: usize,
        /// Calibration width.
        cal_w: usize,
        /// Calibration height.
        cal_h: usize,
    },
    /// No master flat for the frame's f-number.
    #[error("no master flat for f-number {wanted}; calibrated: {available}")]
    NoFlat {
        /// The frame's f-number (or "unknown").
        wanted: String,
        /// The f-numbers calibrated.
        available: String,
    },
    /// A parameter is out of range.
    #[error("{name} = {value} is out of range: {allowed}")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// The flat's centre box has no signal in a channel.
    #[error("master flat: channel {channel} has centre mean {mean} DN above dark; the flat level is too low")]
    NoFlatSignal {
        /// Channel 0 R, 1 G, 2 B.
        channel: usize,
        /// Its centre mean.
        mean: f64,
    },
}

/// The per-photosite mean and sample variance of N frames taken with the same settings.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameAverage {
    /// Width, photosites.
    pub width: usize,
    /// Height, photosites.
    pub height: usize,
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Analogue gain.
    pub gain: f64,
    /// Frames averaged.
    pub frames: usize,
    /// Mean DN per photosite.
    pub mean: Vec<f64>,
    /// Sample variance of one frame's DN per photosite (N - 1 in the denominator; 0 for one frame).
    pub variance: Vec<f64>,
    /// Photosites that reached the white level in any frame (their mean is clipped).
    pub saturated: Vec<bool>,
    /// The frames' colour filter array.
    pub bayer: Option<BayerPattern>,
}

impl FrameAverage {
    /// Averages `frames` (all the same size, exposure and gain).
    pub fn of(frames: &[RawFrame], what: &'static str) -> Result<FrameAverage, DarkFlatError> {
        let first = frames.first().ok_or(DarkFlatError::NoFrames { what })?;
        let (w, h) = (first.width, first.height);
        let (t, g) = (first.meta.exposure_s, first.meta.gain);
        for (index, f) in frames.iter().enumerate() {
            if f.width != w || f.height != h || f.meta.exposure_s != t || f.meta.gain != g || f.data.len() != w * h {
                return Err(DarkFlatError::Inconsistent {
                    what,
                    index,
                    got: format!("{}x{}, {} s, gain {}", f.width, f.height, f.meta.exposure_s, f.meta.gain),
                    expected: format!("{w}x{h}, {t} s, gain {g}"),
                });
            }
        }
        let n = frames.len();
        let mut mean = vec![0.0; w * h];
        let mut variance = vec![0.0; w * h];
        let mut saturated = vec![false; w * h];
        mean.par_iter_mut().zip(variance.par_iter_mut()).zip(saturated.par_iter_mut()).enumerate().for_each(
            |(i, ((m, v), s))| {
                // Two passes over N values per photosite: exact, and N is small.
                let mu = frames.iter().map(|f| f64::from(f.data[i])).sum::<f64>() / n as f64;
                *m = mu;
                if n > 1 {
                    *v = frames.iter().map(|f| (f64::from(f.data[i]) - mu).powi(2)).sum::<f64>() / (n - 1) as f64;
                }
                *s = frames.iter().any(|f| f.data[i] >= f.meta.white_level);
            },
        );
        Ok(FrameAverage {
            width: w,
            height: h,
            exposure_s: t,
            gain: g,
            frames: n,
            mean,
            variance,
            saturated,
            bayer: first.meta.bayer,
        })
    }
}

/// The fitted per-photosite dark model (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DarkModel {
    /// Width, photosites.
    pub width: usize,
    /// Height, photosites.
    pub height: usize,
    /// Electrons per DN at gain 1 (the sensor's conversion gain the model is expressed in).
    pub electrons_per_dn: f64,
    /// Bias (DN at zero exposure) per photosite.
    pub bias_dn: Vec<f32>,
    /// Dark current per photosite, e-/s.
    pub rate_e_per_s: Vec<f32>,
    /// Standard error of each photosite's bias, DN.
    pub bias_sigma_dn: Vec<f32>,
    /// Standard error of each photosite's dark current, e-/s.
    pub rate_sigma_e_per_s: Vec<f32>,
    /// Defective photosites: dark current above the hot threshold, or too few unsaturated
    /// dark averages to fit; replaced by neighbours in corrected frames.
    pub defect: Vec<bool>,
    /// The hot threshold used, e-/s.
    pub hot_threshold_e_per_s: f64,
}

impl DarkModel {
    /// Fits the model to dark averages at >= 2 distinct `exposure · gain` values. Each
    /// average is weighted per photosite by `frames / variance` (variance floored at the
    /// quantisation's 1/12 DN²), so short, quiet exposures pin the bias and long ones the rate.
    /// Photosites with a dark current above `hot_threshold_e_per_s` are flagged as defects.
    pub fn fit(
        averages: &[FrameAverage],
        electrons_per_dn: f64,
        hot_threshold_e_per_s: f64,
    ) -> Result<DarkModel, DarkFlatError> {
        if !(electrons_per_dn.is_finite() && electrons_per_dn > 0.0) {
            return Err(DarkFlatError::OutOfRange {
                name: "electrons_per_dn",
                value: electrons_per_dn,
                allowed: "finite and > 0",
            });
        }
        if !(hot_threshold_e_per_s > 0.0) {
            return Err(DarkFlatError::OutOfRange {
                name: "hot_threshold_e_per_s",
                value: hot_threshold_e_per_s,
                allowed: "> 0",
            });
        }
        let first = averages.first().ok_or(DarkFlatError::NoFrames { what: "dark model" })?;
        let (w, h) = (first.width, first.height);
        if let Some((index, a)) = averages.iter().enumerate().find(|(_, a)| a.width != w || a.height != h) {
            return Err(DarkFlatError::Inconsistent {
                what: "dark model",
                index,
                got: format!("{}x{}", a.width, a.height),
                expected: format!("{w}x{h}"),
            });
        }
        // u = t · g / e_per_dn: DN per (e-/s) of dark current.
        let u: Vec<f64> = averages.iter().map(|a| a.exposure_s * a.gain / electrons_per_dn).collect();
        let mut distinct = u.clone();
        distinct.sort_by(f64::total_cmp);
        distinct.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * b.abs().max(1e-300));
        if distinct.len() < 2 {
            let settings =
                averages.iter().map(|a| format!("{} s x gain {}", a.exposure_s, a.gain)).collect::<Vec<_>>().join(", ");
            return Err(DarkFlatError::TooFewSettings { distinct: distinct.len(), settings });
        }
        let n = w * h;
        let mut out: Vec<(f32, f32, f32, f32, bool)> = vec![(0.0, 0.0, 0.0, 0.0, false); n];
        out.par_iter_mut().enumerate().for_each(|(i, o)| {
            // Weighted least squares of mean = b + r u over the unsaturated averages.
            let (mut s0, mut s1, mut s2, mut sy, mut suy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            let mut us = Vec::with_capacity(u.len());
            for (a, &ui) in averages.iter().zip(&u) {
                if a.saturated[i] {
                    continue;
                }
                let var = a.variance[i].max(1.0 / 12.0);
                let wgt = a.frames as f64 / var;
                s0 += wgt;
                s1 += wgt * ui;
                s2 += wgt * ui * ui;
                sy += wgt * a.mean[i];
                suy += wgt * ui * a.mean[i];
                us.push(ui);
            }
            us.sort_by(f64::total_cmp);
            let spread = us.last().zip(us.first()).map_or(0.0, |(hi, lo)| hi - lo);
            let det = s0 * s2 - s1 * s1;
            if us.len() < 2 || spread <= 0.0 || !(det > 0.0) {
                *o = (f32::NAN, 0.0, f32::INFINITY, f32::INFINITY, true);
                return;
            }
            let rate = (s0 * suy - s1 * sy) / det;
            let bias = (s2 * sy - s1 * suy) / det;
            // Covariance of (b, r) is the inverse normal matrix when weights are 1/variance.
            let (sb, sr) = ((s2 / det).sqrt(), (s0 / det).sqrt());
            *o = (bias as f32, rate as f32, sb as f32, sr as f32, rate > hot_threshold_e_per_s);
        });
        // A photosite that could not be fitted takes the median bias (it is replaced anyway).
        let mut biases: Vec<f32> = out.iter().map(|o| o.0).filter(|b| b.is_finite()).collect();
        biases.sort_by(f32::total_cmp);
        let median_bias = biases.get(biases.len() / 2).copied().unwrap_or(0.0);
        Ok(DarkModel {
            width: w,
            height: h,
            electrons_per_dn,
            bias_dn: out.iter().map(|o| if o.0.is_finite() { o.0 } else { median_bias }).collect(),
            rate_e_per_s: out.iter().map(|o| o.1).collect(),
            bias_sigma_dn: out.iter().map(|o| o.2).collect(),
            rate_sigma_e_per_s: out.iter().map(|o| o.3).collect(),
            defect: out.iter().map(|o| o.4).collect(),
            hot_threshold_e_per_s,
        })
    }

    /// The dark DN of photosite index `i` (row-major) at an exposure and gain.
    pub fn dark_dn(&self, i: usize, exposure_s: f64, gain: f64) -> f64 {
        f64::from(self.bias_dn[i]) + f64::from(self.rate_e_per_s[i]) * exposure_s * gain / self.electrons_per_dn
    }

    /// Photosites flagged as defects.
    pub fn defects(&self) -> usize {
        self.defect.iter().filter(|&&d| d).count()
    }
}

/// A master flat: per-photosite relative gain (vignetting × PRNU), 1 at the centre per channel.
#[derive(Debug, Clone, PartialEq)]
pub struct FlatField {
    /// Width, photosites.
    pub width: usize,
    /// Height, photosites.
    pub height: usize,
    /// The f-number the flat was taken at.
    pub f_number: f64,
    /// Relative gain per photosite.
    pub gain: Vec<f32>,
    /// Standard error of each photosite's relative gain (from the frames' spread).
    pub sigma: Vec<f32>,
    /// Mean signal over the centre box per channel, DN above dark.
    pub centre_level_dn: [f64; 3],
    /// Frames averaged.
    pub frames: usize,
}

impl FlatField {
    /// The master flat of `avg` (frames of a uniform-radiance field) at `f_number`: the
    /// average minus `dark` at its exposure and gain, divided per channel by the channel's
    /// mean over the centre box (`centre_fraction` of width and height, 0 < f <= 1).
    pub fn fit(
        avg: &FrameAverage,
        dark: &DarkModel,
        f_number: f64,
        centre_fraction: f64,
    ) -> Result<FlatField, DarkFlatError> {
        let (w, h) = (avg.width, avg.height);
        if (w, h) != (dark.width, dark.height) {
            return Err(DarkFlatError::SizeMismatch { got_w: w, got_h: h, cal_w: dark.width, cal_h: dark.height });
        }
        if !(centre_fraction > 0.0 && centre_fraction <= 1.0) {
            return Err(DarkFlatError::OutOfRange {
                name: "centre_fraction",
                value: centre_fraction,
                allowed: "0 < f <= 1",
            });
        }
        let channel = |x: usize, y: usize| avg.bayer.map_or(1, |b| b.channel_at(x, y));
        let signal: Vec<f64> = (0..w * h).map(|i| avg.mean[i] - dark.dark_dn(i, avg.exposure_s, avg.gain)).collect();
        // Centre box, at least 2 x 2 so every Bayer channel is in it.
        let (bw, bh) = (((w as f64 * centre_fraction) as usize).max(2), ((h as f64 * centre_fraction) as usize).max(2));
        let (x0, y0) = ((w - bw.min(w)) / 2, (h - bh.min(h)) / 2);
        let (mut sum, mut count) = ([0.0f64; 3], [0usize; 3]);
        for y in y0..(y0 + bh).min(h) {
            for x in x0..(x0 + bw).min(w) {
                let i = y * w + x;
                if !dark.defect[i] && !avg.saturated[i] {
                    sum[channel(x, y)] += signal[i];
                    count[channel(x, y)] += 1;
                }
            }
        }
        let mut level = [0.0; 3];
        let used: Vec<usize> = if avg.bayer.is_some() { vec![0, 1, 2] } else { vec![1] };
        for &c in &used {
            level[c] = sum[c] / count[c].max(1) as f64;
            if !(level[c] > 0.0) {
                return Err(DarkFlatError::NoFlatSignal { channel: c, mean: level[c] });
            }
        }
        if avg.bayer.is_none() {
            level = [level[1]; 3];
        }
        let n = avg.frames.max(1) as f64;
        let mut gain = vec![0.0f32; w * h];
        let mut sigma = vec![0.0f32; w * h];
        gain.par_chunks_mut(w).zip(sigma.par_chunks_mut(w)).enumerate().for_each(|(y, (g, s))| {
            for x in 0..w {
                let i = y * w + x;
                let l = level[channel(x, y)];
                g[x] = (signal[i] / l) as f32;
                s[x] = ((avg.variance[i] / n).sqrt() / l) as f32;
            }
        });
        Ok(FlatField { width: w, height: h, f_number, gain, sigma, centre_level_dn: level, frames: avg.frames })
    }

    /// RMS of the per-photosite standard error, relative (the flat's noise).
    pub fn rms_sigma(&self) -> f64 {
        (self.sigma.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / self.sigma.len().max(1) as f64).sqrt()
    }
}

/// A dark model and the master flats of a camera: what the pipeline corrects frames with.
#[derive(Debug, Clone, PartialEq)]
pub struct DarkFlat {
    /// The dark model.
    pub dark: DarkModel,
    /// One master flat per f-number.
    pub flats: Vec<FlatField>,
}

impl DarkFlat {
    /// The master flat for `f_number`: the one within 1% of it; with `None` (a frame that does
    /// not say), the only flat if there is exactly one.
    pub fn flat_for(&self, f_number: Option<f64>) -> Result<&FlatField, DarkFlatError> {
        let found = match f_number {
            Some(n) => self.flats.iter().find(|f| (f.f_number - n).abs() <= 0.01 * n.abs()),
            None if self.flats.len() == 1 => self.flats.first(),
            None => None,
        };
        found.ok_or_else(|| DarkFlatError::NoFlat {
            wanted: f_number.map_or("unknown".to_string(), |n| n.to_string()),
            available: self.flats.iter().map(|f| f.f_number.to_string()).collect::<Vec<_>>().join(", "),
        })
    }

    /// Dark-subtracted, flat-fielded DN per photosite, row-major: `(DN - dark_dn) / flat`, with
    /// defective photosites replaced by the mean of their non-defective same-colour
    /// neighbours two photosites away (one for a monochrome sensor).
    pub fn corrected_dn(&self, frame: &RawFrame) -> Result<Vec<f32>, DarkFlatError> {
        let (w, h) = (frame.width, frame.height);
        let d = &self.dark;
        if (w, h) != (d.width, d.height) || frame.data.len() != w * h {
            return Err(DarkFlatError::SizeMismatch { got_w: w, got_h: h, cal_w: d.width, cal_h: d.height });
        }
        let flat = self.flat_for(frame.meta.f_number)?;
        if (flat.width, flat.height) != (w, h) {
            return Err(DarkFlatError::SizeMismatch { got_w: w, got_h: h, cal_w: flat.width, cal_h: flat.height });
        }
        let (t, g) = (frame.meta.exposure_s, frame.meta.gain);
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let i = y * w + x;
                // A flat near 0 (a dead or fully vignetted photosite) would blow up: treat it
                // as a defect below.
                let f = flat.gain[i];
                *o = if f > MIN_FLAT {
                    ((f64::from(frame.data[i]) - d.dark_dn(i, t, g)) / f64::from(f)) as f32
                } else {
                    f32::NAN
                };
            }
        });
        replace_defects(&mut out, w, h, frame.meta.bayer.is_some(), &d.defect);
        Ok(out)
    }

    /// The dark model and the flat for `f_number` as the per-photosite calibration of an HDR
    /// merge or a metering ([`crate::hdr::PhotositeCalibration`]); photosites the merge cannot
    /// trust (defects, a flat near 0) are for [`MeasuredCalibration::replace_defects`] to
    /// fill afterwards.
    pub fn merge_calibration(&self, f_number: Option<f64>) -> Result<MeasuredCalibration<'_>, DarkFlatError> {
        let d = &self.dark;
        let flat = self.flat_for(f_number)?;
        if (flat.width, flat.height) != (d.width, d.height) {
            return Err(DarkFlatError::SizeMismatch {
                got_w: flat.width,
                got_h: flat.height,
                cal_w: d.width,
                cal_h: d.height,
            });
        }
        Ok(MeasuredCalibration { dark: d, flat })
    }
}

/// A flat below this is a dead or fully vignetted photosite: its value is replaced, not divided.
const MIN_FLAT: f32 = 0.05;

/// A measured dark model and master flat seen through [`crate::hdr::PhotositeCalibration`].
#[derive(Debug, Clone, Copy)]
pub struct MeasuredCalibration<'a> {
    dark: &'a DarkModel,
    flat: &'a FlatField,
}

impl MeasuredCalibration<'_> {
    /// Replaces the values of defective photosites (and of those with a flat near 0, or a
    /// non-finite value) in a row-major per-photosite image of the calibration's size by the
    /// mean of their good same-colour neighbours, as [`DarkFlat::corrected_dn`] does.
    pub fn replace_defects(&self, values: &mut [f32], bayer: bool) {
        let bad: Vec<bool> = self.dark.defect.iter().zip(&self.flat.gain).map(|(&d, &f)| d || f <= MIN_FLAT).collect();
        replace_defects(values, self.dark.width, self.dark.height, bayer, &bad);
    }
}

impl crate::hdr::PhotositeCalibration for MeasuredCalibration<'_> {
    fn dark_dn(&self, x: usize, y: usize, meta: &btfrig_core::frame::FrameMeta) -> f64 {
        self.dark.dark_dn(y * self.dark.width + x, meta.exposure_s, meta.gain)
    }
    fn dark_electrons(&self, x: usize, y: usize, meta: &btfrig_core::frame::FrameMeta) -> f64 {
        f64::from(self.dark.rate_e_per_s[y * self.dark.width + x]).max(0.0) * meta.exposure_s
    }
    fn flat(&self, x: usize, y: usize) -> f64 {
        let f = self.flat.gain[y * self.flat.width + x];
        // Replaced afterwards (replace_defects); 1 keeps the merge finite meanwhile.
        if f > MIN_FLAT {
            f64::from(f)
        } else {
            1.0
        }
    }
}

/// Replaces `values[i]` where `defect[i]` or the value is not finite by the mean of the good
/// same-colour neighbours two photosites away (one for a mono sensor), 0 if there is none.
fn replace_defects(values: &mut [f32], w: usize, h: usize, bayer: bool, defect: &[bool]) {
    let step = if bayer { 2 } else { 1 };
    let bad = |i: usize| defect[i] || !values[i].is_finite();
    let fixes: Vec<(usize, f32)> = (0..w * h)
        .into_par_iter()
        .filter(|&i| bad(i))
        .map(|i| {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let (mut sum, mut k) = (0.0f32, 0u32);
            for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)] {
                let (xx, yy) = (x + dx * step, y + dy * step);
                if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
                    let j = yy as usize * w + xx as usize;
                    if !bad(j) {
                        sum += values[j];
                        k += 1;
                    }
                }
            }
            (i, if k > 0 { sum / k as f32 } else { 0.0 })
        })
        .collect();
    for (i, v) in fixes {
        values[i] = v;
    }
}

/// The canonical linear intermediate: per-photosite signal rate, e-/s, of `frame` corrected
/// with `cal` (see the module docs), defects replaced by neighbours. Saturated photosites are
/// NOT marked here: the caller tells them by `frame.data[i] >= frame.meta.white_level`.
pub fn photosite_rates(frame: &RawFrame, cal: &DarkFlat) -> Result<Vec<f32>, DarkFlatError> {
    let (t, g) = (frame.meta.exposure_s, frame.meta.gain);
    if !(t.is_finite() && t > 0.0) {
        return Err(DarkFlatError::OutOfRange { name: "exposure_s", value: t, allowed: "finite and > 0" });
    }
    if !(g.is_finite() && g > 0.0) {
        return Err(DarkFlatError::OutOfRange { name: "gain", value: g, allowed: "finite and > 0" });
    }
    let k = (cal.dark.electrons_per_dn / g / t) as f32;
    let mut v = cal.corrected_dn(frame)?;
    v.par_iter_mut().for_each(|x| *x *= k);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::frame::FrameMeta;

    fn frame(w: usize, h: usize, t: f64, g: f64, f: impl Fn(usize, usize) -> u16) -> RawFrame {
        RawFrame {
            width: w,
            height: h,
            data: (0..w * h).map(|i| f(i % w, i / w)).collect(),
            meta: FrameMeta {
                sequence: 0,
                exposure_s: t,
                gain: g,
                f_number: Some(8.0),
                black_level: 100,
                white_level: 4000,
                bit_depth: 12,
                bayer: Some(BayerPattern::Rggb),
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn noise_free_dark_and_flat_are_recovered_and_a_frame_is_corrected_exactly() {
        // bias 100 + x, rate 10 y e-/s (e_per_dn 2): dark DN = 100 + x + 5 y t g; (2,2) is hot.
        let (w, h) = (8, 6);
        let rate = |x: usize, y: usize| if (x, y) == (2, 2) { 500.0 } else { 10.0 * y as f64 };
        let dark_dn = |x: usize, y: usize, t: f64, g: f64| 100.0 + x as f64 + rate(x, y) * t * g / 2.0;
        let darks: Vec<FrameAverage> = [(1.0, 1.0), (2.0, 1.0), (1.0, 4.0)]
            .iter()
            .map(|&(t, g)| FrameAverage::of(&[frame(w, h, t, g, |x, y| dark_dn(x, y, t, g) as u16)], "dark").unwrap())
            .collect();
        let dark = DarkModel::fit(&darks, 2.0, 100.0).unwrap();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                assert!((f64::from(dark.bias_dn[i]) - 100.0 - x as f64).abs() < 1e-3, "({x},{y})");
                assert!((f64::from(dark.rate_e_per_s[i]) - rate(x, y)).abs() < 1e-3, "({x},{y})");
            }
        }
        assert_eq!(dark.defects(), 1);
        assert!(dark.defect[2 * w + 2]);
        // Flat: gain 1 - 0.01 r² around the centre; signal 2000 DN at gain 1.
        let rel = |x: usize, y: usize| 1.0 - 0.01 * ((x as f64 - 3.5).powi(2) + (y as f64 - 2.5).powi(2));
        let flat_frame = frame(w, h, 0.1, 1.0, |x, y| (dark_dn(x, y, 0.1, 1.0) + 2000.0 * rel(x, y)).round() as u16);
        let avg = FrameAverage::of(&[flat_frame], "flat").unwrap();
        let flat = FlatField::fit(&avg, &dark, 8.0, 0.25).unwrap();
        // The centre box (2 x 2 at 25%) has rel 0.995 everywhere: the flat is rel / 0.995.
        for i in [0, 13, 47] {
            let (x, y) = (i % w, i / w);
            assert!((f64::from(flat.gain[i]) - rel(x, y) / 0.995).abs() < 1e-3, "{i}");
        }
        let cal = DarkFlat { dark, flats: vec![flat] };
        // A scene of 300 e-/s everywhere at t = 2 s, gain 2: DN = dark + 300 · 2 · 2 / 2 · rel.
        let f = frame(w, h, 2.0, 2.0, |x, y| (dark_dn(x, y, 2.0, 2.0) + 600.0 * rel(x, y) / 0.995).round() as u16);
        let r = photosite_rates(&f, &cal).unwrap();
        assert!(r.iter().all(|&v| (v - 300.0).abs() < 1.0), "{r:?}");
        // The same calibration in an HDR merge: a bracket of the scene at 2 s and 0.25 s gives
        // the same rates (the hot photosite replaced by its neighbours afterwards).
        let short = frame(w, h, 0.25, 2.0, |x, y| (dark_dn(x, y, 0.25, 2.0) + 75.0 * rel(x, y) / 0.995).round() as u16);
        let mc = cal.merge_calibration(Some(8.0)).unwrap();
        let noise = crate::hdr::NoiseModel { electrons_per_dn: 2.0, read_noise_e: 3.0 };
        let mut m = crate::hdr::merge_bracket(&[&f, &short], &mc, &noise, &Default::default()).unwrap();
        mc.replace_defects(&mut m.rate, true);
        assert!(m.rate.iter().all(|&v| (v - 300.0).abs() < 1.0), "{:?}", m.rate);
        assert!(cal.merge_calibration(Some(4.0)).is_err());
        // Errors name the problem.
        let mut other = f.clone();
        other.meta.f_number = Some(4.0);
        assert!(photosite_rates(&other, &cal).unwrap_err().to_string().contains("f-number 4; calibrated: 8"));
        let e = DarkModel::fit(&darks[..1], 2.0, 100.0).unwrap_err().to_string();
        assert!(e.contains("1 distinct"), "{e}");
    }
}
