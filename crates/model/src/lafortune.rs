//! Per-texel Lafortune lobes (seed 000, section 3.1) fitted by bounded Levenberg–Marquardt.
//!
//! A texel's radiance factor under light `l` seen from `v` (unit vectors, sample frame) is
//! modelled as
//!
//! ```text
//! I_c(l, v) = l_z · ( ρ_c + Σ_k max(0, C_xy,k (l_x v_x + l_y v_y) + C_z,k l_z v_z)^{n_k} ),   k = 1..K
//! ```
//!
//! a colour diffuse albedo `ρ_c` and `K` grey isotropic lobes (`C_xy < 0` forward scattering
//! around the mirror direction, `C_xy > 0` retro-reflection), `3 + 3K` values per texel.
//! With a normal map (photometric stereo's) the directions are first taken into each texel's
//! local frame (tangent `t ⟂ n` in the `x z` plane, `b = n × t`, `n`), so the lobes are those
//! of the tilted facet and `l_z` is its cosine `n·l`; an observation with `n·l ≤ 0` or
//! `n·v ≤ 0` is the facet's attached shadow or back side and predicts 0.
//!
//! The lobes are fitted to the channels' mean by Levenberg–Marquardt with the parameters
//! projected onto their bounds after each step (`0 ≤ ρ ≤ 2`, `−3 ≤ C_xy ≤ 3`, `0 ≤ C_z ≤ 3`,
//! `1 ≤ n ≤ 1000`), with analytic derivatives. Well-posed starts: the albedo is the lower
//! quartile of `I / l_z`; lobe `k` starts from the fit with `K − 1` lobes plus a forward
//! lobe (`C_xy = −C_z`) of exponent 8 or 60, whichever ends lower. At grazing angles and
//! outside a lobe the base is 0, the lobe 0 and its exponent derivative 0 (no `ln 0`), so
//! nothing becomes NaN. The colour albedo then follows by linear least squares per channel.

use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};

/// Bounds of the lobe parameters `(C_xy, C_z, n)`.
pub const LOBE_BOUNDS: [(f64, f64); 3] = [(-3.0, 3.0), (0.0, 3.0), (1.0, 1000.0)];
/// Bounds of the grey albedo.
pub const ALBEDO_BOUNDS: (f64, f64) = (0.0, 2.0);

/// One texel's fitted model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Lobe {
    /// Weight of the tangential product `l_x v_x + l_y v_y`.
    pub cxy: f64,
    /// Weight of `l_z v_z`.
    pub cz: f64,
    /// Exponent.
    pub n: f64,
}

/// Lafortune models of every texel.
#[derive(Debug, Clone, Serialize)]
pub struct LafortuneMap {
    /// Lobes per texel.
    pub lobes: usize,
    /// Texels.
    pub texels: usize,
    /// Diffuse albedo per texel and channel.
    pub albedo: Vec<[f32; 3]>,
    /// `texels * lobes` lobes, texel-major.
    pub lobe: Vec<Lobe>,
    /// LM iterations summed over texels.
    pub iterations: u64,
    /// The texels' normals the lobes are relative to (`None`: the sample's normal).
    pub normal: Option<Vec<[f64; 3]>>,
}

/// `d` in the local frame of the unit normal `n` (`t ⟂ n` in the `x z` plane, `b = n × t`).
pub fn to_local(n: &[f64; 3], d: &[f64; 3]) -> [f64; 3] {
    // t = normalise(e_x − n_x n): defined unless n is along x, which a surface normal is not.
    let mut t = [1.0 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]];
    let tl = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt().max(1e-12);
    t = t.map(|x| x / tl);
    let b = [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]];
    let dot = |a: &[f64; 3]| a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
    [dot(&t), dot(&b), dot(n)]
}

impl LafortuneMap {
    /// Values stored per texel (`3 + 3K`).
    pub fn values_per_texel(&self) -> usize {
        3 + 3 * self.lobes
    }

