//! Self-shadowing and self-occlusion maps on top of an SBRDF (seed 003).
//!
//! An SBRDF (per-texel reflectance model, here [`crate::lafortune`]) has no shadows or masking
//! of the surface's own relief. Seed 003 adds two factors per texel, each in `[0, 1]`:
//!
//! ```text
//! I_c(l, v) ≈ S(t, l) · O(t, v) · B_c(t, l, v)
//! ```
//!
//! `B` is the SBRDF's prediction, `S` the self-shadowing factor (one per light direction:
//! view-independent) and `O` the self-occlusion factor (one per view direction:
//! light-independent). They are fitted per texel by alternating least squares over the
//! measured (light, view) pairs, each factor having a closed form given the other
//! (`S(l) = Σ I·O·B / Σ (O·B)²` over the pairs with that light, summed over channels),
//! kept `≥ 0`. The SBRDF was fitted to shadowed data, so it is too dark where the texel is lit
//! and seen: the factors may exceed 1 during the fit, and at the end each texel's largest
//! `S` and largest `O` are divided out into a per-texel gain `g` (which folds into the SBRDF
//! exactly: `ρ·g` and, for a Lafortune lobe, `C·g^{1/n}`):
//! `I ≈ g(t) · S(t, l) · O(t, v) · B`, with `S, O ∈ [0, 1]` and the largest of each 1.
//! A light or view whose predictions are all ~0 has nothing to say and keeps the factor 1;
//! constant or zero input gives finite factors, never NaN. The maps store
//! `texels × (light directions + view directions)` values (8 bits each suffice for
//! `[0, 1]`) plus the gain; at an unmeasured direction the nearest stored one is used.

use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};

/// Directions closer than this (Euclidean, unit vectors) are the same light or view.
const SAME_DIRECTION: f64 = 1e-6;

/// The observations and the SBRDF's prediction of each.
#[derive(Debug, Clone, Copy)]
pub struct ShadowInput<'a> {
    /// Texels per image.
    pub texels: usize,
    /// Light direction of each image (sample frame).
    pub lights: &'a [[f64; 3]],
    /// View direction of each image.
    pub views: &'a [[f64; 3]],
    /// The measured images.
    pub images: &'a [&'a [[f32; 3]]],
    /// The SBRDF's prediction of each image.
    pub base: &'a [&'a [[f32; 3]]],
}

/// Tuning of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ShadowParams {
    /// Alternating rounds.
    pub iterations: usize,
}

impl Default for ShadowParams {
    fn default() -> Self {
        ShadowParams { iterations: 50 }
    }
}

/// The self-shadowing and self-occlusion maps.
#[derive(Debug, Clone, Serialize)]
pub struct ShadowOcclusionMaps {
    /// Texels.
    pub texels: usize,
    /// The distinct light directions, one shadowing factor each per texel.
    pub light_dirs: Vec<[f64; 3]>,
    /// The distinct view directions, one occlusion factor each per texel.
    pub view_dirs: Vec<[f64; 3]>,
    /// `S`: `texels × light_dirs.len()`, texel-major, in `[0, 1]`.
    pub shadow: Vec<f32>,
    /// `O`: `texels × view_dirs.len()`, texel-major, in `[0, 1]`.
    pub occlusion: Vec<f32>,
    /// `g`: per texel, the SBRDF's brightness correction (the factors' maxima).
    pub gain: Vec<f32>,
}

