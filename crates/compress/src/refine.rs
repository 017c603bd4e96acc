//! Local-PCA reassignment on the data itself (Kambhatla & Leen 1997; Müller et al. 2003):
//! the step of PCMF that moves every texel to the cluster whose affine rank-$k$ model
//! reconstructs its ABRDF best, measured on every measured row of every channel.
//!
//! With cluster $j$'s model in channel $c$ — mean ABRDF $\mu_{jc}$ and orthonormal basis
//! $U_{jc}$ ($R \times k_c$, $R$ the measured rows) — the squared reconstruction error of texel
//! $x$ (ABRDF $b_{xc}$) is
//!
//! $$e_j(x) = \sum_c \lVert b_{xc} - \mu_{jc}\rVert^2 - \lVert U_{jc}^\top (b_{xc} - \mu_{jc})\rVert^2
//!          = \sum_c \lVert b_{xc}\rVert^2 - 2\mu_{jc}^\top b_{xc} + \lVert\mu_{jc}\rVert^2
//!            - \lVert U_{jc}^\top b_{xc} - U_{jc}^\top\mu_{jc}\rVert^2 .$$
//!
//! Everything it needs from the data is $\lVert b_{xc}\rVert^2$ and the projections
//! $[\mu_{jc}, U_{jc}]^\top b_{xc}$: sums over rows, so one streaming pass in any order
//! accumulates them, $P_c \mathrel{+}= A_c[a,:]^\top x_{ac}$ with $A_c = [\mu_{1c}, U_{1c}, \dots]$
//! ($R \times C(k_c + 1)$), batched into matrix products. Memory: $P_c$, $C (k_c + 1) \times n$
//! in `f64` per channel (the products of a batch in `f32`, added in `f64`).
//!
//! [`Reassign::finish`] gives every texel the cluster of least error and reports the total
//! error under the old and the new assignment (the old one is the current model's squared
//! error against the data, before storage rounding). An emptied cluster is re-seeded with
//! the worst-reconstructed texels of clusters that keep at least one.

use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One cluster's model in one channel, on the measured rows.
pub struct ClusterModel {
    /// Mean ABRDF (one value per measured row).
    pub mean: Vec<f64>,
    /// Orthonormal basis, measured rows x k.
    pub u: DMatrix<f64>,
}

/// What one reassignment did.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RefineStep {
    /// Texels that changed cluster.
    pub moved: usize,
    /// Relative RMS reconstruction error of the models against the data with the assignment
    /// they were fitted to: $\sqrt{\sum_x e_{k(x)}(x) / \sum_x \lVert b_x\rVert^2}$.
    pub rel_err_before: f64,
    /// The same with every texel in its best cluster (before the models are refitted).
    pub rel_err_after: f64,
    /// Smallest cluster after the move, texels.
    pub min_cluster: usize,
    /// Largest cluster after the move, texels.
    pub max_cluster: usize,
}

/// The accumulator of one reassignment pass (see the module documentation).
pub struct Reassign {
    n: usize,
    kc: usize,
    k: [usize; 3],
    rowmap: Vec<u32>,
    a: Vec<DMatrix<f32>>,
    mu2: Vec<Vec<f64>>,
    umu: Vec<Vec<Vec<f64>>>,
    p: Vec<DMatrix<f64>>,
    x2: Vec<f64>,
    batch: usize,
    rows: Vec<u32>,
    tex: Vec<Vec<[f32; 3]>>,
}

