//! Streaming randomized SVD: the low level of every model.
//!
//! The matrix $X$ ($m \times n$, here: captures x texels) is never held: its rows arrive one
//! at a time, in any order, once per *pass*. Following Halko, Martinsson & Tropp (2011,
//! algorithms 4.3/4.4) with sketch size $\ell = k + p$ ($k$ the rank kept, $p$ the
//! oversampling) and $q$ power iterations:
//!
//! 1. pass 1: $Y = X\Omega$ with $\Omega$ an $n \times \ell$ Gaussian matrix (row $i$ of $Y$ is
//!    $x_i \Omega$: local to the row); $Q = \operatorname{orth}(Y)$;
//! 2. for each power iteration: a pass $Z = X^\top Q = \sum_i x_i^\top q_i$ (a sum of
//!    per-row outer products), $\Omega = \operatorname{orth}(Z)$; a pass $Y = X\Omega$,
//!    $Q = \operatorname{orth}(Y)$;
//! 3. last pass: $Z = X^\top Q$, so $X \approx Q Q^\top X = Q Z^\top$. With
//!    $Z^\top Z = W \Sigma^2 W^\top$ (an $\ell \times \ell$ eigenproblem), the rank-$k$ result is
//!    $U = Q W_k$, $S = \Sigma_k$ and $S V^\top = (Z W_k)^\top$.
//!
//! That is $2 + 2q$ passes. Memory: $Y$, $Q$ ($m \times \ell$), $Z$, $\Omega$ ($n \times \ell$) and
//! one batch of rows ($n \times$ `batch`), i.e. proportional to the model being built
//! ($(m + n) k$), never to $m \times n$. Rows are buffered in batches so that both products
//! are real matrix products (`Ω^T · X_b^T` and `X_b^T · Q_b`), not matrix-vector products.
//!
//! **Error bound** (Halko et al. theorem 10.5 with the truncation argument of their §9.3):
//! for $q = 0$ and $p \ge 2$,
//! $\mathbb{E}\,\lVert X - U S V^\top\rVert_F^2 \le \left(2 + \tfrac{k}{p-1}\right)\tau_{k+1}^2$,
//! where $\tau_{k+1}^2 = \sum_{j>k}\sigma_j^2$ is the optimal rank-$k$ error (Eckart–Young);
//! power iterations only lower the error. In practice, with $q = 1$ the error is within a
//! percent of optimal on BTF data (tests: `rsvd_error_within_bound_of_exact_svd`).

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::error::{bad, CompressError, Result};
use crate::linalg::{orthonormalize, sorted_eigen};

/// Floating-point types the streaming SVD accumulates in (`f32` halves memory and doubles
/// product speed; `f64` is the reference). Factorizations always run in `f64`.
pub trait Real: nalgebra::RealField + Copy + Send + Sync + 'static {
    /// From `f32`.
    fn of_f32(x: f32) -> Self;
    /// From `f64` (rounding).
    fn of_f64(x: f64) -> Self;
    /// To `f64`.
    fn as_f64(self) -> f64;
}

impl Real for f32 {
    fn of_f32(x: f32) -> Self {
        x
    }
    fn of_f64(x: f64) -> Self {
        x as f32
    }
    fn as_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Real for f64 {
    fn of_f32(x: f32) -> Self {
        f64::from(x)
    }
    fn of_f64(x: f64) -> Self {
        x
    }
    fn as_f64(self) -> f64 {
        self
    }
}

/// Knobs of the randomized SVD.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RsvdParams {
    /// Rank kept, `k >= 1`.
    pub rank: usize,
    /// Oversampling `p` (extra sketch columns), default 10.
    pub oversample: usize,
    /// Power iterations `q`, default 1 (each costs two more passes over the data).
    pub power_iters: usize,
    /// Rows per batch (memory: `batch x n` values), default 32.
    pub batch: usize,
    /// Seed of the Gaussian test matrix.
    pub seed: u64,
}

impl RsvdParams {
    /// Rank `k` with the defaults: oversampling 10, one power iteration, batches of 32, seed 1.
    pub fn rank(k: usize) -> Self {
        RsvdParams { rank: k, oversample: 10, power_iters: 1, batch: 32, seed: 1 }
    }

