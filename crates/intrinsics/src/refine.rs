//! Levenberg–Marquardt refinement of the total (weighted) reprojection error over the
//! intrinsics, the distortion and every view's pose, with analytic Jacobians and the normal
//! equations reduced to the 9 camera parameters by a Schur complement over the 6x6 pose
//! blocks (poses do not couple to each other, so one step costs O(views) small solves).

use nalgebra::{Matrix2x6, Matrix6, Point2, Rotation3, SMatrix, SVector, Vector2, Vector3, Vector6};

/// Number of camera parameters: fx, fy, cx, cy, k1, k2, k3, p1, p2.
pub const NCAM: usize = 9;
/// Names of the camera parameters in their order.
pub const CAM_NAMES: [&str; NCAM] = ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2"];

pub type CamVec = SVector<f64, NCAM>;
pub type CamMat = SMatrix<f64, NCAM, NCAM>;
type CamPose = SMatrix<f64, NCAM, 6>;

/// One observation inside the refinement: target point, pixel, weight `1/sigma`.
#[derive(Debug, Clone, Copy)]
pub struct Obs {
    pub target: Point2<f64>,
    pub pixel: Point2<f64>,
    pub w: f64,
}

/// A view's pose (target to camera).
#[derive(Debug, Clone, Copy)]
pub struct Pose {
    pub r: Rotation3<f64>,
    pub t: Vector3<f64>,
}

/// Projection of target point `x` by camera `c` and pose `p`, with the Jacobians with respect
/// to the camera parameters and to the pose (left rotation increment, then translation).
/// `None` if the point is not in front of the camera.
pub fn project(
    c: &CamVec,
    p: &Pose,
    x: &Point2<f64>,
    want_jac: bool,
) -> Option<(Vector2<f64>, SMatrix<f64, 2, NCAM>, Matrix2x6<f64>)> {
    let rx = p.r * Vector3::new(x.x, x.y, 0.0);
    let pc = rx + p.t;
    if !(pc.z > 0.0) {
        return None;
    }
    let iz = 1.0 / pc.z;
    let (xn, yn) = (pc.x * iz, pc.y * iz);
    let [fx, fy, cx, cy, k1, k2, k3, p1, p2] = [c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]];
    let s = xn * xn + yn * yn;
    let rad = 1.0 + s * (k1 + s * (k2 + s * k3));
    let xd = xn * rad + 2.0 * p1 * xn * yn + p2 * (s + 2.0 * xn * xn);
    let yd = yn * rad + p1 * (s + 2.0 * yn * yn) + 2.0 * p2 * xn * yn;
    let uv = Vector2::new(fx * xd + cx, fy * yd + cy);
    let mut jc = SMatrix::<f64, 2, NCAM>::zeros();
    let mut jp = Matrix2x6::<f64>::zeros();
    if !want_jac {
        return Some((uv, jc, jp));
    }
    let (s2, s3) = (s * s, s * s * s);
    jc.row_mut(0).copy_from_slice(&[
        xd,
        0.0,
        1.0,
        0.0,
        fx * xn * s,
        fx * xn * s2,
        fx * xn * s3,
        fx * 2.0 * xn * yn,
        fx * (s + 2.0 * xn * xn),
    ]);
    jc.row_mut(1).copy_from_slice(&[
        0.0,
        yd,
        0.0,
        1.0,
        fy * yn * s,
        fy * yn * s2,
        fy * yn * s3,
        fy * (s + 2.0 * yn * yn),
        fy * 2.0 * xn * yn,
    ]);
    // d(xd, yd) / d(xn, yn)
    let drad = k1 + s * (2.0 * k2 + s * 3.0 * k3);
    let a11 = rad + 2.0 * xn * xn * drad + 2.0 * p1 * yn + 6.0 * p2 * xn;
    let a12 = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn;
    let a22 = rad + 2.0 * yn * yn * drad + 6.0 * p1 * yn + 2.0 * p2 * xn;
    // d(u, v) / d(pc) = diag(f) * Jd * d(xn, yn)/d(pc)
    let dn = nalgebra::Matrix2x3::new(iz, 0.0, -xn * iz, 0.0, iz, -yn * iz);
    let jd = nalgebra::Matrix2::new(fx * a11, fx * a12, fy * a12, fy * a22);
    let duv_dpc = jd * dn;
    // pc(δ) = exp(δ) R x + t  =>  d pc / d δ = -[R x]_×
    let skew = nalgebra::Matrix3::new(0.0, -rx.z, rx.y, rx.z, 0.0, -rx.x, -rx.y, rx.x, 0.0);
    jp.fixed_view_mut::<2, 3>(0, 0).copy_from(&(-duv_dpc * skew));
    jp.fixed_view_mut::<2, 3>(0, 3).copy_from(&duv_dpc);
    Some((uv, jc, jp))
}

