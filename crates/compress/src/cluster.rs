//! Clustering of ABRDFs for the per-cluster model (local PCA, Kambhatla & Leen 1997).
//!
//! Input: every texel's ABRDF as its coefficient vector $c_x \in \mathbb{R}^K$ in a global
//! orthonormal angular basis (the first pass of PCMF, an FMF of the luminance channel), so
//! Euclidean distances between coefficient vectors are distances between the projected
//! ABRDFs. Seeded k-means++ and Lloyd iterations give a first partition; then local PCA
//! iterations: each cluster $j$ gets its mean $\mu_j$ and top-$k$ principal directions $E_j$,
//! and each texel moves to the cluster that reconstructs it best,
//! $\arg\min_j \lVert c_x - \mu_j\rVert^2 - \lVert E_j^\top (c_x - \mu_j)\rVert^2$
//! (the residual of the affine rank-$k$ model; the part of the ABRDF outside the global basis
//! is the same for every cluster and does not change the choice). An emptied cluster is
//! re-seeded with the worst-reconstructed texel.

use nalgebra::DMatrix;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::linalg::sorted_eigen;

/// Knobs of the clustering.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusterParams {
    /// Number of clusters.
    pub clusters: usize,
    /// Terms of each cluster's local PCA (the reconstruction-error metric).
    pub terms: usize,
    /// Lloyd (k-means) iterations.
    pub kmeans_iters: usize,
    /// Local-PCA reassignment iterations.
    pub local_iters: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
}

/// Cluster index of every point (row of `points`, n x K).
pub fn cluster(points: &DMatrix<f64>, p: &ClusterParams) -> Vec<u16> {
    let (n, dim) = points.shape();
    let kc = p.clusters.min(n).max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    // k-means++.
    let mut centres: Vec<Vec<f64>> = Vec::with_capacity(kc);
    let row = |i: usize| -> Vec<f64> { points.row(i).iter().copied().collect() };
    centres.push(row(rng.gen_range(0..n)));
    let mut d2: Vec<f64> = (0..n).map(|i| dist2(points, i, &centres[0])).collect();
    while centres.len() < kc {
        let total: f64 = d2.iter().sum();
        let pick = if total > 0.0 {
            let mut t = rng.gen::<f64>() * total;
            let mut idx = n - 1;
            for (i, &d) in d2.iter().enumerate() {
                if t < d {
                    idx = i;
                    break;
                }
                t -= d;
            }
            idx
        } else {
            rng.gen_range(0..n)
        };
        centres.push(row(pick));
        let c = centres.last().expect("just pushed");
        for (i, d) in d2.iter_mut().enumerate() {
            *d = d.min(dist2(points, i, c));
        }
    }
    let mut assign: Vec<u16> = vec![0; n];
    for _ in 0..p.kmeans_iters.max(1) {
        let mut changed = false;
        for (i, a) in assign.iter_mut().enumerate() {
            let best = (0..kc)
                .min_by(|&x, &y| dist2(points, i, &centres[x]).total_cmp(&dist2(points, i, &centres[y])))
                .expect("clusters") as u16;
            changed |= *a != best;
            *a = best;
        }
        let (means, counts) = means(points, &assign, kc);
        for j in 0..kc {
            if counts[j] > 0 {
                centres[j] = means[j].clone();
            }
        }
        if !changed {
            break;
        }
    }
    // Local PCA.
    let k = p.terms.min(dim);
    for _ in 0..p.local_iters {
        let (mu, counts) = means(points, &assign, kc);
        let mut bases: Vec<DMatrix<f64>> = Vec::with_capacity(kc);
        for j in 0..kc {
            let mut cov = DMatrix::<f64>::zeros(dim, dim);
            if counts[j] > 0 {
                let members: Vec<usize> = (0..n).filter(|&i| assign[i] as usize == j).collect();
                let d = DMatrix::from_fn(members.len(), dim, |r, c| points[(members[r], c)] - mu[j][c]);
                cov = d.transpose() * &d;
            }
            let (_, v) = sorted_eigen(cov);
            bases.push(v.columns(0, k).clone_owned());
        }
        let errs: Vec<(u16, f64)> = {
            use rayon::prelude::*;
            (0..n)
                .into_par_iter()
                .map(|i| {
                    let mut best = (0u16, f64::INFINITY);
                    for j in 0..kc {
                        if counts[j] == 0 {
                            continue;
                        }
                        let d = nalgebra::DVector::from_fn(dim, |c, _| points[(i, c)] - mu[j][c]);
                        let proj = bases[j].transpose() * &d;
                        let e = d.norm_squared() - proj.norm_squared();
                        if e < best.1 {
                            best = (j as u16, e);
                        }
                    }
                    best
                })
                .collect()
        };
        let mut changed = 0usize;
        for (i, &(j, _)) in errs.iter().enumerate() {
            if assign[i] != j {
                changed += 1;
                assign[i] = j;
            }
        }
        // Re-seed empty clusters with the worst-reconstructed points.
        changed += reseed_empty_clusters(&mut assign, kc, |i| errs[i].1);
        if changed == 0 {
            break;
        }
    }
    assign
}