impl Reassign {
    /// An accumulator for `n` texels; `rowmap[a]` the measured row of angular index `a`
    /// (`u32::MAX`: not measured); `models[c][j]` cluster `j`'s model in channel `c`.
    pub fn new(rowmap: Vec<u32>, n: usize, models: &[Vec<ClusterModel>], batch: usize) -> Self {
        let kc = models[0].len();
        let r = rowmap.iter().filter(|&&x| x != u32::MAX).count();
        // A small cluster may have fewer terms than the others (rank at most its texels): its
        // missing columns are zero, which project nothing.
        let k: [usize; 3] = std::array::from_fn(|c| models[c].iter().map(|m| m.u.ncols()).max().unwrap_or(0));
        let mut a = Vec::with_capacity(3);
        let mut mu2 = Vec::with_capacity(3);
        let mut umu = Vec::with_capacity(3);
        for (c, ms) in models.iter().enumerate() {
            let w = k[c] + 1;
            let mut ac = DMatrix::<f32>::zeros(r, kc * w);
            let (mut m2, mut um) = (Vec::with_capacity(kc), Vec::with_capacity(kc));
            for (j, m) in ms.iter().enumerate() {
                for row in 0..r {
                    ac[(row, j * w)] = m.mean[row] as f32;
                    for i in 0..m.u.ncols() {
                        ac[(row, j * w + 1 + i)] = m.u[(row, i)] as f32;
                    }
                }
                m2.push(m.mean.iter().map(|v| v * v).sum::<f64>());
                um.push(
                    (0..k[c])
                        .map(|i| {
                            if i < m.u.ncols() {
                                (0..r).map(|row| m.u[(row, i)] * m.mean[row]).sum::<f64>()
                            } else {
                                0.0
                            }
                        })
                        .collect(),
                );
            }
            a.push(ac);
            mu2.push(m2);
            umu.push(um);
        }
        let p = (0..3).map(|c| DMatrix::<f64>::zeros(kc * (k[c] + 1), n)).collect();
        Reassign {
            n,
            kc,
            k,
            rowmap,
            a,
            mu2,
            umu,
            p,
            x2: vec![0.0; n],
            batch: batch.max(1),
            rows: Vec::new(),
            tex: Vec::new(),
        }
    }

