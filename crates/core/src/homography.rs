//! Plane-to-image homographies by the normalised direct linear transform (Hartley), with a
//! robust screening loop that drops gross outliers before the closed form sees them, and the
//! decomposition of a plane homography into a pose. The one homography of the project: the
//! marker detector's module grid, camera calibration (Zhang), registration and its bench
//! all call it.

use nalgebra::{DMatrix, Isometry3, Matrix3, Point2, Translation3, UnitQuaternion, Vector3};

/// Similarity that moves `pts` to zero mean and mean distance `sqrt(2)` from the origin
/// (Hartley's normalisation: keeps the DLT's matrix well conditioned whatever the units).
fn normaliser(pts: &[Point2<f64>]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |(a, b), p| (a + p.x / n, b + p.y / n));
    let mean_d = pts.iter().map(|p| (p.x - mx).hypot(p.y - my)).sum::<f64>() / n;
    let s = if mean_d > 0.0 { std::f64::consts::SQRT_2 / mean_d } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

fn apply(m: &Matrix3<f64>, p: &Point2<f64>) -> Point2<f64> {
    let q = m * Vector3::new(p.x, p.y, 1.0);
    Point2::new(q.x / q.z, q.y / q.z)
}

/// Maps a plane point through a homography (`None` at the line at infinity).
pub fn map(h: &Matrix3<f64>, p: &Point2<f64>) -> Option<Point2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z.abs() > 1e-300).then(|| Point2::new(q.x / q.z, q.y / q.z))
}

