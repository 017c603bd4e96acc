//! Pinhole camera with Brown–Conrady lens distortion and vignetting, shared by the simulator
//! (which projects) and the calibration (which estimates the same parameters).
//!
//! Conventions (those of OpenCV, so calibration results can be compared one to one):
//!
//! * Camera frame: `x` right, `y` down, `z` forward along the optical axis, metres.
//! * Pixel coordinates: `(u, v)` with `u` to the right and `v` down; **integer coordinates are
//!   pixel centres**, so pixel `(i, j)` covers `[i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]` and the
//!   image spans `[-0.5, width - 0.5] x [-0.5, height - 0.5]`. A centred principal point is
//!   `((width - 1) / 2, (height - 1) / 2)`.
//! * Distortion acts on normalised coordinates `x = X/Z`, `y = Y/Z`, with `r² = x² + y²`:
//!
//!   ```text
//!   x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
//!   y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y
//!   u = fx x_d + cx,   v = fy y_d + cy
//!   ```
//!
//!   exactly OpenCV's `(k1, k2, p1, p2, k3)` model.
//! * Vignetting (relative illumination of the image plane, 1 on the axis):
//!   `V = cos⁴(θ) · max(0, 1 + a1 ρ² + a2 ρ⁴ + a3 ρ⁶)`, where `θ` is the angle between the
//!   pixel's ray and the optical axis (natural falloff) and `ρ` is the pixel's distance from the
//!   principal point divided by the half-diagonal of the image (`ρ = 1` in the corners; the
//!   polynomial models the lens's own, mechanical and optical, vignetting).
//!
//! Beyond some radius a strong barrel distortion folds the image back on itself (the map from
//! `r` to distorted radius stops increasing). Points beyond that fold radius are not imaged
//! by the model: [`CameraModel::project`] returns `None` for them, and
//! [`CameraModel::new`] rejects a camera whose image corners lie beyond the fold, so that
//! every pixel has exactly one ray.

use nalgebra::{Point2, Point3, Vector3};

/// Brown–Conrady distortion coefficients, OpenCV's meaning (dimensionless, acting on
/// normalised image coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    /// Radial coefficient of `r²`.
    pub k1: f64,
    /// Radial coefficient of `r⁴`.
    pub k2: f64,
    /// Radial coefficient of `r⁶`.
    pub k3: f64,
    /// First tangential (decentring) coefficient.
    pub p1: f64,
    /// Second tangential (decentring) coefficient.
    pub p2: f64,
}

impl Distortion {
    /// Radial factor `1 + k1 r² + k2 r⁴ + k3 r⁶` for `s = r²`.
    fn radial(&self, s: f64) -> f64 {
        1.0 + s * (self.k1 + s * (self.k2 + s * self.k3))
    }

    /// Derivative of the distorted radius `r · radial(r²)` with respect to `r`, as a function
    /// of `s = r²`: `1 + 3 k1 s + 5 k2 s² + 7 k3 s³`.
    fn radius_slope(&self, s: f64) -> f64 {
        1.0 + s * (3.0 * self.k1 + s * (5.0 * self.k2 + s * 7.0 * self.k3))
    }

