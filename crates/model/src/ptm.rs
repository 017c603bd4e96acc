//! Polynomial texture maps per view (seed 000, section 3.1.3; Malzbender et al. 2001): for a
//! fixed view, each texel's reflectance field is a biquadratic in the projected light
//! direction `(l_u, l_v) = (l_x, l_y)` (sample frame).
//!
//! ```text
//! L(t, v; l)   = a_0 l_u² + a_1 l_v² + a_2 l_u l_v + a_3 l_u + a_4 l_v + a_5
//! I_c(t, v; l) = max(0, χ_c(t, v) · L(t, v; l))
//! ```
//!
//! Malzbender's LRGB form: the six coefficients model the luminance (here the channels'
//! mean) and a chroma `χ_c` per texel and view (mean 1 for a grey texel) scales it per
//! channel, 9 values per texel and view (an RGB PTM would need 18). The coefficients are the
//! least-squares fit over the view's captures; the chroma then follows by least squares per
//! channel, `χ_c = Σ I_c L / Σ L²`. At an unmeasured view the nearest measured one is used
//! (seed 000's reflectance fields interpolate between the nearest views; not done here).
//!
//! Conditioning: every texel of a view shares the design matrix (the lights are the
//! captures'), so the normal matrix `ΦᵀΦ` is built and factorised once per view. `l_u, l_v`
//! are first divided by their largest magnitude over the view's lights (lights within 15° of
//! the zenith have `|l_u| ≤ 0.26`, which would make the quadratic columns ~15x smaller than
//! the constant); a ridge `λ · tr(ΦᵀΦ)/6 · I` (`λ` = [`PtmParams::ridge`]) keeps the solve
//! finite when the lights do not determine a biquadratic (six lights on one ring lie on a
//! conic: `l_u² + l_v²` is then the constant), and each view's reciprocal condition number
//! (smallest over largest eigenvalue of the scaled `ΦᵀΦ`) is reported. A view needs at least
//! 6 distinct light directions; fewer are refused with the view named.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};
use crate::lafortune::check_images_and_directions;
use crate::sbrdf::{distinct, nearest};

/// Coefficients of the biquadratic.
pub const COEFFICIENTS: usize = 6;

/// The observations: `images[i]` under light `lights[i]` seen from `views[i]` (sample frame).
#[derive(Debug, Clone, Copy)]
pub struct PtmInput<'a> {
    /// Texels per image.
    pub texels: usize,
    /// Light direction of each image.
    pub lights: &'a [[f64; 3]],
    /// View direction of each image.
    pub views: &'a [[f64; 3]],
    /// The images.
    pub images: &'a [&'a [[f32; 3]]],
}

/// Tuning of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PtmParams {
    /// Ridge relative to the mean eigenvalue of the scaled normal matrix.
    pub ridge: f64,
}

impl Default for PtmParams {
    fn default() -> Self {
        PtmParams { ridge: 1e-6 }
    }
}

/// One view's fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PtmView {
    /// The view direction (sample frame).
    pub dir: [f64; 3],
    /// Captures of this view.
    pub captures: usize,
    /// Distinct light directions among them.
    pub lights: usize,
    /// Smallest over largest eigenvalue of the scaled `ΦᵀΦ` (before the ridge); near 0: the
    /// lights do not determine the biquadratic and the ridge chose among the fits.
    pub rcond: f64,
}

/// The polynomial texture maps of every view.
#[derive(Debug, Clone, Serialize)]
pub struct PtmMap {
    /// Texels.
    pub texels: usize,
    /// The views, in the order of their maps.
    pub views: Vec<PtmView>,
    /// `a_0..a_5` per view and texel, view-major (`views.len() × texels`).
    pub coeffs: Vec<[f32; COEFFICIENTS]>,
    /// `χ_c` per view and texel, view-major.
    pub chroma: Vec<[f32; 3]>,
}

/// `[l_u², l_v², l_u l_v, l_u, l_v, 1]`.
pub fn basis(lu: f64, lv: f64) -> [f64; COEFFICIENTS] {
    [lu * lu, lv * lv, lu * lv, lu, lv, 1.0]
}

