//! Geometric camera calibration from views of a planar target: Zhang's closed form, then a
//! Levenberg–Marquardt refinement of the reprojection error over intrinsics, Brown–Conrady
//! distortion (k1, k2, k3, p1, p2) and every view's pose, with outlier rejection and
//! per-parameter uncertainties. The estimated model is [`btfrig_core::camera::CameraModel`]
//! (OpenCV's conventions; integer pixel coordinates are pixel centres).
//!
//! Numerics only: [`file`] converts a result to and from TOML text, and callers do the I/O.
//! The procedure on a rig (calibration plan, rendered board frames, detection, the camera the
//! pipeline processes with) is the crate `btfrig-calibrate`.
//! Method, file format and measured accuracy: `docs/camera-calibration.md`.
#![warn(missing_docs)]

// The files, one job each:
// - lib:    the calibration (views, options, result, uncertainties)
// - zhang:  Zhang's closed form
// - refine: Levenberg-Marquardt refinement over intrinsics, distortion and poses
// - metric: comparing two camera models over the image
// - file:   the calibration file (calibration/*.toml) as text

pub mod file;
pub mod metric;
mod refine;
pub mod zhang;

use btfrig_core::camera::{CameraError, CameraModel, Distortion, Vignetting};
use btfrig_core::homography;
use nalgebra::{Isometry3, Matrix3, Point2, Translation3, UnitQuaternion};

pub use file::{CalibrationFile, FileError};
pub use metric::{distortion_difference, mapping_difference, mapping_difference_up_to_rotation};
pub use refine::CAM_NAMES;

/// One detected target point: where it is on the target and where it was seen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// Position on the target plane (`z = 0` of the target frame), metres.
    pub target: Point2<f64>,
    /// Observed (distorted) pixel position, OpenCV convention (integers at pixel centres).
    pub pixel: Point2<f64>,
    /// Standard deviation of the pixel position per axis, pixels (`None`: unknown, all equal).
    pub sigma_px: Option<f64>,
}

/// All correspondences of one image of the target.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct View {
    /// The detected points (at least [`MIN_POINTS_PER_VIEW`]).
    pub points: Vec<Correspondence>,
}

/// Fewest views accepted.
pub const MIN_VIEWS: usize = 3;
/// Fewest points per view accepted (a homography needs 4; a few more make it overdetermined
/// so that outliers can be seen).
pub const MIN_POINTS_PER_VIEW: usize = 6;

/// Settings of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Estimate k3 (else held at 0; long lenses see too little field to separate it from k2).
    pub estimate_k3: bool,
    /// Estimate the tangential terms p1, p2 (else held at 0).
    pub estimate_tangential: bool,
    /// Points whose residual norm exceeds `reject_k` robust standard deviations (per axis) are
    /// excluded and the fit repeated; a rejected point is readmitted if it fits later.
    pub reject_k: f64,
    /// Most rejection rounds.
    pub max_rounds: usize,
    /// Most Levenberg–Marquardt iterations per round.
    pub max_iterations: usize,
    /// Fewest views whose target shows a relative depth variation of at least
    /// [`Options::min_depth_variation`] (perspective that the closed form needs).
    pub min_tilted_views: usize,
    /// Relative depth variation across the detected target points that makes a view count as
    /// tilted (0.01: the far edge is 1% farther than the near one, about 5 degrees of tilt for
    /// a target that spans a sixth of its distance).
    pub min_depth_variation: f64,
    /// Hold the principal point at this pixel position instead of estimating it (OpenCV's
    /// `CALIB_FIX_PRINCIPAL_POINT`; for long lenses, whose views hardly constrain it).
    pub fixed_principal_point: Option<Point2<f64>>,
    /// Vignetting to put into the returned model (geometry does not estimate it).
    pub vignetting: Vignetting,
}

impl Options {
    /// Defaults for an image of the given size.
    pub fn new(width: usize, height: usize) -> Self {
        Options {
            width,
            height,
            estimate_k3: true,
            estimate_tangential: true,
            reject_k: 5.0,
            max_rounds: 6,
            max_iterations: 100,
            min_tilted_views: 2,
            min_depth_variation: 0.01,
            fixed_principal_point: None,
            vignetting: Vignetting::default(),
        }
    }
}

