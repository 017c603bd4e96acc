//! `btfrig calibrate radiometric`: runs a dark/flat calibration plan on the rig, captured
//! through its devices (`btfrig_measurement::captured_calibration::capture_dark_flat`: lens
//! capped, then a uniform field), prints the figures (and, on a simulated rig, the errors
//! against its truth, `btfrig_sim_calibration::dark_flat::compare_with_truth`) and writes the
//! maps (`btfrig_calibrate::dark_flat`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_calibrate::dark_flat::{write_calibration, RadiometricPlan};
use btfrig_measurement::captured_calibration::{capture_dark_flat, CalibrationSession};
use btfrig_sim_calibration::dark_flat::compare_with_truth;
use clap::Args;

/// `btfrig calibrate radiometric`.
#[derive(Debug, Args)]
pub struct CalibrateRadiometricArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Plan file (default: the embedded rig-configs/plans/calibration-radiometric.toml).
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Directory to write dark.exr, dark-sigma.exr, flat-f<N>.exr and dark-flat.toml into.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// The dome's or camera array's camera (arc position) to calibrate.
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    /// Print the header, statistics and truth errors as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs the command.
pub fn run(a: &CalibrateRadiometricArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = crate::rig::display_name(a.rig.as_deref());
    let (plan, plan_name) = crate::rig::plan_or_default(
        a.plan.as_deref(),
        "plan",
        RadiometricPlan::default_plan,
        "<embedded>",
        RadiometricPlan::from_toml,
    )?;
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    if !a.json {
        println!(
            "calibrate radiometric: rig {} ({rig_name}), plan {}, {}x{} photosites, seed {seed}",
            cfg.rig.name, plan.name, cfg.camera.width_px, cfg.camera.height_px
        );
    }
    let json = a.json;
    let session = CalibrationSession::installed(&cfg, seed);
    let res = capture_dark_flat(&session, &plan, a.camera, |line| {
        if !json {
            println!("  {line}");
        }
    })
    .context("radiometric calibration failed")?;
    // Error figures against the truth: simulated rigs only.
    let truth = if crate::rig::all_simulated(&cfg) {
        Some(compare_with_truth(&cfg, &res.cal, plan.flat.centre_fraction)?)
    } else {
        None
    };
    let header = write_calibration(&a.out, &res, &cfg.rig.name, &plan, seed)
        .with_context(|| format!("cannot write the calibration into {}", a.out.display()))?;
    // The header names the command that made it.
    let header_path = a.out.join(btfrig_calibrate::dark_flat::HEADER_FILE);
    let text =
        std::fs::read_to_string(&header_path).with_context(|| format!("cannot read {}", header_path.display()))?;
    std::fs::write(
        &header_path,
        format!(
            "# Made by: btfrig calibrate radiometric --rig {rig_name} --plan {plan_name} --camera {} --seed {seed} (captured through the devices)\n{text}",
            a.camera
        ),
    )
    .with_context(|| format!("cannot write {}", header_path.display()))?;
    let elapsed = t0.elapsed().as_secs_f64();
    if a.json {
        let v = serde_json::json!({ "header": header, "truth_error": truth, "elapsed_s": elapsed });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let s = &res.stats;
    let Some(truth) = truth else {
        println!(
            "dark model: bias median {:.2} DN (stated sigma {:.3} DN rms), dark current median {:.3} e-/s (stated sigma \
             {:.3} e-/s rms), {} defects",
            s.bias_median_dn, s.bias_sigma_rms_dn, s.rate_median_e_per_s, s.rate_sigma_rms_e_per_s, s.defects
        );
        for f in &s.flats {
            println!(
                "flat f/{}: {} frames, gain {:.4}..{:.4}, stated sigma {:.4}% rms",
                f.f_number,
                f.frames,
                f.min,
                f.max,
                100.0 * f.sigma_rms
            );
        }
        println!("wrote {} ({elapsed:.1} s)", a.out.join(btfrig_calibrate::dark_flat::HEADER_FILE).display());
        return Ok(());
    };
    println!(
        "dark model: bias median {:.2} DN (stated sigma {:.3} DN rms; error vs truth {:.3} DN rms, z {:.2}), \
         dark current median {:.3} e-/s (stated sigma {:.3} e-/s rms; error vs truth {:.3} e-/s rms, z {:.2})",
        s.bias_median_dn,
        s.bias_sigma_rms_dn,
        truth.bias_rms_dn,
        truth.bias_z_rms,
        s.rate_median_e_per_s,
        s.rate_sigma_rms_e_per_s,
        truth.rate_rms_e_per_s,
        truth.rate_z_rms
    );
    println!(
        "defects: {} flagged (threshold {} e-/s); truth: {} hot, {} found, {} flagged that are not hot",
        s.defects, plan.dark.hot_threshold_e_per_s, truth.hot_true, truth.hot_found, truth.false_defects
    );
    for (k, f) in s.flats.iter().enumerate() {
        println!(
            "flat f/{}: {} frames, gain {:.4}..{:.4}, stated sigma {:.4}% rms; error vs true vignetting x PRNU \
             {:.4}% rms ({:.4}% in the corners)",
            f.f_number,
            f.frames,
            f.min,
            f.max,
            100.0 * f.sigma_rms,
            100.0 * truth.flat_rms_rel[k],
            100.0 * truth.flat_corner_rms_rel[k]
        );
    }
    println!("wrote {} ({elapsed:.1} s)", a.out.join(btfrig_calibrate::dark_flat::HEADER_FILE).display());
    Ok(())
}
