//! `btfrig calibrate color`: runs a colour calibration plan on the rig through its devices
//! (`btfrig_measurement::color_calibration`), prints every model's held-out CIEDE2000 and fit
//! time, writes the chosen model's calibration file. The numerics are in
//! `btfrig_calibrate::color`; the reference values are the charts' published ones or measured
//! files (`--reference`), and the file says which.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use btfrig_calibrate::color::{describe_status, ColorPlan, ReferenceValues};
use btfrig_calibrate::processing_camera;
use btfrig_measurement::backend::RigTime;
use btfrig_measurement::color_calibration::{calibrate_color_on_rig, chart_references};
use serde_json::json;

use crate::args::CalibrateColorArgs;

/// Runs the command.
pub fn color(a: &CalibrateColorArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(a.rig.as_deref())?;
    let rig_name = a.rig.as_ref().map_or("<embedded bonn-gonio-sim>".to_string(), |p| p.display().to_string());
    let (plan, plan_name) = match &a.plan {
        None => (ColorPlan::default_plan(), "<embedded rig-configs/plans/calibration-color.toml>".to_string()),
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read colour calibration plan {}", p.display()))?;
            (ColorPlan::from_toml(&text, &p.display().to_string())?, p.display().to_string())
        }
    };
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let camera = processing_camera(&cfg, a.rig.as_deref()).context("processing camera")?;
    let quiet = a.json;
    if !quiet {
        let charts: Vec<String> =
            plan.charts.iter().map(|c| format!("{} (hold out every {})", c.name, c.hold_out_every)).collect();
        println!(
            "calibrate color: rig {} ({rig_name}), plan {} ({plan_name}), charts {}, view ({}, {}) deg, lamp ({}, {}) \
             deg, seed {seed}",
            cfg.rig.name,
            plan.name,
            charts.join(", "),
            plan.view_theta_deg,
            plan.view_phi_deg,
            plan.light_theta_deg,
            plan.light_phi_deg
        );
    }
    let mut values = vec![ReferenceValues::Published; plan.charts.len()];
    for r in &a.reference {
        let Some((chart, file)) = r.split_once('=') else {
            bail!("--reference {r:?}: allowed CHART=FILE (a chart of the plan and a CSV of its L, a, b values)");
        };
        let Some(i) = plan.charts.iter().position(|c| c.name == chart) else {
            let names: Vec<&str> = plan.charts.iter().map(|c| c.name.as_str()).collect();
            bail!("--reference {r:?}: the plan has no chart {chart:?} (its charts: {})", names.join(", "));
        };
        let text = std::fs::read_to_string(file).with_context(|| format!("--reference {r:?}: cannot read {file}"))?;
        values[i] = ReferenceValues::measured_from_csv(&text, file, chart)?;
    }
    let references = chart_references(&cfg, a.rig.as_deref(), &plan, &values)?;
    let r = calibrate_color_on_rig(&cfg, None, &camera, &plan, &references, seed, RigTime::for_rig(&cfg), |line| {
        if !quiet {
            println!("  {line}")
        }
    })
    .context("colour calibration failed")?;
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-color.toml", cfg.rig.name)));
    let file = r.file(&cfg.rig.name, &plan, seed);
    let command = format!(
        "btfrig calibrate color --rig {rig_name} --plan {plan_name} --seed {seed}{}",
        a.reference.iter().map(|r| format!(" --reference {r}")).collect::<String>()
    );
    std::fs::write(&out, format!("# Made by: {command}\n{}", file.to_toml()))
        .with_context(|| format!("cannot write calibration file {}", out.display()))?;
    let chosen = r.chosen();
    if a.json {
        let models: Vec<_> = r
            .models
            .iter()
            .map(|m| {
                json!({
                    "model": m.kind.name(),
                    "cv_mean": m.cv.as_ref().ok().map(|s| s.mean),
                    "held_out": m.held_out.as_ref().ok().map(|s| json!({
                        "mean": s.mean, "median": s.median, "p95": s.p95, "max": s.max })),
                    "fit_ms": m.fit_s * 1e3,
                    "apply_ms_per_mpix": m.apply_s_per_mpix * 1e3,
                    "error": m.model.as_ref().err().or(m.cv.as_ref().err()).map(|e| e.to_string()),
                })
            })
            .collect();
        let held: Vec<_> = r.patches.iter().filter(|p| !p.fit && p.status.is_valid()).collect();
        let per_patch: Vec<_> = match chosen.held_out.as_ref() {
            Ok(s) => held
                .iter()
                .zip(&s.per_patch)
                .map(|(p, de)| json!({ "chart": p.chart, "patch": p.name, "delta_e00": de }))
                .collect(),
            Err(_) => Vec::new(),
        };
        let excluded: Vec<_> = r
            .patches
            .iter()
            .filter(|p| !p.status.is_valid())
            .map(|p| json!({ "chart": p.chart, "patch": p.name, "reason": describe_status(&p.status) }))
            .collect();
        let v = json!({
            "rig": cfg.rig.name, "plan": plan.name, "seed": seed,
            "chosen": chosen.kind.name(),
            "exposure_s": r.exposure_s,
            "white_balance": r.white_balance,
            "fit_patches": r.patches.iter().filter(|p| p.fit && p.status.is_valid()).count(),
            "held_out_patches": held.len(),
            "models": models,
            "held_out_per_patch": per_patch,
            "excluded": excluded,
            "references": r.references,
            "out": out.display().to_string(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("reference values: {}", r.references.join("; "));
    let fit_n = r.patches.iter().filter(|p| p.fit && p.status.is_valid()).count();
    let held_n = r.patches.iter().filter(|p| !p.fit && p.status.is_valid()).count();
    println!("CIEDE2000 on {held_n} held-out patches (not fitted), cross-validated mean on {fit_n} fitting patches:");
    println!(
        "{:<10} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9} {:>12}",
        "model", "cv mean", "mean", "median", "p95", "max", "fit ms", "apply ms/MP"
    );
    for m in &r.models {
        let mark = if m.kind == chosen.kind { "*" } else { " " };
        match (&m.cv, &m.held_out) {
            (Ok(cv), Ok(s)) => println!(
                "{:<9}{mark} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>9.3} {:>12.2}",
                m.kind.name(),
                cv.mean,
                s.mean,
                s.median,
                s.p95,
                s.max,
                m.fit_s * 1e3,
                m.apply_s_per_mpix * 1e3
            ),
            (cv, s) => {
                let why = cv.as_ref().err().or(s.as_ref().err()).map(|e| e.to_string()).unwrap_or_default();
                println!("{:<9}{mark} failed: {why}", m.kind.name());
            }
        }
    }
    if let Ok(s) = chosen.held_out.as_ref() {
        println!(
            "chosen: {} (lowest cross-validated mean); held-out mean {:.3}, median {:.3}, p95 {:.3}, max {:.3} dE00",
            chosen.kind.name(),
            s.mean,
            s.median,
            s.p95,
            s.max
        );
        let held: Vec<_> = r.patches.iter().filter(|p| !p.fit && p.status.is_valid()).collect();
        let mut worst: Vec<(f64, String)> =
            held.iter().zip(&s.per_patch).map(|(p, de)| (*de, format!("{} {}", p.chart, p.name))).collect();
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        let w: Vec<String> = worst.iter().take(5).map(|(d, n)| format!("{n} {d:.2}")).collect();
        println!("worst held-out patches: {}", w.join(", "));
    }
    println!(
        "white balance [{:.4}, {:.4}, {:.4}], exposure {:.4} s; time: capture {:.1} s, measure {:.1} s, total {:.1} s",
        r.white_balance[0],
        r.white_balance[1],
        r.white_balance[2],
        r.exposure_s,
        r.render_s,
        r.measure_s,
        t0.elapsed().as_secs_f64()
    );
    println!("wrote {}", out.display());
    Ok(())
}