/// Why a calibration failed; each variant names what is missing or wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CalibError {
    /// Too few views.
    #[error("calibration needs at least {need} views of the target, got {got}")]
    TooFewViews {
        /// Views given.
        got: usize,
        /// Views needed.
        need: usize,
    },
    /// A view has too few (usable) points.
    #[error("view {view} has {got} usable target points, needs at least {need}")]
    TooFewPoints {
        /// Index of the view.
        view: usize,
        /// Points present (after outlier screening when that is the cause).
        got: usize,
        /// Points needed.
        need: usize,
    },
    /// A value is not finite, or a standard deviation is not positive.
    #[error("view {view}, point {point}: {what}")]
    BadInput {
        /// Index of the view.
        view: usize,
        /// Index of the point.
        point: usize,
        /// What is wrong.
        what: String,
    },
    /// The target points of a view lie (nearly) on a line.
    #[error("view {view}: the target points are (nearly) collinear (spread ratio {ratio:.2e}); a plane needs points spread in two directions")]
    CollinearTarget {
        /// Index of the view.
        view: usize,
        /// Smaller over larger standard deviation of the target points' spread.
        ratio: f64,
    },
    /// Too few views show the target tilted against the image plane.
    #[error(
        "only {tilted} of {views} views show the target tilted against the image plane (relative depth variation >= \
         {min_variation}); need at least {need}: views parallel to the image plane do not determine the focal length \
         and principal point; tilt the target by 20-60 degrees about different axes (largest variation seen: {max_seen:.4})"
    )]
    ParallelViews {
        /// Views counted as tilted.
        tilted: usize,
        /// All views.
        views: usize,
        /// Views needed.
        need: usize,
        /// The threshold used.
        min_variation: f64,
        /// The largest relative depth variation of any view.
        max_seen: f64,
    },
    /// The homography of a view could not be estimated.
    #[error("view {view}: no plane-to-image homography fits its points (degenerate layout)")]
    NoHomography {
        /// Index of the view.
        view: usize,
    },
    /// Zhang's closed form found no camera.
    #[error("the closed-form intrinsics are undetermined ({why}); the views' target planes are too close to parallel to each other or to the image: tilt the target about different axes")]
    ClosedForm {
        /// Detail.
        why: String,
    },
    /// The refined parameters do not make a valid camera.
    #[error("the refined camera is invalid: {0}")]
    InvalidCamera(#[from] CameraError),
}

/// Standard uncertainties (one standard deviation) of the camera parameters.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Uncertainty {
    /// Of fx, pixels.
    pub fx_px: f64,
    /// Of fy, pixels.
    pub fy_px: f64,
    /// Of cx, pixels.
    pub cx_px: f64,
    /// Of cy, pixels.
    pub cy_px: f64,
    /// Of k1.
    pub k1: f64,
    /// Of k2.
    pub k2: f64,
    /// Of k3 (0 when held fixed).
    pub k3: f64,
    /// Of p1 (0 when held fixed).
    pub p1: f64,
    /// Of p2 (0 when held fixed).
    pub p2: f64,
}

/// How the closed form initialised the intrinsics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    /// Zhang's closed form with all four intrinsics.
    Zhang,
    /// Zhang's constraints with the principal point held at the image centre, or at
    /// [`Options::fixed_principal_point`] (used when that is set, or when the full closed form
    /// puts the principal point outside the image or is ill-conditioned).
    HeldPrincipalPoint,
}

