//! Colour-correction models: camera RGB → target colour (XYZ or linear sRGB), each a linear
//! combination of terms of the camera RGB fitted by (weighted, optionally ridge-regularised,
//! optionally white-constrained) least squares.
//!
//! | kind | terms | exposure invariant |
//! |---|---|---|
//! | [`ModelKind::Linear`] | r, g, b (3) | yes |
//! | [`ModelKind::Polynomial2`] | r, g, b, r², g², b², rg, gb, rb (9) | no |
//! | [`ModelKind::Polynomial3`] | the 9 above + r³, g³, b³, rg², gb², rb², gr², bg², br², rgb (19) | no |
//! | [`ModelKind::RootPolynomial2`] | r, g, b, √(rg), √(gb), √(rb) (6) | yes |
//! | [`ModelKind::RootPolynomial3`] | the 6 above + ∛(rg²), ∛(gb²), ∛(rb²), ∛(gr²), ∛(bg²), ∛(br²), ∛(rgb) (13) | yes |
//!
//! The polynomial terms follow Finlayson, Mackiewicz and Hurlbert (2015), "Color correction
//! using root-polynomial regression", IEEE TIP 24(5); the root-polynomial terms are the k-th
//! roots of the degree-k monomials, so every term scales linearly with exposure and
//! `apply(k·rgb) = k·apply(rgb)` for k > 0.
//!
//! **Negative camera values** (dark-frame-subtracted noise on dark patches) would make √(rg)
//! NaN. We use the sign-preserving square root `sgn(x)·√|x|` of the product (the cube root is
//! odd already). It keeps every term finite, continuous through zero and still homogeneous of
//! degree 1 (so exposure invariance holds for any sign), and it changes nothing for the
//! non-negative values that carry the fit. Clamping to zero instead would bias dark patches.
//!
//! **Solver**: the design matrix (rows weighted by √w) has its columns scaled to unit norm
//! (equilibration, so the condition number does not depend on units or term magnitudes) and is
//! solved by SVD. Its condition number σ_max/σ_min (with a ridge λ:
//! √((σ_max² + λ)/(σ_min² + λ))) is checked against [`FitOptions::max_condition`]; above it the
//! fit fails with [`ColorError::IllConditioned`] instead of returning coefficients that fit
//! noise. Separately, the camera r, g, b columns alone must have a condition number under
//! [`FitOptions::max_colour_condition`] ([`ColorError::FewColours`] otherwise): all-grey or
//! few-hued patch sets cannot determine a colour map however well it fits them. A white constraint (`M·φ(w_cam) = w_target`)
//! is imposed exactly by solving in the constraint's null space (a Householder basis).

use nalgebra::{DMatrix, DVector};

use crate::error::ColorError;
use crate::kind::{terms_linear, terms_poly2, terms_poly3, terms_root2, terms_root3, ModelKind, MAX_TERMS};

/// `Σ_j t_j · coef_j` for a fixed number of terms (unrolled by the compiler).
#[inline(always)]
fn combine<const M: usize>(t: &[f64; M], coef: &[[f64; 3]; M]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for j in 0..M {
        out[0] += t[j] * coef[j][0];
        out[1] += t[j] * coef[j][1];
        out[2] += t[j] * coef[j][2];
    }
    out
}

/// Applies terms `f` and coefficients to every pixel (monomorphised per model).
#[inline(always)]
fn batch<const M: usize>(pixels: &mut [[f32; 3]], coefficients: &[[f64; 3]], f: impl Fn([f64; 3]) -> [f64; M]) {
    let coef: [[f64; 3]; M] = std::array::from_fn(|j| coefficients[j]);
    for p in pixels.iter_mut() {
        let o = combine(&f([p[0] as f64, p[1] as f64, p[2] as f64]), &coef);
        *p = [o[0] as f32, o[1] as f32, o[2] as f32];
    }
}

// Here, not in kind.rs: parsing fails with a ColorError, and the errors name model kinds.
impl std::str::FromStr for ModelKind {
    type Err = ColorError;
    fn from_str(s: &str) -> Result<Self, ColorError> {
        ModelKind::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| ColorError::UnknownModel(s.to_string()))
    }
}

/// A white-preservation constraint: the fitted model maps `camera` exactly onto `target`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WhiteConstraint {
    /// Camera RGB of the white reference (e.g. the chart's white patch, or (1, 1, 1) after
    /// white balance).
    pub camera: [f64; 3],
    /// Its target colour (linear sRGB (1, 1, 1) for a perfect white, or its XYZ).
    pub target: [f64; 3],
}