impl PtmMap {
    /// Values stored per texel (9 per view).
    pub fn values_per_texel(&self) -> usize {
        self.views.len() * (COEFFICIENTS + 3)
    }

    /// Index of the view nearest `v` (the one whose map is used).
    pub fn view_index(&self, v: &[f64; 3]) -> usize {
        let dirs: Vec<[f64; 3]> = self.views.iter().map(|x| x.dir).collect();
        nearest(&dirs, v)
    }

    fn eval_at(&self, j: usize, t: usize, phi: &[f64; COEFFICIENTS]) -> [f32; 3] {
        let a = &self.coeffs[j * self.texels + t];
        let lum: f64 = a.iter().zip(phi).map(|(a, p)| f64::from(*a) * p).sum();
        self.chroma[j * self.texels + t].map(|c| (f64::from(c) * lum).max(0.0) as f32)
    }

    /// The model's radiance factor of texel `t` under `l` seen from `v` (sample frame).
    pub fn eval(&self, t: usize, l: &[f64; 3], v: &[f64; 3]) -> [f32; 3] {
        self.eval_at(self.view_index(v), t, &basis(l[0], l[1]))
    }

    /// The model's texture for one (light, view) pair.
    pub fn texture(&self, l: &[f64; 3], v: &[f64; 3]) -> Vec<[f32; 3]> {
        let (j, phi) = (self.view_index(v), basis(l[0], l[1]));
        (0..self.texels).into_par_iter().map(|t| self.eval_at(j, t, &phi)).collect()
    }
}

/// Validates `input` (sizes, directions above the surface, finite values).
fn check(input: &PtmInput<'_>) -> Result<()> {
    let m = input.images.len();
    if m == 0 || input.texels == 0 {
        return Err(ModelError::Empty("polynomial texture map: no images or no texels".into()));
    }
    for (what, got) in [("light directions", input.lights.len()), ("view directions", input.views.len())] {
        if got != m {
            return Err(ModelError::WrongSize { what: format!("polynomial texture map: {what}"), got, expected: m });
        }
    }
    check_images_and_directions(input.images, input.texels, input.lights, input.views)?;
    for (i, img) in input.images.iter().enumerate() {
        if let Some(x) = img.iter().flatten().find(|x| !x.is_finite()) {
            return Err(ModelError::OutOfRange {
                field: format!("image {i}"),
                value: x.to_string(),
                allowed: "finite values".into(),
            });
        }
    }
    Ok(())
}

fn deg(d: &[f64; 3]) -> (f64, f64) {
    (d[2].clamp(-1.0, 1.0).acos().to_degrees(), d[1].atan2(d[0]).to_degrees().rem_euclid(360.0))
}

/// One view's least-squares operator: `coeffs = P · y` (6 x m, natural units) and `rcond`.
fn view_operator(lights: &[[f64; 3]], ridge: f64) -> (Vec<[f64; COEFFICIENTS]>, f64) {
    // Scale l_u, l_v to [-1, 1] over the view's lights so the columns are comparable.
    let s = lights.iter().map(|l| l[0].abs().max(l[1].abs())).fold(0.0, f64::max);
    let s = if s > 1e-9 { s } else { 1.0 };
    let rows: Vec<SVector<f64, COEFFICIENTS>> =
        lights.iter().map(|l| SVector::from(basis(l[0] / s, l[1] / s))).collect();
    let mut n = SMatrix::<f64, COEFFICIENTS, COEFFICIENTS>::zeros();
    for r in &rows {
        n += r * r.transpose();
    }
    let eig = n.symmetric_eigenvalues();
    let (lo, hi) = eig.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &e| (a.min(e), b.max(e)));
    let rcond = if hi > 0.0 { (lo / hi).max(0.0) } else { 0.0 };
    let mut reg = n;
    let lambda = ridge * n.trace() / COEFFICIENTS as f64;
    for d in 0..COEFFICIENTS {
        reg[(d, d)] += lambda.max(1e-300);
    }
    // Positive definite with the ridge; the identity if nothing at all was lit.
    let inv = reg.cholesky().map(|c| c.inverse()).unwrap_or_else(SMatrix::identity);
    // Back to natural units: a_u² = â/s², a_u = â/s, constant unchanged.
    let unscale = [1.0 / (s * s), 1.0 / (s * s), 1.0 / (s * s), 1.0 / s, 1.0 / s, 1.0];
    let p = rows
        .iter()
        .map(|r| {
            let c = inv * r;
            std::array::from_fn(|k| c[k] * unscale[k])
        })
        .collect();
    (p, rcond)
}

