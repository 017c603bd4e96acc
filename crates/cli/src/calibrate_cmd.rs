//! `btfrig calibrate geometry`: runs a geometric calibration plan on the rig through its
//! devices (`btfrig_measurement::geometric_calibration`: the robot presents the board, the
//! camera captures) and writes the calibration file. A simulated rig's truth probe adds the
//! error figures.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_calibrate::CalibrationPlan;
use btfrig_intrinsics::{distortion_difference, mapping_difference_up_to_rotation, CalibrationFile};
use btfrig_measurement::backend::RigTime;
use btfrig_measurement::geometric_calibration::calibrate_geometry;

use crate::args::CalibrateGeometryArgs;

/// Runs the command; prints the estimates with their uncertainty (and, on a simulated rig,
/// against the truth) and writes the file.
pub fn geometry(a: &CalibrateGeometryArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = a.rig.as_ref().map_or("<embedded bonn-gonio-sim>".to_string(), |p| p.display().to_string());
    let (plan, plan_name) = match &a.plan {
        None => (CalibrationPlan::default_plan(), "<embedded rig-configs/plans/calibration-geometry.toml>".to_string()),
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("cannot read calibration plan {}", p.display()))?;
            (CalibrationPlan::from_toml(&text, &p.display().to_string())?, p.display().to_string())
        }
    };
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let b = &plan.target;
    println!(
        "calibrate geometry: rig {} ({rig_name}), plan {} ({plan_name}): {} views, board {n} x {n} markers of {:.0} mm \
         on a {:.0} mm pitch ({}), seed {seed}",
        cfg.rig.name,
        plan.name,
        plan.views().len(),
        b.marker_size_m * 1e3,
        b.pitch_m * 1e3,
        b.dictionary,
        n = b.markers_per_side,
    );
    let command = format!("btfrig calibrate geometry --rig {rig_name} --plan {plan_name} --seed {seed}");
    let time = RigTime::for_rig(&cfg);
    let cal = calibrate_geometry(&cfg, None, &plan, seed, time, |line| println!("  {line}"))
        .context("geometric calibration failed")?;
    let r = &cal.result;
    let c = &r.calibration;
    let (e, u) = (&c.camera, &c.uncertainty);
    let Some(t) = cal.truth.as_ref() else {
        println!("{:<6} {:>14} {:>12}", "param", "estimate", "sigma");
        for (name, est, sd) in [
            ("fx_px", e.fx, u.fx_px),
            ("fy_px", e.fy, u.fy_px),
            ("cx_px", e.cx, u.cx_px),
            ("cy_px", e.cy, u.cy_px),
            ("k1", e.distortion.k1, u.k1),
            ("k2", e.distortion.k2, u.k2),
            ("k3", e.distortion.k3, u.k3),
            ("p1", e.distortion.p1, u.p1),
            ("p2", e.distortion.p2, u.p2),
        ] {
            println!("{name:<6} {est:>14.6} {:>12}", format!("± {sd:.6}"));
        }
        return finish(a, &cfg, &plan, &command, &cal, t0);
    };
    println!("{:<6} {:>14} {:>12} {:>14} {:>12}", "param", "estimate", "sigma", "truth", "error");
    let rows: [(&str, f64, f64, f64); 9] = [
        ("fx_px", e.fx, u.fx_px, t.fx),
        ("fy_px", e.fy, u.fy_px, t.fy),
        ("cx_px", e.cx, u.cx_px, t.cx),
        ("cy_px", e.cy, u.cy_px, t.cy),
        ("k1", e.distortion.k1, u.k1, t.distortion.k1),
        ("k2", e.distortion.k2, u.k2, t.distortion.k2),
        ("k3", e.distortion.k3, u.k3, t.distortion.k3),
        ("p1", e.distortion.p1, u.p1, t.distortion.p1),
        ("p2", e.distortion.p2, u.p2, t.distortion.p2),
    ];
    for (name, est, sd, truth) in rows {
        println!("{name:<6} {est:>14.6} {:>12} {truth:>14.6} {:>+12.6}", format!("± {sd:.6}"), est - truth);
    }
    let (rot_px, rot_rad) = mapping_difference_up_to_rotation(t, e, 81);
    println!(
        "focal length error {:+.4}% / {:+.4}% (fx / fy), principal point error {:.3} px, distortion difference \
         (max displacement over the image) {:.4} px, mapping difference up to a rotation of {:.1e} rad {:.4} px",
        (e.fx / t.fx - 1.0) * 100.0,
        (e.fy / t.fy - 1.0) * 100.0,
        (e.cx - t.cx).hypot(e.cy - t.cy),
        distortion_difference(t, e, 81),
        rot_rad,
        rot_px,
    );
    finish(a, &cfg, &plan, &command, &cal, t0)
}

/// The figures every rig prints, and the file.
fn finish(
    a: &CalibrateGeometryArgs,
    cfg: &btfrig_core::config::RigConfig,
    plan: &CalibrationPlan,
    command: &str,
    cal: &btfrig_measurement::geometric_calibration::GeometricCalibration,
    t0: Instant,
) -> anyhow::Result<()> {
    let r = &cal.result;
    let c = &r.calibration;
    let b = &plan.target;
    let skipped: Vec<String> = r
        .captures
        .iter()
        .enumerate()
        .filter_map(|(i, cap)| cap.skipped.as_ref().map(|s| format!("view {i}: {s}")))
        .collect();
    println!(
        "RMS reprojection error {:.4} px (sigma0 {:.3}); views used {} of {}, corners detected {}, used {}, rejected {}{}",
        c.rms_px,
        c.sigma0,
        r.views_used(),
        r.captures.len(),
        r.points_detected,
        c.points_used,
        c.outliers,
        if skipped.is_empty() { String::new() } else { format!(" (skipped: {})", skipped.join("; ")) }
    );
    let source = format!(
        "{command}: rig {} through its devices ({}), board {n} x {n} markers {:.0} mm pitch {:.0} mm, {} of {} views \
         at {:.4} s, {} detection passes",
        cfg.rig.name,
        cal.devices,
        b.marker_size_m * 1e3,
        b.pitch_m * 1e3,
        r.views_used(),
        r.captures.len(),
        cal.exposure_s,
        r.passes,
        n = b.markers_per_side,
    );
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-geometry.toml", cfg.rig.name)));
    // The header names the command that made the file.
    std::fs::write(&out, format!("# Made by: {command}\n{}", CalibrationFile::from_calibration(c, &source).to_toml()))
        .with_context(|| format!("cannot write calibration file {}", out.display()))?;
    println!(
        "time: capture {:.1} s, detect {:.1} s, calibrate {:.2} s, total {:.1} s",
        r.render_s,
        r.detect_s,
        r.calibrate_s,
        t0.elapsed().as_secs_f64()
    );
    println!("wrote {}", out.display());
    Ok(())
}
