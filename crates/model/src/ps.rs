//! Calibrated photometric stereo: per-texel normal, albedo and their uncertainty.
//!
//! A Lambertian texel with albedo `ρ` and unit normal `n`, lit from the unit direction `l`,
//! has the radiance factor `I = ρ max(0, n·l)` (a white Lambertian reflector lit along its
//! normal gives 1). With `b = ρ n` every lit observation is linear in `b`:
//!
//! ```text
//! I_i = l_iᵀ b,   i = 1..m      →   b = (Lᵀ W L)⁻¹ Lᵀ W I,   n = b/|b|,   ρ = |b|
//! ```
//!
//! [`PsMethod::LeastSquares`] is the classic method (Woodham 1980): `W = I`, every
//! observation. It is biased wherever the model does not hold: cast and attached shadows
//! (darker than `l·b`, often 0) pull `b` away from the shadowed lights, highlights towards
//! the mirror direction.
//!
//! [`PsMethod::Robust`] keeps the same model and changes which observations count:
//! 0. **a start from one value per light direction**: when a light direction was captured
//!    from several views (a gonio's views under one lamp position), steps 1–3 first run on
//!    one value per direction, the `group_quantile` of its views (by the channels' mean;
//!    default the median): a Lambertian texel looks the same from every view, while
//!    highlights are view-dependent and brighter. That fit is the start of step 3 on every
//!    observation, which then averages the views' noise and rejects their highlights;
//! 1. **shadow threshold**: observations darker than `shadow_fraction` of the texel's
//!    bright level are dropped (the 3 brightest are always kept). The bright level is the
//!    brightest value once the brightest fifth of the observations is set aside: a glossy
//!    texel's highlights are tens of times its diffuse level, and measured against the
//!    brightest (the rule before) every diffuse observation of lacquered wood counted as a
//!    shadow, leaving the fit to the highlights (16° mean error on the full plan's views up
//!    to 15°, `docs/material-models.md`);
//! 2. **leave-one-light-out start**: with 4 to 16 distinct light directions the start is the
//!    best of the fit on all of them and the fits leaving each direction out (scored by the
//!    Tukey loss below), so one shadowed or highlighted light cannot steer the start;
//! 3. **IRLS with Tukey's biweight** `w(r) = (1 − (r/cs)²)²` for `|r| < cs`, else 0, with
//!    `c = tukey_c` and the residual scale `s` the larger of 1.4826·MAD of the residuals
//!    (when there are at least 6 observations) and `relative_noise·|b|`; an observation
//!    whose model value `l·b` is ≤ 0 (attached shadow) gets weight 0.
//!
//! Uncertainty: the covariance of `b` is `σ² (Lᵀ W L)⁻¹`, `σ²` the weighted residual
//! variance (`relative_noise·|b|` when there are no residual degrees of freedom); the
//! normal's angular standard deviation is `sqrt(tr(P Σ P))/|b|` with `P = I − n nᵀ`.
//! Albedo per colour channel is the weighted least-squares `ρ_c = Σ w I_c s / Σ w s²`,
//! `s = n·l`; the normal comes from the mean of the channels.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};

/// Which estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PsMethod {
    /// Calibrated Lambertian least squares over every observation.
    LeastSquares,
    /// Shadow threshold, leave-one-light-out start, Tukey IRLS (module documentation).
    Robust,
}

impl PsMethod {
    /// Its name in files and tables.
    pub fn name(self) -> &'static str {
        match self {
            PsMethod::LeastSquares => "least-squares",
            PsMethod::Robust => "robust",
        }
    }
}

/// The fraction of a texel's observations, the brightest, left out of its bright level (the
/// reference of the shadow threshold).
const BRIGHT_LEVEL_SKIP: f64 = 0.2;

/// Tuning of [`photometric_stereo`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PsParams {
    /// The estimator.
    pub method: PsMethod,
    /// Robust: observations below this fraction of the texel's bright level (its brightest
    /// once the brightest fifth is set aside) are shadows.
    pub shadow_fraction: f64,
    /// Robust: Tukey's constant, in residual scales (4.685: 95 % efficiency for Gaussian noise).
    pub tukey_c: f64,
    /// Robust: IRLS iterations at most.
    pub iterations: usize,
    /// Noise floor, relative to `|b|` (the residual scale when there are no degrees of freedom).
    pub relative_noise: f64,
    /// Robust: the quantile of a light direction's observations over its views that stands
    /// for them (0: the darkest, 0.5: the median).
    pub group_quantile: f64,
    /// Two light directions closer than this (radians) are one direction (a gonio's views
    /// under the same lamp position).
    pub same_light_rad: f64,
}