/// Fits one PTM per view (module documentation).
pub fn fit(input: &PtmInput<'_>, params: &PtmParams) -> Result<PtmMap> {
    check(input)?;
    if !(params.ridge >= 0.0 && params.ridge.is_finite()) {
        return Err(ModelError::OutOfRange {
            field: "ridge".into(),
            value: params.ridge.to_string(),
            allowed: "a finite value >= 0".into(),
        });
    }
    let (view_dirs, view_of) = distinct(input.views);
    // The captures of each view and their distinct lights; every view must have 6.
    let groups: Vec<Vec<usize>> =
        (0..view_dirs.len()).map(|j| (0..view_of.len()).filter(|&i| view_of[i] == j).collect()).collect();
    let lights_of = |g: &[usize]| distinct(&g.iter().map(|&i| input.lights[i]).collect::<Vec<_>>()).0.len();
    let short: Vec<(usize, usize)> =
        groups.iter().enumerate().map(|(j, g)| (j, lights_of(g))).filter(|&(_, n)| n < COEFFICIENTS).collect();
    if let Some(&(j, n)) = short.first() {
        let (th, ph) = deg(&view_dirs[j]);
        let most = groups.iter().map(|g| lights_of(g)).max().unwrap_or(0);
        return Err(ModelError::OutOfRange {
            field: format!("view {j} (theta {th:.1} deg, phi {ph:.1} deg)"),
            value: format!("{n} distinct light direction(s)"),
            allowed: format!(
                "a per-view polynomial texture map has {COEFFICIENTS} coefficients and needs at least {COEFFICIENTS} \
                 distinct light directions in every view; {} of the {} views have fewer (the most in one view: \
                 {most}): use a dataset with more lights per view (a dome, or a plan with more light directions)",
                short.len(),
                groups.len()
            ),
        });
    }
    let mut map = PtmMap {
        texels: input.texels,
        views: Vec::with_capacity(groups.len()),
        coeffs: Vec::with_capacity(groups.len() * input.texels),
        chroma: Vec::with_capacity(groups.len() * input.texels),
    };
    for (j, g) in groups.iter().enumerate() {
        let lights: Vec<[f64; 3]> = g.iter().map(|&i| input.lights[i]).collect();
        let (p, rcond) = view_operator(&lights, params.ridge);
        let phis: Vec<[f64; COEFFICIENTS]> = lights.iter().map(|l| basis(l[0], l[1])).collect();
        let per_texel: Vec<([f32; COEFFICIENTS], [f32; 3])> = (0..input.texels)
            .into_par_iter()
            .map(|t| {
                let rgb: Vec<[f64; 3]> = g.iter().map(|&i| input.images[i][t].map(f64::from)).collect();
                let mut a = [0.0f64; COEFFICIENTS];
                for (pi, c) in p.iter().zip(&rgb) {
                    let y = (c[0] + c[1] + c[2]) / 3.0;
                    for k in 0..COEFFICIENTS {
                        a[k] += pi[k] * y;
                    }
                }
                let lum: Vec<f64> = phis.iter().map(|phi| a.iter().zip(phi).map(|(a, p)| a * p).sum()).collect();
                let den: f64 = lum.iter().map(|x| x * x).sum();
                let chroma = [0, 1, 2].map(|c| {
                    if den > 1e-300 {
                        (lum.iter().zip(&rgb).map(|(l, p)| l * p[c]).sum::<f64>() / den) as f32
                    } else {
                        1.0
                    }
                });
                (a.map(|x| x as f32), chroma)
            })
            .collect();
        for (a, c) in per_texel {
            map.coeffs.push(a);
            map.chroma.push(c);
        }
        map.views.push(PtmView { dir: view_dirs[j], captures: g.len(), lights: lights_of(g), rcond });
    }
    Ok(map)
}
