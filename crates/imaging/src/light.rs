//! White-reference measurements of the light: the camera-RGB signal of a Lambertian surface
//! of the sample plane, reduced to what a white reflector would give facing the lamp at the
//! nominal distance. The light calibration (`btfrig-calibrate`, a white tile on the holder)
//! and the per-capture drift estimate of the pipeline (the holder plate's white area around
//! the sample) both measure with [`lambertian_signal`].
//!
//! For a Lambertian point `p` of albedo `rho` (camera RGB, per channel) on the plane `z = 0`
//! of the sample frame, lit by a point lamp at `l` and seen by the camera at image position
//! `q`, the dark-corrected signal rate is
//!
//! ```text
//! rate_c(p) = W_c * rho_c * g(p) * vignetting(q),   g(p) = cos(theta_i) * d^2 / |l - p|^2
//! ```
//!
//! where `W_c` is the signal rate of a white (rho = 1) Lambertian reflector lit along its
//! normal from the nominal lamp distance `d` (the light calibration's figure) and `theta_i`
//! the angle between the plane's normal and `l - p`. So `rate_c / (vignetting * g) = W_c rho_c`
//! at every point; [`lambertian_signal`] averages it over a set of points, robustly (points
//! that are shadowed, on a marker, or otherwise not the white reference fall out as outliers).

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use nalgebra::{Point2, Point3};

use crate::radiometry::Radiometry;
use crate::rectify::{bilinear, sample_to_camera, RgbSource};

/// Why a white-reference measurement failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LightError {
    /// Too few reference points were usable (outside the image, lamp or camera behind the
    /// plane, outliers).
    #[error("white reference: {used} usable point(s) of {total}, at least {needed} needed")]
    TooFewPoints {
        /// Points left after all rejections.
        used: usize,
        /// Points offered.
        total: usize,
        /// The minimum.
        needed: usize,
    },
    /// A parameter is out of range.
    #[error("white reference: {name} = {value} is invalid, allowed {allowed}")]
    Parameter {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
}

/// Which points of the holder plate serve as the white reference: the plate's matte surface
/// between the sample square and the plate edge, away from the markers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchOptions {
    /// Clearance from the sample square, metres: the relief casts shadows on the plate near
    /// the sample at grazing light (a 1 mm bump at 75 degrees: 3.7 mm), and at grazing views it
    /// hides the plate behind it.
    pub sample_margin_m: f64,
    /// Clearance around each marker's quiet zone, metres (blur of the black edges).
    pub marker_margin_m: f64,
    /// Clearance from the plate's outer edge, metres.
    pub edge_margin_m: f64,
    /// Grid step of the points, metres.
    pub step_m: f64,
}

impl Default for PatchOptions {
    /// 6 mm from the sample, 3 mm from markers and edge, a 2 mm grid.
    fn default() -> Self {
        PatchOptions { sample_margin_m: 0.006, marker_margin_m: 0.003, edge_margin_m: 0.003, step_m: 0.002 }
    }
}

/// The white-reference points of the holder plate (sample frame, metres) per `opts`.
pub fn plate_patch_points(plate: &PlateConfig, opts: &PatchOptions) -> Vec<Point2<f64>> {
    let inner = plate.sample_side_m / 2.0 + opts.sample_margin_m;
    let outer = plate.side_m / 2.0 - opts.edge_margin_m;
    // A marker's quiet zone is one module wide (docs/renderer.md).
    let module = plate.marker_size_m / 6.0;
    let keep_out = plate.marker_size_m / 2.0 + module + opts.marker_margin_m;
    let centres: Vec<(f64, f64)> = plate
        .marker_placements()
        .iter()
        .map(|m| {
            let c = m.corners_sample_m;
            ((c[0].x + c[2].x) / 2.0, (c[0].y + c[2].y) / 2.0)
        })
        .collect();
    let step = opts.step_m.max(1e-5);
    let n = (2.0 * outer / step).floor() as i64;
    let mut out = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (-outer + i as f64 * step, -outer + j as f64 * step);
            if x.abs().max(y.abs()) < inner || x.abs().max(y.abs()) > outer {
                continue;
            }
            if centres.iter().any(|&(cx, cy)| (x - cx).abs() < keep_out && (y - cy).abs() < keep_out) {
                continue;
            }
            out.push(Point2::new(x, y));
        }
    }
    out
}

/// Points on a grid of step `step_m` over the centred square of side `side_m` (e.g. a white
/// tile on the holder, minus a margin).
pub fn square_points(side_m: f64, step_m: f64) -> Vec<Point2<f64>> {
    let h = side_m / 2.0;
    let step = step_m.max(1e-5);
    let n = (side_m / step).floor() as i64;
    let off = (side_m - n as f64 * step) / 2.0;
    (0..=n)
        .flat_map(|j| (0..=n).map(move |i| Point2::new(-h + off + i as f64 * step, -h + off + j as f64 * step)))
        .collect()
}

