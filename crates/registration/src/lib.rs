//! Marker-based registration: the true pose of the sample plane in one frame, estimated from
//! observed marker corners on the holder plate, so rectification can use the measured pose
//! instead of the nominal (kinematic) one.
//!
//! Method (details and measured figures in `docs/registration.md`):
//!
//! 1. Undistort every observed corner with the camera model to normalised coordinates.
//! 2. RANSAC over pairs of markers (seeded; every pair when there are few): a normalised-DLT
//!    homography from the pair's corners, decomposed into a plane pose with the known
//!    intrinsics. Hypotheses farther from the nominal pose than the rig's positioning
//!    tolerance are rejected (the kinematic prior catches wrong markers). A marker is an inlier
//!    only if all its corners are, so a bad marker drops out whole.
//! 3. Levenberg–Marquardt refinement of the 6-DoF pose minimising the weighted reprojection
//!    error through the full distorted camera model (optionally with a weak Gaussian prior
//!    at the nominal pose), re-selecting inliers with a tight gate until the set is stable.
//! 4. Checks that refuse a pose rather than return a wrong one: too few inlier markers,
//!    collinear or too small a spread of points, an ill-conditioned normal matrix, a result
//!    outside the prior tolerance.
//!
//! The camera is the fixed reference: the result keeps the nominal `camera_to_world` and
//! lamp and replaces `sample_to_world` so that `camera_to_world⁻¹ · sample_to_world` is the
//! measured sample-to-camera transform (all rectification depends on).
#![warn(missing_docs)]

// The files, one job each:
// - lib:    pose estimation from marker corners (RANSAC, checks, Registration)
// - frame:  one frame: detect the plate's markers, pair them, register (PlateRegistrar)
// - refine: Levenberg-Marquardt refinement of the plane pose
// - metric: the texel position error

pub mod frame;
pub mod metric;
pub mod refine;

use std::collections::BTreeMap;

use btfrig_core::camera::CameraModel;
use btfrig_core::homography;
use btfrig_core::pose::ScenePose;
use btfrig_imaging::Region;
use nalgebra::{Isometry3, Point2, Vector3};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub use frame::{
    FallbackCause, FrameError, FrameRegistration, GreyFrame, MarkerSearch, PlateRegistrar, SearchRecord,
    BIN_MIN_MODULE_PX,
};
pub use metric::{back_project, sample_to_camera, texel_position_error, texel_position_error_with_cameras};
pub use refine::{Matrix6, Vector6};

/// One observed marker corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// Where the corner is on the sample plane `z = 0`, metres, sample frame.
    pub plane: Point2<f64>,
    /// Where it was observed, distorted pixel coordinates (integer = pixel centre).
    pub pixel: Point2<f64>,
    /// Standard deviation of the observation per image axis, pixels (> 0).
    pub sigma_px: f64,
    /// Id of the marker the corner belongs to (corners of one marker share it).
    pub marker: u32,
}

/// Settings of [`register`].
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterOptions {
    /// Fewest inlier markers accepted (at least 2).
    pub min_markers: usize,
    /// Most RANSAC hypotheses; when the number of marker pairs is not larger, every pair is
    /// tried once (in seeded random order).
    pub max_hypotheses: usize,
    /// Seed of the hypothesis order.
    pub seed: u64,
    /// Gate for a corner to support a RANSAC hypothesis, pixels (the hypothesis comes from
    /// two markers only, so it is looser than the final gate).
    pub hypothesis_gate_px: f64,
    /// Final gate: a corner is an inlier if its reprojection error is below this many of
    /// its standard deviations (radially) ...
    pub inlier_sigmas: f64,
    /// ... or below this many pixels, whichever is larger (guards against sigmas that are
    /// too optimistic).
    pub inlier_floor_px: f64,
    /// Largest rotation between the estimate and the nominal pose, degrees: the rig's
    /// positioning tolerance.
    pub max_rotation_deg: f64,
    /// Largest translation between the estimate and the nominal pose, metres.
    pub max_translation_m: f64,
    /// Optional weak Gaussian prior at the nominal pose: `(sigma rotation deg, sigma
    /// translation m)` per component. `None`: the prior only gates.
    pub prior_sigma: Option<(f64, f64)>,
    /// Smallest spread of the inlier points (square root of the smaller eigenvalue of their
    /// 2x2 covariance on the plane), metres: below it the geometry is degenerate.
    pub min_spread_m: f64,
    /// Largest ratio of the larger to the smaller spread (collinearity). One row of the
    /// plate's ring (ratio about 6) already registers worse than the nominal pose on rendered
    /// frames (tilt about the row is seen only across the 2 cm markers), while the whole ring
    /// or any two sides of it stay under 2: the default 4 refuses the row.
    pub max_spread_ratio: f64,
    /// Largest condition number of the 6x6 normal matrix in scaled units.
    pub max_condition: f64,
}

