//! Patch screening, CIEDE2000 statistics, cross-validation and model selection.

use crate::delta_e::delta_e_2000;
use crate::error::ColorError;
use crate::kind::ModelKind;
use crate::model::{ColorModel, FitOptions};
use crate::space::{linear_srgb_to_lab, xyz_to_lab};

/// The space a model's targets are in, which says how to turn them into L*a*b*.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TargetSpace {
    /// Linear sRGB, D65; Lab relative to its white (1, 1, 1).
    LinearSrgb,
    /// CIE XYZ with the given reference white (Y = 1) for Lab.
    Xyz {
        /// Reference white XYZ.
        white: [f64; 3],
    },
}

impl TargetSpace {
    /// L*a*b* of a target-space colour.
    pub fn to_lab(&self, v: [f64; 3]) -> [f64; 3] {
        match self {
            TargetSpace::LinearSrgb => linear_srgb_to_lab(v),
            TargetSpace::Xyz { white } => xyz_to_lab(v, *white),
        }
    }

    /// CIEDE2000 between two target-space colours.
    pub fn delta_e_2000(&self, a: [f64; 3], b: [f64; 3]) -> f64 {
        delta_e_2000(self.to_lab(a), self.to_lab(b))
    }
}

/// Summary of CIEDE2000 values over a set of patches.
///
/// Percentiles (median, p95) use linear interpolation between order statistics (Hyndman and
/// Fan's definition 7, numpy's default): for sorted values x₀ ≤ … ≤ x_{n−1} and fraction p,
/// h = (n − 1)·p and the percentile is x_⌊h⌋ + (h − ⌊h⌋)(x_⌊h⌋+1 − x_⌊h⌋).
#[derive(Debug, Clone, PartialEq)]
pub struct DeltaEStats {
    /// Mean.
    pub mean: f64,
    /// Median (50th percentile).
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Maximum.
    pub max: f64,
    /// ΔE00 per patch, in input order.
    pub per_patch: Vec<f64>,
}

/// Percentile `p` in [0, 1] of sorted values (definition 7, see [`DeltaEStats`]).
pub fn percentile_sorted(sorted: &[f64], p: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

impl DeltaEStats {
    /// Statistics of `per_patch` (in any order). Errors with [`ColorError::Empty`] for no
    /// values and [`ColorError::NonFinite`] for a NaN.
    pub fn from_values(per_patch: Vec<f64>) -> Result<DeltaEStats, ColorError> {
        if per_patch.is_empty() {
            return Err(ColorError::Empty);
        }
        if let Some((index, &value)) = per_patch.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ColorError::NonFinite { what: "delta_e", index, value });
        }
        let mut s = per_patch.clone();
        s.sort_by(f64::total_cmp);
        Ok(DeltaEStats {
            mean: s.iter().sum::<f64>() / s.len() as f64,
            median: percentile_sorted(&s, 0.5),
            p95: percentile_sorted(&s, 0.95),
            max: s[s.len() - 1],
            per_patch,
        })
    }
}

/// CIEDE2000 of `model` on (camera, target) pairs (e.g. held-out patches).
pub fn evaluate(
    model: &ColorModel,
    camera: &[[f64; 3]],
    target: &[[f64; 3]],
    space: TargetSpace,
) -> Result<DeltaEStats, ColorError> {
    if target.len() != camera.len() {
        return Err(ColorError::LengthMismatch { what: "target", expected: camera.len(), got: target.len() });
    }
    DeltaEStats::from_values(camera.iter().zip(target).map(|(c, t)| space.delta_e_2000(model.apply(*c), *t)).collect())
}

/// k-fold cross-validation of `kind` on the fitting set: sample i goes to fold `i % folds`
/// (interleaved, so a chart's rows of similar colours spread over the folds); each fold is
/// predicted by a model fitted on the others, and the out-of-fold CIEDE2000 values of all
/// samples with positive weight are pooled. `folds = camera.len()` is leave-one-out.
///
/// Errors: [`ColorError::InvalidOption`] for `folds` outside 2..=n, and the first fold's fit
/// error (e.g. [`ColorError::TooFewSamples`] when a fold leaves too few).
pub fn cross_validate(
    kind: ModelKind,
    camera: &[[f64; 3]],
    target: &[[f64; 3]],
    weights: Option<&[f64]>,
    options: &FitOptions,
    space: TargetSpace,
    folds: usize,
) -> Result<DeltaEStats, ColorError> {
    let n = camera.len();
    if target.len() != n {
        return Err(ColorError::LengthMismatch { what: "target", expected: n, got: target.len() });
    }
    if let Some(w) = weights {
        if w.len() != n {
            return Err(ColorError::LengthMismatch { what: "weights", expected: n, got: w.len() });
        }
    }
    if folds < 2 || folds > n {
        return Err(ColorError::InvalidOption {
            what: "folds",
            value: folds as f64,
            allowed: "2 ..= number of samples",
        });
    }
    let w_of = |i: usize| weights.map_or(1.0, |w| w[i]);
    let mut values = Vec::with_capacity(n);
    for f in 0..folds {
        let train_w: Vec<f64> = (0..n).map(|i| if i % folds == f { 0.0 } else { w_of(i) }).collect();
        let model = ColorModel::fit(kind, camera, target, Some(&train_w), options)?;
        for i in (f..n).step_by(folds) {
            if w_of(i) > 0.0 {
                values.push(space.delta_e_2000(model.apply(camera[i]), target[i]));
            }
        }
    }
    DeltaEStats::from_values(values)
}

/// One candidate of [`select_model`].
#[derive(Debug, Clone, PartialEq)]
pub struct ModelReport {
    /// The model family.
    pub kind: ModelKind,
    /// Its cross-validated CIEDE2000 on the fitting set, or why it failed.
    pub cv: Result<DeltaEStats, ColorError>,
    /// The model fitted on the whole fitting set, or why it failed.
    pub model: Result<ColorModel, ColorError>,
}

