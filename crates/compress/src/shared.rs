//! PCMF in a shared angular basis: local PCA of the texels' FMF coefficients (numerics only,
//! no I/O; the builder feeds it, [`crate::model::SharedBasis`] holds and expands the result).
//!
//! Per channel, an FMF of $K$ terms gives the mean ABRDF $\mu$, the orthonormal angular basis
//! $W \in \mathbb{R}^{m \times K}$ and every texel's coefficients $c_x = W^\top (b_x - \mu)
//! \in \mathbb{R}^K$. Cluster $j$ has a mean $a_j$ and an orthonormal basis
//! $A_j \in \mathbb{R}^{K \times k}$ in those coefficients (the top $k$ eigenvectors of the
//! scatter of its members' $c_x - a_j$), and a texel of cluster $j$ is
//!
//! $$b_x \approx \mu + W\,(a_j + A_j t_x), \qquad t_x = A_j^\top (c_x - a_j):$$
//!
//! a PCMF whose per-cluster means $\mu + W a_j$ and bases $W A_j$ are constrained to the span
//! of $W$. Storage per channel: $m (K + 1)$ once, $K (k + 1)$ per cluster, $k$ per texel,
//! instead of PCMF's $m (k + 1)$ per cluster. Because $W$ is orthonormal, the error of $x$ in
//! cluster $j$ is $\lVert b_x - \mu - W c_x\rVert^2 + \lVert c_x - a_j\rVert^2 -
//! \lVert A_j^\top (c_x - a_j)\rVert^2$; the first term does not depend on $j$, so local-PCA
//! reassignment ($x \to \arg\min_j$, summed over the channels) runs on the coefficients alone,
//! without another pass over the data, and is exactly local PCA on the data restricted to the
//! span of $W$. An emptied cluster is re-seeded with the worst-reconstructed texel
//! ([`crate::cluster::reseed_empty_clusters`]).
//!
//! The stored values ($a_j$, $A_j$, $t_x$) are rounded to the model's precision, $t_x$
//! computed from the rounded $a_j$ and $A_j$.

use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::cluster::reseed_empty_clusters;
use crate::linalg::{at_b, sorted_eigen};
use crate::model::Precision;

/// One channel of a [`SharedFit`].
#[derive(Debug, Clone, PartialEq)]
pub struct SharedChannelFit {
    /// Per cluster $a_j$ (`K`), rounded to the precision.
    pub cluster_mean: Vec<Vec<f32>>,
    /// Per cluster $A_j$ (`K` x terms, row-major), rounded to the precision.
    pub cluster_basis: Vec<Vec<f32>>,
    /// Per cluster the singular values of its centred coefficients (terms, descending).
    pub s: Vec<Vec<f32>>,
    /// Per cluster $t_x$ of its texels in increasing texel order (texels x terms, row-major),
    /// rounded to the precision.
    pub coef: Vec<Vec<f32>>,
}

/// The result of [`fit`].
#[derive(Debug, Clone, PartialEq)]
pub struct SharedFit {
    /// Cluster of every texel (`0..clusters`, none empty).
    pub assign: Vec<u16>,
    /// Per channel.
    pub channels: Vec<SharedChannelFit>,
    /// Texels moved by each reassignment iteration.
    pub moved: Vec<usize>,
    /// Per iteration, the mean squared error in the span of `W` (all channels, per texel)
    /// before it and after it reassigned (before refitting).
    pub err: Vec<(f64, f64)>,
}

/// Rounds to the stored precision.
pub fn round(v: f64, precision: Precision) -> f32 {
    match precision {
        Precision::F16 => half::f16::from_f64(v).to_f32(),
        Precision::F32 => v as f32,
    }
}

/// Mean and orthonormal basis (`K` x terms, row-major) of one cluster, unrounded, and its
/// singular values.
struct Local {
    mean: Vec<f64>,
    basis: Vec<f64>,
    terms: usize,
    s: Vec<f64>,
}

impl Local {
    /// $\lVert c - a\rVert^2 - \lVert A^\top (c - a)\rVert^2$.
    fn residual(&self, c: &[f64], d: &mut [f64]) -> f64 {
        let mut e = 0.0;
        for ((d, c), a) in d.iter_mut().zip(c).zip(&self.mean) {
            *d = c - a;
            e += *d * *d;
        }
        let t = self.terms;
        for q in 0..t {
            let mut p = 0.0;
            for (i, d) in d.iter().enumerate() {
                p += self.basis[i * t + q] * d;
            }
            e -= p * p;
        }
        e.max(0.0)
    }
}

fn members(assign: &[u16], kc: usize) -> Vec<Vec<usize>> {
    let mut m = vec![Vec::new(); kc];
    for (x, &j) in assign.iter().enumerate() {
        m[j as usize].push(x);
    }
    m
}