impl Default for RegisterOptions {
    fn default() -> Self {
        RegisterOptions {
            min_markers: 3,
            max_hypotheses: 200,
            seed: 0x5eed_4e61,
            hypothesis_gate_px: 3.0,
            inlier_sigmas: 5.0,
            inlier_floor_px: 0.5,
            max_rotation_deg: 2.0,
            max_translation_m: 0.01,
            prior_sigma: None,
            min_spread_m: 0.005,
            max_spread_ratio: 4.0,
            max_condition: 1e10,
        }
    }
}

impl RegisterOptions {
    /// Defaults with the rig's pose tolerance: how far (degrees of rotation, metres of
    /// translation) the sample may be from its nominal pose (the rig config's
    /// `[geometry] pose_tolerance_deg` and `pose_tolerance_mm`).
    pub fn with_pose_tolerance(rotation_deg: f64, translation_m: f64) -> Self {
        RegisterOptions { max_rotation_deg: rotation_deg, max_translation_m: translation_m, ..Default::default() }
    }
}

/// Why no pose was returned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RegisterError {
    /// An input value is unusable.
    #[error("correspondence {index}: {what} = {value} is invalid ({allowed})")]
    BadInput {
        /// Index into the correspondences.
        index: usize,
        /// Field.
        what: &'static str,
        /// Offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// An option is out of range.
    #[error("register option {name} = {value} is invalid ({allowed})")]
    BadOption {
        /// Option name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// Too few good markers to trust a pose.
    #[error("registration needs at least {needed} good markers, found {found} ({detail})")]
    TooFewMarkers {
        /// Good markers found.
        found: usize,
        /// Markers needed ([`RegisterOptions::min_markers`]).
        needed: usize,
        /// Which markers were seen and which were rejected.
        detail: String,
    },
    /// The points cannot determine a pose.
    #[error("degenerate marker geometry: {why}")]
    Degenerate {
        /// What is wrong.
        why: String,
    },
    /// The markers fit a pose the rig cannot be in.
    #[error(
        "no pose consistent with the nominal pose: best fit is {rotation_deg:.3} deg / {translation_mm:.2} mm away, \
         tolerance {max_rotation_deg} deg / {max_translation_mm} mm"
    )]
    PriorMismatch {
        /// Rotation from the nominal pose, degrees (NaN if no hypothesis was formed).
        rotation_deg: f64,
        /// Translation from the nominal pose, mm.
        translation_mm: f64,
        /// Tolerance, degrees.
        max_rotation_deg: f64,
        /// Tolerance, mm.
        max_translation_mm: f64,
    },
}

/// A measured sample pose.
#[derive(Debug, Clone)]
pub struct Registration {
    /// The scene pose to rectify with: nominal camera and lamp, measured sample.
    pub pose: ScenePose,
    /// Measured sample-to-camera transform.
    pub sample_to_camera: Isometry3<f64>,
    /// Indices of the inlier correspondences.
    pub inliers: Vec<usize>,
    /// Ids of the inlier markers, ascending.
    pub inlier_markers: Vec<u32>,
    /// Ids of the markers rejected as outliers, ascending.
    pub rejected_markers: Vec<u32>,
    /// RMS reprojection error of the inliers, pixels (per point, radial).
    pub rms_px: f64,
    /// Chi-square per degree of freedom of the inliers (about 1 when the sigmas are right).
    pub chi2_per_dof: f64,
    /// Covariance of the pose (from the weighted normal matrix, not rescaled by chi-square)
    /// in the parameters of [`refine::perturb`]: rotation vector (rad, camera frame, applied
    /// on the left), then translation (m, camera frame).
    pub covariance: Matrix6,
    /// RANSAC hypotheses tried.
    pub hypotheses: usize,
    /// LM iterations of the last refinement.
    pub iterations: usize,
}