impl PsParams {
    /// Defaults for `method`.
    pub fn new(method: PsMethod) -> Self {
        PsParams {
            method,
            shadow_fraction: 0.15,
            tukey_c: 4.685,
            iterations: 15,
            relative_noise: 0.03,
            group_quantile: 0.5,
            same_light_rad: 1e-3,
        }
    }
}

/// The observations of photometric stereo: `images[i]` is lit from `lights[i]` (unit vector
/// in the sample frame, `z` along the sample normal); all images share one texel grid
/// (rectified textures), row-major, `width * height` RGB radiance factors.
#[derive(Debug, Clone, Copy)]
pub struct PsInput<'a> {
    /// What the observations are (for messages: "view 3", "all captures").
    pub what: &'a str,
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Light direction of each image.
    pub lights: &'a [[f64; 3]],
    /// The images.
    pub images: &'a [&'a [[f32; 3]]],
}

/// Photometric stereo's result, row-major like the input.
#[derive(Debug, Clone, Serialize)]
pub struct NormalMap {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Unit normals (sample frame); `[0, 0, 1]` where a texel had no usable light.
    pub normal: Vec<[f64; 3]>,
    /// Lambertian albedo per colour channel.
    pub albedo: Vec<[f32; 3]>,
    /// Standard deviation of the normal's direction, degrees.
    pub sigma_deg: Vec<f32>,
    /// Observations with non-zero weight.
    pub used: Vec<u32>,
}

impl NormalMap {
    /// Surface gradients `(∂h/∂x, ∂h/∂y)` of each normal, with `n_z` clamped to `min_nz`
    /// (grazing normals would give unbounded slopes).
    pub fn gradients(&self, min_nz: f64) -> Vec<[f64; 2]> {
        self.normal.iter().map(|n| [-n[0] / n[2].max(min_nz), -n[1] / n[2].max(min_nz)]).collect()
    }

    /// Standard deviation of each gradient component from the angular one: a tilt `dθ`
    /// changes the slope `tan θ` by `dθ / cos² θ` (`cos θ = n_z`, clamped to `min_nz`).
    pub fn gradient_sigma(&self, min_nz: f64) -> Vec<f64> {
        self.normal
            .iter()
            .zip(&self.sigma_deg)
            .map(|(n, s)| f64::from(*s).to_radians() / n[2].max(min_nz).powi(2))
            .collect()
    }
}

/// Distinct light directions among `lights` (within `tol` radians), and each light's group.
pub fn light_groups(lights: &[[f64; 3]], tol: f64) -> (Vec<[f64; 3]>, Vec<usize>) {
    let mut reps: Vec<[f64; 3]> = Vec::new();
    let mut group = Vec::with_capacity(lights.len());
    let cos_tol = tol.cos();
    for l in lights {
        let found = reps.iter().position(|r| r[0] * l[0] + r[1] * l[1] + r[2] * l[2] >= cos_tol);
        match found {
            Some(g) => group.push(g),
            None => {
                group.push(reps.len());
                reps.push(*l);
            }
        }
    }
    (reps, group)
}

/// Smallest over largest eigenvalue of `Σ l lᵀ` over `lights`.
fn spread(lights: &[[f64; 3]]) -> f64 {
    let mut a = Matrix3::zeros();
    for l in lights {
        let v = Vector3::from(*l);
        a += v * v.transpose();
    }
    let e = a.symmetric_eigen().eigenvalues;
    let (lo, hi) = (e.min(), e.max());
    if hi > 0.0 {
        lo / hi
    } else {
        0.0
    }
}

