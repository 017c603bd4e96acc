//! Height from gradients: weighted least-squares (Poisson) integration with natural boundaries.
//!
//! Given slopes `p = ∂h/∂x`, `q = ∂h/∂y` per texel (texture rows grow along `−y`, columns
//! along `+x`, texel side `Δ`), every pair of neighbouring texels gives one equation, the
//! trapezoid rule along their edge:
//!
//! ```text
//! h[i+1, j] − h[i, j] = Δ (p[i, j] + p[i+1, j]) / 2          (along a row)
//! h[i, j+1] − h[i, j] = −Δ (q[i, j] + q[i, j+1]) / 2         (down a column)
//! ```
//!
//! The height minimises `Σ_e w_e (h_b − h_a − d_e)²` over the edges `e` inside the grid
//! only: no equation reaches outside, so the boundary is the natural (Neumann) one of the
//! discrete Poisson equation `Dᵀ W D h = Dᵀ W d` and nothing is assumed about the heights
//! beyond the edge (a Fourier integrator would make the field periodic). Edge weights
//! `w_e = min(w_a, w_b)` let uncertain texels (steep, shadowed) count less. The system is
//! solved by conjugate gradients with a Jacobi preconditioner; the constant it leaves free
//! is fixed by a zero mean.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::error::{ModelError, Result};

/// Tuning of [`integrate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntegrateParams {
    /// Relative residual at which conjugate gradients stop.
    pub tolerance: f64,
    /// Iterations at most (0: `20 · (width + height) + 100`).
    pub max_iterations: usize,
}

impl Default for IntegrateParams {
    fn default() -> Self {
        IntegrateParams { tolerance: 1e-9, max_iterations: 0 }
    }
}

/// A height map, row-major, metres, zero mean.
#[derive(Debug, Clone)]
pub struct HeightMap {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Heights.
    pub h: Vec<f64>,
    /// Conjugate-gradient iterations taken.
    pub iterations: usize,
}

struct Edges {
    /// (a, b, target, weight)
    list: Vec<(usize, usize, f64, f64)>,
}

fn edges(w: usize, h: usize, grad: &[[f64; 2]], weight: Option<&[f64]>, texel_m: f64) -> Edges {
    let wt = |i: usize| weight.map_or(1.0, |v| v[i]);
    let mut list = Vec::with_capacity(2 * w * h);
    for j in 0..h {
        for i in 0..w {
            let a = j * w + i;
            if i + 1 < w {
                let b = a + 1;
                list.push((a, b, texel_m * 0.5 * (grad[a][0] + grad[b][0]), wt(a).min(wt(b))));
            }
            if j + 1 < h {
                let b = a + w;
                list.push((a, b, -texel_m * 0.5 * (grad[a][1] + grad[b][1]), wt(a).min(wt(b))));
            }
        }
    }
    Edges { list }
}

fn apply(e: &Edges, x: &[f64], out: &mut [f64]) {
    out.fill(0.0);
    for &(a, b, _, w) in &e.list {
        let d = w * (x[b] - x[a]);
        out[b] += d;
        out[a] -= d;
    }
}

fn remove_mean(v: &mut [f64]) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    for x in v {
        *x -= m;
    }
}