/// The distinct directions of `dirs` and each one's index into them.
pub(crate) fn distinct(dirs: &[[f64; 3]]) -> (Vec<[f64; 3]>, Vec<usize>) {
    let mut uniq: Vec<[f64; 3]> = Vec::new();
    let idx = dirs
        .iter()
        .map(|d| {
            if let Some(j) = uniq.iter().position(|u| dist2(u, d) < SAME_DIRECTION * SAME_DIRECTION) {
                j
            } else {
                uniq.push(*d);
                uniq.len() - 1
            }
        })
        .collect();
    (uniq, idx)
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// The index of the direction of `dirs` nearest `d`.
pub(crate) fn nearest(dirs: &[[f64; 3]], d: &[f64; 3]) -> usize {
    let mut best = (f64::INFINITY, 0);
    for (j, u) in dirs.iter().enumerate() {
        let e = dist2(u, d);
        if e < best.0 {
            best = (e, j);
        }
    }
    best.1
}

impl ShadowOcclusionMaps {
    /// Values stored per texel (the factors and the gain).
    pub fn values_per_texel(&self) -> usize {
        self.light_dirs.len() + self.view_dirs.len() + 1
    }

    /// `g(t) · S(t, l) · O(t, v)` at the nearest stored directions.
    pub fn factor(&self, t: usize, l: &[f64; 3], v: &[f64; 3]) -> f32 {
        let (nl, nv) = (self.light_dirs.len(), self.view_dirs.len());
        self.gain[t]
            * self.shadow[t * nl + nearest(&self.light_dirs, l)]
            * self.occlusion[t * nv + nearest(&self.view_dirs, v)]
    }

    /// The combined model's texture: the SBRDF's texture `base` for `(l, v)` times the factors.
    pub fn apply(&self, l: &[f64; 3], v: &[f64; 3], base: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let (li, vi) = (nearest(&self.light_dirs, l), nearest(&self.view_dirs, v));
        let (nl, nv) = (self.light_dirs.len(), self.view_dirs.len());
        base.iter()
            .enumerate()
            .map(|(t, b)| {
                let f = self.gain[t] * self.shadow[t * nl + li] * self.occlusion[t * nv + vi];
                b.map(|x| x * f)
            })
            .collect()
    }
}

/// Fits the maps (module documentation).
pub fn fit(input: &ShadowInput<'_>, params: &ShadowParams) -> Result<ShadowOcclusionMaps> {
    let n = input.images.len();
    if n == 0 || input.texels == 0 {
        return Err(ModelError::Empty("shadow/occlusion maps: no images or no texels".into()));
    }
    for (what, got) in [
        ("light directions", input.lights.len()),
        ("view directions", input.views.len()),
        ("SBRDF predictions", input.base.len()),
    ] {
        if got != n {
            return Err(ModelError::WrongSize { what: what.into(), got, expected: n });
        }
    }
    for (i, (im, b)) in input.images.iter().zip(input.base).enumerate() {
        for (what, got) in [("image", im.len()), ("SBRDF prediction", b.len())] {
            if got != input.texels {
                return Err(ModelError::WrongSize { what: format!("{what} {i}"), got, expected: input.texels });
            }
        }
        if let Some(x) = im.iter().chain(b.iter()).flatten().find(|x| !x.is_finite()) {
            return Err(ModelError::OutOfRange {
                field: format!("image or prediction {i}"),
                value: x.to_string(),
                allowed: "finite values".into(),
            });
        }
    }
    let (light_dirs, li) = distinct(input.lights);
    let (view_dirs, vi) = distinct(input.views);
    let (nl, nv) = (light_dirs.len(), view_dirs.len());
    let per_texel: Vec<(Vec<f32>, Vec<f32>, f32)> = (0..input.texels)
        .into_par_iter()
        .map(|t| {
            // Per image: Σ_c I·B and Σ_c B² (the only sums the updates need).
            let ib: Vec<f64> = (0..n)
                .map(|i| (0..3).map(|c| f64::from(input.images[i][t][c]) * f64::from(input.base[i][t][c])).sum())
                .collect();
            let bb: Vec<f64> = (0..n).map(|i| (0..3).map(|c| f64::from(input.base[i][t][c]).powi(2)).sum()).collect();
            let floor = 1e-12 * bb.iter().cloned().fold(0.0, f64::max).max(1e-300);
            let mut s = vec![1.0f64; nl];
            let mut o = vec![1.0f64; nv];
            let update = |f: &mut [f64], other: &[f64], own: &[usize], oth: &[usize]| {
                let mut num = vec![0.0; f.len()];
                let mut den = vec![0.0; f.len()];
                for i in 0..n {
                    num[own[i]] += ib[i] * other[oth[i]];
                    den[own[i]] += bb[i] * other[oth[i]] * other[oth[i]];
                }
                for j in 0..f.len() {
                    if den[j] > floor {
                        f[j] = (num[j] / den[j]).max(0.0);
                    }
                }
            };
            for _ in 0..params.iterations {
                update(&mut s, &o, &li, &vi);
                update(&mut o, &s, &vi, &li);
                // Keep the split balanced (the product's scale is free during the fit).
                let m = o.iter().cloned().fold(0.0, f64::max);
                if m > 1e-12 {
                    o.iter_mut().for_each(|x| *x /= m);
                    s.iter_mut().for_each(|x| *x *= m);
                }
            }
            let mut g = 1.0;
            for f in [&mut s, &mut o] {
                let m = f.iter().cloned().fold(0.0, f64::max);
                if m > 1e-12 {
                    f.iter_mut().for_each(|x| *x /= m);
                    g *= m;
                } else {
                    g = 0.0;
                }
            }
            (s.iter().map(|&x| x as f32).collect(), o.iter().map(|&x| x as f32).collect(), g as f32)
        })
        .collect();
    let mut shadow = Vec::with_capacity(input.texels * nl);
    let mut occlusion = Vec::with_capacity(input.texels * nv);
    let mut gain = Vec::with_capacity(input.texels);
    for (s, o, g) in per_texel {
        shadow.extend(s);
        occlusion.extend(o);
        gain.push(g);
    }
    Ok(ShadowOcclusionMaps { texels: input.texels, light_dirs, view_dirs, shadow, occlusion, gain })
}