/// Checks the input and says what is missing: at least 3 distinct, non-coplanar lights above
/// the surface, images of the grid's size, finite values.
pub fn check_input(input: &PsInput<'_>, params: &PsParams) -> Result<()> {
    let what = input.what.to_string();
    if input.width == 0 || input.height == 0 {
        return Err(ModelError::Empty(format!("{what}: an empty texel grid ({} x {})", input.width, input.height)));
    }
    if input.lights.len() != input.images.len() {
        return Err(ModelError::WrongSize {
            what: format!("{what}: light directions"),
            got: input.lights.len(),
            expected: input.images.len(),
        });
    }
    for (i, l) in input.lights.iter().enumerate() {
        let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        if !((norm - 1.0).abs() < 1e-6) || !(l[2] > 0.0) {
            return Err(ModelError::OutOfRange {
                field: format!("{what}: light {i}"),
                value: format!("{l:?}"),
                allowed: "a unit vector above the surface (z > 0)".into(),
            });
        }
    }
    for (i, img) in input.images.iter().enumerate() {
        if img.len() != input.width * input.height {
            return Err(ModelError::WrongSize {
                what: format!("{what}: image {i}"),
                got: img.len(),
                expected: input.width * input.height,
            });
        }
        if let Some(t) = img.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(ModelError::OutOfRange {
                field: format!("{what}: image {i}, texel {t}"),
                value: format!("{:?}", img[t]),
                allowed: "finite radiance factors".into(),
            });
        }
    }
    let (reps, _) = light_groups(input.lights, params.same_light_rad);
    if reps.len() < 3 {
        return Err(ModelError::TooFewLights { what, have: reps.len(), need: 3 });
    }
    let ratio = spread(&reps);
    let min = 1e-4;
    if !(ratio > min) {
        return Err(ModelError::DegenerateLights { what, have: reps.len(), ratio, min });
    }
    Ok(())
}

/// Per-texel photometric stereo (module documentation).
pub fn photometric_stereo(input: &PsInput<'_>, params: &PsParams) -> Result<NormalMap> {
    check_input(input, params)?;
    let n = input.width * input.height;
    let (reps, group) = light_groups(input.lights, params.same_light_rad);
    let lights: Vec<Vector3<f64>> = input.lights.iter().map(|l| Vector3::from(*l)).collect();
    let q = params.group_quantile;
    if !(0.0..=1.0).contains(&q) {
        return Err(ModelError::OutOfRange {
            field: "group_quantile".into(),
            value: q.to_string(),
            allowed: "0 ..= 1".into(),
        });
    }
    let grouped = params.method == PsMethod::Robust && reps.len() < lights.len();
    let rep_lights: Vec<Vector3<f64>> = reps.iter().map(|l| Vector3::from(*l)).collect();
    let identity: Vec<usize> = (0..reps.len()).collect();
    let members: Vec<Vec<usize>> =
        (0..reps.len()).map(|g| (0..group.len()).filter(|&i| group[i] == g).collect()).collect();
    let texels: Vec<TexelFit> = (0..n)
        .into_par_iter()
        .map_init(
            || (Scratch::new(input.images.len()), Scratch::new(reps.len()), Vec::new()),
            |(sc, sg, order), t| {
                for (i, img) in input.images.iter().enumerate() {
                    let p = img[t];
                    sc.rgb[i] = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
                    sc.grey[i] = (sc.rgb[i][0] + sc.rgb[i][1] + sc.rgb[i][2]) / 3.0;
                }
                if !grouped {
                    return fit_texel(&lights, &group, reps.len(), params, sc, None);
                }
                for (g, m) in members.iter().enumerate() {
                    order.clear();
                    order.extend_from_slice(m);
                    order.sort_by(|&a, &b| sc.grey[a].total_cmp(&sc.grey[b]));
                    let pick = order[((q * (order.len() - 1) as f64).round() as usize).min(order.len() - 1)];
                    sg.rgb[g] = sc.rgb[pick];
                    sg.grey[g] = sc.grey[pick];
                }
                let start = fit_texel(&rep_lights, &identity, reps.len(), params, sg, None);
                if start.used == 0 {
                    return start;
                }
                fit_texel(&lights, &group, reps.len(), params, sc, Some(start.b))
            },
        )
        .collect();
    let mut out = NormalMap {
        width: input.width,
        height: input.height,
        normal: Vec::with_capacity(n),
        albedo: Vec::with_capacity(n),
        sigma_deg: Vec::with_capacity(n),
        used: Vec::with_capacity(n),
    };
    for f in texels {
        out.normal.push(f.normal);
        out.albedo.push(f.albedo);
        out.sigma_deg.push(f.sigma_deg);
        out.used.push(f.used);
    }
    Ok(out)
}