/// Options of [`ColorModel::fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Ridge (Tikhonov) parameter λ ≥ 0 on the column-equilibrated design matrix (whose
    /// columns have unit norm, so λ is relative: 1e-4 shrinks directions whose singular value
    /// is below 0.01). 0 = plain least squares.
    pub ridge: f64,
    /// Largest accepted condition number of the (equilibrated, ridge-regularised) design
    /// matrix; above it the fit fails with [`ColorError::IllConditioned`]. This guards the
    /// numerics (digits lost in the solve), not over-fitting: cross-validation judges that.
    pub max_condition: f64,
    /// Largest accepted condition number of the samples' (equilibrated) camera r, g, b alone:
    /// how well they span the three colour dimensions. Above it the fit fails with
    /// [`ColorError::FewColours`] for every model, because a set of (nearly) grey or
    /// few-hued patches leaves the map's response to other colours undetermined even when
    /// the fit itself reproduces the patches.
    pub max_colour_condition: f64,
    /// Optional exact white constraint.
    pub white: Option<WhiteConstraint>,
}

impl FitOptions {
    /// Default limit of [`FitOptions::max_condition`]. Measured on the 24 ColorChecker patches
    /// (Nikon D5100, 12 lamps, docs/color.md): linear ~10, root-polynomial degree 2 ~2e2–4e2,
    /// degree 3 ~5e5–1.1e6, polynomial degree 3 ~5e4–2e5; an exactly rank-deficient design
    /// gives > 1e13. 1e10 still leaves ~6 significant digits in the solution.
    pub const DEFAULT_MAX_CONDITION: f64 = 1e10;
    /// Default limit of [`FitOptions::max_colour_condition`]: the 24 ColorChecker patches give
    /// 9–15 under every lamp of the shipped illuminant table; 100 means the weakest colour
    /// direction carries 1 % of the strongest.
    pub const DEFAULT_MAX_COLOUR_CONDITION: f64 = 100.0;
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            ridge: 0.0,
            max_condition: Self::DEFAULT_MAX_CONDITION,
            max_colour_condition: Self::DEFAULT_MAX_COLOUR_CONDITION,
            white: None,
        }
    }
}

/// A fitted colour-correction model: `target_c = Σ_j coefficients[j][c] · term_j(rgb)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorModel {
    kind: ModelKind,
    /// One row per term (in [`ModelKind::term_names`] order), one column per output channel.
    coefficients: Vec<[f64; 3]>,
    /// Condition number of the fit's design matrix (NaN for models built from coefficients).
    condition: f64,
    /// Weighted RMS residual over the fitting samples, per output channel (NaN if unknown).
    rms_residual: [f64; 3],
}

fn check_finite(what: &'static str, v: &[[f64; 3]]) -> Result<(), ColorError> {
    for (index, x) in v.iter().enumerate() {
        if let Some(&value) = x.iter().find(|c| !c.is_finite()) {
            return Err(ColorError::NonFinite { what, index, value });
        }
    }
    Ok(())
}

/// Orthonormal basis (columns) of the complement of `p` (a Householder reflector's columns
/// 2..n: the reflector maps e1 to ±p/|p|, so its other columns are orthogonal to p).
fn null_space_basis(p: &DVector<f64>) -> DMatrix<f64> {
    let n = p.len();
    let norm = p.norm();
    let mut v = p.clone();
    let s = if p[0] >= 0.0 { 1.0 } else { -1.0 };
    v[0] += s * norm;
    let vv = v.dot(&v);
    let h = DMatrix::identity(n, n) - (&v * v.transpose()) * (2.0 / vv);
    h.columns(1, n - 1).into_owned()
}

/// Condition number of `a` with unit-norm columns (infinite for a zero column).
fn condition_number(a: &DMatrix<f64>) -> f64 {
    let mut ae = a.clone();
    for j in 0..ae.ncols() {
        let s = ae.column(j).norm();
        if !(s > 0.0 && s.is_finite()) {
            return f64::INFINITY;
        }
        ae.column_mut(j).scale_mut(1.0 / s);
    }
    let sv = ae.singular_values();
    let c = sv.max() / sv.min();
    if c.is_nan() {
        f64::INFINITY
    } else {
        c
    }
}

