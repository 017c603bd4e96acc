//! Issue 4 acceptance, geometric calibration: the default calibration plan on the simulated
//! default rig (rendered board frames with the rig's seeded sensor noise, marker detection,
//! calibration) against the rig's true camera.

use std::time::Instant;

use btfrig_calibrate::CalibrationPlan;
use btfrig_core::config::RigConfig;
use btfrig_intrinsics::{distortion_difference, mapping_difference_up_to_rotation};
use btfrig_sim_calibration::calibrate_simulated;

#[test]
fn default_plan_on_the_simulated_rig_recovers_the_true_camera() {
    let cfg =
        RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap();
    // The default plan with the renderer's edge supersampling at 4 instead of 8: a third of
    // the render time, to keep the test near a minute. With 8 the principal point meets the
    // issue's 0.5 px (docs/camera-calibration.md); with 4 it does not in x (see below).
    let plan = CalibrationPlan { marker_supersampling: 4, ..CalibrationPlan::default_plan() };
    let t0 = Instant::now();
    let sim = calibrate_simulated(&cfg, &plan, cfg.rig.seed, |s| println!("{s}")).unwrap();
    let (r, t) = (&sim.result, &sim.truth);
    let c = &r.calibration;
    let e = &c.camera;
    let u = &c.uncertainty;
    let (fx_rel, fy_rel) = (e.fx / t.fx - 1.0, e.fy / t.fy - 1.0);
    let (dcx, dcy) = (e.cx - t.cx, e.cy - t.cy);
    let dist = distortion_difference(t, e, 81);
    let (rot_px, _) = mapping_difference_up_to_rotation(t, e, 81);
    println!(
        "{} views, {} corners ({} rejected): fx {:+.4}% fy {:+.4}% (sd {:.3} / {:.3} px), cx {dcx:+.3} cy {dcy:+.3} px \
         (sd {:.3} / {:.3}), distortion difference {dist:.4} px, mapping up to rotation {rot_px:.4} px, rms {:.4} px, \
         sigma0 {:.3}; render {:.1} s, detect {:.1} s, total {:.1} s",
        r.views_used(),
        c.points_used,
        c.outliers,
        fx_rel * 100.0,
        fy_rel * 100.0,
        u.fx_px,
        u.fy_px,
        u.cx_px,
        u.cy_px,
        c.rms_px,
        c.sigma0,
        r.render_s,
        r.detect_s,
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(r.views_used(), plan.views().len(), "every planned view is used");
    assert!(c.points_used > 8000, "{}", c.points_used);
    // Issue bounds that hold with margin: focal length within 0.1 %, distortion within 0.1 px.
    assert!(fx_rel.abs() < 0.001 && fy_rel.abs() < 0.001, "focal length {fx_rel} {fy_rel}");
    assert!(dist < 0.1, "distortion difference {dist} px");
    // RMS reported and plausible for the detector's ~0.01 px corners (norm of both axes).
    assert!(c.rms_px > 0.005 && c.rms_px < 0.12, "rms {}", c.rms_px);
    // Principal point: the 0.5 px. With the detector's edge model on the green
    // photosites (corners ~0.01 px) this holds even at supersampling 4: measured at the rig's
    // seed cx -0.037, cy -0.082 px (sd 0.060 / 0.036). (With the earlier scanline detector it
    // was -0.57 px in x: docs/camera-calibration.md.)
    assert!(dcx.abs() < 0.5 && dcy.abs() < 0.5, "principal point error ({dcx}, {dcy}) px");
    assert!(dcx.abs() < (4.0 * u.cx_px).max(0.1) && dcy.abs() < (4.0 * u.cy_px).max(0.1), "beyond 4 sigma");
    // The camera images the scene as the truth does, up to the free rotation.
    assert!(rot_px < 0.1, "mapping up to rotation {rot_px}");
}
