//! `btfrig calibrate sensor`: the sensor's characterisation after EMVA 1288, captured through
//! the devices (`btfrig_measurement::captured_calibration::capture_sensor`: a uniform field at
//! rising exposure, then the lens capped), fitted by `btfrig_calibrate::emva`; prints each
//! figure with its uncertainty (on a simulated rig next to the configured truth,
//! `btfrig_sim_calibration::sensor::emva_truth`) and writes the file (docs/emva1288.md).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_calibrate::emva::{SensorCalibrationFile, SensorPlan, SENSOR_FORMAT_VERSION};
use btfrig_measurement::captured_calibration::{capture_sensor, CalibrationSession};
use btfrig_sim_calibration::sensor::emva_truth;

/// `btfrig calibrate sensor`.
#[derive(Debug, clap::Args)]
pub struct CalibrateSensorArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Sensor plan file (default: the embedded rig-configs/plans/calibration-sensor.toml).
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Calibration file to write (default: `<rig name>-sensor.toml` in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The dome's or camera array's camera (arc position) to characterise.
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the command.
pub fn sensor(a: &CalibrateSensorArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = crate::rig::display_name(a.rig.as_deref());
    let (plan, plan_name) = crate::rig::plan_or_default(
        a.plan.as_deref(),
        "sensor plan",
        SensorPlan::default_plan,
        "<embedded rig-configs/plans/calibration-sensor.toml>",
        SensorPlan::from_toml,
    )?;
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let json = a.json;
    let session = CalibrationSession::installed(&cfg, seed);
    let cap = capture_sensor(&session, &plan, a.camera, |line| {
        if !json {
            println!("  {line}");
        }
    })
    .context("sensor characterisation failed")?;
    let source = format!(
        "btfrig calibrate sensor --rig {rig_name} --plan {plan_name} --camera {} --seed {seed}: rig {}, {} frames \
         captured through the devices",
        a.camera, cfg.rig.name, cap.frames
    );
    let file = SensorCalibrationFile {
        format_version: SENSOR_FORMAT_VERSION,
        source,
        plan: plan.name.clone(),
        gain: plan.gain,
        result: cap.result.clone(),
    };
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-sensor.toml", cfg.rig.name)));
    std::fs::write(&out, file.to_toml())
        .with_context(|| format!("cannot write sensor calibration {}", out.display()))?;
    let truth =
        if crate::rig::all_simulated(&cfg) { Some(emva_truth(&cfg, &plan).map_err(anyhow::Error::msg)?) } else { None };
    let r = &cap.result;
    let rows = [
        ("system gain K, DN/e-", r.system_gain_dn_per_e, truth.as_ref().map(|t| t.system_gain_dn_per_e)),
        ("read noise, e-", r.read_noise_e, truth.as_ref().map(|t| t.read_noise_e)),
        ("dark current, e-/s", r.dark_current_e_per_s, truth.as_ref().map(|t| t.dark_current_e_per_s)),
        ("DSNU, e-", r.dsnu_e, truth.as_ref().map(|t| t.dsnu_e)),
        ("PRNU, %", r.prnu_pct, truth.as_ref().map(|t| t.prnu_pct)),
        ("saturation capacity, e-", r.saturation_capacity_e, truth.as_ref().map(|t| t.saturation_capacity_e)),
        ("linearity error, %", r.linearity_error_pct, truth.as_ref().map(|t| t.linearity_error_pct)),
    ];
    if json {
        let v = serde_json::json!({
            "rig": cfg.rig.name,
            "result": r,
            "truth": truth,
            "frames": cap.frames,
            "ptc_exposures_s": cap.ptc_exposures_s,
            "wall_s": t0.elapsed().as_secs_f64(),
            "out": out.display().to_string(),
        });
        println!("{v}");
        return Ok(());
    }
    println!(
        "sensor characterisation (EMVA 1288) of {} ({rig_name}), camera {}, gain {}, {} frames, seed {seed}:",
        cfg.rig.name, a.camera, plan.gain, cap.frames
    );
    println!("  {:<26} {:>14} {:>12} {:>14} {:>8}", "parameter", "estimate", "sigma", "truth", "|z|");
    for (name, e, t) in rows {
        match t {
            Some(t) => println!("  {name:<26} {:>14.6} {:>12.6} {t:>14.6} {:>8.2}", e.value, e.sigma, e.z(t)),
            None => println!("  {name:<26} {:>14.6} {:>12.6}", e.value, e.sigma),
        }
    }
    if let Some(t) = &truth {
        println!("  (the simulated sensor clips at {:.1} e-, 4 read-noise sigmas below its full well)", t.clip_e);
    }
    println!("  {} photon-transfer points, {} hot photosites left out of DSNU and PRNU", r.ptc_points, r.hot_pixels);
    println!("wrote {} ({:.1} s)", out.display(), t0.elapsed().as_secs_f64());
    Ok(())
}