/// Result of a calibration.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The calibrated camera (vignetting from [`Options::vignetting`]).
    pub camera: CameraModel,
    /// Standard uncertainties of its parameters, from `(JᵀWJ)⁻¹ σ₀²`.
    pub uncertainty: Uncertainty,
    /// Covariance of `(fx, fy, cx, cy, k1, k2, k3, p1, p2)` (order of [`CAM_NAMES`]).
    pub covariance: [[f64; 9]; 9],
    /// RMS reprojection error over the inliers, pixels (root mean of the squared residual
    /// norm, i.e. of both axes together).
    pub rms_px: f64,
    /// RMS reprojection error of each view's inliers, pixels.
    pub per_view_rms_px: Vec<f64>,
    /// A-posteriori standard deviation of unit weight: `sqrt(χ² / (2 n − parameters))` of the
    /// whitened residuals (≈ 1 when the given `sigma_px` are right; the pixel noise per axis
    /// when none are given).
    pub sigma0: f64,
    /// Pose of the target in each view (target frame to camera frame, metres).
    pub poses: Vec<Isometry3<f64>>,
    /// Standard deviations of each pose: rotation (rad, about the camera axes) then
    /// translation (m).
    pub pose_sigma: Vec<[f64; 6]>,
    /// Which points were used (false: rejected as outliers).
    pub inliers: Vec<Vec<bool>>,
    /// Number of rejected points.
    pub outliers: usize,
    /// Points used.
    pub points_used: usize,
    /// How the intrinsics were initialised.
    pub init: Init,
    /// Levenberg–Marquardt iterations over all rounds.
    pub iterations: usize,
}

fn check_input(views: &[View]) -> Result<(), CalibError> {
    if views.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews { got: views.len(), need: MIN_VIEWS });
    }
    for (vi, v) in views.iter().enumerate() {
        if v.points.len() < MIN_POINTS_PER_VIEW {
            return Err(CalibError::TooFewPoints { view: vi, got: v.points.len(), need: MIN_POINTS_PER_VIEW });
        }
        for (pi, p) in v.points.iter().enumerate() {
            let bad = |what: String| Err(CalibError::BadInput { view: vi, point: pi, what });
            if ![p.target.x, p.target.y, p.pixel.x, p.pixel.y].iter().all(|x| x.is_finite()) {
                return bad(format!("non-finite coordinates target {:?} pixel {:?}", p.target, p.pixel));
            }
            if let Some(s) = p.sigma_px {
                if !(s.is_finite() && s > 0.0) {
                    return bad(format!("sigma_px = {s} must be finite and positive"));
                }
            }
        }
        // Spread of the target points: eigenvalues of their 2x2 covariance.
        let n = v.points.len() as f64;
        let (mx, my) = v.points.iter().fold((0.0, 0.0), |a, p| (a.0 + p.target.x / n, a.1 + p.target.y / n));
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for p in &v.points {
            let (dx, dy) = (p.target.x - mx, p.target.y - my);
            sxx += dx * dx;
            sxy += dx * dy;
            syy += dy * dy;
        }
        let tr = sxx + syy;
        let disc = ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt();
        let (l1, l2) = (0.5 * (tr + disc), 0.5 * (tr - disc));
        let ratio = if l1 > 0.0 { (l2.max(0.0) / l1).sqrt() } else { 0.0 };
        if ratio < 1e-3 {
            return Err(CalibError::CollinearTarget { view: vi, ratio });
        }
    }
    Ok(())
}