/// Least squares `min |A x − B|² + λ|x'|²` (per column of B) on the column-equilibrated A.
/// Returns the solution and the condition number, or the condition number if over `limit`.
fn solve_ls(a: &DMatrix<f64>, b: &DMatrix<f64>, ridge: f64, limit: f64) -> Result<(DMatrix<f64>, f64), f64> {
    let m = a.ncols();
    let scale: Vec<f64> = (0..m).map(|j| a.column(j).norm()).collect();
    if scale.iter().any(|&s| s == 0.0 || !s.is_finite()) {
        return Err(f64::INFINITY);
    }
    let mut ae = a.clone();
    for (j, s) in scale.iter().enumerate() {
        ae.column_mut(j).scale_mut(1.0 / s);
    }
    let svd = ae.svd(true, true);
    let sv = &svd.singular_values;
    let smax = sv.max();
    let smin = sv.min();
    let condition = ((smax * smax + ridge) / (smin * smin + ridge)).sqrt();
    if condition.is_nan() || condition > limit {
        return Err(if condition.is_nan() { f64::INFINITY } else { condition });
    }
    let u = svd.u.as_ref().expect("computed");
    let vt = svd.v_t.as_ref().expect("computed");
    // x' = V diag(σ/(σ²+λ)) Uᵀ B.
    let mut utb = u.transpose() * b;
    for i in 0..sv.len() {
        let f = sv[i] / (sv[i] * sv[i] + ridge);
        utb.row_mut(i).scale_mut(f);
    }
    let mut x = vt.transpose() * utb;
    for (j, s) in scale.iter().enumerate() {
        x.row_mut(j).scale_mut(1.0 / s);
    }
    Ok((x, condition))
}