    /// The model's radiance factor of texel `t` under `l` seen from `v` (sample frame).
    pub fn eval(&self, t: usize, l: &[f64; 3], v: &[f64; 3]) -> [f32; 3] {
        let (l, v) = match &self.normal {
            Some(n) => (to_local(&n[t], l), to_local(&n[t], v)),
            None => (*l, *v),
        };
        if !(l[2] > 0.0 && v[2] > 0.0) {
            return [0.0; 3];
        }
        let s = lobe_sum(&self.lobe[t * self.lobes..(t + 1) * self.lobes], &l, &v);
        let a = self.albedo[t];
        [0, 1, 2].map(|c| (l[2] * (f64::from(a[c]) + s)) as f32)
    }

    /// The model's texture for one (light, view) pair.
    pub fn texture(&self, l: &[f64; 3], v: &[f64; 3]) -> Vec<[f32; 3]> {
        (0..self.texels).into_par_iter().map(|t| self.eval(t, l, v)).collect()
    }
}

fn base(lb: &Lobe, l: &[f64; 3], v: &[f64; 3]) -> (f64, f64) {
    let t = l[0] * v[0] + l[1] * v[1];
    let z = l[2] * v[2];
    (lb.cxy * t + lb.cz * z, t)
}

pub(crate) fn lobe_sum(lobes: &[Lobe], l: &[f64; 3], v: &[f64; 3]) -> f64 {
    lobes
        .iter()
        .map(|lb| {
            let (b, _) = base(lb, l, v);
            if b > 0.0 {
                b.powf(lb.n)
            } else {
                0.0
            }
        })
        .sum()
}

/// Tuning of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LafortuneParams {
    /// Lobes per texel, 1..=3.
    pub lobes: usize,
    /// LM iterations at most per start.
    pub iterations: usize,
}

impl LafortuneParams {
    /// `lobes` lobes, 60 iterations.
    pub fn new(lobes: usize) -> Self {
        LafortuneParams { lobes, iterations: 60 }
    }
}

/// The observations: `images[i]` under light `lights[i]` seen from `views[i]` (sample frame),
/// one texel grid of `texels` values.
#[derive(Debug, Clone, Copy)]
pub struct BtfInput<'a> {
    /// Texels per image.
    pub texels: usize,
    /// Light direction of each image.
    pub lights: &'a [[f64; 3]],
    /// View direction of each image.
    pub views: &'a [[f64; 3]],
    /// The images.
    pub images: &'a [&'a [[f32; 3]]],
    /// Unit normal per texel (photometric stereo's) the lobes are relative to, or `None`.
    pub normals: Option<&'a [[f64; 3]]>,
}

/// Checks `input` for a fit of `lobes` lobes (`what` names the fit in the messages).
pub(crate) fn check_input(input: &BtfInput<'_>, lobes: usize, what: &str) -> Result<()> {
    if !(1..=3).contains(&lobes) {
        return Err(ModelError::OutOfRange {
            field: "lobes".into(),
            value: lobes.to_string(),
            allowed: "1, 2 or 3".into(),
        });
    }
    let m = input.images.len();
    if input.lights.len() != m || input.views.len() != m {
        return Err(ModelError::WrongSize {
            what: format!("{what}: directions"),
            got: input.lights.len().min(input.views.len()),
            expected: m,
        });
    }
    let need = 1 + 3 * lobes;
    if m < need {
        return Err(ModelError::TooFewObservations { what: format!("a {what} with {lobes} lobe(s)"), have: m, need });
    }
    check_images_and_directions(input.images, input.texels, input.lights, input.views)?;
    if let Some(n) = input.normals {
        if n.len() != input.texels {
            return Err(ModelError::WrongSize { what: "normals".into(), got: n.len(), expected: input.texels });
        }
    }
    Ok(())
}

/// Every image has `texels` values and every direction is finite and above the surface.
pub(crate) fn check_images_and_directions(
    images: &[&[[f32; 3]]],
    texels: usize,
    lights: &[[f64; 3]],
    views: &[[f64; 3]],
) -> Result<()> {
    for (i, img) in images.iter().enumerate() {
        if img.len() != texels {
            return Err(ModelError::WrongSize { what: format!("image {i}"), got: img.len(), expected: texels });
        }
    }
    if let Some(i) = lights.iter().chain(views).position(|d| !(d[2] > 0.0) || d.iter().any(|x| !x.is_finite())) {
        return Err(ModelError::OutOfRange {
            field: format!("direction {i}"),
            value: format!("{:?}", lights.iter().chain(views).nth(i)),
            allowed: "finite unit vectors above the surface".into(),
        });
    }
    Ok(())
}

