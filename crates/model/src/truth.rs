//! The truth an error figure is measured against, injected by the caller.
//!
//! Estimation never sees it: [`crate::ps::photometric_stereo`] takes frames' textures and
//! light directions only. A simulator (or a synthetic test) implements
//! [`SurfaceTruthProbe`]; the benches hand it to [`surface_errors`] after the estimate is
//! made, as a run hands its truth probe to the report and nothing else.

use serde::Serialize;

/// A rectangle of the sample plane, metres (row 0 along `y_max`, column 0 along `x_min`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Region {
    /// Left edge.
    pub x_min: f64,
    /// Right edge.
    pub x_max: f64,
    /// Bottom edge.
    pub y_min: f64,
    /// Top edge.
    pub y_max: f64,
}

/// The true surface over a texel grid.
#[derive(Debug, Clone)]
pub struct SurfaceTruth {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Unit normal per texel (the normalised mean over the texel's area).
    pub normal: Vec<[f64; 3]>,
    /// Mean height per texel, metres.
    pub height_m: Vec<f64>,
}

/// What knows the true surface (a simulated sample).
pub trait SurfaceTruthProbe {
    /// The true surface over `region` on a `width x height` texel grid.
    fn surface(&self, region: Region, width: usize, height: usize) -> SurfaceTruth;
}

/// Error figures of a normal and height estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SurfaceErrors {
    /// Mean angular error of the normals, degrees.
    pub normal_mean_deg: f64,
    /// Median, degrees.
    pub normal_median_deg: f64,
    /// 95th percentile, degrees.
    pub normal_p95_deg: f64,
    /// RMS height error (both maps zero-mean) over the true height range (max − min).
    pub height_rel_rmse: f64,
    /// The true height range, metres.
    pub height_range_m: f64,
    /// Mean predicted angular standard deviation, degrees (compare with the actual error).
    pub predicted_sigma_deg: f64,
}

/// Angle between two unit vectors, degrees (clamped, never NaN).
pub fn angle_deg(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
    d.acos().to_degrees()
}

/// Percentile `p` (0..=1) of `v` (sorted in place), nearest rank.
pub fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let k = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[k]
}

/// Compares estimated normals (and heights, if given) with the truth.
pub fn surface_errors(
    normal: &[[f64; 3]],
    height_m: Option<&[f64]>,
    sigma_deg: &[f32],
    truth: &SurfaceTruth,
) -> SurfaceErrors {
    let mut ang: Vec<f64> = normal.iter().zip(&truth.normal).map(|(a, b)| angle_deg(a, b)).collect();
    let mean = ang.iter().sum::<f64>() / ang.len().max(1) as f64;
    let median = percentile(&mut ang, 0.5);
    let p95 = percentile(&mut ang, 0.95);
    let (lo, hi) = truth.height_m.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
    let range = (hi - lo).max(0.0);
    let height_rel_rmse = match height_m {
        Some(h) => {
            let n = h.len().max(1) as f64;
            let me = h.iter().sum::<f64>() / n;
            let mt = truth.height_m.iter().sum::<f64>() / n;
            let mse = h.iter().zip(&truth.height_m).map(|(a, b)| ((a - me) - (b - mt)).powi(2)).sum::<f64>() / n;
            if range > 0.0 {
                mse.sqrt() / range
            } else {
                f64::NAN
            }
        }
        None => f64::NAN,
    };
    let predicted_sigma_deg = sigma_deg.iter().map(|s| f64::from(*s)).sum::<f64>() / sigma_deg.len().max(1) as f64;
    SurfaceErrors {
        normal_mean_deg: mean,
        normal_median_deg: median,
        normal_p95_deg: p95,
        height_rel_rmse,
        height_range_m: range,
        predicted_sigma_deg,
    }
}