/// Whitened residual vector `w (projection - pixel)` of one observation (`None` behind the camera).
fn residual(c: &CamVec, p: &Pose, o: &Obs) -> Option<Vector2<f64>> {
    project(c, p, &o.target, false).map(|(uv, _, _)| (uv - o.pixel.coords) * o.w)
}

/// Sum of squared whitened residuals over the active observations; infinite if any point is
/// behind its camera.
pub fn cost(c: &CamVec, poses: &[Pose], obs: &[Vec<Obs>], active: &[Vec<bool>]) -> f64 {
    let mut sum = 0.0;
    for ((p, os), act) in poses.iter().zip(obs).zip(active) {
        for (o, &a) in os.iter().zip(act) {
            if a {
                match residual(c, p, o) {
                    Some(r) => sum += r.norm_squared(),
                    None => return f64::INFINITY,
                }
            }
        }
    }
    sum
}

/// Normal equations of the current linearisation.
struct Normal {
    u: CamMat,
    ga: CamVec,
    v: Vec<Matrix6<f64>>,
    w: Vec<CamPose>,
    gp: Vec<Vector6<f64>>,
}

fn normal(c: &CamVec, poses: &[Pose], obs: &[Vec<Obs>], active: &[Vec<bool>], free: &[bool; NCAM]) -> Normal {
    let mut n = Normal {
        u: CamMat::zeros(),
        ga: CamVec::zeros(),
        v: vec![Matrix6::zeros(); poses.len()],
        w: vec![CamPose::zeros(); poses.len()],
        gp: vec![Vector6::zeros(); poses.len()],
    };
    for (i, ((p, os), act)) in poses.iter().zip(obs).zip(active).enumerate() {
        for (o, &a) in os.iter().zip(act) {
            if !a {
                continue;
            }
            let Some((uv, mut jc, jp)) = project(c, p, &o.target, true) else { continue };
            for (k, &f) in free.iter().enumerate() {
                if !f {
                    jc.column_mut(k).fill(0.0);
                }
            }
            let r = (uv - o.pixel.coords) * o.w;
            let jc = jc * o.w;
            let jp = jp * o.w;
            n.u += jc.transpose() * jc;
            n.ga += jc.transpose() * r;
            n.v[i] += jp.transpose() * jp;
            n.w[i] += jc.transpose() * jp;
            n.gp[i] += jp.transpose() * r;
        }
    }
    // Fixed parameters: identity rows keep the reduced system regular and their step zero.
    for (k, &f) in free.iter().enumerate() {
        if !f {
            n.u[(k, k)] = 1.0;
        }
    }
    n
}

/// Solves the damped normal equations by the Schur complement; returns the camera step and
/// the pose steps, or `None` if a block is not positive definite.
fn solve(n: &Normal, lambda: f64) -> Option<(CamVec, Vec<Vector6<f64>>)> {
    let damp6 = |m: &Matrix6<f64>| {
        let mut m = *m;
        for k in 0..6 {
            m[(k, k)] *= 1.0 + lambda;
        }
        m
    };
    let mut s = n.u;
    for k in 0..NCAM {
        s[(k, k)] *= 1.0 + lambda;
    }
    let mut rhs = -n.ga;
    let mut vinv = Vec::with_capacity(n.v.len());
    for i in 0..n.v.len() {
        let vi = damp6(&n.v[i]).cholesky()?.inverse();
        let wv = n.w[i] * vi;
        s -= wv * n.w[i].transpose();
        rhs += wv * n.gp[i];
        vinv.push(vi);
    }
    // Symmetric diagonal scaling: the camera parameters span ten orders of magnitude in
    // their columns (fx in pixels against k3 on r⁶), which Cholesky would not survive unscaled.
    let d = CamVec::from_iterator((0..NCAM).map(|k| 1.0 / s[(k, k)].abs().max(1e-300).sqrt()));
    let ss = CamMat::from_fn(|r, c| s[(r, c)] * d[r] * d[c]);
    let da = ss.cholesky()?.solve(&rhs.component_mul(&d)).component_mul(&d);
    let dp = (0..n.v.len()).map(|i| vinv[i] * (-n.gp[i] - n.w[i].transpose() * da)).collect();
    Some((da, dp))
}

fn step_pose(p: &Pose, d: &Vector6<f64>) -> Pose {
    let dr = Rotation3::new(Vector3::new(d[0], d[1], d[2]));
    Pose { r: dr * p.r, t: p.t + Vector3::new(d[3], d[4], d[5]) }
}

/// Result of one refinement.
pub struct Refined {
    pub cam: CamVec,
    pub poses: Vec<Pose>,
    pub cost: f64,
    pub iterations: usize,
    /// Inverse of the reduced (camera) normal matrix at the optimum: the camera parameters'
    /// covariance for unit-weight residuals. Zero rows/columns for fixed parameters.
    pub cam_cov: CamMat,
    /// Diagonal of each pose's covariance for unit-weight residuals (rotation rad², translation m²).
    pub pose_var: Vec<Vector6<f64>>,
}

