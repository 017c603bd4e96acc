//! Zhang's closed form: intrinsics (zero skew) from plane homographies through the
//! constraints `h1ᵀ B h2 = 0`, `h1ᵀ B h1 = h2ᵀ B h2` on `B = K⁻ᵀ K⁻¹`, then each view's pose.

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};

/// Pinhole intrinsics without distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    /// Focal length along u, pixels.
    pub fx: f64,
    /// Focal length along v, pixels.
    pub fy: f64,
    /// Principal point u, pixels.
    pub cx: f64,
    /// Principal point v, pixels.
    pub cy: f64,
}

impl Pinhole {
    /// The matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }
}

/// Why the closed form found no intrinsics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClosedFormFailure {
    /// The constraints leave more than one solution: `ratio` is the second smallest over the
    /// largest singular value of the constraint matrix.
    IllConditioned {
        /// The ratio (tiny when degenerate).
        ratio: f64,
    },
    /// The solution is not a real camera (`B` not positive definite).
    NotPositive,
}

/// Row `v_ij` of Zhang's constraint matrix with the skew entry `B12` dropped:
/// unknowns `(B11, B22, B13, B23, B33)`.
fn v_row(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 5] {
    let (a, b) = (h.column(i), h.column(j));
    [a[0] * b[0], a[1] * b[1], a[2] * b[0] + a[0] * b[2], a[2] * b[1] + a[1] * b[2], a[2] * b[2]]
}

/// Intrinsics from homographies (each mapping target metres to image coordinates that should
/// be pre-normalised to order one for conditioning). Needs at least two views whose planes
/// are tilted differently.
pub fn intrinsics(hs: &[Matrix3<f64>]) -> Result<Pinhole, ClosedFormFailure> {
    let mut v = DMatrix::<f64>::zeros((2 * hs.len()).max(5), 5);
    for (n, h) in hs.iter().enumerate() {
        // Each homography has its own scale: normalise so every view weighs the same.
        let h = h / h.column(0).norm().max(h.column(1).norm());
        let r12 = v_row(&h, 0, 1);
        let r11 = v_row(&h, 0, 0);
        let r22 = v_row(&h, 1, 1);
        let d: Vec<f64> = (0..5).map(|k| r11[k] - r22[k]).collect();
        v.row_mut(2 * n).copy_from_slice(&r12);
        v.row_mut(2 * n + 1).copy_from_slice(&d);
    }
    let svd = v.svd(false, true);
    let vt = svd.v_t.ok_or(ClosedFormFailure::NotPositive)?;
    let mut idx: Vec<usize> = (0..svd.singular_values.len()).collect();
    idx.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let sv = |k: usize| svd.singular_values[idx[k]];
    let ratio = sv(3) / sv(0);
    if !(ratio > 1e-9) {
        return Err(ClosedFormFailure::IllConditioned { ratio });
    }
    let b = vt.row(idx[4]);
    let (b11, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4]);
    if b11 * b22 <= 0.0 {
        return Err(ClosedFormFailure::NotPositive);
    }
    let cx = -b13 / b11;
    let cy = -b23 / b22;
    let lam = b33 - b13 * b13 / b11 - b23 * b23 / b22;
    let (fx2, fy2) = (lam / b11, lam / b22);
    if !(fx2 > 0.0 && fy2 > 0.0 && cx.is_finite() && cy.is_finite()) {
        return Err(ClosedFormFailure::NotPositive);
    }
    Ok(Pinhole { fx: fx2.sqrt(), fy: fy2.sqrt(), cx, cy })
}

/// Intrinsics with the principal point held at `(cx, cy)`: the focal lengths alone from the
/// same constraints by linear least squares in `(1/fx², 1/fy²)` (the fallback when the full
/// closed form is ill-conditioned, as for long lenses whose views show little perspective).
pub fn focal_with_centre(hs: &[Matrix3<f64>], cx: f64, cy: f64) -> Result<Pinhole, ClosedFormFailure> {
    let shift = Matrix3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    // With the principal point at the origin, B = diag(a, b, 1) up to scale; constraints:
    // h1x h2x a + h1y h2y b = -h1z h2z, (h1x² - h2x²) a + (h1y² - h2y²) b = -(h1z² - h2z²).
    let mut ata = nalgebra::Matrix2::<f64>::zeros();
    let mut atb = nalgebra::Vector2::<f64>::zeros();
    for h in hs {
        let h = shift * h;
        let h = h / h.column(0).norm().max(h.column(1).norm());
        let (a, b) = (h.column(0), h.column(1));
        for (row, rhs) in [
            (nalgebra::Vector2::new(a[0] * b[0], a[1] * b[1]), -a[2] * b[2]),
            (
                nalgebra::Vector2::new(a[0] * a[0] - b[0] * b[0], a[1] * a[1] - b[1] * b[1]),
                -(a[2] * a[2] - b[2] * b[2]),
            ),
        ] {
            ata += row * row.transpose();
            atb += row * rhs;
        }
    }
    let sol = ata.try_inverse().ok_or(ClosedFormFailure::IllConditioned { ratio: 0.0 })? * atb;
    if !(sol.x > 0.0 && sol.y > 0.0) {
        return Err(ClosedFormFailure::NotPositive);
    }
    Ok(Pinhole { fx: 1.0 / sol.x.sqrt(), fy: 1.0 / sol.y.sqrt(), cx, cy })
}

/// Pose of the target (rotation, translation: target to camera) from its homography and `K`.
pub fn pose(h: &Matrix3<f64>, k: &Matrix3<f64>) -> Option<(Rotation3<f64>, Vector3<f64>)> {
    let iso = btfrig_core::homography::decompose(&(k.try_inverse()? * h))?;
    Some((iso.rotation.to_rotation_matrix(), iso.translation.vector))
}