/// Texel `t`'s observations that its facet can see and be lit in, in its frame.
pub(crate) struct Gathered {
    /// Light directions (texel frame).
    pub lights: Vec<[f64; 3]>,
    /// View directions (texel frame).
    pub views: Vec<[f64; 3]>,
    /// The texel's colour in each.
    pub rgb: Vec<[f64; 3]>,
    /// Each one's index into the input's images.
    pub index: Vec<usize>,
}

impl Gathered {
    /// The channels' mean per observation (what the grey lobes are fitted to).
    pub fn grey(&self) -> Vec<f64> {
        self.rgb.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect()
    }
}

pub(crate) fn gather(input: &BtfInput<'_>, t: usize) -> Gathered {
    let mut g = Gathered { lights: Vec::new(), views: Vec::new(), rgb: Vec::new(), index: Vec::new() };
    for (i, ((l, v), img)) in input.lights.iter().zip(input.views).zip(input.images).enumerate() {
        let (l, v) = match input.normals {
            Some(n) => (to_local(&n[t], l), to_local(&n[t], v)),
            None => (*l, *v),
        };
        if l[2] > 1e-3 && v[2] > 1e-3 {
            g.lights.push(l);
            g.views.push(v);
            g.rgb.push(img[t].map(f64::from));
            g.index.push(i);
        }
    }
    g
}

/// No lobes (too few lit observations for them): the albedo alone.
pub(crate) fn no_lobes(lobes: usize) -> Vec<Lobe> {
    vec![Lobe { cxy: 0.0, cz: 0.0, n: 1.0 }; lobes]
}

/// Fits `params.lobes` lobes per texel (module documentation).
pub fn fit(input: &BtfInput<'_>, params: &LafortuneParams) -> Result<LafortuneMap> {
    check_input(input, params.lobes, "Lafortune fit")?;
    let fits: Vec<([f32; 3], Vec<Lobe>, u64)> = (0..input.texels)
        .into_par_iter()
        .map(|t| {
            let g = gather(input, t);
            let y = g.grey();
            let o = TexelObs { lights: &g.lights, views: &g.views, y: &y, view: &[], scales: 0 };
            if y.len() < 1 + 3 * params.lobes {
                let none = no_lobes(params.lobes);
                return (colour_albedo(0.0, &none, &[], &o, &g.rgb), none, 0);
            }
            let (rho, lobes, it) = fit_texel(&o, params);
            (colour_albedo(rho, &lobes, &[], &o, &g.rgb), lobes, it)
        })
        .collect();
    let mut out = LafortuneMap {
        lobes: params.lobes,
        texels: input.texels,
        albedo: Vec::with_capacity(input.texels),
        lobe: Vec::with_capacity(input.texels * params.lobes),
        iterations: 0,
        normal: input.normals.map(|n| n.to_vec()),
    };
    for (a, l, it) in fits {
        out.albedo.push(a);
        out.lobe.extend(l);
        out.iterations += it;
    }
    Ok(out)
}

/// `(ρ, lobes, view scales)` of a parameter vector with `scales` view scales at its end.
pub(crate) fn unpack(p: &[f64], scales: usize) -> (f64, Vec<Lobe>, &[f64]) {
    let k = p.len() - scales;
    (p[0], p[1..k].chunks_exact(3).map(|c| Lobe { cxy: c[0], cz: c[1], n: c[2] }).collect(), &p[k..])
}

/// The parameter vector `[ρ, (C_xy, C_z, n) per lobe, T per view]`.
pub(crate) fn pack(rho: f64, lobes: &[Lobe], scales: &[f64]) -> Vec<f64> {
    std::iter::once(rho).chain(lobes.iter().flat_map(|l| [l.cxy, l.cz, l.n])).chain(scales.iter().copied()).collect()
}

