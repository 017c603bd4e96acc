//! BTF space segmentation (seed 002, II.A): k-means over the (light, view) pairs' textures.
//!
//! Pixel-wise comparison of textures seen from different views is meaningless (masking moves
//! the texels), so a pair is described by its colour distribution only, as the seed does with
//! cumulative colour histograms in CIE Lab: here the inverse of the cumulative histogram, the
//! deciles 10..90 % of each channel after a cube root (Lab's lightness is a cube root of
//! luminance: equal steps are roughly equally visible). 27 features per pair. k-means++
//! seeding from a seeded ChaCha8 stream, then Lloyd iterations to a fixed point; an emptied
//! cluster takes the pair farthest from its centre.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Deciles per channel in the features.
const DECILES: usize = 9;

/// The features of one texture (`3 × 9` cube-rooted deciles).
pub fn features(image: &[[f32; 3]]) -> Vec<f64> {
    let mut out = Vec::with_capacity(3 * DECILES);
    for c in 0..3 {
        let mut v: Vec<f64> = image.iter().map(|p| f64::from(p[c]).max(0.0).cbrt()).collect();
        v.sort_by(f64::total_cmp);
        for d in 1..=DECILES {
            out.push(v[(d * (v.len() - 1)) / (DECILES + 1)]);
        }
    }
    out
}

fn dist2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum()
}

/// The nearest of `centres` to `p`.
fn nearest(centres: &[Vec<f64>], p: &[f64]) -> (usize, f64) {
    centres
        .iter()
        .enumerate()
        .map(|(j, c)| (j, dist2(c, p)))
        .fold((0, f64::INFINITY), |b, x| if x.1 < b.1 { x } else { b })
}

/// The cluster of every point (`k` clusters at most, fewer when there are fewer distinct
/// points), seeded and deterministic.
pub fn kmeans(points: &[Vec<f64>], k: usize, seed: u64) -> Vec<usize> {
    let n = points.len();
    if n == 0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut centres = vec![points[rng.gen_range(0..n)].clone()];
    while centres.len() < k.min(n) {
        let d: Vec<f64> = points.iter().map(|p| nearest(&centres, p).1).collect();
        let total: f64 = d.iter().sum();
        if total <= 0.0 {
            break; // every point sits on a centre
        }
        let mut t = rng.gen::<f64>() * total;
        let pick = d.iter().position(|&x| {
            t -= x;
            t < 0.0
        });
        centres.push(points[pick.unwrap_or(n - 1)].clone());
    }
    let mut assign = vec![usize::MAX; n];
    for _ in 0..100 {
        let next: Vec<usize> = points.iter().map(|p| nearest(&centres, p).0).collect();
        if next == assign {
            break;
        }
        assign = next;
        for (j, c) in centres.iter_mut().enumerate() {
            let members: Vec<&Vec<f64>> =
                points.iter().zip(&assign).filter(|(_, a)| **a == j).map(|(p, _)| p).collect();
            if members.is_empty() {
                continue;
            }
            for (i, x) in c.iter_mut().enumerate() {
                *x = members.iter().map(|m| m[i]).sum::<f64>() / members.len() as f64;
            }
        }
        // An emptied cluster takes the point farthest from its own centre.
        for j in 0..centres.len() {
            if !assign.contains(&j) {
                let far = (0..n).max_by(|&a, &b| {
                    dist2(&points[a], &centres[assign[a]]).total_cmp(&dist2(&points[b], &centres[assign[b]]))
                });
                if let Some(f) = far {
                    centres[j] = points[f].clone();
                    assign[f] = j;
                }
            }
        }
    }
    // Renumber by first appearance, so cluster ids are dense.
    let mut ids: Vec<usize> = Vec::new();
    assign
        .iter()
        .map(|a| match ids.iter().position(|x| x == a) {
            Some(i) => i,
            None => {
                ids.push(*a);
                ids.len() - 1
            }
        })
        .collect()
}