    /// Passes over the data: `2 + 2 q`.
    pub fn passes(&self) -> usize {
        2 + 2 * self.power_iters
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<()> {
        if self.rank == 0 || self.rank > 4096 {
            return Err(bad("rank", self.rank, "1..=4096 terms"));
        }
        if self.oversample > 1024 {
            return Err(bad("oversample", self.oversample, "0..=1024"));
        }
        if self.power_iters > 8 {
            return Err(bad("power_iters", self.power_iters, "0..=8"));
        }
        if self.batch == 0 || self.batch > 4096 {
            return Err(bad("batch", self.batch, "1..=4096 rows"));
        }
        Ok(())
    }
}

/// The result: `X ≈ U diag(S) V^T`, stored as `U` (m x k, orthonormal columns), `S` and
/// `SV = V diag(S)` (n x k, one row per column of `X`: the coefficients of each texel).
#[derive(Debug, Clone)]
pub struct Svd {
    /// Left singular vectors, m x k.
    pub u: DMatrix<f64>,
    /// Singular values, descending.
    pub s: Vec<f64>,
    /// `V diag(S)`, n x k.
    pub sv: DMatrix<f64>,
}

impl Svd {
    /// `U` (m x k).
    #[allow(non_snake_case)]
    pub fn U(&self) -> &DMatrix<f64> {
        &self.u
    }
    /// `S`.
    #[allow(non_snake_case)]
    pub fn S(&self) -> &[f64] {
        &self.s
    }
    /// `V` (n x k, unit columns where `S > 0`).
    #[allow(non_snake_case)]
    pub fn V(&self) -> DMatrix<f64> {
        let mut v = self.sv.clone();
        for (j, &s) in self.s.iter().enumerate() {
            if s > 0.0 {
                v.column_mut(j).scale_mut(1.0 / s);
            }
        }
        v
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// `Y = X Ω`.
    Range,
    /// `Z = X^T Q`.
    CoRange,
}

/// A randomized SVD fed row by row over several passes (see the module documentation).
pub struct StreamingRsvd<T: Real> {
    rows: usize,
    cols: usize,
    rank: usize,
    width: usize,
    params: RsvdParams,
    pass: usize,
    stage: Stage,
    omega_t: DMatrix<T>,
    y: DMatrix<T>,
    q: DMatrix<T>,
    z: DMatrix<T>,
    batch: DMatrix<T>,
    batch_rows: Vec<usize>,
}

impl<T: Real> StreamingRsvd<T> {
    /// A streaming SVD of an `rows x cols` matrix.
    pub fn new(rows: usize, cols: usize, params: &RsvdParams) -> Result<Self> {
        params.validate()?;
        if rows == 0 || cols == 0 {
            return Err(bad("matrix size", format!("{rows} x {cols}"), "at least 1 x 1"));
        }
        let width = (params.rank + params.oversample).min(rows).min(cols).max(1);
        let rank = params.rank.min(width);
        let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
        let omega_t = DMatrix::from_fn(width, cols, |_, _| {
            T::of_f64(<StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng))
        });
        let batch_n = params.batch.min(rows);
        Ok(StreamingRsvd {
            rows,
            cols,
            rank,
            width,
            params: *params,
            pass: 0,
            stage: Stage::Range,
            omega_t,
            y: DMatrix::zeros(rows, width),
            q: DMatrix::zeros(0, 0),
            z: DMatrix::zeros(0, 0),
            batch: DMatrix::zeros(cols, batch_n),
            batch_rows: Vec::with_capacity(batch_n),
        })
    }

    /// Rows of the matrix.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Columns of the matrix (length of every row pushed).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Rank that will be returned (`min(rank, rows, cols)`).
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// Current pass, from 0.
    pub fn pass(&self) -> usize {
        self.pass
    }

    /// Total passes.
    pub fn passes(&self) -> usize {
        self.params.passes()
    }

    /// Bytes held (sketches, test matrix, batch).
    pub fn memory_bytes(&self) -> usize {
        let n = self.omega_t.len() + self.y.len() + self.q.len() + self.z.len() + self.batch.len();
        n * std::mem::size_of::<T>()
    }

    /// Feeds row `row` (`cols` values) of the current pass. Each row once per pass, in any
    /// order (the caller checks: see [`crate::build::Builder`]).
    ///
    /// # Panics
    /// If `row >= rows` or `x.len() != cols`.
    pub fn push(&mut self, row: usize, x: &[T]) {
        assert!(row < self.rows && x.len() == self.cols, "StreamingRsvd::push: row {row}, {} values", x.len());
        let slot = self.batch_rows.len();
        self.batch.column_mut(slot).copy_from_slice(x);
        self.batch_rows.push(row);
        if self.batch_rows.len() == self.batch.ncols() {
            self.flush();
        }
    }

    /// Feeds a row given as `f32`, converting.
    pub fn push_f32(&mut self, row: usize, x: &[f32]) {
        assert!(row < self.rows && x.len() == self.cols, "StreamingRsvd::push_f32: row {row}, {} values", x.len());
        let slot = self.batch_rows.len();
        for (d, &s) in self.batch.column_mut(slot).iter_mut().zip(x) {
            *d = T::of_f32(s);
        }
        self.batch_rows.push(row);
        if self.batch_rows.len() == self.batch.ncols() {
            self.flush();
        }
    }

