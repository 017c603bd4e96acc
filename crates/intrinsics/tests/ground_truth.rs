//! Calibration against ground truth: a planar target of marker-corner-like points is projected
//! through the default rig's camera (rig-configs/bonn-gonio-sim.toml) at seeded random tilted
//! poses, Gaussian pixel noise is added, and the recovered camera is compared with the truth.

use std::time::Instant;

mod support;

use btfrig_core::camera::CameraModel;
use btfrig_intrinsics::{
    calibrate, distortion_difference, mapping_difference, mapping_difference_up_to_rotation, CalibError, Calibration,
    CalibrationFile, Options, View,
};
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use support::{rig, scene, truth, wide};

fn timed(views: &[View], opts: &Options) -> (Result<Calibration, CalibError>, f64) {
    let t0 = Instant::now();
    let r = calibrate(views, opts);
    (r, t0.elapsed().as_secs_f64() * 1e3)
}

/// The issue's acceptance figures of one calibration.
struct Figures {
    /// Largest relative focal length error.
    focal_rel: f64,
    /// Principal point error, pixels.
    pp_px: f64,
    /// Largest difference of the distortion displacement over the image, pixels.
    distortion_px: f64,
}

/// Prints the figures of a calibration against the truth and the issue's bounds.
fn report(label: &str, t: &CameraModel, c: &Calibration, sigma: f64, ms: f64) -> Figures {
    let e = &c.camera;
    let dfx = (e.fx - t.fx) / t.fx;
    let dfy = (e.fy - t.fy) / t.fy;
    let dc = (e.cx - t.cx).hypot(e.cy - t.cy);
    let dd = distortion_difference(t, e, 81);
    let dm = mapping_difference(t, e, 81);
    println!(
        "{label}: {ms:.1} ms, {} views, {} points, {} rejected, {} iterations, init {:?}\n  \
         fx {:.3} (err {:+.4}%, sd {:.3}), fy {:.3} (err {:+.4}%, sd {:.3}), cx {:.3} (sd {:.3}), cy {:.3} (sd {:.3}), \
         pp err {dc:.3} px\n  k1 {:.5} k2 {:.4} k3 {:.3} p1 {:.2e} p2 {:.2e}; distortion effect diff max {dd:.4} px, \
         whole mapping diff max {dm:.3} px\n  rms {:.4} px (noise sigma {sigma} per axis => expected ~{:.4}), sigma0 {:.4}",
        c.poses.len(),
        c.points_used,
        c.outliers,
        c.iterations,
        c.init,
        e.fx,
        dfx * 100.0,
        c.uncertainty.fx_px,
        e.fy,
        dfy * 100.0,
        c.uncertainty.fy_px,
        e.cx,
        c.uncertainty.cx_px,
        e.cy,
        c.uncertainty.cy_px,
        e.distortion.k1,
        e.distortion.k2,
        e.distortion.k3,
        e.distortion.p1,
        e.distortion.p2,
        c.rms_px,
        sigma * std::f64::consts::SQRT_2,
        c.sigma0,
    );
    let (dr, _) = mapping_difference_up_to_rotation(t, e, 81);
    let f = Figures { focal_rel: dfx.abs().max(dfy.abs()), pp_px: dc, distortion_px: dd };
    println!(
        "  whole mapping up to a camera rotation: max {dr:.3} px; issue bounds (0.1%, 0.5 px, 0.1 px): {}",
        if f.focal_rel < 1e-3 && f.pp_px < 0.5 && f.distortion_px < 0.1 { "met" } else { "NOT met" }
    );
    f
}

/// Every free parameter's error is within 4 of its reported standard uncertainties.
fn assert_consistent(label: &str, t: &CameraModel, c: &Calibration) {
    for (k, z) in z_scores(t, c).iter().enumerate() {
        if z.is_finite() {
            assert!(z.abs() < 4.0, "{label}: {} error is {z:.2} reported sigmas", btfrig_intrinsics::CAM_NAMES[k]);
        }
    }
}