    /// Applies the distortion to normalised coordinates.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let s = x * x + y * y;
        let rad = self.radial(s);
        (
            x * rad + 2.0 * self.p1 * x * y + self.p2 * (s + 2.0 * x * x),
            y * rad + self.p1 * (s + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian `d(x_d, y_d) / d(x, y)` as `[[dxd/dx, dxd/dy], [dyd/dx, dyd/dy]]`.
    fn jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let s = x * x + y * y;
        let rad = self.radial(s);
        // d radial / d s
        let drad = self.k1 + s * (2.0 * self.k2 + s * 3.0 * self.k3);
        let (p1, p2) = (self.p1, self.p2);
        [
            [rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x, 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y],
            [2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y, rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x],
        ]
    }

    /// The squared normalised radius at which the radial part folds over (its distorted radius
    /// stops increasing), or infinity if it never does.
    pub fn fold_radius_sq(&self) -> f64 {
        // The slope is a cubic in s with value 1 at s = 0: scan for its first sign change on
        // a geometric grid (fine enough that two roots closer than 0.1% cannot hide), then
        // bisect.
        let mut prev = 0.0;
        let mut s = 1e-6;
        while s < 1e6 {
            if self.radius_slope(s) <= 0.0 {
                let (mut lo, mut hi) = (prev, s);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if self.radius_slope(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return lo;
            }
            prev = s;
            s *= 1.001;
        }
        f64::INFINITY
    }
}

/// How vignetting is modelled: natural cos⁴ falloff (optional) times a polynomial in the
/// normalised image radius ρ (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vignetting {
    /// Apply the natural cos⁴(θ) falloff of a thin lens.
    pub cos4: bool,
    /// Coefficients `(a1, a2, a3)` of `1 + a1 ρ² + a2 ρ⁴ + a3 ρ⁶`.
    pub poly: [f64; 3],
}

impl Default for Vignetting {
    fn default() -> Self {
        Vignetting { cos4: true, poly: [0.0; 3] }
    }
}

/// Why a camera model cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CameraError {
    /// A parameter is non-finite or out of its physical range.
    #[error("camera parameter {name} = {value} is invalid: {why}")]
    BadParameter {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// What is required.
        why: &'static str,
    },
    /// The distortion folds the image over inside the frame, so some pixels would see two
    /// directions.
    #[error(
        "lens distortion folds over inside the image: normalised radius {corner_radius:.4} of the \
         farthest image corner exceeds the fold radius {fold_radius:.4} (reduce |k1|, |k2|, |k3|)"
    )]
    FoldInsideImage {
        /// Undistorted normalised radius needed to reach the farthest corner (or the fold
        /// radius when the corner cannot be reached at all).
        corner_radius: f64,
        /// Normalised radius at which the distortion folds.
        fold_radius: f64,
    },
}

/// Pinhole intrinsics, distortion and vignetting of one camera. No I/O.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraModel {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Focal length in pixels along `u`.
    pub fx: f64,
    /// Focal length in pixels along `v`.
    pub fy: f64,
    /// Principal point `u`, pixels (integer = pixel centre).
    pub cx: f64,
    /// Principal point `v`, pixels.
    pub cy: f64,
    /// Lens distortion.
    pub distortion: Distortion,
    /// Vignetting model.
    pub vignetting: Vignetting,
    /// Cached fold radius squared (see [`Distortion::fold_radius_sq`]).
    fold_sq: f64,
}

/// Residual (pixels) below which undistortion counts as converged.
const UNDISTORT_TOL_PX: f64 = 1e-10;

