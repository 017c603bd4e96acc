//! Texel position error: how far (in texels) the surface point a rectification samples for
//! each texel lies from the texel's own centre, given the true pose.

use btfrig_core::camera::CameraModel;
use btfrig_core::pose::ScenePose;
use btfrig_imaging::Region;
use nalgebra::{Isometry3, Point2, Point3};

/// Sample-to-camera transform of a scene pose (the only part rectification depends on).
pub fn sample_to_camera(pose: &ScenePose) -> Isometry3<f64> {
    pose.camera_to_world.inverse() * pose.sample_to_world
}

/// The sample-plane point seen at pixel `px` when the plane has pose `truth` (sample to
/// camera), or `None` if the pixel has no ray or its ray misses the plane's front.
pub fn back_project(camera: &CameraModel, truth: &Isometry3<f64>, px: Point2<f64>) -> Option<Point2<f64>> {
    let ray = camera.try_pixel_ray(px)?;
    let n = truth.rotation * nalgebra::Vector3::z();
    let c0 = truth.translation.vector;
    let denom = n.dot(&ray);
    if denom.abs() < 1e-12 {
        return None;
    }
    let s = n.dot(&c0) / denom;
    if !(s > 0.0) {
        return None;
    }
    let p = truth.inverse_transform_point(&Point3::from(ray * s));
    Some(Point2::new(p.x, p.y))
}

/// Where texel `p`, rectified with `estimate`, really samples the surface under `truth`:
/// project with the estimate, back-project with the truth.
pub(crate) fn sampled_point(
    camera: &CameraModel,
    truth: &Isometry3<f64>,
    estimate: &Isometry3<f64>,
    p: Point2<f64>,
) -> Option<Point2<f64>> {
    let px = camera.project(&(estimate * Point3::new(p.x, p.y, 0.0)))?;
    back_project(camera, truth, px)
}

/// Mean and maximum texel position error over every texel centre of a `size x size` texture
/// of `region`: the distance, in texels (each axis divided by its texel pitch), between a
/// texel's centre and the surface point that rectification with `estimated` samples for it
/// when the plane truly has pose `truth`. Texels whose centre does not project (outside the
/// lens field) or whose pixel ray misses the plane are skipped; `(NaN, NaN)` if all are.
pub fn texel_position_error(
    truth: &ScenePose,
    estimated: &ScenePose,
    camera: &CameraModel,
    region: Region,
    size: usize,
) -> (f64, f64) {
    texel_position_error_with_cameras(truth, camera, estimated, camera, region, size)
}

/// [`texel_position_error`] when the camera model that rectifies (`processing`, e.g. a
/// calibrated one) is not the true camera (`true_camera`): each texel centre is projected with
/// the estimated pose through the processing camera, and the pixel's ray is cast with the
/// true camera onto the truly posed plane. A calibration error thus counts as what it does to
/// the texture.
pub fn texel_position_error_with_cameras(
    truth: &ScenePose,
    true_camera: &CameraModel,
    estimated: &ScenePose,
    processing: &CameraModel,
    region: Region,
    size: usize,
) -> (f64, f64) {
    let t = sample_to_camera(truth);
    let e = sample_to_camera(estimated);
    let pitch_x = (region.x_max - region.x_min) / size as f64;
    let pitch_y = (region.y_max - region.y_min) / size as f64;
    let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
    for row in 0..size {
        for col in 0..size {
            let (x, y) = region.point(size, size, col as f64 + 0.5, row as f64 + 0.5);
            let p = Point2::new(x, y);
            let px = processing.project(&(e * Point3::new(p.x, p.y, 0.0)));
            if let Some(q) = px.and_then(|px| back_project(true_camera, &t, px)) {
                let d = ((q.x - x) / pitch_x).hypot((q.y - y) / pitch_y);
                sum += d;
                max = max.max(d);
                n += 1;
            }
        }
    }
    if n == 0 {
        (f64::NAN, f64::NAN)
    } else {
        (sum / n as f64, max)
    }
}
