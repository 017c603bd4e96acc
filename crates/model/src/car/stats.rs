//! Texture statistics that a probabilistic model promises to keep (seed 002: "the same visual
//! impression without pixel-wise correspondence"), and distances between two textures' ones:
//!
//! - per channel mean and variance, and the correlation coefficients between the channels
//!   (R-G, R-B, G-B: what the spectral factorisation has to give back);
//! - the normalised autocorrelation `ρ(k) = cov(Y_r, Y_{r+k}) / var` at lags 1..[`MAX_LAG`]
//!   along x and along y (mirror-free: only pairs inside the texture); its distance is the
//!   RMS difference over channels, axes and lags;
//! - the histogram distance: per channel the earth mover's distance (1D Wasserstein-1,
//!   `∫ |F_a⁻¹ − F_b⁻¹|`, on 256 quantiles), divided by the reference channel's standard
//!   deviation (a shift by one standard deviation is 1).

use serde::Serialize;

/// Lags of the autocorrelation.
pub const MAX_LAG: usize = 8;

/// Quantiles kept for the histogram distance.
const QUANTILES: usize = 256;

/// One texture's statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TextureStats {
    /// Mean per channel.
    pub mean: [f64; 3],
    /// Variance per channel.
    pub variance: [f64; 3],
    /// Correlation coefficients R-G, R-B, G-B.
    pub correlation: [f64; 3],
    /// `ρ(k)` along x, per channel, lags 1..=MAX_LAG.
    pub acf_x: [[f64; MAX_LAG]; 3],
    /// `ρ(k)` along y.
    pub acf_y: [[f64; MAX_LAG]; 3],
    /// Quantiles per channel at `(i + 0.5) / 256`.
    #[serde(skip)]
    pub quantiles: [Vec<f64>; 3],
}

/// How far a texture's statistics are from a reference's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StatsDistance {
    /// Largest `|μ − μ_ref| / μ_ref` over the channels.
    pub mean_rel: f64,
    /// `var / var_ref` per channel.
    pub variance_ratio: [f64; 3],
    /// Largest difference of the channels' correlation coefficients.
    pub correlation_diff: f64,
    /// RMS difference of the normalised autocorrelations.
    pub acf_rms: f64,
    /// Largest per-channel EMD over the reference's standard deviation.
    pub emd_rel: f64,
}

impl StatsDistance {
    /// The variance ratio furthest from 1, as a factor (`max(r, 1/r)`).
    pub fn worst_variance_factor(&self) -> f64 {
        self.variance_ratio.iter().map(|r| if *r >= 1.0 { *r } else { 1.0 / r.max(1e-300) }).fold(1.0, f64::max)
    }
}

/// The statistics of a `width x height` colour texture.
pub fn stats(width: usize, height: usize, image: &[[f32; 3]]) -> TextureStats {
    let n = image.len().max(1) as f64;
    let mut mean = [0.0; 3];
    let mut variance = [0.0; 3];
    let mut acf_x = [[0.0; MAX_LAG]; 3];
    let mut acf_y = [[0.0; MAX_LAG]; 3];
    let quantiles = [0, 1, 2].map(|c| {
        let mut v: Vec<f64> = image.iter().map(|p| f64::from(p[c])).collect();
        v.sort_by(f64::total_cmp);
        (0..QUANTILES)
            .map(
                |i| if v.is_empty() { 0.0 } else { v[((i as f64 + 0.5) / QUANTILES as f64 * v.len() as f64) as usize] },
            )
            .collect()
    });
    for c in 0..3 {
        let y = |x: usize, r: usize| f64::from(image[r * width + x][c]);
        mean[c] = image.iter().map(|p| f64::from(p[c])).sum::<f64>() / n;
        variance[c] = image.iter().map(|p| (f64::from(p[c]) - mean[c]).powi(2)).sum::<f64>() / n;
        let var = variance[c];
        for k in 1..=MAX_LAG {
            let (mut sx, mut nx, mut sy, mut ny) = (0.0, 0usize, 0.0, 0usize);
            for r in 0..height {
                for x in 0..width {
                    if x + k < width {
                        sx += (y(x, r) - mean[c]) * (y(x + k, r) - mean[c]);
                        nx += 1;
                    }
                    if r + k < height {
                        sy += (y(x, r) - mean[c]) * (y(x, r + k) - mean[c]);
                        ny += 1;
                    }
                }
            }
            // A constant channel is perfectly correlated with itself.
            let norm = |s: f64, m: usize| if var > 0.0 && m > 0 { s / m as f64 / var } else { 1.0 };
            acf_x[c][k - 1] = norm(sx, nx);
            acf_y[c][k - 1] = norm(sy, ny);
        }
    }
    let correlation = [(0, 1), (0, 2), (1, 2)].map(|(a, b)| {
        let cov = image.iter().map(|p| (f64::from(p[a]) - mean[a]) * (f64::from(p[b]) - mean[b])).sum::<f64>() / n;
        let den = (variance[a] * variance[b]).sqrt();
        // Constant channels: no correlation to speak of.
        if den > 0.0 {
            cov / den
        } else {
            0.0
        }
    });
    TextureStats { mean, variance, correlation, acf_x, acf_y, quantiles }
}

/// The distance of `s`'s statistics from the reference `r`'s.
pub fn distance(s: &TextureStats, r: &TextureStats) -> StatsDistance {
    let mut mean_rel: f64 = 0.0;
    let mut emd_rel: f64 = 0.0;
    let mut acf = 0.0;
    let variance_ratio = [0, 1, 2].map(|c| s.variance[c] / r.variance[c].max(1e-300));
    for c in 0..3 {
        mean_rel = mean_rel.max((s.mean[c] - r.mean[c]).abs() / r.mean[c].abs().max(1e-12));
        for k in 0..MAX_LAG {
            acf += (s.acf_x[c][k] - r.acf_x[c][k]).powi(2) + (s.acf_y[c][k] - r.acf_y[c][k]).powi(2);
        }
        let emd =
            s.quantiles[c].iter().zip(&r.quantiles[c]).map(|(a, b)| (a - b).abs()).sum::<f64>() / QUANTILES as f64;
        emd_rel = emd_rel.max(emd / r.variance[c].sqrt().max(1e-12));
    }
    let correlation_diff = (0..3).map(|k| (s.correlation[k] - r.correlation[k]).abs()).fold(0.0, f64::max);
    StatsDistance {
        mean_rel,
        variance_ratio,
        correlation_diff,
        acf_rms: (acf / (3 * 2 * MAX_LAG) as f64).sqrt(),
        emd_rel,
    }
}