/// The mean of `rate / (vignetting * g)` (see the module documentation) over the usable points,
/// per camera channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WhiteSignal {
    /// Per channel, e-/s per photosite: `W_c * rho_c`.
    pub mean: [f64; 3],
    /// Standard error of `mean` (scatter over the points / sqrt(points); neighbouring points
    /// share pixels through the demosaic, so it is a lower bound).
    pub sigma: [f64; 3],
    /// Points used.
    pub points: usize,
    /// Points offered.
    pub offered: usize,
}

/// Fewest usable points a measurement accepts.
pub const MIN_POINTS: usize = 16;

/// Measures the Lambertian reference at `points` (sample frame, `z = 0`) in the demosaiced
/// `image` seen by `camera` in `pose`, the lamp at `pose.lamp_position`, the nominal lamp
/// distance `lamp_distance_m`. `to_rate` converts image values to signal rates: a
/// [`Radiometry`] whose `convert(value, vignetting)` gives `rate / vignetting` (nominal
/// irradiance 1, white balance 1, identity matrix; its dark current is subtracted).
/// Points whose image position is outside the frame, lit at more than 85 degrees, seen from
/// behind, or whose value is an outlier (more than 4 robust standard deviations from the median
/// in any channel: shadow, marker, dust) are left out.
pub fn lambertian_signal<I: RgbSource + ?Sized>(
    image: &I,
    camera: &CameraModel,
    pose: &ScenePose,
    lamp_distance_m: f64,
    to_rate: &Radiometry,
    points: &[Point2<f64>],
) -> Result<WhiteSignal, LightError> {
    if !(lamp_distance_m.is_finite() && lamp_distance_m > 0.0) {
        return Err(LightError::Parameter {
            name: "lamp_distance_m",
            value: lamp_distance_m,
            allowed: "finite and > 0",
        });
    }
    let to_cam = sample_to_camera(pose);
    let lamp = pose.lamp_in_sample();
    let cam_centre = pose.camera_in_sample();
    let d2 = lamp_distance_m * lamp_distance_m;
    let cos_min = (85f64).to_radians().cos();
    let mut values: Vec<[f64; 3]> = Vec::with_capacity(points.len());
    let (w, h) = (image.width(), image.height());
    if image.pixels_held() == w * h && w > 1 && h > 1 && cam_centre.z > 0.0 {
        for p in points {
            let p3 = Point3::new(p.x, p.y, 0.0);
            let l = lamp - p3;
            let r2 = l.norm_squared();
            let cos_i = l.z / r2.sqrt();
            if !(cos_i > cos_min) {
                continue;
            }
            let Some(q) = camera.project(&to_cam.transform_point(&p3)).filter(|q| camera.in_image(*q)) else {
                continue;
            };
            let vig = camera.vignetting(q);
            let Some(v) = bilinear(image, q.x, q.y).filter(|_| vig > 0.0) else { continue };
            let g = cos_i * d2 / r2;
            let rate = to_rate.convert(v, vig);
            values.push(std::array::from_fn(|c| f64::from(rate[c]) / g));
        }
    }
    let offered = points.len();
    let kept = reject_outliers(&values);
    if kept.len() < MIN_POINTS {
        return Err(LightError::TooFewPoints { used: kept.len(), total: offered, needed: MIN_POINTS });
    }
    let n = kept.len() as f64;
    let mean: [f64; 3] = std::array::from_fn(|c| kept.iter().map(|v| v[c]).sum::<f64>() / n);
    let sigma = std::array::from_fn(|c| {
        let var = kept.iter().map(|v| (v[c] - mean[c]).powi(2)).sum::<f64>() / (n - 1.0);
        (var / n).sqrt()
    });
    Ok(WhiteSignal { mean, sigma, points: kept.len(), offered })
}

/// The values within 4 robust standard deviations (1.4826 MAD) of the median in every channel.
fn reject_outliers(values: &[[f64; 3]]) -> Vec<[f64; 3]> {
    if values.is_empty() {
        return Vec::new();
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let m = v.len() / 2;
        if v.len() % 2 == 1 {
            v[m]
        } else {
            (v[m - 1] + v[m]) / 2.0
        }
    };
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    for c in 0..3 {
        let med = median(values.iter().map(|v| v[c]).collect());
        let mad = median(values.iter().map(|v| (v[c] - med).abs()).collect());
        // A perfectly flat (noise-free) reference has MAD 0: keep what equals the median to
        // a relative 1e-9 then.
        let tol = (4.0 * 1.4826 * mad).max(med.abs() * 1e-9);
        lo[c] = med - tol;
        hi[c] = med + tol;
    }
    values.iter().filter(|v| (0..3).all(|c| v[c] >= lo[c] && v[c] <= hi[c] && v[c].is_finite())).copied().collect()
}

