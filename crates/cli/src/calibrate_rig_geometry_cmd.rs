//! `btfrig calibrate rig-geometry`: the joints' zero offsets from the marker plate registered
//! at a few dozen poses, through the rig's devices
//! (`btfrig_measurement::rig_geometry_calibration`); prints the offsets with their
//! uncertainty, the nominal-vs-registered pose error before and after, and (simulated rig)
//! the true offsets; writes the file a rig config's `[geometry] calibration` names.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_calibrate::processing_camera;
use btfrig_calibrate::rig_geometry::{fixed_offsets, RigGeometryFile, RIG_GEOMETRY_FORMAT_VERSION};
use btfrig_measurement::backend::RigTime;
use btfrig_measurement::rig_geometry_calibration::calibrate_rig_geometry;

/// `btfrig calibrate rig-geometry`.
#[derive(Debug, clap::Args)]
pub struct CalibrateRigGeometryArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Poses to register (3..=200).
    #[arg(long, default_value_t = 36)]
    pub poses: usize,
    /// Calibration file to write (default: `<rig name>-rig-geometry.toml` in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seed of a simulated rig's noise and positioning error (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Runs the command.
pub fn rig_geometry(a: &CalibrateRigGeometryArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    if !(3..=200).contains(&a.poses) {
        anyhow::bail!("--poses {}: allowed 3..=200", a.poses);
    }
    let mut cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = a.rig.as_ref().map_or("<embedded bonn-gonio-sim>".to_string(), |p| p.display().to_string());
    // The registration starts from the nominal pose without any earlier offsets.
    cfg.geometry.calibration = None;
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let camera = processing_camera(&cfg, a.rig.as_deref()).context("processing camera")?;
    println!("calibrate rig-geometry: rig {} ({rig_name}), {} poses, seed {seed}", cfg.rig.name, a.poses);
    let r = calibrate_rig_geometry(&cfg, None, &camera, a.poses, seed, RigTime::for_rig(&cfg), |l| println!("  {l}"))
        .context("rig geometry calibration failed")?;
    let f = &r.fit;
    let truth = (!r.true_offsets.is_empty()).then(|| {
        let n = r.true_offsets.len() as f64;
        let mean =
            |g: &dyn Fn(&btfrig_core::kinematics::JointState) -> f64| r.true_offsets.iter().map(g).sum::<f64>() / n;
        let rail = mean(&|t| t.rail).to_degrees();
        // What the markers observe: pan - rail, tilt, roll + turntable.
        [
            mean(&|t| t.robot[0]).to_degrees() - rail,
            mean(&|t| t.robot[1]).to_degrees(),
            mean(&|t| t.robot[2] + t.turntable).to_degrees(),
        ]
    });
    println!("{:<22} {:>10} {:>10} {:>22}", "offset", "estimate", "sigma", "truth (mean true-cmd)");
    let names = ["pan - rail (deg)", "tilt (deg)", "roll + turntable (deg)"];
    for k in 0..3 {
        let t = truth.map_or("-".to_string(), |t| format!("{:.4}", t[k]));
        println!("{:<22} {:>10.4} {:>10.4} {:>22}", names[k], f.offsets.robot_deg[k], f.robot_sigma_deg[k], t);
    }
    for line in fixed_offsets() {
        println!("fixed: {line}");
    }
    let g = &f.figures;
    println!(
        "pose error, nominal vs registered over {} poses: RMS {:.4} deg before, {:.4} deg after ({:.1}x smaller); \
         max {:.4} -> {:.4} deg",
        g.poses,
        g.rms_before_deg,
        g.rms_after_deg,
        g.rms_before_deg / g.rms_after_deg.max(1e-12),
        g.max_before_deg,
        g.max_after_deg
    );
    if !r.skipped.is_empty() {
        println!("skipped: {}", r.skipped.join("; "));
    }
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-rig-geometry.toml", cfg.rig.name)));
    let file = RigGeometryFile {
        format_version: RIG_GEOMETRY_FORMAT_VERSION,
        source: format!(
            "btfrig calibrate rig-geometry --rig {rig_name} --poses {} --seed {seed}: rig {} through its devices \
             ({}), {} of {} poses registered at {:.4} s",
            a.poses, cfg.rig.name, r.devices, g.poses, r.poses_planned, r.exposure_s
        ),
        offsets: f.offsets,
        robot_sigma_deg: f.robot_sigma_deg,
        fixed: fixed_offsets(),
        fit: f.figures,
    };
    std::fs::write(&out, file.to_toml()).with_context(|| format!("cannot write {}", out.display()))?;
    println!("time {:.1} s; wrote {}", t0.elapsed().as_secs_f64(), out.display());
    Ok(())
}