/// Projects onto the bounds (view scales in `[0, 1]`).
fn project(p: &mut [f64], scales: usize) {
    let k = p.len() - scales;
    p[0] = p[0].clamp(ALBEDO_BOUNDS.0, ALBEDO_BOUNDS.1);
    for c in p[1..k].chunks_exact_mut(3) {
        for (x, (lo, hi)) in c.iter_mut().zip(LOBE_BOUNDS) {
            *x = x.clamp(lo, hi);
        }
    }
    p[k..].iter_mut().for_each(|t| *t = t.clamp(0.0, 1.0));
}

/// One texel's observations in its frame: `y[i] ≈ T(view[i]) · l_z (ρ + S(l, v))`. Plain lobes
/// have no view scales (`scales = 0`, `T = 1`); scaled lobes ([`crate::scaled_lafortune`])
/// have `scales` of them at the end of the parameter vector ([`pack`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct TexelObs<'a> {
    pub lights: &'a [[f64; 3]],
    pub views: &'a [[f64; 3]],
    pub y: &'a [f64],
    /// Each observation's view (index of its scale).
    pub view: &'a [usize],
    /// View scales in the parameters.
    pub scales: usize,
}

impl TexelObs<'_> {
    /// Observation `i`'s view scale under the scales `t` (1 without).
    fn scale(&self, t: &[f64], i: usize) -> f64 {
        if t.is_empty() {
            1.0
        } else {
            t[self.view[i]]
        }
    }
}

fn cost(p: &[f64], o: &TexelObs<'_>) -> f64 {
    let (rho, lobes, t) = unpack(p, o.scales);
    o.lights
        .iter()
        .zip(o.views)
        .zip(o.y)
        .enumerate()
        .map(|(i, ((l, v), yi))| (yi - o.scale(t, i) * l[2] * (rho + lobe_sum(&lobes, l, v))).powi(2))
        .sum()
}

