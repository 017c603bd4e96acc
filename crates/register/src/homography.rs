//! The plane homography and its decomposition into a plane pose: the calibration crate's
//! (one implementation of the normalised DLT in the project). Registration calls them with
//! the sample plane's points and undistorted normalised image coordinates.

pub use btfrig_camcal::homography::{decompose, dlt};

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point2, Vector3};

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
