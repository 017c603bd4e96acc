//! `btfrig calibrate light`: runs a light calibration plan on the rig: a white reference tile
//! on the holder gives the lamp's power and colour, the plate around it its albedo relative to
//! the tile (the drift reference of every run); writes the light calibration file. The frames
//! are captured through the devices (`btfrig_measurement::captured_calibration::capture_light`),
//! measured by `btfrig_calibrate::light` (docs/light.md); on a simulated rig the truth comes
//! from `btfrig_sim_calibration::light::light_truth`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_calibrate::light::{LightCalibrationFile, LightPlan, LAMP};
use btfrig_measurement::captured_calibration::{capture_light, CalibrationSession};
use btfrig_process::light::{LampReference, LightCorrection};
use btfrig_sim_calibration::light::light_truth;

/// `btfrig calibrate light`.
#[derive(Debug, clap::Args)]
pub struct CalibrateLightArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Light calibration plan file (default: the embedded rig-configs/plans/calibration-light.toml).
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Calibration file to write (default: `<rig name>-light.toml` in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the command; prints the estimates against the truth and writes the file.
pub fn light(a: &CalibrateLightArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = crate::rig::display_name(a.rig.as_deref());
    let (plan, plan_name) = crate::rig::plan_or_default(
        a.plan.as_deref(),
        "light calibration plan",
        LightPlan::default_plan,
        "<embedded rig-configs/plans/calibration-light.toml>",
        LightPlan::from_toml,
    )?;
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let source = format!(
        "btfrig calibrate light --rig {rig_name} --plan {plan_name} --seed {seed}: rig {}, {} frames captured through \
         the devices",
        cfg.rig.name,
        plan.captures.len() * plan.repeats as usize
    );
    let session = CalibrationSession::installed(&cfg, seed);
    let file = capture_light(&session, &plan, source).context("light calibration failed")?.file;
    // The truth, for error figures: simulated rigs only (NaN otherwise).
    let (true_white_rate, true_plate_albedo) =
        if crate::rig::all_simulated(&cfg) { light_truth(&cfg)? } else { ([f64::NAN; 3], [f64::NAN; 3]) };
    let r = Truth { true_white_rate, true_plate_albedo };
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-light.toml", cfg.rig.name)));
    std::fs::write(&out, file.to_toml())
        .with_context(|| format!("cannot write light calibration {}", out.display()))?;
    let e = file.light(&plan.light).context("the calibration has the plan's light")?;
    let rel = |a: f64, b: f64| 100.0 * (a / b - 1.0);
    let twb: [f64; 3] = std::array::from_fn(|c| r.true_white_rate[1] / r.true_white_rate[c]);
    if a.json {
        let v = serde_json::json!({
            "light": plan.light,
            "frames": e.frames,
            "white_rate_e_per_s": e.white_rate_e_per_s,
            "white_rate_sigma": e.white_rate_sigma,
            "true_white_rate_e_per_s": r.true_white_rate,
            "white_rate_err_pct": (0..3).map(|c| rel(e.white_rate_e_per_s[c], r.true_white_rate[c])).collect::<Vec<_>>(),
            "white_balance": e.white_balance,
            "true_white_balance": twb,
            "plate_albedo": e.plate_albedo,
            "plate_albedo_sigma": e.plate_albedo_sigma,
            "true_plate_albedo": r.true_plate_albedo,
            "plate_albedo_err_pct": (0..3).map(|c| rel(e.plate_albedo[c], r.true_plate_albedo[c])).collect::<Vec<_>>(),
            "wall_s": t0.elapsed().as_secs_f64(),
            "out": out.display().to_string(),
        });
        println!("{v}");
        return Ok(());
    }
    println!(
        "calibrate light: rig {} ({rig_name}), plan {} ({plan_name}): light {:?}, white tile {:.0} %, {} frames, seed {seed}",
        cfg.rig.name,
        plan.name,
        plan.light,
        100.0 * plan.reference_albedo,
        e.frames
    );
    println!("{:<22} {:>14} {:>14} {:>14}", "", "R", "G", "B");
    let row = |name: &str, v: [f64; 3]| println!("{name:<22} {:>14.6} {:>14.6} {:>14.6}", v[0], v[1], v[2]);
    row("white rate e-/s", e.white_rate_e_per_s);
    row("  truth", r.true_white_rate);
    row("  error %", std::array::from_fn(|c| rel(e.white_rate_e_per_s[c], r.true_white_rate[c])));
    row("  sigma %", std::array::from_fn(|c| 100.0 * e.white_rate_sigma[c] / e.white_rate_e_per_s[c]));
    row("white balance", e.white_balance);
    row("  truth", twb);
    row("plate albedo", e.plate_albedo);
    row("  truth", r.true_plate_albedo);
    row("  error %", std::array::from_fn(|c| rel(e.plate_albedo[c], r.true_plate_albedo[c])));
    row("  sigma %", std::array::from_fn(|c| 100.0 * e.plate_albedo_sigma[c] / e.plate_albedo[c]));
    println!("time {:.1} s", t0.elapsed().as_secs_f64());
    println!("wrote {}", out.display());
    Ok(())
}

/// The simulator's truth next to a light calibration.
struct Truth {
    true_white_rate: [f64; 3],
    true_plate_albedo: [f64; 3],
}

/// The lamp's correction from the light calibration file at `path`.
pub fn load(path: &std::path::Path) -> anyhow::Result<LightCorrection> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read light calibration {}", path.display()))?;
    correction(&LightCalibrationFile::from_toml(&text, &path.display().to_string())?)
}

/// The lamp's correction from a light calibration file.
pub fn correction(file: &LightCalibrationFile) -> anyhow::Result<LightCorrection> {
    let e = file.light(LAMP).with_context(|| format!("the light calibration has no {LAMP:?} entry"))?;
    Ok(LightCorrection::new(LampReference {
        light: LAMP.into(),
        white_rate: e.white_rate_e_per_s,
        plate_albedo: e.plate_albedo,
    }))
}
