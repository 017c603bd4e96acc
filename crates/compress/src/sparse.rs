//! Linear-basis applications (den Brok et al., seed 001 §4): sparse acquisition and
//! denoising.
//!
//! With an FMF model of a similar BTF as basis — per channel the mean ABRDF $\mu$ and the
//! orthonormal angular basis $U$ ($m \times k$), singular values $S$ — a BTF measured only at
//! the rows $M$ (a subset of the (light, view) pairs) is completed as
//!
//! $$B \approx \mu 1^\top + U C, \qquad C = (U_M^\top U_M + \Lambda)^{-1} U_M^\top (\tilde B - \mu_M 1^\top),$$
//!
//! the regularised form of $U (MU)^{+} \tilde B$: $\Lambda = \operatorname{diag}(\sigma^2/\tau_j^2)$
//! with $\tau_j^2 = S_j^2/n$ the spread of coefficient $j$ over the basis' texels and $\sigma^2$
//! (`ridge`) the noise variance of one measured value: the maximum a-posteriori coefficients
//! under a Gaussian prior, so directions the subset barely sees stay near the mean instead
//! of amplifying noise. $U_M^\top(\tilde B - \mu_M)$ is a sum over the captured rows, so the
//! captures stream in and memory is $k \times n$.
//!
//! **Denoising** is the same with every row measured and $\sigma^2 = 0$: the projection
//! $\mu + U U^\top (B - \mu)$ onto the basis.
//!
//! **Choice of $M$** ([`select`]): the rows of the stacked bases $[U_0\,U_1\,U_2]$ (so every
//! channel stays determined) chosen by pivoted QR and greedy volume growth
//! ([`crate::linalg::select_rows`]), among the pairs the basis was measured at (the rig
//! reaches them); $\kappa(U_M)$ is reported per channel.

use nalgebra::DMatrix;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::build::{check_finite, RowSource};
use crate::error::{bad, CompressError, Result};
use crate::linalg::{condition_number, select_rows};
use crate::model::{Channel, Layout, Method, Model, Part, PartRows};

/// How the subset is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Strategy {
    /// Pivoted QR + greedy maximum volume on the basis rows.
    MaxVolume,
    /// Uniformly random (seeded), for comparison.
    Random(u64),
}

/// A chosen subset of captures.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// `(light, view)` pairs, in the order chosen.
    pub pairs: Vec<(usize, usize)>,
    /// Condition number of `U_M` per channel.
    pub kappa: [f64; 3],
}

fn check_basis(basis: &Model) -> Result<()> {
    if basis.method != Method::Fmf || basis.channels.iter().any(|c| c.parts.len() != 1) {
        return Err(bad("basis", basis.method.name(), "an FMF model (one angular basis per channel)"));
    }
    if !basis.color.is_linear() {
        return Err(bad("basis colour model", basis.color.name(), "rgb or yuv (a linear colour model)"));
    }
    Ok(())
}

fn basis_rows(basis: &Model, rows: &[usize], c: usize) -> DMatrix<f64> {
    let p = &basis.channels[c].parts[0];
    DMatrix::from_fn(rows.len(), p.k, |i, j| f64::from(p.u[rows[i] * p.k + j]))
}

/// Chooses `count` captures among the basis' measured pairs.
pub fn select(basis: &Model, count: usize, strategy: Strategy) -> Result<Selection> {
    check_basis(basis)?;
    let candidates: Vec<usize> = (0..basis.layout.n_angular()).filter(|&a| basis.layout.measured[a]).collect();
    if count == 0 || count > candidates.len() {
        return Err(bad("captures", count, format!("1..={} (the measurable pairs)", candidates.len())));
    }
    let rows: Vec<usize> = match strategy {
        Strategy::MaxVolume => {
            let blocks: Vec<DMatrix<f64>> = (0..3).map(|c| basis_rows(basis, &candidates, c)).collect();
            let width: usize = blocks.iter().map(|b| b.ncols()).sum();
            let mut stacked = DMatrix::zeros(candidates.len(), width);
            let mut off = 0;
            for b in &blocks {
                stacked.columns_mut(off, b.ncols()).copy_from(b);
                off += b.ncols();
            }
            select_rows(&stacked, count).into_iter().map(|i| candidates[i]).collect()
        }
        Strategy::Random(seed) => {
            let mut c = candidates.clone();
            c.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
            c.truncate(count);
            c
        }
    };
    let kappa = std::array::from_fn(|c| condition_number(&basis_rows(basis, &rows, c)));
    Ok(Selection { pairs: rows.iter().map(|&a| basis.layout.pair(a)).collect(), kappa })
}