/// The outcome of [`select_model`]: every candidate (failures included, so a fallback is
/// visible) and the index of the chosen one.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// One report per candidate, in the order given.
    pub reports: Vec<ModelReport>,
    /// Index into `reports` of the chosen model: the lowest cross-validated mean ΔE00 among
    /// candidates whose fit and cross-validation both succeeded (ties: the earlier).
    pub chosen: Option<usize>,
}

impl Selection {
    /// The chosen candidate, or [`ColorError::NoUsableModel`] naming the first failure.
    pub fn best(&self) -> Result<(&ModelReport, &ColorModel), ColorError> {
        match self.chosen {
            Some(i) => {
                let r = &self.reports[i];
                Ok((r, r.model.as_ref().expect("chosen models fitted")))
            }
            None => {
                let first_error = self
                    .reports
                    .iter()
                    .find_map(|r| r.model.as_ref().err().or(r.cv.as_ref().err()))
                    .map_or_else(|| "no candidate models".to_string(), |e| e.to_string());
                Err(ColorError::NoUsableModel { first_error })
            }
        }
    }
}

/// Fits and cross-validates each of `kinds` on the fitting set and chooses the one with the
/// lowest cross-validated mean CIEDE2000 (see [`Selection::chosen`]). A candidate that cannot
/// be fitted (too few samples, ill-conditioned) is reported with its error and skipped: the
/// graceful fallback to a simpler model is explicit in [`Selection::reports`]. Evaluate the
/// chosen model on a separate held-out set with [`evaluate`].
pub fn select_model(
    kinds: &[ModelKind],
    camera: &[[f64; 3]],
    target: &[[f64; 3]],
    weights: Option<&[f64]>,
    options: &FitOptions,
    space: TargetSpace,
    folds: usize,
) -> Selection {
    let reports: Vec<ModelReport> = kinds
        .iter()
        .map(|&kind| ModelReport {
            kind,
            cv: cross_validate(kind, camera, target, weights, options, space, folds),
            model: ColorModel::fit(kind, camera, target, weights, options),
        })
        .collect();
    let mut chosen: Option<usize> = None;
    for (i, r) in reports.iter().enumerate() {
        if let (Ok(cv), Ok(_)) = (&r.cv, &r.model) {
            let better = match chosen {
                None => true,
                Some(j) => cv.mean < reports[j].cv.as_ref().expect("chosen has cv").mean,
            };
            if better {
                chosen = Some(i);
            }
        }
    }
    Selection { reports, chosen }
}

/// Thresholds of [`screen_patches`], in camera units where the sensor's full scale is 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScreenOptions {
    /// A channel at or above this level is treated as clipped (default 0.98: a patch mean a
    /// little below full scale already hides clipped pixels).
    pub saturation: f64,
    /// A patch whose largest channel mean is below this is too dark to carry colour
    /// (default 0.002: at the simulator's noise such a patch's chromaticity is mostly noise).
    pub dark: f64,
}

impl Default for ScreenOptions {
    fn default() -> Self {
        ScreenOptions { saturation: 0.98, dark: 0.002 }
    }
}

/// Why a patch may or may not be used for fitting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PatchStatus {
    /// Usable.
    Valid,
    /// A channel value is NaN or infinite.
    NonFinite {
        /// The channel (0 = R).
        channel: usize,
    },
    /// A channel reaches the saturation level (its mean, or its brightest pixel when peaks
    /// are given): the patch's colour is distorted.
    Clipped {
        /// The channel (0 = R).
        channel: usize,
        /// The value that reached the level.
        value: f64,
    },
    /// Every channel is below the dark level.
    Dark {
        /// The largest channel mean.
        max: f64,
    },
}

impl PatchStatus {
    /// Whether the patch can be used.
    pub fn is_valid(&self) -> bool {
        matches!(self, PatchStatus::Valid)
    }
}

/// Flags patches that should not be fitted: non-finite, clipped, or too dark. `means` are the
/// patches' mean camera RGB; `peaks` (optional) their brightest pixel per channel, which
/// catches a patch that is only partly clipped (its mean can stay below the level).
/// Use [`valid_indices`] or weights of 0 to exclude them from [`ColorModel::fit`].
pub fn screen_patches(means: &[[f64; 3]], peaks: Option<&[[f64; 3]]>, options: &ScreenOptions) -> Vec<PatchStatus> {
    means
        .iter()
        .enumerate()
        .map(|(i, m)| {
            if let Some(channel) = m.iter().position(|v| !v.is_finite()) {
                return PatchStatus::NonFinite { channel };
            }
            let probe = peaks.and_then(|p| p.get(i)).unwrap_or(m);
            if let Some(channel) = (0..3).find(|&c| probe[c] >= options.saturation || m[c] >= options.saturation) {
                return PatchStatus::Clipped { channel, value: probe[channel].max(m[channel]) };
            }
            let max = m.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            if max < options.dark {
                return PatchStatus::Dark { max };
            }
            PatchStatus::Valid
        })
        .collect()
}

/// Indices of the valid patches.
pub fn valid_indices(status: &[PatchStatus]) -> Vec<usize> {
    status.iter().enumerate().filter(|(_, s)| s.is_valid()).map(|(i, _)| i).collect()
}

/// Fit weights from a screening: 1 for valid patches, 0 for flagged ones (pass to
/// [`ColorModel::fit`], [`cross_validate`] or [`select_model`]).
pub fn screen_weights(status: &[PatchStatus]) -> Vec<f64> {
    status.iter().map(|s| if s.is_valid() { 1.0 } else { 0.0 }).collect()
}
