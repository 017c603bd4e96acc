//! Scaled Lafortune lobes (seed 000, section 3.1.2, Daubert et al.): Lafortune lobes times a
//! per-texel, view-dependent scale `T(v)` that models the relief's occlusion (masking).
//!
//! ```text
//! I_c(l, v) = T(t, v) · l_z · ( ρ_c + Σ_k max(0, C_xy,k (l_x v_x + l_y v_y) + C_z,k l_z v_z)^{n_k} )
//! ```
//!
//! Seed 000's equation 4, `BTF(x, v, l) ≈ T_x(v) (ρ_d,x + Σ_j s_x,j(v, l))`, in the form of
//! [`crate::lafortune`]: a colour albedo `ρ_c`, `K` grey lobes (fitted to the channels'
//! mean, as Meseth et al. do, not one set per channel as Daubert et al.) and the foreshortening
//! `l_z`, with the directions in the texel's frame when a normal map is given. `T` is one grey
//! value per texel and distinct view direction of the data (the lookup table), in `[0, 1]`
//! with each texel's largest 1 (the split between `T` and the lobes is otherwise free); at an
//! unmeasured view the nearest measured one is used. Storage: `3 + 3K` values and one
//! `T` per view per texel.
//!
//! Fit per texel: the plain Lafortune fit (`T = 1`); `T(v) = Σ y B / Σ B²` over the view's
//! observations in closed form given it (`B = l_z (ρ + S)`, the grey model); then albedo, lobes
//! and every `T` at once by [`crate::lafortune`]'s bounded Levenberg–Marquardt (`T ∈ [0, 1]`;
//! each observation depends on one `T`, so `JᵀJ` is accumulated over `2 + 3K` entries). The
//! split between `T` and the lobes is free: at the end the largest `T` is divided out into
//! `ρ·m` and `C·m^{1/n}` (the same model). A view that sees nothing of the texel keeps
//! `T = 1`. The colour albedo then follows by linear least squares per channel, as for the
//! plain lobes.

use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};
use crate::lafortune::{
    check_input, colour_albedo, fit_texel, gather, lobe_sum, no_lobes, pack, refine_texel, unpack, BtfInput, Gathered,
    LafortuneMap, LafortuneParams, Lobe, TexelObs, ALBEDO_BOUNDS, LOBE_BOUNDS,
};
use crate::sbrdf::{distinct, nearest};

/// Tuning of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScaledParams {
    /// The plain lobes' fit that starts it (lobes per texel, LM iterations per start).
    pub lafortune: LafortuneParams,
    /// LM iterations at most of the joint fit of lobes and view scales.
    pub iterations: usize,
}

impl ScaledParams {
    /// `lobes` lobes, 100 joint iterations.
    pub fn new(lobes: usize) -> Self {
        ScaledParams { lafortune: LafortuneParams::new(lobes), iterations: 100 }
    }
}

/// Scaled Lafortune models of every texel.
#[derive(Debug, Clone, Serialize)]
pub struct ScaledLafortuneMap {
    /// Albedo, lobes and the normals they are relative to.
    pub lafortune: LafortuneMap,
    /// The distinct view directions (sample frame), one scale each per texel.
    pub view_dirs: Vec<[f64; 3]>,
    /// `T`: `texels × view_dirs.len()`, texel-major, in `[0, 1]`.
    pub scale: Vec<f32>,
}

impl ScaledLafortuneMap {
    /// Values stored per texel (`3 + 3K` and one scale per view).
    pub fn values_per_texel(&self) -> usize {
        self.lafortune.values_per_texel() + self.view_dirs.len()
    }

    /// The model's radiance factor of texel `t` under `l` seen from `v` (sample frame).
    pub fn eval(&self, t: usize, l: &[f64; 3], v: &[f64; 3]) -> [f32; 3] {
        let s = self.scale[t * self.view_dirs.len() + nearest(&self.view_dirs, v)];
        self.lafortune.eval(t, l, v).map(|x| x * s)
    }

    /// The model's texture for one (light, view) pair.
    pub fn texture(&self, l: &[f64; 3], v: &[f64; 3]) -> Vec<[f32; 3]> {
        let j = nearest(&self.view_dirs, v);
        let nv = self.view_dirs.len();
        let mut out = self.lafortune.texture(l, v);
        for (t, p) in out.iter_mut().enumerate() {
            let s = self.scale[t * nv + j];
            *p = p.map(|x| x * s);
        }
        out
    }
}

/// One texel's grey model `l_z (ρ + S)` per observation.
fn grey_model(rho: f64, lobes: &[Lobe], lights: &[[f64; 3]], views: &[[f64; 3]]) -> Vec<f64> {
    lights.iter().zip(views).map(|(l, v)| l[2] * (rho + lobe_sum(lobes, l, v))).collect()
}