/// Levenberg–Marquardt from `p`, projected on the bounds; returns the cost and iterations.
/// An observation depends on `ρ`, the lobes and one view scale: `JᵀJ` is accumulated over
/// those entries only.
fn lm(p: &mut Vec<f64>, o: &TexelObs<'_>, iterations: usize) -> (f64, u64) {
    let (lights, views, y) = (o.lights, o.views, o.y);
    let k = p.len();
    let shared = k - o.scales;
    let mut c = cost(p, o);
    let mut lambda = 1e-3;
    let mut it = 0u64;
    let mut jtj = vec![0.0; k * k];
    let mut jtr = vec![0.0; k];
    let mut row = vec![0.0; shared + 1];
    let mut idx: Vec<usize> = (0..=shared).collect();
    for _ in 0..iterations {
        it += 1;
        jtj.fill(0.0);
        jtr.fill(0.0);
        let (rho, lobes, t) = unpack(p, o.scales);
        for (i, ((l, v), yi)) in lights.iter().zip(views).zip(y).enumerate() {
            let mut model = rho;
            row[0] = l[2];
            for (j, lb) in lobes.iter().enumerate() {
                let (b, tp) = base(lb, l, v);
                let o = 1 + 3 * j;
                if b > 1e-12 {
                    let bn = b.powf(lb.n);
                    let d = lb.n * bn / b;
                    model += bn;
                    row[o] = l[2] * d * tp;
                    row[o + 1] = l[2] * d * l[2] * v[2];
                    row[o + 2] = l[2] * bn * b.ln();
                } else {
                    row[o] = 0.0;
                    row[o + 1] = 0.0;
                    row[o + 2] = 0.0;
                }
            }
            // The view scale multiplies the model and so every derivative; its own
            // derivative is the unscaled model.
            let s = o.scale(t, i);
            row[..shared].iter_mut().for_each(|x| *x *= s);
            let n = if o.scales > 0 {
                row[shared] = l[2] * model;
                idx[shared] = shared + o.view[i];
                shared + 1
            } else {
                shared
            };
            let r = yi - s * l[2] * model;
            for a in 0..n {
                jtr[idx[a]] += row[a] * r;
                for b in 0..n {
                    jtj[idx[a] * k + idx[b]] += row[a] * row[b];
                }
            }
        }
        let mut improved = false;
        for _ in 0..8 {
            let mut a = nalgebra::DMatrix::from_row_slice(k, k, &jtj);
            for d in 0..k {
                a[(d, d)] += lambda * jtj[d * k + d].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|ch| ch.solve(&nalgebra::DVector::from_column_slice(&jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let mut q: Vec<f64> = p.iter().zip(step.iter()).map(|(x, s)| x + s).collect();
            project(&mut q, o.scales);
            let cq = cost(&q, o);
            if cq.is_finite() && cq < c {
                let rel = (c - cq) / c.max(1e-300);
                *p = q;
                c = cq;
                lambda = (lambda * 0.3).max(1e-9);
                improved = rel > 1e-10;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (c, it)
}

/// Plain lobes from scratch (module documentation: well-posed starts); `o` without scales.
pub(crate) fn fit_texel(o: &TexelObs<'_>, params: &LafortuneParams) -> (f64, Vec<Lobe>, u64) {
    debug_assert_eq!(o.scales, 0, "plain lobes");
    let mut ratios: Vec<f64> = o.lights.iter().zip(o.y).map(|(l, yi)| yi / l[2]).collect();
    ratios.sort_by(|a, b| a.total_cmp(b));
    let rho0 = ratios[ratios.len() / 4].clamp(ALBEDO_BOUNDS.0, ALBEDO_BOUNDS.1);
    let mut best: (f64, Vec<f64>) = (cost(&[rho0], o), vec![rho0]);
    let mut iters = 0;
    for _ in 0..params.lobes {
        let mut round: Option<(f64, Vec<f64>)> = None;
        for n0 in [8.0, 60.0] {
            let mut p = best.1.clone();
            p.extend([-0.9, 0.9, n0]);
            let (c, it) = lm(&mut p, o, params.iterations);
            iters += it;
            if round.as_ref().is_none_or(|r| c < r.0) {
                round = Some((c, p));
            }
        }
        best = round.expect("two starts");
    }
    let (rho, lobes, _) = unpack(&best.1, 0);
    (rho, lobes, iters)
}

/// Refines the parameters `p` ([`pack`]) by LM from where they are (projected on the bounds
/// first); the cost and iterations.
pub(crate) fn refine_texel(p: &mut Vec<f64>, o: &TexelObs<'_>, iterations: usize) -> (f64, u64) {
    project(p, o.scales);
    lm(p, o, iterations)
}

/// The colour albedo given the lobes and view scales `t` (empty: 1):
/// `I_c = s l_z (ρ_c + S)` → `ρ_c = Σ s l_z (I_c − s l_z S) / Σ (s l_z)²`,
/// clamped to `[0, 2 max(ρ, 1)]` (`ρ` the grey fit's).
pub(crate) fn colour_albedo(rho: f64, lobes: &[Lobe], t: &[f64], o: &TexelObs<'_>, rgb: &[[f64; 3]]) -> [f32; 3] {
    let mut albedo = [0.0f32; 3];
    let sl: Vec<f64> = o.lights.iter().enumerate().map(|(i, l)| o.scale(t, i) * l[2]).collect();
    let den: f64 = sl.iter().map(|x| x * x).sum();
    for (c, a) in albedo.iter_mut().enumerate() {
        let num: f64 = sl
            .iter()
            .zip(o.lights.iter().zip(o.views))
            .zip(rgb)
            .map(|((sl, (l, v)), p)| sl * (p[c] - sl * lobe_sum(lobes, l, v)))
            .sum();
        *a = if den > 0.0 { (num / den).clamp(0.0, 2.0 * rho.max(1.0)) as f32 } else { 0.0 };
    }
    albedo
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
        let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    }

    #[test]
    fn a_known_lobe_is_recovered_and_grazing_angles_stay_finite() {
        let truth = Lobe { cxy: -1.0, cz: 1.0, n: 20.0 };
        let mut lights = Vec::new();
        let mut views = Vec::new();
        for lt in [0.0, 20.0, 40.0, 60.0, 89.9] {
            for lp in [0.0, 90.0, 200.0] {
                for vt in [10.0, 30.0, 50.0, 70.0, 89.9] {
                    for vp in [0.0, 100.0, 180.0, 270.0] {
                        lights.push(dir(lt, lp));
                        views.push(dir(vt, vp));
                    }
                }
            }
        }
        let rho = [0.3f32, 0.2, 0.1];
        let imgs: Vec<Vec<[f32; 3]>> = lights
            .iter()
            .zip(&views)
            .map(|(l, v)| {
                let s = lobe_sum(&[truth], l, v);
                vec![rho.map(|r| (l[2] * (f64::from(r) + s)) as f32); 2]
            })
            .collect();
        let refs: Vec<&[[f32; 3]]> = imgs.iter().map(|v| v.as_slice()).collect();
        let input = BtfInput { texels: 2, lights: &lights, views: &views, images: &refs, normals: None };
        for k in 1..=3 {
            let m = fit(&input, &LafortuneParams::new(k)).unwrap();
            let mut err = 0.0f64;
            let mut norm = 0.0f64;
            for (i, (l, v)) in lights.iter().zip(&views).enumerate() {
                let e = m.eval(0, l, v);
                for c in 0..3 {
                    err += (f64::from(e[c]) - f64::from(imgs[i][0][c])).powi(2);
                    norm += f64::from(imgs[i][0][c]).powi(2);
                }
                assert!(e.iter().all(|x| x.is_finite()));
            }
            let rel = (err / norm).sqrt();
            assert!(rel < 1e-3, "{k} lobes: relative RMSE {rel}, {:?}", &m.lobe[..k]);
            assert!((m.albedo[0][0] - 0.3).abs() < 0.01, "{:?}", m.albedo[0]);
        }
        // Too few observations for 3 lobes are named.
        let few = BtfInput { texels: 2, lights: &lights[..5], views: &views[..5], images: &refs[..5], normals: None };
        let e = fit(&few, &LafortuneParams::new(3)).unwrap_err().to_string();
        assert!(e.contains("5 observation(s)") && e.contains("at least 10"), "{e}");
    }

    #[test]
    fn lobes_of_a_tilted_facet_need_its_normal() {
        // A facet tilted 30 deg with a Phong-like lobe in its own frame.
        let n = dir(30.0, 60.0);
        let truth = Lobe { cxy: -1.0, cz: 1.0, n: 12.0 };
        let (mut lights, mut views) = (Vec::new(), Vec::new());
        for lt in [0.0, 15.0, 30.0, 45.0, 60.0, 75.0] {
            for lp in [0.0, 72.0, 144.0, 216.0, 288.0] {
                for vt in [0.0, 20.0, 40.0, 60.0] {
                    for vp in [30.0, 150.0, 270.0] {
                        lights.push(dir(lt, lp));
                        views.push(dir(vt, vp));
                    }
                }
            }
        }
        let model = |l: &[f64; 3], v: &[f64; 3]| {
            let (ll, vl) = (to_local(&n, l), to_local(&n, v));
            if ll[2] <= 0.0 || vl[2] <= 0.0 {
                return 0.0;
            }
            ll[2] * (0.4 + lobe_sum(&[truth], &ll, &vl))
        };
        let imgs: Vec<Vec<[f32; 3]>> = lights.iter().zip(&views).map(|(l, v)| vec![[model(l, v) as f32; 3]]).collect();
        let refs: Vec<&[[f32; 3]]> = imgs.iter().map(|v| v.as_slice()).collect();
        let rel = |normals: Option<&[[f64; 3]]>| {
            let input = BtfInput { texels: 1, lights: &lights, views: &views, images: &refs, normals };
            let m = fit(&input, &LafortuneParams::new(1)).unwrap();
            let (mut e, mut s) = (0.0, 0.0);
            for (i, (l, v)) in lights.iter().zip(&views).enumerate() {
                let p = m.eval(0, l, v);
                assert!(p.iter().all(|x| x.is_finite()));
                e += (f64::from(p[0]) - f64::from(imgs[i][0][0])).powi(2);
                s += f64::from(imgs[i][0][0]).powi(2);
            }
            (e / s).sqrt()
        };
        let normals = [n];
        let (with, without) = (rel(Some(&normals)), rel(None));
        assert!(with < 1e-3, "with the normal: {with}");
        assert!(without > 20.0 * with.max(1e-4), "without: {without}, with: {with}");
    }
}