impl Registration {
    /// Predicted standard deviation (RMS radius) of the texel position error, in texels, at
    /// the worst of a 5x5 grid over `region` (`size x size` texels), from the covariance by
    /// first-order propagation.
    pub fn texel_sigma(&self, camera: &CameraModel, region: Region, size: usize) -> f64 {
        let est = self.sample_to_camera;
        let pitch_x = (region.x_max - region.x_min) / size as f64;
        let pitch_y = (region.y_max - region.y_min) / size as f64;
        const H: f64 = 1e-7;
        let mut worst = 0.0f64;
        for i in 0..5 {
            for j in 0..5 {
                let (x, y) = region.point(4, 4, i as f64, j as f64);
                let p = Point2::new(x, y);
                // Sampled point as a function of the estimate's error, truth held fixed.
                let mut jac = nalgebra::SMatrix::<f64, 2, 6>::zeros();
                let mut ok = true;
                for k in 0..6 {
                    let mut d = Vector6::zeros();
                    d[k] = H;
                    let a = metric::sampled_point(camera, &est, &refine::perturb(&est, &d), p);
                    let b = metric::sampled_point(camera, &est, &refine::perturb(&est, &(-d)), p);
                    match (a, b) {
                        (Some(a), Some(b)) => {
                            jac[(0, k)] = (a.x - b.x) / (2.0 * H) / pitch_x;
                            jac[(1, k)] = (a.y - b.y) / (2.0 * H) / pitch_y;
                        }
                        _ => ok = false,
                    }
                }
                if ok {
                    worst = worst.max((jac * self.covariance * jac.transpose()).trace().sqrt());
                }
            }
        }
        worst
    }
}

/// How much farther from the nominal pose than the tolerance a RANSAC hypothesis may be.
const HYPOTHESIS_SLACK: f64 = 3.0;

/// A candidate set of markers with its score (more markers, then lower truncated cost).
struct Scored {
    pose: Isometry3<f64>,
    markers: Vec<u32>,
    cost: f64,
}

fn check_options(o: &RegisterOptions) -> Result<(), RegisterError> {
    let bad = |name, value, allowed| Err(RegisterError::BadOption { name, value, allowed });
    if o.min_markers < 2 {
        return bad("min_markers", o.min_markers as f64, ">= 2");
    }
    if o.max_hypotheses == 0 {
        return bad("max_hypotheses", 0.0, ">= 1");
    }
    for (name, v) in [
        ("hypothesis_gate_px", o.hypothesis_gate_px),
        ("inlier_sigmas", o.inlier_sigmas),
        ("inlier_floor_px", o.inlier_floor_px),
        ("max_rotation_deg", o.max_rotation_deg),
        ("max_translation_m", o.max_translation_m),
        ("max_spread_ratio", o.max_spread_ratio),
        ("max_condition", o.max_condition),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return bad(name, v, "finite and > 0");
        }
    }
    if !(o.min_spread_m.is_finite() && o.min_spread_m >= 0.0) {
        return bad("min_spread_m", o.min_spread_m, "finite and >= 0");
    }
    if let Some((r, t)) = o.prior_sigma {
        if !(r.is_finite() && r > 0.0) {
            return bad("prior_sigma.rotation_deg", r, "finite and > 0");
        }
        if !(t.is_finite() && t > 0.0) {
            return bad("prior_sigma.translation_m", t, "finite and > 0");
        }
    }
    Ok(())
}