impl ColorModel {
    /// Fits `kind` to pairs (`camera[i]`, `target[i]`) with optional non-negative `weights`
    /// (a weight of 0 excludes a sample, e.g. a clipped patch; see
    /// [`crate::eval::screen_patches`]).
    ///
    /// Errors: [`ColorError::LengthMismatch`], [`ColorError::NonFinite`],
    /// [`ColorError::InvalidWeight`], [`ColorError::InvalidOption`],
    /// [`ColorError::TooFewSamples`] (fewer usable samples than free coefficients),
    /// [`ColorError::IllConditioned`] (too few distinct colours for the model). Never returns
    /// non-finite coefficients.
    pub fn fit(
        kind: ModelKind,
        camera: &[[f64; 3]],
        target: &[[f64; 3]],
        weights: Option<&[f64]>,
        options: &FitOptions,
    ) -> Result<ColorModel, ColorError> {
        let n = camera.len();
        if target.len() != n {
            return Err(ColorError::LengthMismatch { what: "target", expected: n, got: target.len() });
        }
        check_finite("camera", camera)?;
        check_finite("target", target)?;
        if let Some(w) = weights {
            if w.len() != n {
                return Err(ColorError::LengthMismatch { what: "weights", expected: n, got: w.len() });
            }
            if let Some((index, &value)) = w.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= 0.0)) {
                return Err(ColorError::InvalidWeight { index, value });
            }
        }
        if !(options.ridge.is_finite() && options.ridge >= 0.0) {
            return Err(ColorError::InvalidOption { what: "ridge", value: options.ridge, allowed: "finite, >= 0" });
        }
        if options.max_condition.is_nan() || options.max_condition < 1.0 {
            return Err(ColorError::InvalidOption {
                what: "max_condition",
                value: options.max_condition,
                allowed: ">= 1",
            });
        }
        if options.max_colour_condition.is_nan() || options.max_colour_condition < 1.0 {
            return Err(ColorError::InvalidOption {
                what: "max_colour_condition",
                value: options.max_colour_condition,
                allowed: ">= 1",
            });
        }
        if let Some(wc) = options.white {
            check_finite("white.camera", &[wc.camera])?;
            check_finite("white.target", &[wc.target])?;
        }
        let m = kind.terms();
        let used: Vec<(usize, f64)> =
            (0..n).map(|i| (i, weights.map_or(1.0, |w| w[i]))).filter(|&(_, w)| w > 0.0).collect();
        let free = if options.white.is_some() { m - 1 } else { m };
        if used.len() < free.max(1) {
            return Err(ColorError::TooFewSamples { model: kind, samples: used.len(), needed: free.max(1) });
        }
        let mut t = [0.0; MAX_TERMS];
        let mut a = DMatrix::zeros(used.len(), m);
        let mut bm = DMatrix::zeros(used.len(), 3);
        for (row, &(i, w)) in used.iter().enumerate() {
            let sw = w.sqrt();
            kind.eval_terms(camera[i], &mut t);
            for j in 0..m {
                a[(row, j)] = sw * t[j];
            }
            for c in 0..3 {
                bm[(row, c)] = sw * target[i][c];
            }
        }
        let colour_condition = condition_number(&a.columns(0, 3).into_owned());
        if colour_condition.is_nan() || colour_condition > options.max_colour_condition {
            return Err(ColorError::FewColours {
                model: kind,
                condition: colour_condition,
                limit: options.max_colour_condition,
            });
        }
        let ill = |condition: f64| ColorError::IllConditioned { model: kind, condition, limit: options.max_condition };
        let (x, condition) = match options.white {
            None => solve_ls(&a, &bm, options.ridge, options.max_condition).map_err(ill)?,
            Some(wc) => {
                kind.eval_terms(wc.camera, &mut t);
                let p = DVector::from_column_slice(&t[..m]);
                let pp = p.dot(&p);
                if pp.is_nan() || pp <= 0.0 {
                    return Err(ColorError::InvalidOption {
                        what: "white.camera (all model terms zero)",
                        value: pp,
                        allowed: "a non-black white reference",
                    });
                }
                // x = x0 + N z with x0 = p tᵀ/|p|² (satisfies pᵀx = t) and N ⟂ p.
                let x0 = &p * DMatrix::from_row_slice(1, 3, &wc.target) / pp;
                let nb = null_space_basis(&p);
                let (z, cond) = if m == 1 {
                    (DMatrix::zeros(0, 3), 1.0)
                } else {
                    solve_ls(&(&a * &nb), &(&bm - &a * &x0), options.ridge, options.max_condition).map_err(ill)?
                };
                (x0 + nb * z, cond)
            }
        };
        if x.iter().any(|v| !v.is_finite()) {
            return Err(ill(f64::INFINITY));
        }
        let coefficients: Vec<[f64; 3]> = (0..m).map(|j| [x[(j, 0)], x[(j, 1)], x[(j, 2)]]).collect();
        let res = &a * &x - &bm;
        let wsum: f64 = used.iter().map(|u| u.1).sum();
        let rms_residual = std::array::from_fn(|c| (res.column(c).norm_squared() / wsum).sqrt());
        Ok(ColorModel { kind, coefficients, condition, rms_residual })
    }

    /// A model from stored coefficients (one row per term, see [`ColorModel::coefficients`]).
    pub fn from_coefficients(kind: ModelKind, coefficients: Vec<[f64; 3]>) -> Result<ColorModel, ColorError> {
        if coefficients.len() != kind.terms() {
            return Err(ColorError::WrongTermCount { model: kind, expected: kind.terms(), got: coefficients.len() });
        }
        check_finite("coefficients", &coefficients)?;
        Ok(ColorModel { kind, coefficients, condition: f64::NAN, rms_residual: [f64::NAN; 3] })
    }

    /// The model family.
    pub fn kind(&self) -> ModelKind {
        self.kind
    }

    /// Coefficients: one row per term (in [`ModelKind::term_names`] order), holding that
    /// term's weight in each of the three output channels.
    pub fn coefficients(&self) -> &[[f64; 3]] {
        &self.coefficients
    }

    /// Condition number of the design matrix the model was fitted with (NaN when built by
    /// [`ColorModel::from_coefficients`]).
    pub fn condition(&self) -> f64 {
        self.condition
    }

    /// Weighted RMS residual per output channel over the fitting samples (NaN when unknown).
    pub fn rms_residual(&self) -> [f64; 3] {
        self.rms_residual
    }

    /// The target colour of camera RGB `rgb`.
    #[inline]
    pub fn apply(&self, rgb: [f64; 3]) -> [f64; 3] {
        let mut t = [0.0; MAX_TERMS];
        self.kind.eval_terms(rgb, &mut t);
        let mut out = [0.0; 3];
        for (tj, cj) in t.iter().zip(&self.coefficients) {
            out[0] += tj * cj[0];
            out[1] += tj * cj[1];
            out[2] += tj * cj[2];
        }
        out
    }

    /// Applies the model in place to a batch of f32 pixels (a whole texture). Each pixel is
    /// evaluated in f64 (the terms of the polynomial models cancel; f32 arithmetic would lose
    /// up to ~1e-5 relative) and rounded once, so the result agrees with [`ColorModel::apply`]
    /// to f32 rounding. Single-threaded: callers parallelise over chunks.
    pub fn apply_f32(&self, pixels: &mut [[f32; 3]]) {
        let c = &self.coefficients;
        match self.kind {
            ModelKind::Linear => batch(pixels, c, terms_linear),
            ModelKind::Polynomial2 => batch(pixels, c, terms_poly2),
            ModelKind::Polynomial3 => batch(pixels, c, terms_poly3),
            ModelKind::RootPolynomial2 => batch(pixels, c, terms_root2),
            ModelKind::RootPolynomial3 => batch(pixels, c, terms_root3),
        }
    }
}
