//! Denoising demultiplexed images by projection onto a linear basis (seed 001, §4.2:
//! `B_denoised = U (Uᵀ B_demultiplexed)`).
//!
//! `B` holds one view group's demultiplexed images as rows (`n` sources x `t` values: texels x
//! channels). Reflectance as a function of the light direction is smooth and low-rank across
//! the texels of one material, while demultiplexing noise is spread evenly over all `n`
//! source dimensions, so projecting the columns of `B` onto a `k`-dimensional basis `U` of
//! the light dimension keeps the signal and about `k / n` of the noise energy. `U` here is the
//! group's own leading `k` left singular vectors (the per-view FMF of the measurement itself,
//! the basis our compression models use; no database of other materials is needed): the
//! eigenvectors of the `n x n` Gram matrix `B Bᵀ` (`n² t` multiply-adds), then `U (Uᵀ B)`
//! (`2 n k t`), which is small next to rectifying `n` textures. Rows left out of the fit (faulty sources) are neither used for
//! `U` nor changed.

use nalgebra::{DMatrix, SymmetricEigen};

use crate::error::MuxError;

/// Columns copied to f64 at a time.
const CHUNK: usize = 1024;

/// What the projection did.
#[derive(Debug, Clone, PartialEq)]
pub struct Projection {
    /// Basis terms kept.
    pub terms: usize,
    /// Sources in the fit (the rows not left out).
    pub sources: usize,
    /// Fraction of the fitted rows' energy (sum of squares) the basis keeps.
    pub energy_kept: f64,
}

/// Projects the rows of `rows` (`n` rows of `t` values, row-major) onto their leading `terms`
/// left singular vectors, in place; rows with `skip[i]` are left out of the fit and kept as
/// they are. `terms` must be in `1..` the fitted rows.
pub fn project_onto_own_basis(rows: &mut [f32], n: usize, terms: usize, skip: &[bool]) -> Result<Projection, MuxError> {
    let bad = |what: &'static str, value: f64, allowed: &'static str| MuxError::OutOfRange { what, value, allowed };
    if n == 0 || rows.len() % n != 0 {
        return Err(bad("rows", rows.len() as f64, "a multiple of the sources (n x values)"));
    }
    if skip.len() != n {
        return Err(bad("skip flags", skip.len() as f64, "one per source"));
    }
    let t = rows.len() / n;
    let fit: Vec<usize> = (0..n).filter(|&i| !skip[i]).collect();
    let m = fit.len();
    if terms == 0 || terms >= m {
        return Err(bad("denoise terms", terms as f64, "at least 1 and fewer than the sources fitted"));
    }
    if rows.iter().any(|v| !v.is_finite()) {
        return Err(bad("demultiplexed value", f64::NAN, "finite values"));
    }
    // Gram matrix of the fitted rows, in f64 (t can be 10⁵ and more), over column chunks so
    // only an m x CHUNK copy is held.
    let mut g = DMatrix::<f64>::zeros(m, m);
    let chunk =
        |rows: &[f32], x0: usize, w: usize| DMatrix::<f64>::from_fn(m, w, |a, c| f64::from(rows[fit[a] * t + x0 + c]));
    for x0 in (0..t).step_by(CHUNK) {
        let c = chunk(rows, x0, CHUNK.min(t - x0));
        g.gemm(1.0, &c, &c.transpose(), 1.0);
    }
    let total: f64 = g.diagonal().sum();
    let eig = SymmetricEigen::new(g);
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let u = DMatrix::<f64>::from_fn(m, terms, |r, c| eig.eigenvectors[(r, order[c])]);
    let kept: f64 = order[..terms].iter().map(|&c| eig.eigenvalues[c].max(0.0)).sum();
    // B <- U (Uᵀ B), chunk by chunk: 2 m k t multiply-adds.
    let ut = u.transpose();
    for x0 in (0..t).step_by(CHUNK) {
        let w = CHUNK.min(t - x0);
        let projected = &u * (&ut * chunk(rows, x0, w));
        for (a, &i) in fit.iter().enumerate() {
            for c in 0..w {
                rows[i * t + x0 + c] = projected[(a, c)] as f32;
            }
        }
    }
    Ok(Projection { terms, sources: m, energy_kept: if total > 0.0 { kept / total } else { 1.0 } })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn rms(a: &[f32], b: &[f32]) -> f64 {
        (a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    }

    /// A rank-`r` signal of `n` sources x `t` values plus white noise: the projection onto
    /// `k >= r` terms keeps the signal and about `k / n` of the noise energy.
    #[test]
    fn projection_removes_all_but_k_over_n_of_white_noise() {
        let (n, t, r, k) = (198usize, 4096usize, 6usize, 12usize);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let a: Vec<f64> = (0..n * r).map(|_| unit.sample(&mut rng)).collect();
        let b: Vec<f64> = (0..r * t).map(|_| unit.sample(&mut rng)).collect();
        let clean: Vec<f32> = (0..n * t)
            .map(|e| {
                let (i, x) = (e / t, e % t);
                (0..r).map(|q| a[i * r + q] * b[q * t + x]).sum::<f64>() as f32
            })
            .collect();
        let sigma = 0.5;
        let noisy: Vec<f32> = clean.iter().map(|v| v + (sigma * unit.sample(&mut rng)) as f32).collect();
        let mut den = noisy.clone();
        let p = project_onto_own_basis(&mut den, n, k, &vec![false; n]).unwrap();
        let (before, after) = (rms(&noisy, &clean), rms(&den, &clean));
        let expected = sigma * (k as f64 / n as f64).sqrt();
        assert!((before / sigma - 1.0).abs() < 0.02, "noise before {before}");
        assert!(after < 1.15 * expected && after > 0.85 * expected, "after {after}, expected about {expected}");
        assert!(p.energy_kept > 0.9 && p.energy_kept <= 1.0, "{p:?}");
    }

    #[test]
    fn skipped_rows_are_neither_fitted_nor_changed_and_bad_input_is_refused() {
        let (n, t) = (10usize, 50usize);
        let mut rows: Vec<f32> = (0..n * t).map(|e| ((e / t) as f32 + 1.0) * ((e % t) as f32 * 0.1).sin()).collect();
        // Row 3 is garbage (a stuck source): left out, it must not leak into the others.
        for x in 0..t {
            rows[3 * t + x] = 1000.0 * (x as f32).cos();
        }
        let original = rows.clone();
        let mut skip = vec![false; n];
        skip[3] = true;
        project_onto_own_basis(&mut rows, n, 1, &skip).unwrap();
        assert_eq!(&rows[3 * t..4 * t], &original[3 * t..4 * t]);
        // The other rows are rank 1 (row i = (i + 1) s): reproduced by one term.
        assert!(rms(&rows, &original) < 1e-4, "{}", rms(&rows, &original));
        assert!(project_onto_own_basis(&mut rows, n, 9, &skip).is_err(), "9 terms of 9 fitted rows");
        assert!(project_onto_own_basis(&mut rows, n, 0, &skip).is_err());
        assert!(project_onto_own_basis(&mut rows[..7], n, 1, &skip).is_err());
        rows[0] = f32::NAN;
        assert!(project_onto_own_basis(&mut rows, n, 2, &skip).is_err());
    }
}