struct Scratch {
    rgb: Vec<[f64; 3]>,
    grey: Vec<f64>,
    w: Vec<f64>,
}

impl Scratch {
    fn new(m: usize) -> Self {
        Scratch { rgb: vec![[0.0; 3]; m], grey: vec![0.0; m], w: vec![0.0; m] }
    }
}

struct TexelFit {
    normal: [f64; 3],
    albedo: [f32; 3],
    sigma_deg: f32,
    used: u32,
    /// `ρ n` of the channels' mean.
    b: Vector3<f64>,
}

/// Weighted least squares for `b`; `None` when the kept lights do not span 3 dimensions.
fn solve(lights: &[Vector3<f64>], y: &[f64], w: &[f64]) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let mut a = Matrix3::zeros();
    let mut r = Vector3::zeros();
    for ((l, &yi), &wi) in lights.iter().zip(y).zip(w) {
        if wi > 0.0 {
            a += wi * l * l.transpose();
            r += wi * yi * l;
        }
    }
    let e = a.symmetric_eigen().eigenvalues;
    if !(e.min() > 1e-6 * e.max().max(1e-300)) {
        return None;
    }
    let inv = a.try_inverse()?;
    Some((inv * r, inv))
}

fn tukey(r: f64, cs: f64) -> f64 {
    let u = r / cs;
    if u.abs() >= 1.0 {
        0.0
    } else {
        (1.0 - u * u).powi(2)
    }
}

fn tukey_loss(r: f64, cs: f64) -> f64 {
    let u = (r / cs).clamp(-1.0, 1.0);
    1.0 - (1.0 - u * u).powi(3)
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let k = v.len() / 2;
    if v.len() % 2 == 1 {
        v[k]
    } else {
        0.5 * (v[k - 1] + v[k])
    }
}

/// The residual scale of a fit: 1.4826·MAD over the weighted observations (6 or more), never
/// below the noise floor.
fn scale(lights: &[Vector3<f64>], y: &[f64], w: &[f64], b: &Vector3<f64>, params: &PsParams) -> f64 {
    let floor = (params.relative_noise * b.norm()).max(1e-6);
    let mut r: Vec<f64> =
        lights.iter().zip(y).zip(w).filter(|(_, &wi)| wi > 0.0).map(|((l, yi), _)| yi - l.dot(b)).collect();
    if r.len() < 6 {
        return floor;
    }
    let med = median(&mut r.clone());
    for x in &mut r {
        *x = (*x - med).abs();
    }
    (1.4826 * median(&mut r)).max(floor)
}