impl CameraModel {
    /// Builds and checks a camera: positive size and focal lengths, finite parameters, and a
    /// distortion that does not fold over inside the image.
    // The eight arguments are the camera's own parameters, named at every call site.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        width: usize,
        height: usize,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        distortion: Distortion,
        vignetting: Vignetting,
    ) -> Result<Self, CameraError> {
        let bad = |name, value, why| Err(CameraError::BadParameter { name, value, why });
        if width == 0 {
            return bad("width", 0.0, "must be at least 1");
        }
        if height == 0 {
            return bad("height", 0.0, "must be at least 1");
        }
        for (name, v) in [("fx", fx), ("fy", fy)] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, v, "must be finite and positive");
            }
        }
        let d = distortion;
        for (name, v) in [
            ("cx", cx),
            ("cy", cy),
            ("k1", d.k1),
            ("k2", d.k2),
            ("k3", d.k3),
            ("p1", d.p1),
            ("p2", d.p2),
            ("vignetting a1", vignetting.poly[0]),
            ("vignetting a2", vignetting.poly[1]),
            ("vignetting a3", vignetting.poly[2]),
        ] {
            if !v.is_finite() {
                return bad(name, v, "must be finite");
            }
        }
        let cam = CameraModel { width, height, fx, fy, cx, cy, distortion, vignetting, fold_sq: d.fold_radius_sq() };
        // Every image corner must have a preimage inside the fold radius.
        let (w, h) = (width as f64, height as f64);
        for corner in [(-0.5, -0.5), (w - 0.5, -0.5), (-0.5, h - 0.5), (w - 0.5, h - 0.5)] {
            let px = Point2::new(corner.0, corner.1);
            match cam.try_undistort(px) {
                Some((x, y)) => {
                    let r2 = x * x + y * y;
                    if r2 >= cam.fold_sq || cam.jacobian_det(x, y) <= 0.0 {
                        return Err(CameraError::FoldInsideImage {
                            corner_radius: r2.sqrt(),
                            fold_radius: cam.fold_sq.sqrt(),
                        });
                    }
                }
                None => {
                    return Err(CameraError::FoldInsideImage {
                        corner_radius: cam.fold_sq.sqrt(),
                        fold_radius: cam.fold_sq.sqrt(),
                    })
                }
            }
        }
        Ok(cam)
    }

    /// An ideal pinhole camera (no distortion, cos⁴ vignetting only), principal point centred.
    pub fn pinhole(width: usize, height: usize, f: f64) -> Result<Self, CameraError> {
        Self::new(
            width,
            height,
            f,
            f,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
            Distortion::default(),
            Vignetting::default(),
        )
    }

    /// Normalised radius at which the distortion folds over (infinite if never).
    pub fn fold_radius(&self) -> f64 {
        self.fold_sq.sqrt()
    }

    fn jacobian_det(&self, x: f64, y: f64) -> f64 {
        let j = self.distortion.jacobian(x, y);
        j[0][0] * j[1][1] - j[0][1] * j[1][0]
    }

    /// Projects a camera-frame point (metres) to distorted pixel coordinates. `None` when the
    /// point is not in front of the camera (`z <= 0`) or lies beyond the distortion's fold
    /// radius (outside the lens model's valid field). The result may lie outside the image.
    pub fn project(&self, p_cam: &Point3<f64>) -> Option<Point2<f64>> {
        if !(p_cam.z > 0.0) {
            return None;
        }
        let x = p_cam.x / p_cam.z;
        let y = p_cam.y / p_cam.z;
        if x * x + y * y >= self.fold_sq || self.jacobian_det(x, y) <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distortion.apply(x, y);
        Some(Point2::new(self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// Pixel coordinates to undistorted normalised coordinates by damped Newton iteration,
    /// kept inside the fold radius. `None` if it does not converge to
    /// [`UNDISTORT_TOL_PX`] (only for pixels far outside the valid field).
    fn try_undistort(&self, px: Point2<f64>) -> Option<(f64, f64)> {
        let xd = (px.x - self.cx) / self.fx;
        let yd = (px.y - self.cy) / self.fy;
        // Residual measured in pixels, so the tolerance means the same for any focal length.
        let resid = |x: f64, y: f64| {
            let (ax, ay) = self.distortion.apply(x, y);
            ((ax - xd) * self.fx, (ay - yd) * self.fy)
        };
        // Start from the exact inverse of the radial part (monotone below the fold, so a
        // safeguarded 1-D Newton always finds it); the 2-D Newton below then only has to
        // absorb the small tangential terms.
        let rd = xd.hypot(yd);
        let (mut x, mut y) = match self.invert_radial(rd) {
            Some(r) if rd > 0.0 => (xd * r / rd, yd * r / rd),
            _ => (xd, yd),
        };
        let (mut ex, mut ey) = resid(x, y);
        let mut err = ex.hypot(ey);
        for _ in 0..100 {
            if err < 1e-3 * UNDISTORT_TOL_PX {
                break;
            }
            let j = self.distortion.jacobian(x, y);
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det.abs() < 1e-300 {
                break;
            }
            // Newton step in normalised coordinates: J * delta = -(residual / f).
            let (rx, ry) = (ex / self.fx, ey / self.fy);
            let dx = -(j[1][1] * rx - j[0][1] * ry) / det;
            let dy = -(-j[1][0] * rx + j[0][0] * ry) / det;
            // Backtrack until the step stays inside the fold and reduces the residual; this is
            // what keeps strong distortion from jumping to the second, folded preimage.
            let mut t = 1.0;
            let mut improved = false;
            for _ in 0..60 {
                let (nx, ny) = (x + t * dx, y + t * dy);
                if nx * nx + ny * ny < self.fold_sq && self.jacobian_det(nx, ny) > 0.0 {
                    let (nex, ney) = resid(nx, ny);
                    let nerr = nex.hypot(ney);
                    if nerr < err {
                        x = nx;
                        y = ny;
                        ex = nex;
                        ey = ney;
                        err = nerr;
                        improved = true;
                        break;
                    }
                }
                t *= 0.5;
            }
            if !improved {
                break; // at the floating-point floor (or stuck): judged below
            }
        }
        (err < UNDISTORT_TOL_PX).then_some((x, y))
    }

    /// The undistorted normalised radius `r` whose radial distortion gives radius `rd`
    /// (tangential terms ignored), by Newton's method safeguarded with bisection on
    /// `[0, fold radius)`. `None` if `rd` lies beyond the largest radius the lens reaches.
    fn invert_radial(&self, rd: f64) -> Option<f64> {
        let d = &self.distortion;
        let f = |r: f64| r * d.radial(r * r) - rd;
        let mut lo = 0.0;
        let mut hi = if self.fold_sq.is_finite() {
            self.fold_sq.sqrt()
        } else {
            let mut h = rd.max(1e-3);
            for _ in 0..200 {
                if f(h) >= 0.0 {
                    break;
                }
                h *= 2.0;
            }
            h
        };
        if f(hi) < 0.0 {
            return None;
        }
        let mut r = rd.clamp(lo, hi);
        for _ in 0..100 {
            let fr = f(r);
            if fr == 0.0 {
                return Some(r);
            }
            if fr < 0.0 {
                lo = r;
            } else {
                hi = r;
            }
            let slope = d.radius_slope(r * r);
            let mut next = r - fr / slope;
            if !(slope > 0.0 && next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
            if (next - r).abs() <= 1e-16 * (1.0 + r) {
                return Some(next);
            }
            r = next;
        }
        Some(r)
    }

    /// Unit ray (camera frame) through pixel `px`, or `None` if `px` has no preimage inside the
    /// lens model's valid field (never for pixels inside the image of a camera built by
    /// [`CameraModel::new`]).
    pub fn try_pixel_ray(&self, px: Point2<f64>) -> Option<Vector3<f64>> {
        self.try_undistort(px).map(|(x, y)| Vector3::new(x, y, 1.0).normalize())
    }

    /// Unit ray (camera frame) through pixel `px` (distorted pixel coordinates), found by
    /// inverting the distortion with damped Newton iteration to 1e-10 px. For the rare pixel
    /// far outside the image that has no preimage, returns the ray of the undistorted pinhole
    /// (distortion ignored); use [`CameraModel::try_pixel_ray`] to detect that case.
    pub fn pixel_ray(&self, px: Point2<f64>) -> Vector3<f64> {
        self.try_pixel_ray(px)
            .unwrap_or_else(|| Vector3::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy, 1.0).normalize())
    }

    /// Relative illumination at pixel `px` (1 on the optical axis, see the module docs).
    pub fn vignetting(&self, px: Point2<f64>) -> f64 {
        let cos = if self.vignetting.cos4 { self.pixel_ray(px).z } else { 1.0 };
        self.vignetting_with_cos(px, cos)
    }

    /// [`CameraModel::vignetting`] at `px`, the image of the camera-frame point `p_cam`
    /// (`px = project(p_cam)`): the ray is `p_cam`'s, not found again by undistorting `px`
    /// (the same value to the undistortion's tolerance, without its Newton iterations).
    pub fn vignetting_of_point(&self, p_cam: &Point3<f64>, px: Point2<f64>) -> f64 {
        let cos = if self.vignetting.cos4 { p_cam.z / p_cam.coords.norm() } else { 1.0 };
        self.vignetting_with_cos(px, cos)
    }

    /// The vignetting at `px` whose ray makes the angle of cosine `cos` with the optical axis.
    fn vignetting_with_cos(&self, px: Point2<f64>, cos: f64) -> f64 {
        let mut v = 1.0;
        if self.vignetting.cos4 {
            v *= cos * cos * cos * cos;
        }
        let half_diag = 0.5 * (self.width as f64).hypot(self.height as f64);
        let rho2 = ((px.x - self.cx).powi(2) + (px.y - self.cy).powi(2)) / (half_diag * half_diag);
        let [a1, a2, a3] = self.vignetting.poly;
        v * (1.0 + rho2 * (a1 + rho2 * (a2 + rho2 * a3))).max(0.0)
    }

    /// Whether pixel coordinates lie inside the image area (`[-0.5, width - 0.5]` etc.).
    pub fn in_image(&self, px: Point2<f64>) -> bool {
        px.x >= -0.5 && px.y >= -0.5 && px.x <= self.width as f64 - 0.5 && px.y <= self.height as f64 - 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn realistic() -> CameraModel {
        CameraModel::new(
            1600,
            1200,
            4800.0,
            4805.0,
            801.3,
            598.2,
            Distortion { k1: -0.08, k2: 0.02, k3: 0.0, p1: 1e-4, p2: -1.5e-4 },
            Vignetting { cos4: true, poly: [-0.1, 0.0, 0.0] },
        )
        .unwrap()
    }

    /// Wide-angle camera with strong barrel distortion: corners far out, near the fold.
    fn strong() -> CameraModel {
        CameraModel::new(
            1600,
            1200,
            700.0,
            700.0,
            799.5,
            599.5,
            Distortion { k1: -0.25, k2: 0.04, k3: -0.002, p1: 2e-3, p2: -1e-3 },
            Vignetting::default(),
        )
        .unwrap()
    }

    fn grid(cam: &CameraModel, step: usize) -> impl Iterator<Item = Point2<f64>> + '_ {
        let (w, h) = (cam.width, cam.height);
        (0..=h)
            .step_by(step)
            .flat_map(move |v| (0..=w).step_by(step).map(move |u| Point2::new(u as f64 - 0.5, v as f64 - 0.5)))
    }

    fn max_round_trip(cam: &CameraModel, step: usize) -> f64 {
        let mut worst: f64 = 0.0;
        for px in grid(cam, step) {
            let ray = cam.try_pixel_ray(px).expect("every image pixel has a ray");
            assert!((ray.norm() - 1.0).abs() < 1e-12);
            let back = cam.project(&Point3::from(ray * 2.5)).expect("ray projects");
            worst = worst.max((back - px).norm());
        }
        worst
    }

    #[test]
    fn project_of_pixel_ray_is_identity_over_the_image() {
        let worst = max_round_trip(&realistic(), 8);
        assert!(worst < 1e-9, "worst round trip {worst} px");
    }

    #[test]
    fn strong_distortion_round_trip_is_stable() {
        let cam = strong();
        assert!(cam.fold_radius().is_finite());
        let worst = max_round_trip(&cam, 4);
        assert!(worst < 1e-9, "worst round trip {worst} px");
    }

    #[test]
    fn folding_distortion_is_rejected_and_points_beyond_the_fold_are_not_imaged() {
        let err = CameraModel::new(
            1600,
            1200,
            500.0,
            500.0,
            799.5,
            599.5,
            Distortion { k1: -0.5, ..Default::default() },
            Vignetting::default(),
        )
        .unwrap_err();
        assert!(matches!(err, CameraError::FoldInsideImage { .. }), "{err}");
        // k1 = -0.5: slope 1 - 1.5 s vanishes at s = 2/3.
        let d = Distortion { k1: -0.5, ..Default::default() };
        assert!((d.fold_radius_sq() - 2.0 / 3.0).abs() < 1e-9);
        let cam = CameraModel::new(100, 100, 500.0, 500.0, 49.5, 49.5, d, Vignetting::default()).unwrap();
        assert!(cam.project(&Point3::new(0.9, 0.0, 1.0)).is_none());
        assert!(cam.project(&Point3::new(0.7, 0.0, 1.0)).is_some());
    }

    #[test]
    fn behind_camera_is_none() {
        let cam = realistic();
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(&Point3::new(0.1, 0.1, 0.0)).is_none());
    }

    #[test]
    fn pure_radial_distortion_is_symmetric() {
        let cam = CameraModel::new(
            1601,
            1201,
            4000.0,
            4000.0,
            800.0,
            600.0,
            Distortion { k1: -0.2, k2: 0.05, k3: 0.01, p1: 0.0, p2: 0.0 },
            Vignetting::default(),
        )
        .unwrap();
        for (x, y) in [(0.03, 0.07), (0.1, -0.02), (0.13, 0.13)] {
            let p = |sx: f64, sy: f64| cam.project(&Point3::new(sx * x, sy * y, 1.0)).unwrap();
            let c = Point2::new(cam.cx, cam.cy);
            let a = p(1.0, 1.0) - c;
            for (sx, sy) in [(-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
                let b = p(sx, sy) - c;
                assert!((b.x - sx * a.x).abs() < 1e-9 && (b.y - sy * a.y).abs() < 1e-9);
            }
            // Radial: the distorted point stays on the line through the principal point, and
            // swapping x and y swaps the offsets (fx = fy).
            assert!((a.x * y - a.y * x).abs() < 1e-9);
            let s = cam.project(&Point3::new(y, x, 1.0)).unwrap() - c;
            assert!((s.x - a.y).abs() < 1e-9 && (s.y - a.x).abs() < 1e-9);
        }
        // Barrel distortion (k1 < 0) pulls a far point towards the centre.
        let undist = 0.1 * cam.fx;
        let dist = cam.project(&Point3::new(0.1, 0.0, 1.0)).unwrap().x - cam.cx;
        assert!(dist < undist);
    }

    #[test]
    fn projection_matches_opencv_formula_by_hand() {
        // One point worked by hand with OpenCV's equations.
        let cam = realistic();
        let (x, y) = (0.05_f64, -0.03_f64);
        let r2 = x * x + y * y;
        let rad = 1.0 - 0.08 * r2 + 0.02 * r2 * r2;
        let xd = x * rad + 2.0 * 1e-4 * x * y + (-1.5e-4) * (r2 + 2.0 * x * x);
        let yd = y * rad + 1e-4 * (r2 + 2.0 * y * y) + 2.0 * (-1.5e-4) * x * y;
        let p = cam.project(&Point3::new(x * 3.0, y * 3.0, 3.0)).unwrap();
        assert!((p.x - (4800.0 * xd + 801.3)).abs() < 1e-9);
        assert!((p.y - (4805.0 * yd + 598.2)).abs() < 1e-9);
    }

    #[test]
    fn vignetting_is_one_on_axis_and_falls_off() {
        let cam = realistic();
        let centre = Point2::new(cam.cx, cam.cy);
        assert!((cam.vignetting(centre) - 1.0).abs() < 1e-12);
        let corner = Point2::new(-0.5, -0.5);
        let v = cam.vignetting(corner);
        let ray = cam.pixel_ray(corner);
        let half_diag = 0.5 * 1600f64.hypot(1200.0);
        let rho2 = ((corner.x - cam.cx).powi(2) + (corner.y - cam.cy).powi(2)) / half_diag.powi(2);
        let expect = ray.z.powi(4) * (1.0 - 0.1 * rho2);
        assert!((v - expect).abs() < 1e-12);
        assert!(v < 0.9 && v > 0.8, "{v}");
    }

    #[test]
    fn vignetting_of_a_known_point_equals_vignetting_of_its_image() {
        // Across the field of a distorting lens, near the fold included: the ray from the
        // point itself gives what undistorting its image gives.
        for cam in [realistic(), strong()] {
            let mut worst = 0.0f64;
            for i in 0..=20 {
                for j in 0..=20 {
                    let p = Point3::new((i as f64 - 10.0) * 0.017, (j as f64 - 10.0) * 0.013, 1.0) * 2.5;
                    let Some(q) = cam.project(&p) else { continue };
                    let (a, b) = (cam.vignetting_of_point(&p, q), cam.vignetting(q));
                    worst = worst.max((a - b).abs());
                }
            }
            assert!(worst < 1e-12, "{worst}");
        }
    }
}