/// Levenberg–Marquardt (Marquardt's diagonal scaling, lambda x10 / /10).
pub fn refine(
    mut cam: CamVec,
    mut poses: Vec<Pose>,
    obs: &[Vec<Obs>],
    active: &[Vec<bool>],
    free: &[bool; NCAM],
    max_iter: usize,
) -> Refined {
    let mut c0 = cost(&cam, &poses, obs, active);
    let mut lambda = 1e-3;
    let mut it = 0;
    while it < max_iter {
        it += 1;
        let n = normal(&cam, &poses, obs, active, free);
        let mut accepted = false;
        let mut converged = false;
        for _ in 0..12 {
            if let Some((da, dp)) = solve(&n, lambda) {
                let cam2 = cam + da;
                let poses2: Vec<Pose> = poses.iter().zip(&dp).map(|(p, d)| step_pose(p, d)).collect();
                let c1 = cost(&cam2, &poses2, obs, active);
                if c1 < c0 {
                    let rel = (c0 - c1) / c0.max(1e-300);
                    cam = cam2;
                    poses = poses2;
                    c0 = c1;
                    lambda = (lambda / 10.0).max(1e-12);
                    accepted = true;
                    converged = rel < 1e-12;
                    break;
                }
            }
            lambda *= 10.0;
        }
        // No decrease at any damping: at the minimum to floating-point precision.
        if !accepted || converged {
            break;
        }
    }
    let n = normal(&cam, &poses, obs, active, free);
    let mut cam_cov = CamMat::zeros();
    let mut pose_var = vec![Vector6::zeros(); poses.len()];
    // Covariance: S⁻¹ for the camera block; each pose block is V⁻¹ + V⁻¹ Wᵀ S⁻¹ W V⁻¹.
    let mut s = n.u;
    let mut vinvs = Vec::new();
    for i in 0..n.v.len() {
        let vi = n.v[i].try_inverse().unwrap_or_else(Matrix6::zeros);
        s -= n.w[i] * vi * n.w[i].transpose();
        vinvs.push(vi);
    }
    let d = CamVec::from_iterator((0..NCAM).map(|k| 1.0 / s[(k, k)].abs().max(1e-300).sqrt()));
    let ss = CamMat::from_fn(|r, c| s[(r, c)] * d[r] * d[c]);
    if let Some(inv) = ss.try_inverse() {
        cam_cov = CamMat::from_fn(|r, c| if free[r] && free[c] { inv[(r, c)] * d[r] * d[c] } else { 0.0 });
        for i in 0..n.v.len() {
            let b = vinvs[i] * n.w[i].transpose();
            let full = vinvs[i] + b * cam_cov * b.transpose();
            pose_var[i] = full.diagonal();
        }
    }
    Refined { cam, poses, cost: c0, iterations: it, cam_cov, pose_var }
}

/// Whitened residuals (per observation) at the given parameters; `None` behind the camera.
pub fn residuals(cam: &CamVec, poses: &[Pose], obs: &[Vec<Obs>]) -> Vec<Vec<Option<Vector2<f64>>>> {
    poses.iter().zip(obs).map(|(p, os)| os.iter().map(|o| residual(cam, p, o)).collect()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let cam = CamVec::from_column_slice(&[4800.0, 4790.0, 801.0, 598.0, -0.08, 0.02, 0.01, 1e-4, -2e-4]);
        let pose = Pose { r: Rotation3::new(Vector3::new(0.4, -0.3, 0.2)), t: Vector3::new(0.03, -0.02, 1.2) };
        let x = Point2::new(0.07, -0.05);
        let (_, jc, jp) = project(&cam, &pose, &x, true).unwrap();
        for k in 0..NCAM {
            // Linear in every camera parameter but the focal lengths: a large step is exact.
            let h = if k < 2 { 1e-6 * cam[k] } else { 1e-3 };
            let (mut a, mut b) = (cam, cam);
            a[k] += h;
            b[k] -= h;
            let num = (project(&a, &pose, &x, false).unwrap().0 - project(&b, &pose, &x, false).unwrap().0) / (2.0 * h);
            let ana = jc.column(k);
            assert!((num - ana).norm() <= 1e-6 * (1.0 + ana.norm()), "camera param {k}: {num} vs {ana}");
        }
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = 1e-7;
            let a = step_pose(&pose, &d);
            let b = step_pose(&pose, &-d);
            let num = (project(&cam, &a, &x, false).unwrap().0 - project(&cam, &b, &x, false).unwrap().0) / 2e-7;
            let ana = jp.column(k);
            assert!((num - ana).norm() <= 1e-5 * (1.0 + ana.norm()), "pose param {k}: {num} vs {ana}");
        }
    }
}