fn fit_texel(
    lights: &[Vector3<f64>],
    group: &[usize],
    n_groups: usize,
    params: &PsParams,
    sc: &mut Scratch,
    start: Option<Vector3<f64>>,
) -> TexelFit {
    let m = lights.len();
    let y = &sc.grey;
    let flat = TexelFit { normal: [0.0, 0.0, 1.0], albedo: [0.0; 3], sigma_deg: 90.0, used: 0, b: Vector3::zeros() };
    sc.w.fill(1.0);
    if params.method == PsMethod::Robust {
        let mut order: Vec<usize> = (0..m).collect();
        order.sort_by(|&a, &b| y[b].total_cmp(&y[a]));
        // The bright level: the brightest value once the brightest fifth is set aside, so
        // that highlights (a glossy texel's few near-mirror captures, tens of times the
        // diffuse level) cannot make every diffuse observation look like a shadow.
        let bright = y[order[(BRIGHT_LEVEL_SKIP * m as f64) as usize]];
        for (rank, &i) in order.iter().enumerate() {
            if rank >= 3 && y[i] < params.shadow_fraction * bright {
                sc.w[i] = 0.0;
            }
        }
    }
    let Some((mut b, _)) = solve(lights, y, &sc.w) else { return flat };
    if let Some(s) = start {
        b = s;
    }
    if params.method == PsMethod::Robust {
        // Leave one light direction out: the best start by Tukey loss.
        if start.is_none() && (4..=16).contains(&n_groups) {
            let base = sc.w.clone();
            let cost = |b: &Vector3<f64>| {
                let cs = params.tukey_c * scale(lights, y, &base, b, params);
                lights
                    .iter()
                    .zip(y)
                    .zip(&base)
                    .filter(|(_, &w)| w > 0.0)
                    .map(|((l, yi), _)| tukey_loss(yi - l.dot(b), cs))
                    .sum::<f64>()
            };
            let mut best = (cost(&b), b);
            let mut w = base.clone();
            for g in 0..n_groups {
                for i in 0..m {
                    w[i] = if group[i] == g { 0.0 } else { base[i] };
                }
                if let Some((bg, _)) = solve(lights, y, &w) {
                    let c = cost(&bg);
                    if c < best.0 {
                        best = (c, bg);
                    }
                }
            }
            b = best.1;
            sc.w.copy_from_slice(&base);
        }
        let keep = sc.w.clone();
        for _ in 0..params.iterations {
            let cs = params.tukey_c * scale(lights, y, &keep, &b, params);
            for i in 0..m {
                let pred = lights[i].dot(&b);
                sc.w[i] = if keep[i] > 0.0 && pred > 0.0 { tukey(y[i] - pred, cs) } else { 0.0 };
            }
            match solve(lights, y, &sc.w) {
                Some((nb, _)) => {
                    let done = (nb - b).norm() <= 1e-7 * nb.norm().max(1e-12);
                    b = nb;
                    if done {
                        break;
                    }
                }
                None => break,
            }
        }
        // Final weights at the solution.
        let cs = params.tukey_c * scale(lights, y, &keep, &b, params);
        for i in 0..m {
            let pred = lights[i].dot(&b);
            sc.w[i] = if keep[i] > 0.0 && pred > 0.0 { tukey(y[i] - pred, cs) } else { 0.0 };
        }
        if solve(lights, y, &sc.w).is_none() {
            sc.w.copy_from_slice(&keep);
        }
    }
    let Some((b2, inv)) = solve(lights, y, &sc.w) else { return flat };
    let b = if params.method == PsMethod::Robust { b2 } else { b };
    let rho = b.norm();
    if !(rho > 1e-12) {
        return flat;
    }
    let nrm = b / rho;
    // Residual variance with the weights' effective count.
    let (mut ss, mut sw, mut used) = (0.0, 0.0, 0u32);
    for i in 0..m {
        if sc.w[i] > 0.0 {
            let r = y[i] - lights[i].dot(&b);
            ss += sc.w[i] * r * r;
            sw += sc.w[i];
            used += 1;
        }
    }
    let floor = params.relative_noise * rho;
    let var = if sw > 3.5 { (ss / (sw - 3.0)).max(floor * floor * 0.01) } else { floor * floor };
    let cov = inv * var;
    let p = Matrix3::identity() - nrm * nrm.transpose();
    let tang = (p * cov * p).trace().max(0.0);
    let sigma_deg = (tang.sqrt() / rho).atan().to_degrees() as f32;
    // Weighted least squares per channel over the lit, weighted observations.
    let (mut num, mut den) = ([0.0f64; 3], 0.0);
    for ((l, &w), rgb) in lights.iter().zip(&sc.w).zip(&sc.rgb) {
        let s = nrm.dot(l);
        if w > 0.0 && s > 0.0 {
            den += w * s * s;
            for c in 0..3 {
                num[c] += w * rgb[c] * s;
            }
        }
    }
    let albedo = num.map(|x| if den > 0.0 { (x / den) as f32 } else { 0.0 });
    TexelFit { normal: [nrm.x, nrm.y, nrm.z], albedo, sigma_deg, used, b }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_groups_merge_repeated_directions() {
        let a = [0.0, 0.0, 1.0];
        let b = [0.6, 0.0, 0.8];
        let (reps, g) = light_groups(&[a, b, a, b, [0.0, 0.6, 0.8]], 1e-3);
        assert_eq!(reps.len(), 3);
        assert_eq!(g, vec![0, 1, 0, 1, 2]);
    }
}