/// Gives every empty cluster of `assign` (clusters `0..kc`) one point: the worst
/// reconstructed (largest `err`) of the points whose cluster keeps another member. Returns
/// how many points moved. Local PCA and k-means both leave clusters empty at times.
pub fn reseed_empty_clusters(assign: &mut [u16], kc: usize, err: impl Fn(usize) -> f64) -> usize {
    let mut counts = vec![0usize; kc];
    for &a in assign.iter() {
        counts[a as usize] += 1;
    }
    let mut worst: Vec<usize> = (0..assign.len()).collect();
    worst.sort_by(|&a, &b| err(b).total_cmp(&err(a)));
    let mut w = worst.into_iter();
    let mut moved = 0;
    for j in 0..kc {
        if counts[j] == 0 {
            for i in w.by_ref() {
                if counts[assign[i] as usize] > 1 {
                    counts[assign[i] as usize] -= 1;
                    assign[i] = j as u16;
                    counts[j] = 1;
                    moved += 1;
                    break;
                }
            }
        }
    }
    moved
}

fn dist2(points: &DMatrix<f64>, i: usize, c: &[f64]) -> f64 {
    c.iter().enumerate().map(|(j, &x)| (points[(i, j)] - x).powi(2)).sum()
}

fn means(points: &DMatrix<f64>, assign: &[u16], kc: usize) -> (Vec<Vec<f64>>, Vec<usize>) {
    let dim = points.ncols();
    let mut sums = vec![vec![0.0; dim]; kc];
    let mut counts = vec![0usize; kc];
    for (i, &a) in assign.iter().enumerate() {
        counts[a as usize] += 1;
        for j in 0..dim {
            sums[a as usize][j] += points[(i, j)];
        }
    }
    for j in 0..kc {
        if counts[j] > 0 {
            for v in &mut sums[j] {
                *v /= counts[j] as f64;
            }
        }
    }
    (sums, counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, StandardNormal};

    fn g(rng: &mut ChaCha8Rng) -> f64 {
        StandardNormal.sample(rng)
    }

    #[test]
    fn separates_points_on_distinct_subspaces() {
        // Three clusters, each a different 2-D affine subspace of R^10 with small noise.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let dim = 10;
        let per = 200;
        let mut truth = Vec::new();
        let mut rows = Vec::new();
        for j in 0..3 {
            let basis = DMatrix::<f64>::from_fn(dim, 2, |_, _| g(&mut rng));
            let mu: Vec<f64> = (0..dim).map(|_| 5.0 * g(&mut rng)).collect();
            for _ in 0..per {
                let c = nalgebra::DVector::<f64>::from_fn(2, |_, _| 3.0 * g(&mut rng));
                let x = &basis * c;
                rows.push((0..dim).map(|d| mu[d] + x[d] + 0.01 * g(&mut rng)).collect::<Vec<f64>>());
                truth.push(j);
            }
        }
        let pts = DMatrix::from_fn(rows.len(), dim, |r, c| rows[r][c]);
        let a = cluster(&pts, &ClusterParams { clusters: 3, terms: 2, kmeans_iters: 10, local_iters: 10, seed: 1 });
        // Same partition up to relabelling: every true cluster maps to one label.
        for j in 0..3 {
            let labels: std::collections::BTreeSet<u16> =
                (0..rows.len()).filter(|&i| truth[i] == j).map(|i| a[i]).collect();
            assert_eq!(labels.len(), 1, "true cluster {j} split over {labels:?}");
        }
    }
}