/// Integrates `grad[t] = [∂h/∂x, ∂h/∂y]` on a `width x height` grid of texel side `texel_m`
/// (module documentation). `weight`: per-texel weights ≥ 0 (`None`: all 1).
pub fn integrate(
    width: usize,
    height: usize,
    grad: &[[f64; 2]],
    weight: Option<&[f64]>,
    texel_m: f64,
    params: &IntegrateParams,
) -> Result<HeightMap> {
    let n = width * height;
    if n == 0 {
        return Err(ModelError::Empty(format!("height integration: an empty grid ({width} x {height})")));
    }
    if grad.len() != n {
        return Err(ModelError::WrongSize {
            what: "height integration: gradients".into(),
            got: grad.len(),
            expected: n,
        });
    }
    if let Some(w) = weight {
        if w.len() != n {
            return Err(ModelError::WrongSize {
                what: "height integration: weights".into(),
                got: w.len(),
                expected: n,
            });
        }
        if let Some(i) = w.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(ModelError::OutOfRange {
                field: format!("height integration: weight {i}"),
                value: w[i].to_string(),
                allowed: "finite and >= 0".into(),
            });
        }
    }
    if !(texel_m.is_finite() && texel_m > 0.0) {
        return Err(ModelError::OutOfRange {
            field: "texel size".into(),
            value: texel_m.to_string(),
            allowed: "finite and > 0 metres".into(),
        });
    }
    if let Some(i) = grad.iter().position(|g| !(g[0].is_finite() && g[1].is_finite())) {
        return Err(ModelError::OutOfRange {
            field: format!("height integration: gradient {i}"),
            value: format!("{:?}", grad[i]),
            allowed: "finite slopes".into(),
        });
    }
    let e = edges(width, height, grad, weight, texel_m);
    // Right-hand side Dᵀ W d and the Jacobi preconditioner (diagonal of Dᵀ W D).
    let mut rhs = vec![0.0; n];
    let mut diag = vec![0.0; n];
    for &(a, b, d, w) in &e.list {
        rhs[b] += w * d;
        rhs[a] -= w * d;
        diag[a] += w;
        diag[b] += w;
    }
    let inv_diag: Vec<f64> = diag.iter().map(|d| if *d > 0.0 { 1.0 / d } else { 0.0 }).collect();
    remove_mean(&mut rhs);
    let max_it = if params.max_iterations == 0 { 20 * (width + height) + 100 } else { params.max_iterations };
    let mut x = vec![0.0; n];
    let mut r = rhs.clone();
    let norm0 = r.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut z: Vec<f64> = r.iter().zip(&inv_diag).map(|(a, b)| a * b).collect();
    remove_mean(&mut z);
    let mut p = z.clone();
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let mut ap = vec![0.0; n];
    let mut it = 0;
    if norm0 > 0.0 {
        while it < max_it {
            apply(&e, &p, &mut ap);
            let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
            if !(pap > 0.0) {
                break;
            }
            let alpha = rz / pap;
            for k in 0..n {
                x[k] += alpha * p[k];
                r[k] -= alpha * ap[k];
            }
            it += 1;
            let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            if rn <= params.tolerance * norm0 {
                break;
            }
            for k in 0..n {
                z[k] = r[k] * inv_diag[k];
            }
            remove_mean(&mut z);
            let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..n {
                p[k] = z[k] + beta * p[k];
            }
        }
    }
    remove_mean(&mut x);
    Ok(HeightMap { width, height, h: x, iterations: it })
}

/// Per-texel standard deviation of the integrated height when each gradient component of
/// texel `t` has standard deviation `sigma[t]`, by Monte Carlo: `draws` integrations of
/// perturbed gradients (Gaussian, seeded by `seed`), the spread around the unperturbed one.
// The arguments are those of `integrate` plus the noise and its draws.
#[allow(clippy::too_many_arguments)]
pub fn height_sigma(
    width: usize,
    height: usize,
    grad: &[[f64; 2]],
    sigma: &[f64],
    weight: Option<&[f64]>,
    texel_m: f64,
    draws: usize,
    seed: u64,
) -> Result<Vec<f64>> {
    let n = width * height;
    if sigma.len() != n {
        return Err(ModelError::WrongSize { what: "height uncertainty: sigmas".into(), got: sigma.len(), expected: n });
    }
    let params = IntegrateParams { tolerance: 1e-6, max_iterations: 0 };
    let base = integrate(width, height, grad, weight, texel_m, &params)?;
    let runs: Vec<Result<Vec<f64>>> = (0..draws.max(1))
        .into_par_iter()
        .map(|k| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let g: Vec<[f64; 2]> = grad
                .iter()
                .zip(sigma)
                .map(|(g, s)| {
                    let (a, b): (f64, f64) = (StandardNormal.sample(&mut rng), StandardNormal.sample(&mut rng));
                    [g[0] + s * a, g[1] + s * b]
                })
                .collect();
            Ok(integrate(width, height, &g, weight, texel_m, &params)?.h)
        })
        .collect();
    let mut var = vec![0.0; n];
    for r in runs {
        for (v, (a, b)) in var.iter_mut().zip(r?.iter().zip(&base.h)) {
            *v += (a - b) * (a - b);
        }
    }
    Ok(var.into_iter().map(|v| (v / draws.max(1) as f64).sqrt()).collect())
}
