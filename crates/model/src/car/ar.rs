//! The 2D causal autoregressive (CAR) model of one mono-spectral band (seed 002, eq. 1):
//!
//! ```text
//! Y_r = γ X_r + e_r,   e_r ~ N(0, σ²) white,   X_r = [Y_{r+s}]_{s ∈ I_r^c}
//! ```
//!
//! on the band with its mean removed. The causal neighbourhood `I_r^c` of radius `ρ` is the
//! non-symmetric half plane in raster order (rows top to bottom, each left to right):
//! `ρ` texels to the left in the same row and the `2ρ + 1` texels centred above in each of the
//! `ρ` rows above, `ρ (2ρ + 2)` neighbours (radius 1: left, up-left, up, up-right).
//!
//! **Estimate** (seed 002, eq. 2): the Bayesian estimate with a normal-gamma prior,
//! `γ̂ = V_x⁻¹ V_xy`, `σ̂² = λ / β`, `λ = V_y − V_xyᵀ V_x⁻¹ V_xy`, with `V = Σ_r (X_r, Y_r)
//! (X_r, Y_r)ᵀ + V(0)` over every texel whose whole neighbourhood lies in the band, `V(0)` a
//! ridge `δ I` (`δ` = 1e-9 of the mean diagonal: it makes rank-deficient data solvable and
//! changes well-posed estimates by ~1e-9) and `β = n` (`β(0) = 1`). With `δ → 0` this is least
//! squares. A band whose spread is below the caller's floor is constant: the valid model
//! `γ = 0, σ = 0` (it synthesises its mean), never a division by ~0.
//!
//! **Stability.** The recursion is stable iff (Ekstrom & Woods' theorem for non-symmetric half
//! plane filters) the row polynomial `A_0(z) = 1 − Σ_j a_{−j,0} z^{−j}` has its roots inside
//! the unit circle and, at every horizontal frequency `ω`, the row-to-row recursion
//! `Y_y(ω) = Σ_k c_k(ω) Y_{y−k}(ω)`, `c_k = B_k(e^{iω}) / A_0(e^{iω})`,
//! `B_k(z) = Σ_dx a_{dx,−k} z^{dx}`, has its characteristic roots inside it. The
//! [`spectral_radius`] is the largest of those root moduli (`ω` on a 512-point grid); a
//! synthesis refuses a model whose radius is `≥ 1`, and [`fit`] shrinks an unstable estimate
//! (`γ → sγ`, the largest `s` found by bisection with radius ≤ [`STABLE_RADIUS`]) and says so
//! in [`CarModel::shrunk_from`].

use nalgebra::{Complex, DMatrix, DVector};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

/// A fitted estimate whose spectral radius exceeds this is shrunk to it.
pub const STABLE_RADIUS: f64 = 0.995;

/// Horizontal frequencies at which [`spectral_radius`] evaluates the row-to-row recursion.
const FREQUENCIES: usize = 512;

/// The causal neighbourhood of radius `radius` as `(dx, dy)` offsets (`dy < 0`: rows above).
pub fn neighbourhood(radius: usize) -> Vec<[i32; 2]> {
    let r = radius as i32;
    let mut n: Vec<[i32; 2]> = (1..=r).map(|dx| [-dx, 0]).collect();
    for dy in 1..=r {
        n.extend((-r..=r).map(|dx| [dx, -dy]));
    }
    n
}

/// One band's CAR model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CarModel {
    /// Neighbour offsets `(dx, dy)`, the order of `gamma`.
    pub offsets: Vec<[i32; 2]>,
    /// Parameters `γ`.
    pub gamma: Vec<f64>,
    /// Noise standard deviation `σ` (0: a constant band).
    pub sigma: f64,
    /// The band's mean (added back after synthesis).
    pub mean: f64,
    /// Spectral radius of the recursion (< 1: stable).
    pub spectral_radius: f64,
    /// The estimate's spectral radius when it was unstable and shrunk (`None`: not shrunk).
    pub shrunk_from: Option<f64>,
}

impl CarModel {
    /// A model from given parameters (its spectral radius computed).
    pub fn new(offsets: Vec<[i32; 2]>, gamma: Vec<f64>, sigma: f64, mean: f64) -> Self {
        let spectral_radius = spectral_radius(&offsets, &gamma);
        CarModel { offsets, gamma, sigma, mean, spectral_radius, shrunk_from: None }
    }

    /// Values stored: the parameters, `σ` and the mean.
    pub fn values(&self) -> usize {
        self.gamma.len() + 2
    }

    /// Texels of the neighbourhood's reach: rows above and columns either side.
    fn reach(&self) -> (usize, usize) {
        let up = self.offsets.iter().map(|o| (-o[1]).max(0)).max().unwrap_or(0) as usize;
        let side = self.offsets.iter().map(|o| o[0].abs()).max().unwrap_or(0) as usize;
        (up, side)
    }
}

