//! Levenberg–Marquardt refinement of a plane pose against observed pixels through the full
//! (distorted) camera model, with an optional Gaussian prior on the pose.

use btfrig_core::camera::CameraModel;
use nalgebra::{Isometry3, Point2, Point3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3};

/// 6x6 matrix.
pub type Matrix6 = SMatrix<f64, 6, 6>;
/// 6-vector: `(rotation vector, translation)`.
pub type Vector6 = SVector<f64, 6>;

/// A pose update `exp(δω) · T`, `t + δt`: rotation vector applied on the left (camera
/// frame), translation in the camera frame. Covariances use the same parameters.
pub fn perturb(t: &Isometry3<f64>, d: &Vector6) -> Isometry3<f64> {
    let w = Vector3::new(d[0], d[1], d[2]);
    let rot = UnitQuaternion::from_scaled_axis(w) * t.rotation;
    Isometry3::from_parts(Translation3::from(t.translation.vector + Vector3::new(d[3], d[4], d[5])), rot)
}

/// The 6-vector `d` with `perturb(reference, d) ≈ t` (exact for the rotation).
pub fn difference(t: &Isometry3<f64>, reference: &Isometry3<f64>) -> Vector6 {
    let w = (t.rotation * reference.rotation.inverse()).scaled_axis();
    let dt = t.translation.vector - reference.translation.vector;
    Vector6::new(w.x, w.y, w.z, dt.x, dt.y, dt.z)
}

/// One observation: a plane point, its observed pixel and the pixel standard deviation.
#[derive(Debug, Clone, Copy)]
pub struct Obs {
    /// Point on the sample plane `z = 0`, metres.
    pub plane: Point2<f64>,
    /// Observed (distorted) pixel.
    pub pixel: Point2<f64>,
    /// Standard deviation of the pixel, per axis.
    pub sigma: f64,
}

/// Gaussian prior on the pose: centre and per-parameter standard deviations.
#[derive(Debug, Clone, Copy)]
pub struct Prior {
    /// Prior mean.
    pub mean: Isometry3<f64>,
    /// Standard deviation of each rotation-vector component, radians.
    pub sigma_rot: f64,
    /// Standard deviation of each translation component, metres.
    pub sigma_t: f64,
}

/// Outcome of a refinement.
#[derive(Debug, Clone)]
pub struct Refined {
    /// Refined sample-to-camera transform.
    pub pose: Isometry3<f64>,
    /// Normal matrix `JᵀJ` of the weighted residuals at the solution.
    pub normal: Matrix6,
    /// Weighted sum of squared residuals (chi-square) of the observations alone.
    pub chi2: f64,
    /// Iterations used.
    pub iterations: usize,
}

/// Weighted residuals of `obs` (2 per point), plus 6 prior residuals when `prior` is given;
/// `None` when a point does not project (behind the camera or beyond the lens field).
fn residuals(cam: &CameraModel, pose: &Isometry3<f64>, obs: &[Obs], prior: Option<&Prior>) -> Option<Vec<f64>> {
    let mut r = Vec::with_capacity(obs.len() * 2 + 6);
    for o in obs {
        let p = cam.project(&(pose * Point3::new(o.plane.x, o.plane.y, 0.0)))?;
        r.push((p.x - o.pixel.x) / o.sigma);
        r.push((p.y - o.pixel.y) / o.sigma);
    }
    if let Some(pr) = prior {
        let d = difference(pose, &pr.mean);
        for k in 0..3 {
            r.push(d[k] / pr.sigma_rot);
            r.push(d[k + 3] / pr.sigma_t);
        }
    }
    Some(r)
}