    fn flush(&mut self) {
        let b = self.batch_rows.len();
        if b == 0 {
            return;
        }
        let xt = self.batch.columns(0, b);
        match self.stage {
            Stage::Range => {
                // (width x n)(n x b): Y rows of the batch, transposed.
                let yt = &self.omega_t * xt;
                for (j, &r) in self.batch_rows.iter().enumerate() {
                    for c in 0..self.width {
                        self.y[(r, c)] = yt[(c, j)];
                    }
                }
            }
            Stage::CoRange => {
                let qb = DMatrix::from_fn(b, self.width, |j, c| self.q[(self.batch_rows[j], c)]);
                self.z.gemm(T::one(), &xt, &qb, T::one());
            }
        }
        self.batch_rows.clear();
    }

    fn to64(m: &DMatrix<T>) -> DMatrix<f64> {
        m.map(|x| x.as_f64())
    }

    /// Ends the current pass. `Ok(true)`: another pass is needed (push every row again);
    /// `Ok(false)`: done, call [`StreamingRsvd::finish`].
    pub fn end_pass(&mut self) -> Result<bool> {
        if self.pass >= self.passes() {
            return Err(CompressError::State("end_pass after the last pass".into()));
        }
        self.flush();
        match self.stage {
            Stage::Range => {
                let mut y = Self::to64(&self.y);
                orthonormalize(&mut y);
                self.q = y.map(T::of_f64);
                self.y = DMatrix::zeros(0, 0);
                self.z = DMatrix::zeros(self.cols, self.width);
                self.stage = Stage::CoRange;
            }
            Stage::CoRange => {
                if self.pass + 1 < self.passes() {
                    let mut z = Self::to64(&self.z);
                    orthonormalize(&mut z);
                    self.omega_t = z.transpose().map(T::of_f64);
                    self.z = DMatrix::zeros(0, 0);
                    self.y = DMatrix::zeros(self.rows, self.width);
                    self.stage = Stage::Range;
                }
            }
        }
        self.pass += 1;
        Ok(self.pass < self.passes())
    }

    /// The rank-`k` factorization after the last pass.
    pub fn finish(self) -> Result<Svd> {
        if self.pass < self.passes() {
            return Err(CompressError::State(format!("finish after {} of {} passes", self.pass, self.passes())));
        }
        let z = Self::to64(&self.z);
        let q = Self::to64(&self.q);
        let (lam, w) = sorted_eigen(crate::linalg::at_b(&z, &z));
        let k = self.rank;
        let wk = w.columns(0, k).clone_owned();
        let s = lam[..k].iter().map(|l| l.sqrt()).collect();
        Ok(Svd { u: q * &wk, s, sv: z * wk })
    }
}

/// The whole randomized SVD of an in-memory matrix (rows streamed from it), for tests and
/// small problems.
pub fn rsvd_dense<T: Real>(x: &DMatrix<T>, params: &RsvdParams) -> Result<Svd> {
    let mut s = StreamingRsvd::<T>::new(x.nrows(), x.ncols(), params)?;
    let rows: Vec<Vec<T>> = (0..x.nrows()).map(|r| x.row(r).iter().copied().collect()).collect();
    loop {
        // Reverse order on odd passes: order must not matter.
        if s.pass() % 2 == 0 {
            for (r, row) in rows.iter().enumerate() {
                s.push(r, row);
            }
        } else {
            for (r, row) in rows.iter().enumerate().rev() {
                s.push(r, row);
            }
        }
        if !s.end_pass()? {
            break;
        }
    }
    s.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::singular_values;

    /// A matrix with singular values `decay^j` and random singular vectors.
    pub(crate) fn spectrum_matrix(m: usize, n: usize, decay: f64, seed: u64) -> (DMatrix<f64>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let r = m.min(n);
        let mut a = DMatrix::from_fn(m, r, |_, _| StandardNormal.sample(&mut rng));
        let mut b = DMatrix::from_fn(n, r, |_, _| StandardNormal.sample(&mut rng));
        orthonormalize(&mut a);
        orthonormalize(&mut b);
        let s: Vec<f64> = (0..r).map(|j| decay.powi(j as i32)).collect();
        let x = &a * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(s.clone())) * b.transpose();
        (x, s)
    }

    fn rebuild(svd: &Svd) -> DMatrix<f64> {
        &svd.u * svd.sv.transpose()
    }