/// Spread check of plane points: `Err` naming the problem when they are too concentrated
/// or nearly collinear.
fn check_spread(points: &[Point2<f64>], o: &RegisterOptions) -> Result<(), RegisterError> {
    let n = points.len() as f64;
    let (mx, my) = points.iter().fold((0.0, 0.0), |a, p| (a.0 + p.x / n, a.1 + p.y / n));
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in points {
        let (dx, dy) = (p.x - mx, p.y - my);
        sxx += dx * dx / n;
        sxy += dx * dy / n;
        syy += dy * dy / n;
    }
    let tr = sxx + syy;
    let disc = ((sxx - syy).powi(2) / 4.0 + sxy * sxy).sqrt();
    let big = (tr / 2.0 + disc).max(0.0).sqrt();
    let small = (tr / 2.0 - disc).max(0.0).sqrt();
    if small < o.min_spread_m || big > o.max_spread_ratio * small {
        return Err(RegisterError::Degenerate {
            why: format!(
                "{} points spread {:.2} mm x {:.3} mm on the plane (need the smaller >= {:.2} mm and ratio <= {}): \
                 collinear or too concentrated",
                points.len(),
                big * 1e3,
                small * 1e3,
                o.min_spread_m * 1e3,
                o.max_spread_ratio
            ),
        });
    }
    Ok(())
}

