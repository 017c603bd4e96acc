//! Running totals of a pipeline: counts, stage times, error figures.

use std::collections::BTreeMap;

use btfrig_store::StepId;

use crate::light;

/// Texel position errors summed over frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TexelErrorTotals {
    /// Frames measured (with a finite error).
    pub frames: u64,
    /// Sum of the frames' mean errors, texels.
    pub sum_mean: f64,
    /// Largest error of any texel of any frame, texels.
    pub max: f64,
}

impl TexelErrorTotals {
    /// Adds one frame's `(mean, max)`; non-finite values (no texel measurable) are left out.
    pub fn add(&mut self, (mean, max): (f64, f64)) {
        if mean.is_finite() && max.is_finite() {
            self.frames += 1;
            self.sum_mean += mean;
            self.max = self.max.max(max);
        }
    }

    /// Adds another total.
    pub fn merge(&mut self, o: &TexelErrorTotals) {
        self.frames += o.frames;
        self.sum_mean += o.sum_mean;
        self.max = self.max.max(o.max);
    }

    /// Mean over frames of the per-frame mean error (every frame has the same texels, so
    /// this is the mean over all texels), `None` without frames.
    pub fn mean(&self) -> Option<f64> {
        (self.frames > 0).then(|| self.sum_mean / self.frames as f64)
    }

    /// The largest texel error, `None` without frames.
    pub fn max(&self) -> Option<f64> {
        (self.frames > 0).then_some(self.max)
    }
}

/// Running totals of a pipeline.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Totals {
    /// Steps committed.
    pub committed: u64,
    /// Retries (attempts beyond the first) of the committed steps.
    pub retries: u64,
    /// Seconds per stage, summed over frames (thread time, so stages of two frames in
    /// flight overlap in wall time).
    pub stage_s: BTreeMap<String, f64>,
    /// Sum of squared texture errors against the truth.
    pub sq_err: f64,
    /// Sum of squared truth.
    pub sq_truth: f64,
    /// Committed steps that had no recorded truth (not in the error figure).
    pub without_truth: u64,
    /// Previews written (`preview.png` replaced and the in-memory preview updated).
    pub previews: u64,
    /// Previews that failed to encode or write (not fatal: a preview is not data).
    pub preview_failures: u64,
    /// Committed textures rectified with a registered pose.
    pub registered: u64,
    /// Committed textures rectified with the nominal pose because registration failed.
    pub fallbacks: u64,
    /// Committed textures rectified with the nominal pose because the plan asked for it.
    pub nominal_by_plan: u64,
    /// The fallback steps with the reason registration failed, in commit order.
    pub fallback_steps: Vec<(StepId, String)>,
    /// Texel position error of the poses used, against the truth.
    pub texel_err: TexelErrorTotals,
    /// Texel position error of the nominal poses, against the truth.
    pub nominal_texel_err: TexelErrorTotals,
    /// Sum of squared texture errors had the nominal pose been used (only with
    /// [`Processor::with_nominal_comparison`](crate::Processor::with_nominal_comparison)).
    pub sq_err_nominal: f64,
    /// Sum of squared truth of the frames in `sq_err_nominal`.
    pub sq_truth_nominal: f64,
    /// Lamp factors measured on the plate and texture brightness against the truth at the
    /// nominal lamp.
    pub lamp: light::LampTotals,
}

impl Totals {
    /// `sqrt(sum sq_err / sum sq_truth)` over all compared textures, texels and channels.
    pub fn texture_rel_rmse(&self) -> Option<f64> {
        (self.sq_truth > 0.0).then(|| (self.sq_err / self.sq_truth).sqrt())
    }

    /// The same had every texture been rectified with the nominal pose (`None` unless the
    /// processor compared).
    pub fn texture_rel_rmse_nominal(&self) -> Option<f64> {
        (self.sq_truth_nominal > 0.0).then(|| (self.sq_err_nominal / self.sq_truth_nominal).sqrt())
    }
}