/// Fits the CAR model of radius `radius` to a `width x height` band (row-major). Bands whose
/// standard deviation is at most `floor_std` are constant (`γ = 0`, `σ = 0`).
pub fn fit(what: &str, width: usize, height: usize, band: &[f64], radius: usize, floor_std: f64) -> Result<CarModel> {
    if band.len() != width * height {
        return Err(ModelError::WrongSize { what: format!("{what}: band"), got: band.len(), expected: width * height });
    }
    if radius == 0 {
        return Err(ModelError::OutOfRange {
            field: format!("{what}: neighbourhood radius"),
            value: "0".into(),
            allowed: "at least 1 (radius 1: left, up-left, up, up-right)".into(),
        });
    }
    if let Some(i) = band.iter().position(|v| !v.is_finite()) {
        return Err(ModelError::OutOfRange {
            field: format!("{what}: texel ({}, {})", i % width, i / width),
            value: format!("{}", band[i]),
            allowed: "a finite value".into(),
        });
    }
    let offsets = neighbourhood(radius);
    let eta = offsets.len();
    let r = radius;
    let samples = width.saturating_sub(2 * r) * height.saturating_sub(r);
    if samples < eta + 1 {
        return Err(ModelError::OutOfRange {
            field: format!("{what}: size"),
            value: format!("{width} x {height} texels ({samples} complete neighbourhoods)"),
            allowed: format!(
                "a radius-{radius} neighbourhood ({eta} parameters) needs at least {} complete neighbourhoods: more texels or a smaller radius",
                eta + 1
            ),
        });
    }
    let mean = band.iter().sum::<f64>() / band.len() as f64;
    let var = band.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / band.len() as f64;
    if var.sqrt() <= floor_std || var == 0.0 {
        return Ok(CarModel::new(offsets, vec![0.0; eta], 0.0, mean));
    }
    let y = |x: usize, row: usize, o: [i32; 2]| {
        band[(row as i64 + i64::from(o[1])) as usize * width + (x as i64 + i64::from(o[0])) as usize] - mean
    };
    let mut vx = DMatrix::<f64>::zeros(eta, eta);
    let mut vxy = DVector::<f64>::zeros(eta);
    let mut vy = 0.0;
    let mut xr = DVector::<f64>::zeros(eta);
    for row in r..height {
        for x in r..width - r {
            for (k, o) in offsets.iter().enumerate() {
                xr[k] = y(x, row, *o);
            }
            let yr = y(x, row, [0, 0]);
            vx.syger(1.0, &xr, &xr, 1.0);
            vxy.axpy(yr, &xr, 1.0);
            vy += yr * yr;
        }
    }
    let delta = 1e-9 * vx.trace() / eta as f64 + f64::MIN_POSITIVE;
    for k in 0..eta {
        vx[(k, k)] += delta;
    }
    // The lower triangle is what `syger` filled.
    vx.fill_upper_triangle_with_lower_triangle();
    let chol = vx.clone().cholesky().ok_or_else(|| ModelError::OutOfRange {
        field: format!("{what}: V_x"),
        value: "not positive definite".into(),
        allowed: "finite data (the ridge makes any finite band solvable)".into(),
    })?;
    let gamma = chol.solve(&vxy);
    let lambda = (vy - vxy.dot(&gamma)).max(0.0);
    let sigma = (lambda / samples as f64).sqrt();
    let mut model = CarModel::new(offsets, gamma.iter().copied().collect(), sigma, mean);
    if model.spectral_radius > STABLE_RADIUS {
        stabilise(&mut model);
    }
    Ok(model)
}

/// Shrinks `γ` to the largest `s γ` (bisection on `s`) whose radius is at most [`STABLE_RADIUS`].
fn stabilise(m: &mut CarModel) {
    let g0 = m.gamma.clone();
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..40 {
        let s = 0.5 * (lo + hi);
        let g: Vec<f64> = g0.iter().map(|a| a * s).collect();
        if spectral_radius(&m.offsets, &g) <= STABLE_RADIUS {
            lo = s;
        } else {
            hi = s;
        }
    }
    m.shrunk_from = Some(m.spectral_radius);
    m.gamma = g0.iter().map(|a| a * lo).collect();
    m.spectral_radius = spectral_radius(&m.offsets, &m.gamma);
}

/// Roots of the monic polynomial `z^d + c[0] z^{d−1} + … + c[d−1]` (Durand–Kerner).
fn roots(c: &[Complex<f64>]) -> Vec<Complex<f64>> {
    let d = c.len();
    if d == 1 {
        return vec![-c[0]];
    }
    let eval = |z: Complex<f64>| c.iter().fold(Complex::new(1.0, 0.0), |acc, ck| acc * z + ck);
    let scale = 1.0 + c.iter().map(|v| v.norm()).fold(0.0, f64::max);
    let seed = Complex::new(0.4, 0.9);
    let mut z: Vec<Complex<f64>> = (0..d).map(|k| seed.powu(k as u32) * scale).collect();
    for _ in 0..500 {
        let mut moved: f64 = 0.0;
        for i in 0..d {
            let mut den = Complex::new(1.0, 0.0);
            for j in 0..d {
                if i != j {
                    den *= z[i] - z[j];
                }
            }
            let step = eval(z[i]) / den;
            if step.is_finite() {
                z[i] -= step;
                moved = moved.max(step.norm());
            }
        }
        if moved < 1e-14 * scale {
            break;
        }
    }
    z
}