/// Calibrates the camera from views of a planar target. See the module docs.
pub fn calibrate(views: &[View], opts: &Options) -> Result<Calibration, CalibError> {
    check_input(views)?;
    let (w, h) = (opts.width as f64, opts.height as f64);
    // Image coordinates scaled to order one for the closed form: u' = (u - w/2) / s.
    let s = 0.5 * w.max(h);
    let norm = Matrix3::new(1.0 / s, 0.0, -0.5 * w / s, 0.0, 1.0 / s, -0.5 * h / s, 0.0, 0.0, 1.0);
    let unnorm = norm.try_inverse().expect("scaling is invertible");

    // 1. Homographies with gross outliers screened out (distortion of a few pixels is still
    //    in the residuals here, hence the generous floor; the refinement readmits points).
    let mut hs = Vec::new();
    let mut active = Vec::new();
    let mut depth_var = Vec::new();
    for (vi, v) in views.iter().enumerate() {
        let src: Vec<Point2<f64>> = v.points.iter().map(|p| p.target).collect();
        let dst: Vec<Point2<f64>> = v.points.iter().map(|p| p.pixel).collect();
        let (hpx, inl) = homography::robust_dlt(&src, &dst, 4.0, 3.0).ok_or(CalibError::NoHomography { view: vi })?;
        let used = inl.iter().filter(|&&i| i).count();
        if used < MIN_POINTS_PER_VIEW {
            return Err(CalibError::TooFewPoints { view: vi, got: used, need: MIN_POINTS_PER_VIEW });
        }
        // Third row of H is proportional to (r13, r23, tz): depth of (X, Y) relative to the
        // origin's is 1 + (h31 X + h32 Y) / h33, independent of the intrinsics.
        let (lo, hi) =
            src.iter().zip(&inl).filter(|(_, &i)| i).fold((f64::INFINITY, f64::NEG_INFINITY), |a, (p, _)| {
                let d = (hpx[(2, 0)] * p.x + hpx[(2, 1)] * p.y) / hpx[(2, 2)];
                (a.0.min(d), a.1.max(d))
            });
        depth_var.push(hi - lo);
        hs.push(norm * hpx);
        active.push(inl);
    }
    let tilted = depth_var.iter().filter(|&&d| d >= opts.min_depth_variation).count();
    if tilted < opts.min_tilted_views {
        return Err(CalibError::ParallelViews {
            tilted,
            views: views.len(),
            need: opts.min_tilted_views,
            min_variation: opts.min_depth_variation,
            max_seen: depth_var.iter().copied().fold(0.0, f64::max),
        });
    }

    // 2. Closed-form intrinsics (in normalised image coordinates), with a fallback.
    let in_image = |k: &zhang::Pinhole| {
        let c = unnorm * nalgebra::Vector3::new(k.cx, k.cy, 1.0);
        c.x > -0.5 && c.x < w - 0.5 && c.y > -0.5 && c.y < h - 0.5 && (k.fx / k.fy - 1.0).abs() < 0.5
    };
    let full = match opts.fixed_principal_point {
        None => zhang::intrinsics(&hs),
        Some(_) => Err(zhang::ClosedFormFailure::NotPositive),
    };
    let (k_norm, init) = match full {
        Ok(k) if in_image(&k) => (k, Init::Zhang),
        first => {
            let pp = opts.fixed_principal_point.unwrap_or(Point2::new((w - 1.0) / 2.0, (h - 1.0) / 2.0));
            let c = norm * nalgebra::Vector3::new(pp.x, pp.y, 1.0);
            match zhang::focal_with_centre(&hs, c.x, c.y) {
                Ok(k) => (k, Init::HeldPrincipalPoint),
                Err(e) => return Err(CalibError::ClosedForm { why: format!("full: {first:?}; centred: {e:?}") }),
            }
        }
    };
    let kmat = k_norm.k();
    let mut poses = Vec::new();
    for (vi, hn) in hs.iter().enumerate() {
        let (r, t) = zhang::pose(hn, &kmat).ok_or(CalibError::NoHomography { view: vi })?;
        poses.push(refine::Pose { r, t });
    }
    let kpx = unnorm * kmat;
    let mut cam = refine::CamVec::zeros();
    cam[0] = kpx[(0, 0)];
    cam[1] = kpx[(1, 1)];
    cam[2] = kpx[(0, 2)];
    cam[3] = kpx[(1, 2)];

    // 3. Refinement with rejection rounds.
    let obs: Vec<Vec<refine::Obs>> = views
        .iter()
        .map(|v| {
            v.points
                .iter()
                .map(|p| refine::Obs { target: p.target, pixel: p.pixel, w: 1.0 / p.sigma_px.unwrap_or(1.0) })
                .collect()
        })
        .collect();
    let mut free = [true; 9];
    free[6] = opts.estimate_k3;
    free[7] = opts.estimate_tangential;
    free[8] = opts.estimate_tangential;
    free[2] = opts.fixed_principal_point.is_none();
    free[3] = opts.fixed_principal_point.is_none();
    let nfree = free.iter().filter(|&&f| f).count() + 6 * views.len();
    let mut iterations = 0;
    let mut result;
    let mut round = 0;
    loop {
        result = refine::refine(cam, poses.clone(), &obs, &active, &free, opts.max_iterations);
        iterations += result.iterations;
        cam = result.cam;
        poses = result.poses.clone();
        round += 1;
        if round >= opts.max_rounds {
            break;
        }
        // Robust scale from the median of the residual norms (median of a 2-D Gaussian
        // norm = 1.1774 sigma), over the points currently used.
        let res = refine::residuals(&cam, &poses, &obs);
        let mut norms: Vec<f64> = res
            .iter()
            .zip(&active)
            .flat_map(|(rv, av)| {
                rv.iter().zip(av).filter(|(_, &a)| a).map(|(r, _)| r.map_or(f64::INFINITY, |r| r.norm()))
            })
            .collect();
        norms.sort_by(|a, b| a.total_cmp(b));
        let sigma = norms[norms.len() / 2] / 1.1774;
        // The floor keeps exact (noise-free) data from rejecting points over rounding error.
        let thresh = (opts.reject_k * sigma).max(1e-6);
        let next: Vec<Vec<bool>> =
            res.iter().map(|rv| rv.iter().map(|r| r.is_some_and(|r| r.norm() <= thresh)).collect()).collect();
        if next == active {
            break;
        }
        for (vi, a) in next.iter().enumerate() {
            let got = a.iter().filter(|&&x| x).count();
            if got < MIN_POINTS_PER_VIEW {
                return Err(CalibError::TooFewPoints { view: vi, got, need: MIN_POINTS_PER_VIEW });
            }
        }
        active = next;
    }

    // 4. Statistics.
    let res = refine::residuals(&cam, &poses, &obs);
    let mut sum_px2 = 0.0;
    let mut n_used = 0usize;
    let mut per_view = Vec::new();
    for ((rv, av), os) in res.iter().zip(&active).zip(&obs) {
        let (mut s2, mut n) = (0.0, 0usize);
        for ((r, &a), o) in rv.iter().zip(av).zip(os) {
            if let (Some(r), true) = (r, a) {
                s2 += (r / o.w).norm_squared();
                n += 1;
            }
        }
        sum_px2 += s2;
        n_used += n;
        per_view.push(if n > 0 { (s2 / n as f64).sqrt() } else { f64::NAN });
    }
    let dof = (2 * n_used).saturating_sub(nfree).max(1) as f64;
    let sigma0 = (result.cost / dof).sqrt();
    let var0 = sigma0 * sigma0;
    let sd = |k: usize| (result.cam_cov[(k, k)] * var0).max(0.0).sqrt();
    let uncertainty = Uncertainty {
        fx_px: sd(0),
        fy_px: sd(1),
        cx_px: sd(2),
        cy_px: sd(3),
        k1: sd(4),
        k2: sd(5),
        k3: sd(6),
        p1: sd(7),
        p2: sd(8),
    };
    let mut covariance = [[0.0; 9]; 9];
    for (r, row) in covariance.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = result.cam_cov[(r, c)] * var0;
        }
    }
    let camera = CameraModel::new(
        opts.width,
        opts.height,
        cam[0],
        cam[1],
        cam[2],
        cam[3],
        Distortion { k1: cam[4], k2: cam[5], k3: cam[6], p1: cam[7], p2: cam[8] },
        opts.vignetting,
    )?;
    let outliers = active.iter().flatten().filter(|&&a| !a).count();
    Ok(Calibration {
        camera,
        uncertainty,
        covariance,
        rms_px: (sum_px2 / n_used.max(1) as f64).sqrt(),
        per_view_rms_px: per_view,
        sigma0,
        poses: poses
            .iter()
            .map(|p| Isometry3::from_parts(Translation3::from(p.t), UnitQuaternion::from_rotation_matrix(&p.r)))
            .collect(),
        pose_sigma: result.pose_var.iter().map(|v| std::array::from_fn(|k| (v[k] * var0).max(0.0).sqrt())).collect(),
        inliers: active,
        outliers,
        points_used: n_used,
        init,
        iterations,
    })
}