/// Homography `H` with `dst ~ H src` from at least 4 correspondences by the normalised DLT.
/// `None` if the points do not determine it (fewer than 4, or a degenerate layout).
pub fn dlt(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    let n = src.len();
    if n < 4 || dst.len() != n {
        return None;
    }
    let ts = normaliser(src);
    let td = normaliser(dst);
    // At least 9 rows so the thin SVD returns the full 9x9 right singular basis.
    let rows = (2 * n).max(9);
    let mut a = DMatrix::<f64>::zeros(rows, 9);
    for (i, (s, d)) in src.iter().zip(dst).enumerate() {
        let s = apply(&ts, s);
        let d = apply(&td, d);
        let (x, y, u, v) = (s.x, s.y, d.x, d.y);
        let r = 2 * i;
        a.row_mut(r).copy_from_slice(&[-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        a.row_mut(r + 1).copy_from_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
    }
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    let sv = &svd.singular_values;
    let (imin, _) = sv.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    // A second (near-)zero singular value means a family of solutions: collinear points.
    let mut sorted: Vec<f64> = sv.iter().copied().collect();
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted.len() >= 2 && sorted[sorted.len() - 2] < 1e-10 * sorted[0] {
        return None;
    }
    let h = vt.row(imin);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = td.try_inverse()? * hn * ts;
    let scale = h[(2, 2)];
    let h = if scale.abs() > 1e-300 { h / scale } else { h / h.norm() };
    h.iter().all(|v| v.is_finite()).then_some(h)
}

/// The homography from the square `[0, side]²` (corners `(0, 0), (side, 0), (side, side),
/// (0, side)`) onto the quad `q` (the same order), in closed form (Heckbert's projective
/// mapping of the unit square): what [`dlt`] gives for these four points, without its SVD,
/// for callers that need it many times per quad (the marker detector's grid fit). `None`
/// for a degenerate quad (three corners on a line).
pub fn square_to_quad(side: f64, q: &[Point2<f64>; 4]) -> Option<Matrix3<f64>> {
    let [p0, p1, p2, p3] = *q;
    let (sx, sy) = (p0.x - p1.x + p2.x - p3.x, p0.y - p1.y + p2.y - p3.y);
    let (dx1, dx2, dy1, dy2) = (p1.x - p2.x, p3.x - p2.x, p1.y - p2.y, p3.y - p2.y);
    let den = dx1 * dy2 - dx2 * dy1;
    // Degenerate when three corners lie on a line: some turn of the quad is flat.
    let scale2 = q.iter().map(|p| (p - p0).norm_squared()).fold(0.0, f64::max);
    let flat = (0..4).any(|k| {
        let (a, b, c) = (q[k], q[(k + 1) % 4], q[(k + 2) % 4]);
        let (u, v) = (b - a, c - b);
        (u.x * v.y - u.y * v.x).abs() <= 1e-12 * scale2
    });
    if flat || !(den.abs() > 1e-12 * scale2) {
        return None;
    }
    let g = (sx * dy2 - dx2 * sy) / den;
    let h = (dx1 * sy - sx * dy1) / den;
    let unit = Matrix3::new(
        p1.x - p0.x + g * p1.x,
        p3.x - p0.x + h * p3.x,
        p0.x,
        p1.y - p0.y + g * p1.y,
        p3.y - p0.y + h * p3.y,
        p0.y,
        g,
        h,
        1.0,
    );
    let s = 1.0 / side;
    let m = unit * Matrix3::new(s, 0.0, 0.0, 0.0, s, 0.0, 0.0, 0.0, 1.0);
    m.iter().all(|v| v.is_finite()).then_some(m)
}

/// The rigid plane-to-camera transform `[r1 r2 t] ~ H` of a plane homography in normalised
/// camera coordinates (intrinsics already removed), with the plane in front of the camera.
/// The rotation is the nearest orthonormal matrix (SVD) to `[r1 r2 r1 x r2]`. Zhang's
/// extrinsics and registration's pose hypotheses both come from here.
pub fn decompose(h: &Matrix3<f64>) -> Option<Isometry3<f64>> {
    let (h1, h2, h3) = (h.column(0).into_owned(), h.column(1).into_owned(), h.column(2).into_owned());
    let norm = 0.5 * (h1.norm() + h2.norm());
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    let mut lambda = 1.0 / norm;
    // The plane must lie in front of the camera.
    if h3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = h1 * lambda;
    let r2 = h2 * lambda;
    let m = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        r = u2 * vt;
    }
    Some(Isometry3::from_parts(Translation3::from(h3 * lambda), UnitQuaternion::from_matrix(&r)))
}

/// DLT with iterative rejection: fit, measure transfer errors, keep the points within
/// `k` robust standard deviations (median absolute deviation, never below `floor_px`), refit
/// until the inlier set stops changing. Returns the homography and the inlier mask.
pub fn robust_dlt(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    k: f64,
    floor_px: f64,
) -> Option<(Matrix3<f64>, Vec<bool>)> {
    let mut inl = vec![true; src.len()];
    let mut h = dlt(src, dst)?;
    for _ in 0..10 {
        let errs: Vec<f64> =
            src.iter().zip(dst).map(|(s, d)| map(&h, s).map_or(f64::INFINITY, |p| (p - d).norm())).collect();
        let mut sorted: Vec<f64> = errs.iter().zip(&inl).filter(|(_, &i)| i).map(|(e, _)| *e).collect();
        sorted.sort_by(|a, b| a.total_cmp(b));
        // The norm of a 2-D Gaussian error has median 1.1774 sigma.
        let sigma = sorted[sorted.len() / 2] / 1.1774;
        let thresh = (k * sigma).max(floor_px);
        let next: Vec<bool> = errs.iter().map(|&e| e <= thresh).collect();
        if next == inl {
            break;
        }
        let (s, d): (Vec<_>, Vec<_>) =
            src.iter().zip(dst).zip(&next).filter(|(_, &i)| i).map(|((s, d), _)| (*s, *d)).unzip();
        h = dlt(&s, &d)?;
        inl = next;
    }
    Some((h, inl))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A perspective homography of pixel scale (plane metres to pixels).
    fn truth() -> Matrix3<f64> {
        Matrix3::new(900.0, 30.0, 400.0, -20.0, 850.0, 300.0, 0.1, -0.2, 1.0)
    }

    #[test]
    fn recovers_an_exact_homography_from_4_points() {
        // The detector's case: a unit square of modules onto an image quad.
        let h = truth();
        let src = [(0.0, 0.0), (6.0, 0.0), (6.0, 6.0), (0.0, 6.0)].map(|(x, y)| Point2::new(x, y));
        let dst: Vec<_> = src.iter().map(|p| map(&h, &(p / 60.0)).unwrap()).collect();
        let est = dlt(&src, &dst).unwrap();
        for (s, d) in src.iter().zip(&dst) {
            assert!((map(&est, s).unwrap() - d).norm() < 1e-9, "{s} -> {d}");
        }
        // Points between the corners land where the true mapping puts them.
        let mid = Point2::new(2.5, 3.5);
        assert!((map(&est, &mid).unwrap() - map(&h, &(mid / 60.0)).unwrap()).norm() < 1e-9);
        // Three points do not determine it.
        assert!(dlt(&src[..3], &dst[..3]).is_none());
    }

    #[test]
    fn the_closed_form_square_to_quad_is_the_dlt_of_the_four_corners() {
        let h = truth();
        let side = 6.0;
        let src = [(0.0, 0.0), (side, 0.0), (side, side), (0.0, side)].map(|(x, y)| Point2::new(x, y));
        // A perspective quad and a parallelogram (affine: the projective row is zero).
        let persp: [Point2<f64>; 4] = std::array::from_fn(|k| map(&h, &(src[k] / 60.0)).unwrap());
        let para = [(10.0, 20.0), (70.0, 25.0), (75.0, 95.0), (15.0, 90.0)].map(|(x, y)| Point2::new(x, y));
        for q in [persp, para] {
            let closed = square_to_quad(side, &q).unwrap();
            let reference = dlt(&src, &q).unwrap();
            for p in [Point2::new(0.0, 0.0), Point2::new(6.0, 6.0), Point2::new(2.5, 3.5), Point2::new(-1.0, 7.0)] {
                let (a, b) = (map(&closed, &p).unwrap(), map(&reference, &p).unwrap());
                assert!((a - b).norm() < 1e-9, "{p}: {a} vs {b}");
            }
        }
        // Three corners on a line: no homography.
        let flat = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (0.0, 1.0)].map(|(x, y)| Point2::new(x, y));
        assert!(square_to_quad(side, &flat).is_none());
    }

    #[test]
    fn recovers_an_exact_homography_from_many_points_and_refuses_collinear_points() {
        let h = truth();
        let src: Vec<_> =
            (0..5).flat_map(|i| (0..4).map(move |j| Point2::new(0.02 * i as f64, 0.03 * j as f64))).collect();
        let dst: Vec<_> = src.iter().map(|p| map(&h, p).unwrap()).collect();
        let est = dlt(&src, &dst).unwrap();
        assert!((est - h).norm() / h.norm() < 1e-10, "{est}");
        let line: Vec<_> = (0..6).map(|i| Point2::new(0.01 * i as f64, 0.02 * i as f64)).collect();
        let img: Vec<_> = line.iter().map(|p| map(&h, p).unwrap()).collect();
        assert!(dlt(&line, &img).is_none());
    }

    #[test]
    fn noisy_points_give_the_least_squares_accuracy() {
        // 49 points, image noise sigma 0.5 px per axis. A least-squares fit of 8 parameters
        // to 2n observations leaves an expected squared error at the points of 8 sigma^2 in
        // all, so the RMS transfer error against the true mapping is sigma sqrt(8 / n) =
        // 0.20 px; the DLT is algebraic, not the maximum-likelihood fit, but with Hartley's
        // normalisation it comes within a few per cent of it.
        let h = truth();
        let sigma = 0.5;
        let n_side = 7;
        let src: Vec<_> = (0..n_side * n_side)
            .map(|k| Point2::new(0.1 * ((k % n_side) as f64 / 6.0 - 0.5), 0.1 * ((k / n_side) as f64 / 6.0 - 0.5)))
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(25);
        let mut gauss = move || {
            // Box-Muller.
            let (u, v): (f64, f64) = (rng.gen_range(f64::EPSILON..1.0), rng.gen());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        let (mut sum2, mut count) = (0.0, 0);
        for _trial in 0..200 {
            let dst: Vec<_> = src
                .iter()
                .map(|p| map(&h, p).unwrap() + nalgebra::Vector2::new(sigma * gauss(), sigma * gauss()))
                .collect();
            let est = dlt(&src, &dst).unwrap();
            for p in &src {
                sum2 += (map(&est, p).unwrap() - map(&h, p).unwrap()).norm_squared();
                count += 1;
            }
        }
        let rms = (sum2 / count as f64).sqrt();
        let expected = sigma * (8.0 / src.len() as f64).sqrt();
        assert!((rms / expected - 1.0).abs() < 0.1, "RMS transfer error {rms:.4} px, least squares {expected:.4} px");
    }

    #[test]
    fn decompose_recovers_the_pose_of_an_exact_plane_homography() {
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
    }
}