/// Estimates the sample pose of one frame from observed marker corners.
///
/// `nominal` is the kinematic pose (prior and gate); its camera and lamp are kept in the
/// result. Errors (never a silent wrong pose): [`RegisterError::TooFewMarkers`] when fewer
/// than `options.min_markers` markers survive, [`RegisterError::Degenerate`] for collinear
/// or concentrated points or an ill-conditioned fit, [`RegisterError::PriorMismatch`] when
/// the markers only fit a pose outside the tolerance, `BadInput`/`BadOption` for unusable
/// values.
pub fn register(
    correspondences: &[Correspondence],
    camera: &CameraModel,
    nominal: &ScenePose,
    options: &RegisterOptions,
) -> Result<Registration, RegisterError> {
    check_options(options)?;
    let needed = options.min_markers;
    for (index, c) in correspondences.iter().enumerate() {
        let bad = |what, value, allowed| Err(RegisterError::BadInput { index, what, value, allowed });
        for (what, v) in
            [("plane.x", c.plane.x), ("plane.y", c.plane.y), ("pixel.x", c.pixel.x), ("pixel.y", c.pixel.y)]
        {
            if !v.is_finite() {
                return bad(what, v, "finite");
            }
        }
        if !(c.sigma_px.is_finite() && c.sigma_px > 0.0) {
            return bad("sigma_px", c.sigma_px, "finite and > 0");
        }
    }
    // Undistorted normalised coordinates; a pixel without a ray cannot be a real corner.
    let mut norm: Vec<Option<Point2<f64>>> = Vec::with_capacity(correspondences.len());
    for c in correspondences {
        norm.push(camera.try_pixel_ray(c.pixel).map(|r| Point2::new(r.x / r.z, r.y / r.z)));
    }
    let mut by_marker: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (i, c) in correspondences.iter().enumerate() {
        if norm[i].is_some() {
            by_marker.entry(c.marker).or_default().push(i);
        }
    }
    let seen: Vec<u32> = by_marker.keys().copied().collect();
    if seen.len() < needed {
        return Err(RegisterError::TooFewMarkers {
            found: seen.len(),
            needed,
            detail: format!("markers seen: {seen:?}"),
        });
    }
    let all_plane: Vec<Point2<f64>> = correspondences.iter().map(|c| c.plane).collect();
    check_spread(&all_plane, options)?;

    let nominal_t = sample_to_camera(nominal);
    let max_rot = options.max_rotation_deg.to_radians();
    // `slack` > 1 for RANSAC hypotheses: a pose from two markers is much less certain
    // (especially in depth) than the refined one, which must meet the tolerance itself.
    let within_prior = |t: &Isometry3<f64>, slack: f64| {
        let d = refine::difference(t, &nominal_t);
        let rot = Vector3::new(d[0], d[1], d[2]).norm();
        let tr = Vector3::new(d[3], d[4], d[5]).norm();
        (rot <= slack * max_rot && tr <= slack * options.max_translation_m, rot, tr)
    };
    // Per-corner reprojection error (px) under a pose; infinite when it does not project.
    let errors = |t: &Isometry3<f64>| -> Vec<f64> {
        correspondences
            .iter()
            .map(|c| refine::project(camera, t, &c.plane).map_or(f64::INFINITY, |p| (p - c.pixel).norm()))
            .collect()
    };
    // Markers all of whose corners pass `gate(index, error)`, with the truncated cost.
    let classify = |errs: &[f64], gate: &dyn Fn(usize, f64) -> bool| -> (Vec<u32>, f64) {
        let mut inl = Vec::new();
        let mut cost = 0.0;
        for (&id, idx) in &by_marker {
            if idx.iter().all(|&i| gate(i, errs[i])) {
                inl.push(id);
                cost += idx.iter().map(|&i| errs[i] * errs[i]).sum::<f64>();
            } else {
                cost += idx.len() as f64 * options.hypothesis_gate_px.powi(2);
            }
        }
        (inl, cost)
    };

    // Hypotheses: pairs of markers.
    let ids = seen.clone();
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for a in 0..ids.len() {
        for b in a + 1..ids.len() {
            pairs.push((ids[a], ids[b]));
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    pairs.shuffle(&mut rng);
    let mut best: Option<Scored> = None;
    let mut closest_rejected: Option<(f64, f64)> = None;
    let (mut tried, mut degenerate) = (0usize, 0usize);
    let gate_h = options.hypothesis_gate_px;
    for &(a, b) in pairs.iter().take(options.max_hypotheses) {
        tried += 1;
        let idx: Vec<usize> = by_marker[&a].iter().chain(&by_marker[&b]).copied().collect();
        let plane: Vec<Point2<f64>> = idx.iter().map(|&i| correspondences[i].plane).collect();
        let img: Vec<Point2<f64>> = idx.iter().map(|&i| norm[i].expect("filtered")).collect();
        let Some(pose) = homography::dlt(&plane, &img).and_then(|h| homography::decompose(&h)) else {
            degenerate += 1;
            continue;
        };
        let (ok, rot, tr) = within_prior(&pose, HYPOTHESIS_SLACK);
        if !ok {
            if closest_rejected.is_none_or(|(r, _)| rot < r) {
                closest_rejected = Some((rot, tr));
            }
            continue;
        }
        let errs = errors(&pose);
        let (markers, cost) =
            classify(&errs, &|i, e| e < gate_h.max(options.inlier_sigmas * correspondences[i].sigma_px));
        let better = match &best {
            None => true,
            Some(s) => markers.len() > s.markers.len() || (markers.len() == s.markers.len() && cost < s.cost),
        };
        if better {
            best = Some(Scored { pose, markers, cost });
        }
    }
    let Some(best) = best else {
        if degenerate == tried {
            return Err(RegisterError::Degenerate {
                why: format!("all {tried} marker pairs gave no unique homography (collinear or coincident corners)"),
            });
        }
        let (rot, tr) = closest_rejected.unwrap_or((f64::NAN, f64::NAN));
        return Err(RegisterError::PriorMismatch {
            rotation_deg: rot.to_degrees(),
            translation_mm: tr * 1e3,
            max_rotation_deg: options.max_rotation_deg,
            max_translation_mm: options.max_translation_m * 1e3,
        });
    };
    let detail = |inl: &[u32]| {
        let rej: Vec<u32> = seen.iter().filter(|m| !inl.contains(m)).copied().collect();
        format!("markers seen: {seen:?}, rejected as outliers: {rej:?}")
    };
    // A pair of markers may support fewer than `needed` markers and still lead to the right
    // pose after refinement (local optimisation): two markers are 8 corners.
    if best.markers.len() < 2 {
        return Err(RegisterError::TooFewMarkers { found: best.markers.len(), needed, detail: detail(&best.markers) });
    }

    let prior =
        options.prior_sigma.map(|(r, t)| refine::Prior { mean: nominal_t, sigma_rot: r.to_radians(), sigma_t: t });
    let obs_of = |markers: &[u32]| -> (Vec<usize>, Vec<refine::Obs>) {
        let idx: Vec<usize> = markers.iter().flat_map(|m| by_marker[m].iter().copied()).collect();
        let obs = idx
            .iter()
            .map(|&i| {
                let c = &correspondences[i];
                refine::Obs { plane: c.plane, pixel: c.pixel, sigma: c.sigma_px }
            })
            .collect();
        (idx, obs)
    };
    let final_gate =
        |i: usize, e: f64| e < (options.inlier_sigmas * correspondences[i].sigma_px).max(options.inlier_floor_px);
    let mut markers = best.markers;
    let mut pose = best.pose;
    let mut refined = None;
    // Refine, re-select with the tight gate, repeat until the inlier set is stable.
    for _ in 0..5 {
        let (_, obs) = obs_of(&markers);
        let r = refine::refine(camera, &pose, &obs, prior.as_ref()).ok_or_else(|| RegisterError::Degenerate {
            why: "refinement moved a corner out of the lens model's field".into(),
        })?;
        pose = r.pose;
        refined = Some(r);
        let (next, _) = classify(&errors(&pose), &final_gate);
        if next == markers {
            break;
        }
        if next.len() < 2 {
            return Err(RegisterError::TooFewMarkers { found: next.len(), needed, detail: detail(&next) });
        }
        markers = next;
    }
    let refined = refined.expect("refined at least once");
    if markers.len() < needed {
        return Err(RegisterError::TooFewMarkers { found: markers.len(), needed, detail: detail(&markers) });
    }
    let (inliers, _) = obs_of(&markers);
    let inlier_plane: Vec<Point2<f64>> = inliers.iter().map(|&i| correspondences[i].plane).collect();
    check_spread(&inlier_plane, options)?;
    let (ok, rot, tr) = within_prior(&pose, 1.0);
    if !ok {
        return Err(RegisterError::PriorMismatch {
            rotation_deg: rot.to_degrees(),
            translation_mm: tr * 1e3,
            max_rotation_deg: options.max_rotation_deg,
            max_translation_mm: options.max_translation_m * 1e3,
        });
    }
    // Conditioning in scaled units: rotations times the working distance are lengths, so
    // both blocks are compared in metres.
    let z = pose.translation.vector.norm().max(1e-3);
    let mut scaled = refined.normal;
    for a in 0..6 {
        for b in 0..6 {
            let sa = if a < 3 { 1.0 / z } else { 1.0 };
            let sb = if b < 3 { 1.0 / z } else { 1.0 };
            scaled[(a, b)] *= sa * sb;
        }
    }
    let ev = scaled.symmetric_eigen().eigenvalues;
    let (lo, hi) = ev.iter().fold((f64::INFINITY, 0.0f64), |a, &v| (a.0.min(v), a.1.max(v)));
    if !(lo > 0.0) || hi / lo > options.max_condition {
        return Err(RegisterError::Degenerate {
            why: format!("normal matrix condition {:.3e} exceeds {:.1e}", hi / lo, options.max_condition),
        });
    }
    let covariance = refined
        .normal
        .try_inverse()
        .ok_or_else(|| RegisterError::Degenerate { why: "singular normal matrix".into() })?;
    let errs = errors(&pose);
    let rms_px = (inliers.iter().map(|&i| errs[i] * errs[i]).sum::<f64>() / inliers.len() as f64).sqrt();
    let dof = (2 * inliers.len()).saturating_sub(6).max(1);
    let rejected_markers = seen.iter().filter(|m| !markers.contains(m)).copied().collect();
    let sample_to_world = nominal.camera_to_world * pose;
    Ok(Registration {
        pose: ScenePose { sample_to_world, ..*nominal },
        sample_to_camera: pose,
        inliers,
        inlier_markers: markers,
        rejected_markers,
        rms_px,
        chi2_per_dof: refined.chi2 / dof as f64,
        covariance,
        hypotheses: tried,
        iterations: refined.iterations,
    })
}