/// Divides the largest view scale out into the albedo and lobes (`ρ·m`, `C·m^{1/n}`): the
/// same model with `max T = 1`. `m ≤ 1` after the bounded fit, so the lobes stay in bounds.
fn normalise(rho: &mut f64, lobes: &mut [Lobe], t: &mut [f64]) {
    let m = t.iter().cloned().fold(0.0, f64::max);
    if m <= 1e-12 {
        return;
    }
    t.iter_mut().for_each(|x| *x /= m);
    *rho = (*rho * m).clamp(ALBEDO_BOUNDS.0, ALBEDO_BOUNDS.1);
    for lb in lobes {
        let f = m.powf(1.0 / lb.n);
        lb.cxy = (lb.cxy * f).clamp(LOBE_BOUNDS[0].0, LOBE_BOUNDS[0].1);
        lb.cz = (lb.cz * f).clamp(LOBE_BOUNDS[1].0, LOBE_BOUNDS[1].1);
    }
}

/// One texel's fit.
struct TexelFit {
    albedo: [f32; 3],
    lobes: Vec<Lobe>,
    /// `T` per distinct view.
    scale: Vec<f64>,
    iterations: u64,
}

/// One texel.
fn fit_one(g: &Gathered, view_of: &[usize], n_views: usize, params: &ScaledParams) -> TexelFit {
    let y = g.grey();
    let k = params.lafortune.lobes;
    let plain = TexelObs { lights: &g.lights, views: &g.views, y: &y, view: view_of, scales: 0 };
    if y.len() < 1 + 3 * k {
        let none = no_lobes(k);
        return TexelFit {
            albedo: colour_albedo(0.0, &none, &[], &plain, &g.rgb),
            lobes: none,
            scale: vec![1.0; n_views],
            iterations: 0,
        };
    }
    let (mut rho, mut lobes, mut iters) = fit_texel(&plain, &params.lafortune);
    // Start: T per view in closed form given the plain lobes, T = Σ y B / Σ B².
    let b = grey_model(rho, &lobes, &g.lights, &g.views);
    let (mut num, mut den) = (vec![0.0; n_views], vec![0.0; n_views]);
    for ((yi, bi), &j) in y.iter().zip(&b).zip(view_of) {
        num[j] += yi * bi;
        den[j] += bi * bi;
    }
    let floor = 1e-12 * den.iter().cloned().fold(0.0, f64::max).max(1e-300);
    let mut t: Vec<f64> = num.iter().zip(&den).map(|(n, d)| if *d > floor { (n / d).max(0.0) } else { 1.0 }).collect();
    normalise(&mut rho, &mut lobes, &mut t);
    // Then everything at once by the lobes' bounded LM, the scales in [0, 1].
    let scaled = TexelObs { scales: n_views, ..plain };
    let mut p = pack(rho, &lobes, &t);
    let (_, it) = refine_texel(&mut p, &scaled, params.iterations);
    iters += it;
    let (mut rho, mut lobes, t) = unpack(&p, n_views);
    let mut t = t.to_vec();
    normalise(&mut rho, &mut lobes, &mut t);
    TexelFit { albedo: colour_albedo(rho, &lobes, &t, &scaled, &g.rgb), lobes, scale: t, iterations: iters }
}

/// Fits scaled Lafortune lobes per texel (module documentation).
pub fn fit(input: &BtfInput<'_>, params: &ScaledParams) -> Result<ScaledLafortuneMap> {
    check_input(input, params.lafortune.lobes, "scaled Lafortune fit")?;
    if input.texels == 0 {
        return Err(ModelError::Empty("scaled Lafortune fit: no texels".into()));
    }
    let (view_dirs, view_idx) = distinct(input.views);
    let nv = view_dirs.len();
    let k = params.lafortune.lobes;
    let fits: Vec<TexelFit> = (0..input.texels)
        .into_par_iter()
        .map(|t| {
            let g = gather(input, t);
            let view_of: Vec<usize> = g.index.iter().map(|&i| view_idx[i]).collect();
            fit_one(&g, &view_of, nv, params)
        })
        .collect();
    let mut map = LafortuneMap {
        lobes: k,
        texels: input.texels,
        albedo: Vec::with_capacity(input.texels),
        lobe: Vec::with_capacity(input.texels * k),
        iterations: 0,
        normal: input.normals.map(|n| n.to_vec()),
    };
    let mut scale = Vec::with_capacity(input.texels * nv);
    for f in fits {
        map.albedo.push(f.albedo);
        map.lobe.extend(f.lobes);
        scale.extend(f.scale.iter().map(|&x| x as f32));
        map.iterations += f.iterations;
    }
    Ok(ScaledLafortuneMap { lafortune: map, view_dirs, scale })
}