/// Minimises the weighted reprojection error (and prior) from `start` by Levenberg–Marquardt
/// with central-difference Jacobians. `None` if a point leaves the lens model's field.
pub fn refine(cam: &CameraModel, start: &Isometry3<f64>, obs: &[Obs], prior: Option<&Prior>) -> Option<Refined> {
    // Step sizes: 1e-7 rad / 1e-7 m move a point ~1e-3 px, far above round-off and far below
    // the curvature scale of the projection.
    const H: f64 = 1e-7;
    let cost = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    let jac = |pose: &Isometry3<f64>| -> Option<(Vec<f64>, Vec<Vector6>)> {
        let r0 = residuals(cam, pose, obs, prior)?;
        let mut rows = vec![Vector6::zeros(); r0.len()];
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = H;
            let rp = residuals(cam, &perturb(pose, &d), obs, prior)?;
            let rm = residuals(cam, &perturb(pose, &(-d)), obs, prior)?;
            for i in 0..r0.len() {
                rows[i][k] = (rp[i] - rm[i]) / (2.0 * H);
            }
        }
        Some((r0, rows))
    };
    let mut pose = *start;
    let (mut r, mut rows) = jac(&pose)?;
    let mut c = cost(&r);
    let mut mu = 1e-3;
    let mut iterations = 0;
    for it in 0..100 {
        iterations = it + 1;
        let mut n = Matrix6::zeros();
        let mut g = Vector6::zeros();
        for (ri, ji) in r.iter().zip(&rows) {
            n += ji * ji.transpose();
            g += ji * *ri;
        }
        let mut accepted = false;
        for _ in 0..20 {
            let mut damped = n;
            for k in 0..6 {
                damped[(k, k)] += mu * n[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|ch| ch.solve(&(-g))) else {
                mu *= 10.0;
                continue;
            };
            let cand = perturb(&pose, &step);
            if let Some(rc) = residuals(cam, &cand, obs, prior) {
                let cc = cost(&rc);
                if cc <= c {
                    // Converged when the step or the relative gain is negligible (far below the
                    // noise: 1e-10 of the cost moves the pose by ~1e-5 of its sigma).
                    let small = step.norm() < 1e-11 || (c - cc) <= 1e-10 * c.max(1e-300);
                    pose = cand;
                    c = cc;
                    mu = (mu * 0.3).max(1e-12);
                    accepted = true;
                    let (r2, rows2) = jac(&pose)?;
                    r = r2;
                    rows = rows2;
                    if small {
                        return Some(finish(pose, &r, &rows, obs.len(), iterations));
                    }
                    break;
                }
            }
            mu *= 10.0;
        }
        if !accepted {
            break; // no descent left: at the minimum to round-off
        }
    }
    Some(finish(pose, &r, &rows, obs.len(), iterations))
}

fn finish(pose: Isometry3<f64>, r: &[f64], rows: &[Vector6], n_obs: usize, iterations: usize) -> Refined {
    let mut normal = Matrix6::zeros();
    for j in rows {
        normal += j * j.transpose();
    }
    let chi2 = r[..2 * n_obs].iter().map(|v| v * v).sum();
    Refined { pose, normal, chi2, iterations }
}

/// Pixel of a plane point under `pose`, if it projects.
pub fn project(cam: &CameraModel, pose: &Isometry3<f64>, p: &Point2<f64>) -> Option<Point2<f64>> {
    cam.project(&(pose * Point3::new(p.x, p.y, 0.0)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::camera::{Distortion, Vignetting};

    #[test]
    fn perturb_and_difference_are_inverse() {
        let a = Isometry3::new(Vector3::new(0.01, -0.02, 1.2), Vector3::new(0.3, -0.5, 0.2));
        let d = Vector6::new(0.01, -0.02, 0.005, 0.001, 0.002, -0.003);
        let b = perturb(&a, &d);
        assert!((difference(&b, &a) - d).norm() < 1e-12);
    }

    #[test]
    fn lm_recovers_an_exact_pose_through_strong_distortion() {
        let cam = CameraModel::new(
            1600,
            1200,
            1500.0,
            1500.0,
            790.0,
            610.0,
            Distortion { k1: -0.2, k2: 0.05, k3: 0.0, p1: 1e-3, p2: -8e-4 },
            Vignetting::default(),
        )
        .unwrap();
        let truth = Isometry3::new(Vector3::new(0.02, -0.01, 0.5), Vector3::new(0.4, -0.3, 0.1));
        let obs: Vec<Obs> = (0..25)
            .map(|k| {
                let plane = Point2::new(-0.1 + 0.05 * (k % 5) as f64, -0.1 + 0.05 * (k / 5) as f64);
                Obs { plane, pixel: project(&cam, &truth, &plane).unwrap(), sigma: 0.1 }
            })
            .collect();
        let start = perturb(&truth, &Vector6::new(0.02, -0.01, 0.03, 0.005, -0.004, 0.01));
        let r = refine(&cam, &start, &obs, None).unwrap();
        assert!(difference(&r.pose, &truth).norm() < 1e-9, "{}", difference(&r.pose, &truth).norm());
        assert!(r.chi2 < 1e-12);
    }
}
