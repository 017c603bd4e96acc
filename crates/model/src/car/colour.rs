//! Spectral factorisation of a colour texture (seed 002): PCA over its three channels, a 3x3
//! orthonormal decorrelation, so each factor is a mono-spectral, mutually uncorrelated band.
//! A rank-deficient texture (grey, or two channels proportional) gives zero-variance factors,
//! which the CAR fit turns into constant bands: valid, never NaN.

use nalgebra::{Matrix3, SymmetricEigen};
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

/// The decorrelation of one texture's colours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ColourPca {
    /// Mean colour.
    pub mean: [f64; 3],
    /// Rows: the principal directions (orthonormal), largest variance first.
    pub basis: [[f64; 3]; 3],
    /// Variance along each direction.
    pub variance: [f64; 3],
}

impl ColourPca {
    /// The PCA of `pixels` (every value finite).
    pub fn fit(what: &str, pixels: &[[f32; 3]]) -> Result<Self> {
        if pixels.is_empty() {
            return Err(ModelError::Empty(format!("{what}: no texels to factorise")));
        }
        if let Some(i) = pixels.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(ModelError::OutOfRange {
                field: format!("{what}: texel {i}"),
                value: format!("{:?}", pixels[i]),
                allowed: "finite colour values".into(),
            });
        }
        let n = pixels.len() as f64;
        let mut mean = [0.0; 3];
        for p in pixels {
            for c in 0..3 {
                mean[c] += f64::from(p[c]) / n;
            }
        }
        let mut cov = Matrix3::<f64>::zeros();
        for p in pixels {
            let d = nalgebra::Vector3::from_fn(|c, _| f64::from(p[c]) - mean[c]);
            cov += d * d.transpose() / n;
        }
        let eig = SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let basis = order.map(|k| {
            let v = eig.eigenvectors.column(k);
            // Sign: the largest component positive, so the basis is reproducible.
            let s = if v.iter().fold(0.0f64, |m, x| if x.abs() > m.abs() { *x } else { m }) < 0.0 { -1.0 } else { 1.0 };
            [s * v[0], s * v[1], s * v[2]]
        });
        let variance = order.map(|k| eig.eigenvalues[k].max(0.0));
        Ok(ColourPca { mean, basis, variance })
    }

    /// The factors of a colour.
    pub fn forward(&self, p: [f32; 3]) -> [f64; 3] {
        let d = [0, 1, 2].map(|c| f64::from(p[c]) - self.mean[c]);
        self.basis.map(|e| e[0] * d[0] + e[1] * d[1] + e[2] * d[2])
    }

    /// The colour of factors (the inverse of [`ColourPca::forward`]: the basis is orthonormal).
    pub fn inverse(&self, f: [f64; 3]) -> [f32; 3] {
        [0, 1, 2].map(|c| (self.mean[c] + (0..3).map(|k| f[k] * self.basis[k][c]).sum::<f64>()) as f32)
    }
}