    #[test]
    fn rsvd_error_within_bound_of_exact_svd() {
        for (m, n, k, p, q, decay, seed) in [
            (60, 80, 5, 5, 0, 0.8, 1u64),
            (120, 90, 10, 10, 0, 0.9, 2),
            (200, 300, 16, 10, 1, 0.95, 3),
            (300, 150, 20, 10, 2, 0.97, 4),
        ] {
            let (x, s) = spectrum_matrix(m, n, decay, seed);
            let params = RsvdParams { rank: k, oversample: p, power_iters: q, batch: 7, seed };
            let svd = rsvd_dense(&x, &params).unwrap();
            let err = (&x - rebuild(&svd)).norm();
            let optimal: f64 = s[k..].iter().map(|v| v * v).sum::<f64>().sqrt();
            let bound = (2.0 + k as f64 / (p as f64 - 1.0)).sqrt() * optimal;
            assert!(err <= bound, "{m}x{n} k{k} p{p} q{q}: error {err} > bound {bound} (optimal {optimal})");
            if q >= 1 {
                assert!(err <= 1.05 * optimal, "{m}x{n} q{q}: error {err} vs optimal {optimal}");
            }
            // Singular values close to the exact ones.
            for j in 0..k.min(5) {
                assert!((svd.s[j] - s[j]).abs() < 0.05 * s[0], "sigma {j}: {} vs {}", svd.s[j], s[j]);
            }
            // U orthonormal.
            let utu = svd.u.transpose() * &svd.u;
            assert!((utu - DMatrix::identity(k, k)).norm() < 1e-8);
        }
    }

    #[test]
    fn exact_on_rank_deficient_input() {
        // Rank 3 matrix, rank 8 asked: exact reconstruction, singular values 4.. are zero.
        for (m, n) in [(20, 30), (50, 40), (7, 100)] {
            let (full, _) = spectrum_matrix(m, n, 0.5, 11);
            let svd_full = nalgebra::SVD::new(full.clone(), true, true);
            let mut sv = svd_full.singular_values.clone();
            for j in 3..sv.len() {
                sv[j] = 0.0;
            }
            let x = svd_full.u.unwrap() * DMatrix::from_diagonal(&sv) * svd_full.v_t.unwrap();
            let svd =
                rsvd_dense(&x, &RsvdParams { rank: 8, oversample: 4, power_iters: 1, batch: 5, seed: 3 }).unwrap();
            assert!((&x - rebuild(&svd)).norm() < 1e-9 * x.norm(), "{m}x{n}");
            assert!(svd.s[3..].iter().all(|&s| s < 1e-7 * svd.s[0]), "{:?}", svd.s);
            assert!(svd.u.iter().chain(svd.sv.iter()).all(|v| v.is_finite()));
        }
        // The zero matrix: no NaN, zero singular values.
        let x = DMatrix::<f64>::zeros(10, 12);
        let svd = rsvd_dense(&x, &RsvdParams::rank(3)).unwrap();
        assert!(svd.s.iter().all(|&s| s == 0.0));
        assert!(svd.u.iter().chain(svd.sv.iter()).all(|v| v.is_finite()));
    }

    #[test]
    fn f32_agrees_with_f64() {
        for (m, n, k, seed) in [(100, 120, 8, 5u64), (300, 200, 20, 6)] {
            let (x, _) = spectrum_matrix(m, n, 0.9, seed);
            let p = RsvdParams { rank: k, oversample: 10, power_iters: 1, batch: 16, seed };
            let a = rsvd_dense(&x, &p).unwrap();
            let b = rsvd_dense(&x.map(|v| v as f32), &p).unwrap();
            let (ra, rb) = (rebuild(&a), rebuild(&b));
            // f32 accumulation over n terms: relative error ~ 1e-7 * sqrt(n) * conditioning.
            let rel = (&ra - &rb).norm() / ra.norm();
            assert!(rel < 1e-4, "{m}x{n}: f32 vs f64 reconstructions differ by {rel}");
            for j in 0..k {
                assert!((a.s[j] - b.s[j]).abs() < 1e-4 * a.s[0], "sigma {j}");
            }
        }
    }

    #[test]
    fn exact_when_rank_equals_size() {
        let (x, s) = spectrum_matrix(12, 9, 0.7, 8);
        let svd = rsvd_dense(&x, &RsvdParams { rank: 9, oversample: 0, power_iters: 0, batch: 4, seed: 1 }).unwrap();
        assert!((&x - rebuild(&svd)).norm() < 1e-10);
        let exact = singular_values(&x);
        for j in 0..9 {
            assert!((svd.s[j] - exact[j]).abs() < 1e-10 && (exact[j] - s[j]).abs() < 1e-10);
        }
    }

    #[test]
    fn wrong_driving_is_an_error() {
        let mut s = StreamingRsvd::<f64>::new(3, 4, &RsvdParams::rank(2)).unwrap();
        s.push(0, &[1.0, 2.0, 3.0, 4.0]);
        assert!(matches!(s.end_pass(), Ok(true)));
        // finish before the last pass
        assert!(matches!(s.finish(), Err(CompressError::State(_))));
        assert!(matches!(
            StreamingRsvd::<f64>::new(3, 4, &RsvdParams::rank(0)),
            Err(CompressError::BadParameter { .. })
        ));
    }
}