/// Completes a BTF from the captures `source` delivers (any subset of the basis' pairs,
/// every texel), regularised with noise variance `ridge` (0: plain least squares, needs at
/// least as many captures as terms). The result is an FMF model over the basis' layout with
/// the basis' angular factors and new texel coefficients; its `measured` flags are the
/// captured pairs.
pub fn reconstruct(basis: &Model, source: &mut dyn RowSource, ridge: f64) -> Result<Model> {
    check_basis(basis)?;
    if !(ridge >= 0.0 && ridge.is_finite()) {
        return Err(bad("ridge", ridge, "a finite noise variance >= 0"));
    }
    let layout = &basis.layout;
    let n = layout.texels();
    let ks: Vec<usize> = basis.channels.iter().map(|c| c.parts[0].k).collect();
    // Right-hand sides U_M^T (b - mu), k x n per channel, accumulated row by row.
    let mut rhs: Vec<DMatrix<f64>> = ks.iter().map(|&k| DMatrix::zeros(k, n)).collect();
    let mut seen = vec![false; layout.n_angular()];
    source.for_each(&mut |l, v, tex| {
        let (lu, vu) = (l as usize, v as usize);
        if lu >= layout.n_light() || vu >= layout.n_view() {
            return Err(CompressError::UnknownCapture {
                light: l,
                view: v,
                why: "outside the basis' samplings".into(),
            });
        }
        if tex.len() != n {
            return Err(CompressError::WrongTextureSize {
                light: l,
                view: v,
                got: tex.len(),
                expected: n,
                width: layout.width,
                height: layout.height,
            });
        }
        check_finite(l, v, tex, layout.width)?;
        let a = layout.index(lu, vu);
        if std::mem::replace(&mut seen[a], true) {
            return Err(CompressError::DuplicateCapture { light: l, view: v, pass: 1 });
        }
        for c in 0..3 {
            let p = &basis.channels[c].parts[0];
            let mu = f64::from(p.mean[a]);
            let u = &p.u[a * p.k..(a + 1) * p.k];
            let r = &mut rhs[c];
            for (x, t) in tex.iter().enumerate() {
                let d = f64::from(basis.color.forward(*t, basis.log_eps)[c]) - mu;
                for j in 0..p.k {
                    r[(j, x)] += f64::from(u[j]) * d;
                }
            }
        }
        Ok(())
    })?;
    let rows: Vec<usize> = (0..layout.n_angular()).filter(|&a| seen[a]).collect();
    if rows.is_empty() {
        return Err(bad("captures", 0, "at least 1"));
    }
    let mut channels = Vec::new();
    for c in 0..3 {
        let p = &basis.channels[c].parts[0];
        let um = basis_rows(basis, &rows, c);
        let lambda: Vec<f64> =
            p.s.iter()
                .map(|&s| {
                    let tau2 = f64::from(s).powi(2) / n as f64;
                    if ridge == 0.0 {
                        0.0
                    } else {
                        ridge / tau2.max(1e-30)
                    }
                })
                .collect();
        // (U_M^T U_M + Λ)^{-1} rhs: the k x k normal system (see `linalg::ridge_solve`).
        let ata = um.transpose() * &um;
        let mut nmat = ata.clone();
        for (j, l) in lambda.iter().enumerate() {
            nmat[(j, j)] += l;
        }
        let coeff = nalgebra::Cholesky::new(nmat).map(|ch| ch.solve(&rhs[c])).ok_or_else(|| {
            bad(
                "captures",
                rows.len(),
                format!(
                    "at least {} well-spread captures for {} terms without regularisation (use ridge > 0)",
                    p.k, p.k
                ),
            )
        })?;
        let mut sv = vec![0.0f32; n * p.k];
        for x in 0..n {
            for j in 0..p.k {
                sv[x * p.k + j] = coeff[(j, x)] as f32;
            }
        }
        channels.push(Channel::new(vec![Part {
            rows: PartRows::All,
            k: p.k,
            mean: p.mean.clone(),
            u: p.u.clone(),
            s: p.s.clone(),
            sv,
        }]));
    }
    let mut measured = vec![false; layout.n_angular()];
    for &a in &rows {
        measured[a] = true;
    }
    let out_layout = Layout { measured, ..layout.clone() };
    Ok(Model {
        method: Method::Fmf,
        color: basis.color,
        log_eps: basis.log_eps,
        precision: crate::model::Precision::F32,
        layout: out_layout,
        channels,
        clusters: None,
        cluster_col: Vec::new(),
    })
}

/// Denoising: the projection of a fully measured BTF onto the basis (see the module
/// documentation).
pub fn denoise(basis: &Model, source: &mut dyn RowSource) -> Result<Model> {
    reconstruct(basis, source, 0.0)
}
