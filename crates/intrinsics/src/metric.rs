//! Comparing two camera models over the image: how far apart they put the same ray, and how
//! much their distortions differ in effect.

use btfrig_core::camera::CameraModel;
use nalgebra::{Point2, Point3};

/// Grid of pixel positions covering the image of `cam`, `n` points along the longer side
/// (corners and edges included).
fn grid(cam: &CameraModel, n: usize) -> Vec<Point2<f64>> {
    let (w, h) = (cam.width as f64, cam.height as f64);
    let n = n.max(2);
    let step = (w.max(h)) / (n - 1) as f64;
    let nu = (w / step).ceil() as usize + 1;
    let nv = (h / step).ceil() as usize + 1;
    let mut out = Vec::with_capacity(nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            let u = (-0.5 + i as f64 * w / (nu - 1) as f64).min(w - 0.5);
            let v = (-0.5 + j as f64 * h / (nv - 1) as f64).min(h - 0.5);
            out.push(Point2::new(u, v));
        }
    }
    out
}

/// Largest difference, pixels, between the two models' **distortion displacements** over the
/// image of `truth`: for each pixel of an `n`-point grid, the undistorted normalised point
/// `x` of that pixel under `truth`, and for each model the displacement its distortion
/// applies there, `(fx (x_d − x), fy (y_d − y))` with the model's own focal lengths. This
/// is "the distortion matches in effect": different coefficients that bend the image the same
/// way score near zero, and intrinsics differences do not count.
pub fn distortion_difference(truth: &CameraModel, est: &CameraModel, n: usize) -> f64 {
    let mut worst: f64 = 0.0;
    for px in grid(truth, n) {
        let ray = truth.pixel_ray(px);
        let (x, y) = (ray.x / ray.z, ray.y / ray.z);
        let disp = |c: &CameraModel| {
            let (xd, yd) = c.distortion.apply(x, y);
            (c.fx * (xd - x), c.fy * (yd - y))
        };
        let (a, b) = (disp(truth), disp(est));
        worst = worst.max((a.0 - b.0).hypot(a.1 - b.1));
    }
    worst
}

/// Largest difference, pixels, between where the two models image the same ray, over an
/// `n`-point grid of `truth`'s image: the whole mapping (intrinsics and distortion together).
pub fn mapping_difference(truth: &CameraModel, est: &CameraModel, n: usize) -> f64 {
    let mut worst: f64 = 0.0;
    for px in grid(truth, n) {
        let ray = truth.pixel_ray(px);
        match est.project(&Point3::from(ray)) {
            Some(q) => worst = worst.max((q - px).norm()),
            None => return f64::INFINITY,
        }
    }
    worst
}

/// Like [`mapping_difference`], but after turning `est`'s camera frame by the rotation that
/// best aligns the two mappings (least squares over the grid, Gauss–Newton). A rotation of
/// the camera frame is absorbed by the target poses, and for a long lens a principal-point
/// shift is nearly such a rotation (it differs only by about `shift · (field angle)²` pixels),
/// so this is the part of the mapping that views of a target actually pin down. Returns the
/// largest residual difference, pixels, and the rotation angle, radians.
pub fn mapping_difference_up_to_rotation(truth: &CameraModel, est: &CameraModel, n: usize) -> (f64, f64) {
    let pts: Vec<(Point2<f64>, nalgebra::Vector3<f64>)> =
        grid(truth, n).into_iter().map(|p| (p, truth.pixel_ray(p))).collect();
    let resid = |w: &nalgebra::Vector3<f64>| -> Option<Vec<f64>> {
        let r = nalgebra::Rotation3::new(*w);
        let mut out = Vec::with_capacity(2 * pts.len());
        for (px, ray) in &pts {
            let q = est.project(&Point3::from(r * ray))?;
            out.push(q.x - px.x);
            out.push(q.y - px.y);
        }
        Some(out)
    };
    let mut w = nalgebra::Vector3::zeros();
    for _ in 0..20 {
        let Some(r0) = resid(&w) else { return (f64::INFINITY, 0.0) };
        let mut jtj = nalgebra::Matrix3::<f64>::zeros();
        let mut jtr = nalgebra::Vector3::<f64>::zeros();
        let h = 1e-7;
        let cols: Vec<Vec<f64>> = (0..3)
            .map(|k| {
                let mut wp = w;
                wp[k] += h;
                let rp = resid(&wp).unwrap_or_else(|| r0.clone());
                rp.iter().zip(&r0).map(|(a, b)| (a - b) / h).collect()
            })
            .collect();
        for a in 0..3 {
            jtr[a] = cols[a].iter().zip(&r0).map(|(j, r)| j * r).sum();
            for b in 0..3 {
                jtj[(a, b)] = cols[a].iter().zip(&cols[b]).map(|(x, y)| x * y).sum();
            }
        }
        let Some(step) = jtj.try_inverse().map(|m| -(m * jtr)) else { break };
        w += step;
        if step.norm() < 1e-13 {
            break;
        }
    }
    let worst = resid(&w).map_or(f64::INFINITY, |r| r.chunks(2).map(|c| c[0].hypot(c[1])).fold(0.0, f64::max));
    (worst, w.norm())
}