    /// Adds the texture of angular index `a` (colour-transformed channel values).
    pub fn push(&mut self, a: usize, d: &[[f32; 3]]) {
        let r = self.rowmap[a];
        if r == u32::MAX {
            return;
        }
        self.rows.push(r);
        self.tex.push(d.to_vec());
        if self.rows.len() >= self.batch {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.rows.is_empty() {
            return;
        }
        let (rows, tex, n) = (&self.rows, &self.tex, self.n);
        let b = rows.len();
        self.p.par_iter_mut().zip(self.a.par_iter()).enumerate().for_each(|(c, (p, a))| {
            let xb = DMatrix::<f32>::from_fn(b, n, |i, x| tex[i][x][c]);
            let abt = DMatrix::<f32>::from_fn(a.ncols(), b, |col, i| a[(rows[i] as usize, col)]);
            let prod = abt * xb;
            for (pv, &q) in p.iter_mut().zip(prod.iter()) {
                *pv += f64::from(q);
            }
        });
        for t in tex {
            for (s, v) in self.x2.iter_mut().zip(t) {
                *s += v.iter().map(|&z| f64::from(z) * f64::from(z)).sum::<f64>();
            }
        }
        self.rows.clear();
        self.tex.clear();
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.a.iter().map(|a| a.len() * 4).sum::<usize>()
            + self.p.iter().map(|p| p.len() * 8).sum::<usize>()
            + self.x2.len() * 8
            + self.tex.len() * self.n * 12
            + self.rowmap.len() * 4
    }

    /// Squared error of texel `x` under cluster `j`.
    fn error(&self, x: usize, j: usize) -> f64 {
        let mut e = self.x2[x];
        for c in 0..3 {
            let w = self.k[c] + 1;
            let col = self.p[c].column(x);
            e += self.mu2[c][j] - 2.0 * col[j * w];
            for i in 0..self.k[c] {
                let d = col[j * w + 1 + i] - self.umu[c][j][i];
                e -= d * d;
            }
        }
        e.max(0.0)
    }

    /// The new assignment (labels `0..clusters`, every cluster non-empty while there are at
    /// least as many texels) and what it changed, given the current one.
    pub fn finish(mut self, current: &[u16]) -> (Vec<u16>, RefineStep) {
        self.flush();
        let kc = self.kc;
        let best: Vec<(u16, f64, f64)> = (0..self.n)
            .into_par_iter()
            .map(|x| {
                let mut b = (0u16, f64::INFINITY);
                for j in 0..kc {
                    let e = self.error(x, j);
                    if e < b.1 {
                        b = (j as u16, e);
                    }
                }
                (b.0, b.1, self.error(x, current[x] as usize))
            })
            .collect();
        let total: f64 = self.x2.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        let before: f64 = best.iter().map(|b| b.2).sum();
        let after: f64 = best.iter().map(|b| b.1).sum();
        let mut assign: Vec<u16> = best.iter().map(|b| b.0).collect();
        crate::cluster::reseed_empty_clusters(&mut assign, kc, |x| best[x].1);
        let mut counts = vec![0usize; kc];
        for &j in &assign {
            counts[j as usize] += 1;
        }
        let moved = assign.iter().zip(current).filter(|(a, b)| a != b).count();
        let step = RefineStep {
            moved,
            rel_err_before: (before / total).sqrt(),
            rel_err_after: (after / total).sqrt(),
            min_cluster: counts.iter().copied().min().unwrap_or(0),
            max_cluster: counts.iter().copied().max().unwrap_or(0),
        };
        (assign, step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// The streamed error equals the direct residual `‖b − μ − U Uᵀ(b − μ)‖²`, and texels
    /// generated by one cluster's model go to that cluster.
    #[test]
    fn streamed_errors_equal_direct_residuals_and_pick_the_generating_cluster() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
        for (r, n, kc, k) in [(7usize, 30usize, 2usize, 1usize), (40, 200, 4, 3), (65, 120, 3, 5)] {
            // Models per channel and cluster: random mean, orthonormal basis.
            let models: Vec<Vec<ClusterModel>> = (0..3)
                .map(|_| {
                    (0..kc)
                        .map(|_| {
                            let m = DMatrix::<f64>::from_fn(r, k, |_, _| g());
                            let q = m.qr().q();
                            ClusterModel { mean: (0..r).map(|_| 3.0 * g()).collect(), u: q.columns(0, k).into() }
                        })
                        .collect()
                })
                .collect();
            // Texel x is generated by cluster x % kc, plus small noise.
            let truth: Vec<u16> = (0..n).map(|x| (x % kc) as u16).collect();
            let mut b = vec![vec![[0f32; 3]; n]; r];
            for x in 0..n {
                for c in 0..3 {
                    let m = &models[c][truth[x] as usize];
                    let coef: Vec<f64> = (0..k).map(|_| 2.0 * g()).collect();
                    for row in 0..r {
                        let v = m.mean[row] + (0..k).map(|i| m.u[(row, i)] * coef[i]).sum::<f64>() + 1e-3 * g();
                        b[row][x][c] = v as f32;
                    }
                }
            }
            // Rows arrive in reverse order, two unmeasured angular indices in between.
            let mut rowmap: Vec<u32> = (0..r as u32).collect();
            rowmap.insert(1, u32::MAX);
            rowmap.push(u32::MAX);
            let mut acc = Reassign::new(rowmap.clone(), n, &models, 4);
            for a in (0..rowmap.len()).rev() {
                if rowmap[a] != u32::MAX {
                    acc.push(a, &b[rowmap[a] as usize]);
                } else {
                    acc.push(a, &vec![[1e9f32; 3]; n]);
                }
            }
            acc.flush();
            for x in [0, n / 2, n - 1] {
                for j in 0..kc {
                    let mut direct = 0.0;
                    for c in 0..3 {
                        let m = &models[c][j];
                        let d = nalgebra::DVector::from_fn(r, |row, _| f64::from(b[row][x][c]) - m.mean[row]);
                        let res = &d - &m.u * (m.u.transpose() * &d);
                        direct += res.norm_squared();
                    }
                    let streamed = acc.error(x, j);
                    let scale =
                        (0..r).map(|row| (0..3).map(|c| f64::from(b[row][x][c]).powi(2)).sum::<f64>()).sum::<f64>();
                    assert!((streamed - direct).abs() <= 1e-5 * scale, "r {r} x {x} j {j}: {streamed} vs {direct}");
                }
            }
            let wrong: Vec<u16> = truth.iter().map(|&j| ((j as usize + 1) % kc) as u16).collect();
            let (assign, step) = acc.finish(&wrong);
            assert_eq!(assign, truth, "r {r} n {n}");
            assert_eq!(step.moved, n);
            assert!(step.rel_err_after < 1e-2 && step.rel_err_before > 10.0 * step.rel_err_after, "{step:?}");
        }
    }
}