/// z-scores (error over reported standard uncertainty) of the free parameters.
fn z_scores(t: &CameraModel, c: &Calibration) -> [f64; 9] {
    let (e, u) = (&c.camera, &c.uncertainty);
    let (td, ed) = (t.distortion, e.distortion);
    [
        (e.fx - t.fx) / u.fx_px,
        (e.fy - t.fy) / u.fy_px,
        (e.cx - t.cx) / u.cx_px,
        (e.cy - t.cy) / u.cy_px,
        (ed.k1 - td.k1) / u.k1,
        (ed.k2 - td.k2) / u.k2,
        (ed.k3 - td.k3) / u.k3,
        (ed.p1 - td.p1) / u.p1,
        (ed.p2 - td.p2) / u.p2,
    ]
}

#[test]
fn noise_free_views_recover_the_camera_exactly() {
    for (name, t) in [("default rig", truth()), ("wide", wide())] {
        let s = scene(&t, 4, 12, (20.0, 60.0), 0.0, 0.0);
        let c = calibrate(&s.views, &Options::new(t.width, t.height)).unwrap();
        let f = report(&format!("{name}, 12 views, no noise"), &t, &c, 0.0, 0.0);
        assert!(f.focal_rel < 1e-9 && f.pp_px < 1e-6 && f.distortion_px < 1e-6, "{name}");
        assert!(c.rms_px < 1e-8, "{name}: rms {}", c.rms_px);
    }
}

/// The issue's acceptance case: the default rig's camera (a 19-degree lens), 10-20 views tilted
/// 20-60 degrees, 0.1-0.3 px noise. The focal length meets 0.1% where the data carry it; the
/// principal point of so long a lens is determined only to several pixels by any such data
/// (see docs/camera-calibration.md), so what is asserted is that every error lies within the
/// reported uncertainty, and the bounds are printed.
#[test]
fn default_rig_camera_is_recovered_within_its_reported_uncertainty() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    for (seed, n, sigma) in [(1u64, 15usize, 0.2f64), (2, 10, 0.3), (3, 20, 0.1), (4, 20, 0.1)] {
        let s = scene(&t, seed, n, (20.0, 60.0), sigma, 0.0);
        let (c, ms) = timed(&s.views, &opts);
        let c = c.unwrap();
        let label = format!("default rig, seed {seed}, {n} views, noise {sigma} px");
        let f = report(&label, &t, &c, sigma, ms);
        assert_consistent(&label, &t, &c);
        if n == 20 && sigma <= 0.1 {
            assert!(f.focal_rel < 1e-3, "{label}: focal error {}", f.focal_rel);
        }
        // RMS (OpenCV's definition: root mean squared residual norm) is sqrt(2) sigma, less
        // the degrees of freedom the fit absorbs; sigma0 estimates the per-axis sigma.
        let ratio = c.rms_px / (sigma * std::f64::consts::SQRT_2);
        assert!((0.9..1.05).contains(&ratio), "rms {} for noise {sigma}: ratio {ratio}", c.rms_px);
        assert!((c.sigma0 / sigma - 1.0).abs() < 0.1, "sigma0 {} for noise {sigma}", c.sigma0);
        assert_eq!(c.outliers, 0, "no point should be rejected on clean Gaussian noise at 5 sigma");
        for (v, r) in c.per_view_rms_px.iter().enumerate() {
            assert!(*r < 2.5 * sigma, "view {v}: rms {r}");
        }
    }
}

/// Where the views carry the information, the issue's bounds are met: a 53-degree lens with a
/// decentred principal point, 20 views, corner noise 0.05 px (what the AprilTag detector
/// reaches, issue 4 point 5).
#[test]
fn wider_lens_meets_the_issue_bounds() {
    let t = wide();
    let opts = Options::new(t.width, t.height);
    for seed in 1..=4u64 {
        let s = scene(&t, seed, 20, (20.0, 60.0), 0.05, 0.0);
        let (c, ms) = timed(&s.views, &opts);
        let c = c.unwrap();
        let label = format!("wide lens, seed {seed}, 20 views, noise 0.05 px");
        let f = report(&label, &t, &c, 0.05, ms);
        assert_consistent(&label, &t, &c);
        assert!(f.focal_rel < 1e-3, "{label}: focal error {}", f.focal_rel);
        assert!(f.pp_px < 0.5, "{label}: principal point error {} px", f.pp_px);
        assert!(f.distortion_px < 0.1, "{label}: distortion effect differs by {} px", f.distortion_px);
    }
}