/// The spectral radius of the causal recursion with these offsets and parameters: the
/// largest root modulus of the row polynomial and of the row-to-row recursion over the
/// horizontal frequencies (module documentation). `∞` when `A_0` vanishes on the unit circle.
pub fn spectral_radius(offsets: &[[i32; 2]], gamma: &[f64]) -> f64 {
    let rows = offsets.iter().map(|o| (-o[1]).max(0)).max().unwrap_or(0) as usize;
    let left = offsets.iter().filter(|o| o[1] == 0).map(|o| -o[0]).max().unwrap_or(0).max(0) as usize;
    let mut radius: f64 = 0.0;
    if left > 0 {
        // z^left − Σ_j a_{−j,0} z^{left−j}.
        let mut c = vec![Complex::new(0.0, 0.0); left];
        for (o, a) in offsets.iter().zip(gamma) {
            if o[1] == 0 && o[0] < 0 {
                c[(-o[0] - 1) as usize] -= a;
            }
        }
        radius = roots(&c).iter().map(|z| z.norm()).fold(radius, f64::max);
    }
    if rows == 0 {
        return radius;
    }
    for f in 0..FREQUENCIES {
        let w = std::f64::consts::TAU * f as f64 / FREQUENCIES as f64;
        let at = |dx: i32| Complex::from_polar(1.0, w * f64::from(dx));
        let mut a0 = Complex::new(1.0, 0.0);
        let mut b = vec![Complex::new(0.0, 0.0); rows];
        for (o, a) in offsets.iter().zip(gamma) {
            if o[1] == 0 {
                a0 -= at(o[0]) * a;
            } else {
                b[(-o[1] - 1) as usize] += at(o[0]) * a;
            }
        }
        if a0.norm() < 1e-12 {
            return f64::INFINITY;
        }
        // z^rows − Σ_k c_k z^{rows−k}.
        let c: Vec<Complex<f64>> = b.iter().map(|bk| -bk / a0).collect();
        radius = roots(&c).iter().map(|z| z.norm()).fold(radius, f64::max);
    }
    radius
}

/// Texels of burn-in around the requested band: enough for the start (zeros) to decay to
/// 1e-3 at the model's spectral radius, between 8 and 128 (beyond, the lattice would be many
/// times the band: a model that close to the unit circle starts visibly, 0.995^128 = 0.53).
fn burn_in(m: &CarModel) -> usize {
    if m.spectral_radius <= 0.0 || m.sigma == 0.0 {
        return 0;
    }
    let n = (1e-3f64).ln() / m.spectral_radius.ln();
    (n.ceil() as usize).clamp(8, 128)
}

/// Synthesises a `width x height` band: the causal recursion over a lattice larger by the
/// burn-in on the left, right and top, driven by white noise from `rng`, then cropped.
pub fn synthesise(what: &str, m: &CarModel, width: usize, height: usize, rng: &mut impl Rng) -> Result<Vec<f64>> {
    if m.gamma.len() != m.offsets.len() {
        return Err(ModelError::WrongSize {
            what: format!("{what}: CAR parameters"),
            got: m.gamma.len(),
            expected: m.offsets.len(),
        });
    }
    let radius = spectral_radius(&m.offsets, &m.gamma);
    if radius.is_nan() || radius >= 1.0 || !m.sigma.is_finite() || !m.mean.is_finite() {
        return Err(ModelError::OutOfRange {
            field: format!("{what}: CAR model's spectral radius"),
            value: format!("{radius:.4} (sigma {}, mean {})", m.sigma, m.mean),
            allowed: "below 1 (a stable causal recursion) with a finite sigma and mean".into(),
        });
    }
    let b = burn_in(m);
    let (up, side) = m.reach();
    // Lattice: `side` zero columns either side and `up` zero rows on top stand for the
    // start values; the burn-in texels are synthesised and thrown away.
    let (lw, lh) = (width + 2 * b + 2 * side, height + b + up);
    let mut lat = vec![0.0f64; lw * lh];
    let offs: Vec<isize> = m.offsets.iter().map(|o| o[1] as isize * lw as isize + o[0] as isize).collect();
    for row in up..lh {
        for x in side..lw - side {
            let i = row * lw + x;
            let mut v = m.sigma * rng.sample::<f64, _>(StandardNormal);
            for (o, a) in offs.iter().zip(&m.gamma) {
                v += a * lat[(i as isize + o) as usize];
            }
            lat[i] = v;
        }
    }
    let mut out = Vec::with_capacity(width * height);
    for row in 0..height {
        let s = (row + up + b) * lw + side + b;
        out.extend(lat[s..s + width].iter().map(|v| v + m.mean));
    }
    Ok(out)
}