fn fit_locals(coef: &DMatrix<f64>, members: &[Vec<usize>], terms: usize) -> Vec<Local> {
    let k = coef.ncols();
    members
        .par_iter()
        .map(|mem| {
            let mut mean = vec![0.0; k];
            for &x in mem {
                for (i, v) in mean.iter_mut().enumerate() {
                    *v += coef[(x, i)];
                }
            }
            for v in &mut mean {
                *v /= mem.len().max(1) as f64;
            }
            let d = DMatrix::from_fn(mem.len(), k, |r, i| coef[(mem[r], i)] - mean[i]);
            let (vals, vecs) = sorted_eigen(at_b(&d, &d));
            let t = terms.min(k);
            let basis = (0..k).flat_map(|i| (0..t).map(move |q| (i, q))).map(|(i, q)| vecs[(i, q)]).collect();
            Local { mean, basis, terms: t, s: vals.iter().take(t).map(|v| v.sqrt()).collect() }
        })
        .collect()
}

/// Local PCA of the coefficients `coef` (per channel, texels x `K`, the FMF's `V S`), from
/// the assignment `init` (labels `0..clusters`; empty clusters are re-seeded, and dropped
/// only if there are fewer texels than clusters), with `terms` per cluster and channel,
/// `iters` reassignments, values rounded to `precision` (see the module documentation).
pub fn fit(coef: &[DMatrix<f64>], init: &[u16], terms: [usize; 3], iters: usize, precision: Precision) -> SharedFit {
    let n = init.len();
    let k = coef[0].ncols();
    let kc = init.iter().map(|&j| j as usize + 1).max().unwrap_or(1).max(1);
    let mut assign = init.to_vec();
    let (mut moved, mut errs) = (Vec::new(), Vec::new());
    let residuals = |locals: &[Vec<Local>], x: usize, j: usize, d: &mut [f64]| -> f64 {
        let mut e = 0.0;
        for c in 0..coef.len() {
            let row: Vec<f64> = (0..k).map(|i| coef[c][(x, i)]).collect();
            e += locals[c][j].residual(&row, d);
        }
        e
    };
    reseed_empty_clusters(&mut assign, kc, |_| 0.0);
    for _ in 0..iters {
        let mem = members(&assign, kc);
        let locals: Vec<Vec<Local>> = (0..coef.len()).map(|c| fit_locals(&coef[c], &mem, terms[c])).collect();
        let best: Vec<(u16, f64, f64)> = (0..n)
            .into_par_iter()
            .map(|x| {
                let mut d = vec![0.0; k];
                let own = residuals(&locals, x, assign[x] as usize, &mut d);
                let (j, e) = (0..kc)
                    .map(|j| (j as u16, residuals(&locals, x, j, &mut d)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("clusters");
                (j, e, own)
            })
            .collect();
        let before = best.iter().map(|b| b.2).sum::<f64>() / n.max(1) as f64;
        let after = best.iter().map(|b| b.1).sum::<f64>() / n.max(1) as f64;
        let mut next: Vec<u16> = best.iter().map(|b| b.0).collect();
        reseed_empty_clusters(&mut next, kc, |x| best[x].1);
        moved.push(next.iter().zip(&assign).filter(|(a, b)| a != b).count());
        errs.push((before, after));
        assign = next;
    }
    // Drop clusters still empty (fewer texels than clusters) by relabelling.
    let mem = members(&assign, kc);
    let mut relabel = vec![u16::MAX; kc];
    let mut kept = 0u16;
    for (j, m) in mem.iter().enumerate() {
        if !m.is_empty() {
            relabel[j] = kept;
            kept += 1;
        }
    }
    let assign: Vec<u16> = assign.iter().map(|&j| relabel[j as usize]).collect();
    let mem: Vec<Vec<usize>> = mem.into_iter().filter(|m| !m.is_empty()).collect();
    let channels = (0..coef.len())
        .map(|c| {
            let locals = fit_locals(&coef[c], &mem, terms[c]);
            let mut out = SharedChannelFit {
                cluster_mean: Vec::new(),
                cluster_basis: Vec::new(),
                s: Vec::new(),
                coef: Vec::new(),
            };
            for (l, m) in locals.iter().zip(&mem) {
                let a: Vec<f32> = l.mean.iter().map(|&v| round(v, precision)).collect();
                let b: Vec<f32> = l.basis.iter().map(|&v| round(v, precision)).collect();
                let t = l.terms;
                let tx: Vec<f32> = m
                    .par_iter()
                    .flat_map_iter(|&x| {
                        let d: Vec<f64> = (0..k).map(|i| coef[c][(x, i)] - f64::from(a[i])).collect();
                        let b = &b;
                        (0..t)
                            .map(move |q| round((0..k).map(|i| f64::from(b[i * t + q]) * d[i]).sum::<f64>(), precision))
                    })
                    .collect();
                out.cluster_mean.push(a);
                out.cluster_basis.push(b);
                out.s.push(l.s.iter().map(|&v| v as f32).collect());
                out.coef.push(tx);
            }
            out
        })
        .collect();
    SharedFit { assign, channels, moved, err: errs }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Texels drawn from `kc` affine subspaces of dimension `t` in `R^k` (plus `noise`).
    fn mixture(n: usize, k: usize, kc: usize, t: usize, noise: f64, seed: u64) -> (DMatrix<f64>, Vec<u16>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut g = || rng.gen::<f64>() * 2.0 - 1.0;
        let centres: Vec<Vec<f64>> = (0..kc).map(|_| (0..k).map(|_| 5.0 * g()).collect()).collect();
        let dirs: Vec<DMatrix<f64>> = (0..kc).map(|_| DMatrix::from_fn(k, t, |_, _| g())).collect();
        let truth: Vec<u16> = (0..n).map(|x| (x % kc) as u16).collect();
        let mut c = DMatrix::zeros(n, k);
        for x in 0..n {
            let j = truth[x] as usize;
            let w: Vec<f64> = (0..t).map(|_| g()).collect();
            for i in 0..k {
                c[(x, i)] = centres[j][i] + (0..t).map(|q| dirs[j][(i, q)] * w[q]).sum::<f64>() + noise * g();
            }
        }
        (c, truth)
    }

    /// Reconstruction `a_j + A_j t_x` of texel `x` (the `col`-th of its cluster).
    fn recon(f: &SharedChannelFit, j: usize, col: usize, k: usize) -> Vec<f64> {
        let t = f.cluster_basis[j].len() / k;
        (0..k)
            .map(|i| {
                f64::from(f.cluster_mean[j][i])
                    + (0..t)
                        .map(|q| f64::from(f.cluster_basis[j][i * t + q]) * f64::from(f.coef[j][col * t + q]))
                        .sum::<f64>()
            })
            .collect()
    }

    #[test]
    fn exact_subspaces_are_reconstructed_from_a_perfect_start() {
        for (n, k, kc, t) in [(60, 6, 3, 2), (200, 10, 5, 3), (64, 4, 1, 4)] {
            let (c, truth) = mixture(n, k, kc, t, 0.0, n as u64);
            let coef = vec![c.clone(), c.clone(), c.clone()];
            let f = fit(&coef, &truth, [t; 3], 2, Precision::F32);
            assert_eq!(f.assign, truth, "n {n}: a perfect assignment stays");
            let mut col = vec![0usize; kc];
            for x in 0..n {
                let j = f.assign[x] as usize;
                let r = recon(&f.channels[0], j, col[j], k);
                col[j] += 1;
                for i in 0..k {
                    let tol = 1e-4 * (1.0 + c[(x, i)].abs()) * (k as f64);
                    assert!((r[i] - c[(x, i)]).abs() < tol, "n {n} x {x} i {i}: {} vs {}", r[i], c[(x, i)]);
                }
            }
        }
    }

    #[test]
    fn reassignment_never_increases_the_error_and_finds_the_subspaces() {
        let (c, truth) = mixture(300, 8, 4, 2, 1e-3, 9);
        let coef = vec![c.clone(), c.clone(), c];
        // A bad start: texels dealt round-robin with an offset, so every cluster is mixed.
        let init: Vec<u16> = (0..300).map(|x| ((x / 7) % 4) as u16).collect();
        let f = fit(&coef, &init, [2; 3], 10, Precision::F32);
        for (i, &(before, after)) in f.err.iter().enumerate() {
            assert!(after <= before + 1e-12, "iteration {i}: {before} -> {after}");
            // Refitting (PCA is optimal for a fixed assignment) does not raise it either.
            if let Some(&(next, _)) = f.err.get(i + 1) {
                assert!(next <= after * (1.0 + 1e-9) + 1e-12, "refit after iteration {i}: {after} -> {next}");
            }
        }
        let last = f.err.last().expect("iterations").1;
        assert!(last < 1e-4, "final error {last} (noise floor ~ 6 * 1e-6 / 3 * 3)");
        // Same partition as the truth up to a relabelling.
        let mut map = std::collections::HashMap::new();
        for (a, b) in f.assign.iter().zip(&truth) {
            assert_eq!(*map.entry(*a).or_insert(*b), *b, "clusters match the subspaces");
        }
    }

    #[test]
    fn empty_and_surplus_clusters() {
        let (c, _) = mixture(5, 3, 1, 1, 0.1, 3);
        let coef = vec![c.clone(), c.clone(), c];
        // Seven cluster labels for five texels: two must go, none may stay empty.
        let init: Vec<u16> = vec![0, 0, 0, 6, 6];
        let f = fit(&coef, &init, [1; 3], 3, Precision::F16);
        let kc = f.channels[0].cluster_mean.len();
        assert_eq!(kc, 5, "every texel its own cluster at most");
        for j in 0..kc as u16 {
            assert!(f.assign.contains(&j), "cluster {j} is not empty");
        }
        for ch in &f.channels {
            for v in ch.cluster_basis.iter().chain(&ch.cluster_mean).chain(&ch.coef).flatten() {
                assert_eq!(*v, half::f16::from_f32(*v).to_f32(), "f16 values are rounded");
            }
        }
    }
}