#[test]
fn a_fixed_principal_point_is_held_and_the_rest_estimated() {
    let t = truth();
    let mut opts = Options::new(t.width, t.height);
    opts.fixed_principal_point = Some(Point2::new(t.cx, t.cy));
    let s = scene(&t, 3, 20, (20.0, 60.0), 0.1, 0.0);
    let (c, ms) = timed(&s.views, &opts);
    let c = c.unwrap();
    let f = report("default rig, principal point held at the truth, 20 views, noise 0.1 px", &t, &c, 0.1, ms);
    assert_eq!((c.camera.cx, c.camera.cy), (t.cx, t.cy));
    assert_eq!((c.uncertainty.cx_px, c.uncertainty.cy_px), (0.0, 0.0));
    assert_eq!(c.init, btfrig_intrinsics::Init::HeldPrincipalPoint);
    assert!(f.focal_rel < 1e-3, "focal error {}", f.focal_rel);
    assert_consistent("fixed principal point", &t, &c);
}

#[test]
fn reported_uncertainties_are_consistent_with_the_true_errors() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    let mut sum_z2 = [0.0; 9];
    let runs = 6;
    for seed in 0..runs {
        let s = scene(&t, 100 + seed, 12, (20.0, 60.0), 0.2, 0.0);
        let c = calibrate(&s.views, &opts).unwrap();
        let z = z_scores(&t, &c);
        for (k, zk) in z.iter().enumerate() {
            assert!(
                zk.abs() < 3.5,
                "seed {seed}: parameter {} error is {zk:.2} reported sigmas",
                btfrig_intrinsics::CAM_NAMES[k]
            );
            sum_z2[k] += zk * zk;
        }
    }
    // Over all parameters and runs, the mean squared z-score should be near 1 (chi-square
    // with 54 degrees of freedom lies in [0.6, 1.5] x 54 with >99% probability).
    let mean_z2 = sum_z2.iter().sum::<f64>() / (9 * runs) as f64;
    println!("mean squared z-score over {runs} runs x 9 parameters: {mean_z2:.3}");
    assert!((0.5..1.6).contains(&mean_z2), "mean z^2 {mean_z2}");
}

#[test]
fn five_percent_gross_outliers_are_rejected() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    let sigma = 0.2;
    let s = scene(&t, 7, 15, (20.0, 60.0), sigma, 0.05);
    let (c, ms) = timed(&s.views, &opts);
    let c = c.unwrap();
    report("default rig, 15 views, noise 0.2 px, 5% gross outliers 3-30 px", &t, &c, sigma, ms);
    assert_consistent("outliers", &t, &c);
    let (mut caught, mut total, mut false_rej) = (0, 0, 0);
    for (tru, inl) in s.outliers.iter().zip(&c.inliers) {
        for (&o, &i) in tru.iter().zip(inl) {
            total += o as usize;
            caught += (o && !i) as usize;
            false_rej += (!o && !i) as usize;
        }
    }
    println!("  outliers: {caught} of {total} rejected, {false_rej} good points rejected");
    assert!(total > 50);
    assert_eq!(caught, total, "every gross (>= 3 px = 15 sigma) outlier is rejected");
    assert!(false_rej <= 3, "{false_rej} good points rejected");
    assert!((c.sigma0 / sigma - 1.0).abs() < 0.1, "sigma0 {}", c.sigma0);
}

#[test]
fn per_point_sigmas_weight_the_fit_and_make_sigma0_one() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    // Start noise-free, then give each point its own noise level and say so.
    let mut s = scene(&t, 11, 12, (20.0, 60.0), 0.0, 0.0);
    for v in &mut s.views {
        for p in &mut v.points {
            let sd = rng.gen_range(0.05..0.5);
            let n = Normal::new(0.0, sd).unwrap();
            p.pixel += nalgebra::Vector2::new(n.sample(&mut rng), n.sample(&mut rng));
            p.sigma_px = Some(sd);
        }
    }
    let c = calibrate(&s.views, &opts).unwrap();
    report("default rig, 12 views, per-point noise 0.05-0.5 px, weighted", &t, &c, 0.3, 0.0);
    assert_consistent("weighted", &t, &c);
    assert!((c.sigma0 - 1.0).abs() < 0.1, "sigma0 {} should be ~1 with correct sigmas", c.sigma0);
}