/// A [`Radiometry`] that converts image values to `rate / vignetting` (e-/s per photosite):
/// the frame's exposure, gain and dark current, nominal irradiance 1, white balance 1,
/// identity matrix.
pub fn rate_radiometry(r: &Radiometry) -> Radiometry {
    Radiometry {
        nominal_irradiance: 1.0,
        white_balance: [1.0; 3],
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        ..*r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rectify::LinearImage;
    use btfrig_core::Direction;

    fn camera() -> CameraModel {
        CameraModel::pinhole(400, 300, 1200.0).unwrap()
    }

    #[test]
    fn plate_points_avoid_sample_markers_and_edge() {
        let plate = PlateConfig::default();
        let opts = PatchOptions::default();
        let pts = plate_patch_points(&plate, &opts);
        assert!(pts.len() > 2000, "{}", pts.len());
        let centres: Vec<_> = plate.marker_placements().iter().map(|m| m.corners_sample_m[0]).collect();
        for p in &pts {
            let m = p.x.abs().max(p.y.abs());
            assert!((0.05 + 0.006 - 1e-12..=0.1 - 0.003 + 1e-12).contains(&m), "{p:?}");
            for c in &centres {
                // corners_sample_m[0] is (cx - h, cy + h): the centre is (c.x + h, c.y - h).
                let (cx, cy) = (c.x + 0.01, c.y - 0.01);
                assert!((p.x - cx).abs() >= 0.01 + 0.02 / 6.0 + 0.003 || (p.y - cy).abs() >= 0.01 + 0.02 / 6.0 + 0.003);
            }
        }
    }

    /// A synthetic Lambertian plane rendered with the module's formula (no vignetting model
    /// beyond the camera's, lamp off-normal): the measurement returns W * rho exactly, and a
    /// dark patch of points (a "marker") is rejected as outliers.
    #[test]
    fn analytic_plane_gives_white_signal_and_outliers_go() {
        let cam = camera();
        let pose =
            ScenePose::looking_at(Direction::from_degrees(40.0, 30.0), Direction::from_degrees(20.0, 200.0), 1.0, 1.5);
        let w = [900.0, 1000.0, 700.0];
        let rho = 0.8;
        let r = Radiometry {
            dn_range: 4000.0,
            exposure_s: 0.1,
            dn_per_electron: 0.5,
            dark_e_per_s: 2.0,
            nominal_irradiance: 1.0,
            white_balance: [1.0; 3],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        // Render: trace each pixel to the plane z = 0.
        let to_sample = sample_to_camera(&pose).inverse();
        let lamp = pose.lamp_in_sample();
        let mut data = vec![[0.0f32; 3]; cam.width * cam.height];
        for y in 0..cam.height {
            for x in 0..cam.width {
                let q = Point2::new(x as f64, y as f64);
                let d = cam.pixel_ray(q);
                let o = to_sample.transform_point(&Point3::origin());
                let dir = to_sample.transform_vector(&d);
                let t = -o.z / dir.z;
                let p = o + dir * t;
                let dark = p.x.abs() < 0.01 && p.y.abs() < 0.01 && p.x > 0.0;
                let l = lamp - p;
                let g = (l.z / l.norm()) * 1.5 * 1.5 / l.norm_squared();
                let a = if dark { 0.05 } else { rho };
                data[y * cam.width + x] = std::array::from_fn(|c| {
                    let e = (w[c] * a * g * cam.vignetting(q) + 2.0) * 0.1;
                    (e * 0.5 / 4000.0) as f32
                });
            }
        }
        let img = LinearImage { width: cam.width, height: cam.height, data };
        let pts = square_points(0.03, 0.001);
        let s = lambertian_signal(&img, &cam, &pose, 1.5, &r, &pts).unwrap();
        for (mean, wc) in s.mean.iter().zip(w) {
            assert!((mean / (wc * rho) - 1.0).abs() < 2e-4, "{s:?}");
        }
        assert!(s.points < s.offered && s.points > s.offered / 2, "{s:?}");
        // Lamp behind the plane: nothing usable, a named error.
        let behind = ScenePose { lamp_position: Point3::new(0.0, 0.0, -1.0), ..pose };
        let e = lambertian_signal(&img, &cam, &behind, 1.5, &r, &pts).unwrap_err();
        assert!(matches!(e, LightError::TooFewPoints { used: 0, .. }), "{e}");
    }
}
