//! Normalised DLT homography from the sample plane to undistorted normalised image
//! coordinates, and its decomposition into a plane pose for a calibrated camera.

use nalgebra::{Isometry3, Matrix3, Point2, SMatrix, Translation3, UnitQuaternion, Vector3};

/// Similarity that moves the points' centroid to the origin and their mean distance to
/// sqrt(2) (Hartley): keeps the DLT's normal equations well conditioned.
fn normaliser(pts: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    let n = pts.len() as f64;
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + Vector3::new(p.x, p.y, 0.0)) / n;
    let mean_d = pts.iter().map(|p| (p.x - c.x).hypot(p.y - c.y)).sum::<f64>() / n;
    if !(mean_d > 0.0 && mean_d.is_finite()) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_d;
    Some(Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0))
}

/// Homography `H` with `x ~ H (X, Y, 1)` from at least 4 plane points to normalised image
/// points, by the normalised DLT (least squares on the algebraic error). `None` when the
/// points are degenerate (null space not one-dimensional, or coincident points).
pub fn dlt(plane: &[Point2<f64>], image: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if plane.len() < 4 || plane.len() != image.len() {
        return None;
    }
    let t1 = normaliser(plane)?;
    let t2 = normaliser(image)?;
    // Accumulate AᵀA (9x9) directly: with normalised coordinates its condition is fine in f64
    // and it avoids a 2n x 9 SVD (which nalgebra's thin SVD truncates for n = 4).
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (p, q) in plane.iter().zip(image) {
        let a = t1 * Vector3::new(p.x, p.y, 1.0);
        let b = t2 * Vector3::new(q.x, q.y, 1.0);
        let (x, y) = (a.x, a.y);
        let (u, v) = (b.x, b.y);
        let r1 = SMatrix::<f64, 9, 1>::from_column_slice(&[-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        let r2 = SMatrix::<f64, 9, 1>::from_column_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    // A unique solution needs a one-dimensional null space: the second smallest eigenvalue
    // must stand clear of the smallest and of round-off.
    let (l0, l1, lmax) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]], eig.eigenvalues[order[8]]);
    if !(l1 > 1e-10 * lmax) || l0 > 0.5 * l1 {
        return None;
    }
    let h = eig.eigenvectors.column(order[0]);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let t2inv = t2.try_inverse()?;
    let hm = t2inv * hn * t1;
    let s = hm[(2, 2)];
    Some(if s.abs() > 1e-300 { hm / s } else { hm })
}

/// The rigid sample-to-camera transform `[r1 r2 t] ~ H` of a plane homography in normalised
/// coordinates (intrinsics already removed), with the plane in front of the camera. The
/// rotation is the nearest orthonormal matrix (SVD) to `[r1 r2 r1×r2]`.
pub fn decompose(h: &Matrix3<f64>) -> Option<Isometry3<f64>> {
    let h1 = h.column(0).into_owned();
    let h2 = h.column(1).into_owned();
    let h3 = h.column(2).into_owned();
    let norm = 0.5 * (h1.norm() + h2.norm());
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    let mut lambda = 1.0 / norm;
    if h3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = h1 * lambda;
    let r2 = h2 * lambda;
    let r3 = r1.cross(&r2);
    let m = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        r = u2 * vt;
    }
    let rot = UnitQuaternion::from_matrix(&r);
    Some(Isometry3::from_parts(Translation3::from(h3 * lambda), rot))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dlt_recovers_an_exact_homography_and_decompose_its_pose() {
        let truth = Isometry3::new(Vector3::new(0.01, -0.02, 1.2), Vector3::new(0.3, -0.5, 0.2));
        let plane: Vec<Point2<f64>> =
            [(-0.08, 0.08), (0.08, 0.08), (0.08, -0.08), (-0.08, -0.08), (0.0, 0.05), (0.03, -0.01)]
                .iter()
                .map(|&(x, y)| Point2::new(x, y))
                .collect();
        let image: Vec<Point2<f64>> = plane
            .iter()
            .map(|p| {
                let c = truth * nalgebra::Point3::new(p.x, p.y, 0.0);
                Point2::new(c.x / c.z, c.y / c.z)
            })
            .collect();
        let h = dlt(&plane, &image).unwrap();
        let pose = decompose(&h).unwrap();
        assert!((pose.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(pose.rotation.angle_to(&truth.rotation) < 1e-9);
        // Collinear points have no unique homography.
        let line: Vec<Point2<f64>> = (0..6).map(|k| Point2::new(k as f64 * 0.01, 0.02)).collect();
        assert!(dlt(&line, &image).is_none());
    }
}