#[test]
fn degenerate_inputs_fail_naming_what_is_missing() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    let s = scene(&t, 5, 6, (20.0, 60.0), 0.2, 0.0);

    let e = calibrate(&s.views[..2], &opts).unwrap_err();
    assert_eq!(e, CalibError::TooFewViews { got: 2, need: 3 });
    assert!(e.to_string().contains("at least 3 views"), "{e}");

    let mut few = s.views.clone();
    few[1].points.truncate(5);
    let e = calibrate(&few, &opts).unwrap_err();
    assert_eq!(e, CalibError::TooFewPoints { view: 1, got: 5, need: 6 });
    assert!(e.to_string().contains("view 1 has 5"), "{e}");

    let mut line = s.views.clone();
    for (k, p) in line[2].points.iter_mut().enumerate() {
        p.target = Point2::new(0.01 * k as f64, 0.02 * k as f64);
    }
    let e = calibrate(&line, &opts).unwrap_err();
    assert!(matches!(e, CalibError::CollinearTarget { view: 2, .. }), "{e}");
    assert!(e.to_string().contains("collinear"), "{e}");

    let mut nan = s.views.clone();
    nan[0].points[3].sigma_px = Some(0.0);
    let e = calibrate(&nan, &opts).unwrap_err();
    assert!(matches!(e, CalibError::BadInput { view: 0, point: 3, .. }), "{e}");

    // All views parallel to the image plane (only in-plane rotation and position vary).
    let flat = scene(&t, 6, 10, (0.0, 0.0), 0.2, 0.0);
    let e = calibrate(&flat.views, &opts).unwrap_err();
    assert!(matches!(e, CalibError::ParallelViews { tilted: 0, views: 10, need: 2, .. }), "{e}");
    assert!(e.to_string().contains("parallel to the image plane"), "{e}");

    // One tilted view among parallel ones is still not enough.
    let mut one = flat.views.clone();
    one[0] = s.views[0].clone();
    let e = calibrate(&one, &opts).unwrap_err();
    assert!(matches!(e, CalibError::ParallelViews { tilted: 1, .. }), "{e}");
}

#[test]
fn stored_file_round_trips_and_feeds_the_rig_config() {
    let t = truth();
    let opts = Options::new(t.width, t.height);
    let s = scene(&t, 9, 12, (20.0, 60.0), 0.2, 0.0);
    let c = calibrate(&s.views, &opts).unwrap();
    let f = CalibrationFile::from_calibration(&c, "test: seed 9, 12 views");
    let text = f.to_toml();
    let back = CalibrationFile::from_toml(&text, "memory").unwrap();
    assert_eq!(back, f, "{text}");
    // The camera table takes over the rig config's geometric fields and validates.
    let mut cfg = rig();
    cfg.camera = back.apply_to(&cfg.camera);
    cfg.validate().unwrap();
    let m = cfg.camera.to_model().unwrap();
    assert_eq!((m.fx, m.cy, m.distortion), (c.camera.fx, c.camera.cy, c.camera.distortion));
    // Unknown fields and other versions are refused.
    let bad = text.replace("[fit]", "[fit]\nextra = 1");
    assert!(CalibrationFile::from_toml(&bad, "bad.toml").unwrap_err().to_string().contains("bad.toml"));
    let v2 = text.replace("format_version = 1", "format_version = 2");
    assert!(CalibrationFile::from_toml(&v2, "v2.toml").unwrap_err().to_string().contains("format_version 2"));
}

#[test]
fn shipped_calibration_of_the_simulated_rig_matches_its_truth() {
    let t = truth();
    let f = CalibrationFile::from_toml(
        include_str!("../../../calibration/bonn-gonio-sim-geometry.toml"),
        "calibration/bonn-gonio-sim-geometry.toml",
    )
    .unwrap();
    let m = f.apply_to(&rig().camera).to_model().unwrap();
    // Within 4 of its own stated uncertainties, and imaging like the truth up to a rotation.
    let u = &f.uncertainty;
    assert!((m.fx - t.fx).abs() < 4.0 * u.fx_px && (m.fy - t.fy).abs() < 4.0 * u.fy_px);
    assert!((m.cx - t.cx).abs() < 4.0 * u.cx_px && (m.cy - t.cy).abs() < 4.0 * u.cy_px);
    let (d, _) = mapping_difference_up_to_rotation(&t, &m, 41);
    assert!(d < 1.0, "{d} px");
}
