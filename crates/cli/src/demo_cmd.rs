//! `btfrig demo`: the default measurement plan (embedded, no files needed) run end to end
//! on the simulated gonioreflectometer into a new dataset directory, then a summary.

use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use btfrig_measurement::RunRequest;

use crate::args::DemoArgs;

/// The quick demo plan.
const DEMO_PLAN: &str = include_str!("../../../rig-configs/plans/demo.toml");
/// The whole Bonn 81 x 81 plan (`--full`).
const FULL_PLAN: &str = include_str!("../../../rig-configs/plans/bonn-full.toml");

/// The LED dome demo plan (`--rig dome`).
const DOME_PLAN: &str = include_str!("../../../rig-configs/plans/dome-demo.toml");
/// The camera array demo plan (`--rig camera-array`).
const CAMERA_ARRAY_PLAN: &str = include_str!("../../../rig-configs/plans/camera-array-demo.toml");

/// Runs the demo.
pub fn run(a: &DemoArgs) -> anyhow::Result<ExitCode> {
    match crate::rig::load(a.rig.as_deref())?.rig.kind {
        btfrig_core::config::RigKind::LedDome => return run_dome(a, DomeDemo::LED_DOME),
        btfrig_core::config::RigKind::CameraArray => return run_dome(a, DomeDemo::CAMERA_ARRAY),
        btfrig_core::config::RigKind::Gonioreflectometer => {}
    }
    let (name, text) = if a.full { ("bonn-full", FULL_PLAN) } else { ("demo", DEMO_PLAN) };
    let cwd = std::env::current_dir().context("the working directory")?;
    let text = with_overrides(text, a.rig.as_deref(), a.material.as_deref(), &cwd)?;
    let out = crate::captures_cmd::prepare_output(a.out.clone(), "btfrig-demo")?;
    // Relative paths (--rig, --material files) are made absolute above; the plan "file" is
    // only a name for messages.
    // The demo shows what registration gains: each registered frame is also rectified with
    // the nominal pose and compared with the truth.
    let req = RunRequest::from_text(text, &cwd.join(format!("<embedded rig-configs/plans/{name}.toml>")), &out)
        .with_nominal_comparison(true)
        // The lamp's power and colour from the rig's light calibration file ([lamp]
        // calibration, as a run loads it), its drift corrected per frame (docs/light.md).
        .with_light(demo_lamp(a.rig.as_deref())?);
    // The default model (FMF) is built while the demo captures (docs/compression.md).
    let req = req.with_compressed_model(Some(btfrig_core::plan::CompressedModel::Fmf));
    let s = crate::run_cmd::execute(&req)?;
    if let Some(btfrig_measurement::sinks::CompressionOutcome::Failed(e)) = &s.compression {
        anyhow::bail!("the demo's compressed model was not built: {e}");
    }
    if a.json {
        // With the model's figures (`RunSummary::to_json`): `peak_rss_mib` is the whole
        // process's, read after the model is written; `run_peak_rss_mib` the capture's.
        println!("{}", s.to_json());
    } else {
        let skipped: Vec<String> = s.skipped.iter().map(|(r, n)| format!("{n} {r}")).collect();
        let stages: Vec<String> = s.stage_s.iter().map(|(k, v)| format!("{k} {v:.2} s")).collect();
        let on =
            a.rig.as_ref().map_or("the simulated gonioreflectometer".to_string(), |r| format!("rig {}", r.display()));
        println!("btfrig demo: plan {name:?} on {on}");
        println!("  captures          {} of {} planned", s.captures, s.planned_captures);
        println!("  skipped           {}", if skipped.is_empty() { "none".into() } else { skipped.join(", ") });
        println!(
            "  rig time          {:.1} s (planner's lower bound {:.1} s; naive nested-loop order {:.1} s)",
            s.hardware_s, s.critical_path_s, s.naive_order_hardware_s
        );
        println!("  wall time         {:.1} s", s.wall_s);
        if let Some(m) = s.peak_rss_mib {
            println!("  peak memory       {m:.0} MiB");
        }
        println!("  stages            {}", stages.join(", "));
        let f4 = |v: Option<f64>| v.map(|r| format!("{r:.4}")).unwrap_or_else(|| "n/a".into());
        println!(
            "  texture error     {} (nominal pose {}): relative RMSE of the rectified textures against ground truth",
            f4(s.texture_rel_rmse),
            f4(s.texture_rel_rmse_nominal)
        );
        println!(
            "  registration      {} registered, {} fallbacks; texel position error mean {} / max {} texel (nominal pose {} / {})",
            s.registered,
            s.fallbacks,
            f4(s.registration_mean_texel_err),
            f4(s.registration_max_texel_err),
            f4(s.nominal_mean_texel_err),
            f4(s.nominal_max_texel_err)
        );
        if let Some((lo, hi)) = s.lamp.as_ref().and_then(|l| l.factor_range()) {
            println!("  lamp factor       {lo:.4} .. {hi:.4}: lamp output against the light calibration, measured on the plate per frame and divided out");
        }
        if let Some(btfrig_measurement::sinks::CompressionOutcome::Built { figures, .. }) = &s.compression {
            crate::compress_cmd::print_streaming(figures);
        }
        println!("  retries           {}, warnings {}", s.retries, s.warnings.len());
        println!("  dataset           {}", s.dataset.display());
        println!("check it with: btfrig dataset verify {}", s.dataset.display());
    }
    // The demo's plan is embedded and its directory is new each time: starting it again is
    // the way to get a complete demo dataset.
    Ok(crate::run_cmd::finish(&s, "btfrig demo"))
}

/// The plan text with `rig.config` and `rig.material` replaced (files made absolute); also
/// `btfrig run --rig`.
pub(crate) fn with_overrides(
    text: &str,
    rig: Option<&Path>,
    material: Option<&str>,
    cwd: &Path,
) -> anyhow::Result<String> {
    if rig.is_none() && material.is_none() {
        return Ok(text.to_string());
    }
    let mut doc: toml::Table = text.parse().context("the embedded plan")?;
    let section = doc.entry("rig").or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let section = section.as_table_mut().context("the embedded plan's [rig]")?;
    if let Some(r) = rig {
        let config = match crate::rig::builtin(r) {
            Some(name) => name.to_string(),
            None => cwd.join(r).display().to_string(),
        };
        section.insert("config".into(), toml::Value::String(config));
    }
    if let Some(m) = material {
        let m = if m.ends_with(".toml") { cwd.join(m).display().to_string() } else { m.to_string() };
        section.insert("material".into(), toml::Value::String(m));
    }
    Ok(doc.to_string())
}

/// Which dome demo: its plan and how it is named.
struct DomeDemo {
    plan: &'static str,
    name: &'static str,
    rig: &'static str,
}

impl DomeDemo {
    const LED_DOME: DomeDemo = DomeDemo { plan: DOME_PLAN, name: "dome-demo", rig: "LED dome" };
    const CAMERA_ARRAY: DomeDemo = DomeDemo { plan: CAMERA_ARRAY_PLAN, name: "camera-array-demo", rig: "camera array" };
}

/// `btfrig demo --rig dome` / `--rig camera-array`: the dome demo plan on the simulated LED
/// dome, or the camera array demo plan on the simulated camera array (docs/multiplexing.md).
fn run_dome(a: &DemoArgs, demo: DomeDemo) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(!a.full, "--full is the gonioreflectometer's 81 x 81 plan; the {} demo has no --full", demo.rig);
    let cwd = std::env::current_dir().context("the working directory")?;
    let text = with_overrides(demo.plan, a.rig.as_deref(), a.material.as_deref(), &cwd)?;
    let out = crate::captures_cmd::prepare_output(a.out.clone(), &format!("btfrig-{}", demo.name))?;
    let req = btfrig_measurement::dome::DomeRunRequest {
        plan_text: text,
        plan_path: cwd.join(format!("<embedded rig-configs/plans/{}.toml>", demo.name)),
        out,
        faults: None,
        preview: false,
        // The default model (FMF) is built while the demo captures, as the gonio demo's
        // (docs/compression.md).
        compressed_model: Some(btfrig_core::plan::CompressedModel::Fmf),
    };
    let json = a.json;
    let s = btfrig_measurement::dome::run(&req, &mut |line| {
        if !json {
            println!("{line}");
        }
    })?;
    if let Some(btfrig_measurement::sinks::CompressionOutcome::Failed(e)) = &s.compression {
        anyhow::bail!("the demo's compressed model was not built: {e}");
    }
    if json {
        println!("{}", s.to_json());
        return Ok(ExitCode::SUCCESS);
    }
    println!("btfrig demo: plan {:?} on the simulated {}", demo.name, demo.rig);
    crate::run_cmd::print_dome_summary(&s);
    if let Some(btfrig_measurement::sinks::CompressionOutcome::Built { figures, .. }) = &s.compression {
        crate::compress_cmd::print_streaming(figures);
    }
    Ok(ExitCode::SUCCESS)
}

/// The lamp correction of a gonioreflectometer demo: the light calibration file the rig config
/// names (`[lamp] calibration`), drift correction on, as `btfrig run --light FILE` with that
/// file. Without one the run processes in relative units, as `btfrig run` does.
fn demo_lamp(rig: Option<&std::path::Path>) -> anyhow::Result<Option<btfrig_process::light::LightCorrection>> {
    let cfg = crate::rig::load(rig)?;
    let rig_path = rig.filter(|p| crate::rig::builtin(p).is_none());
    let lamp = btfrig_measurement::model::config_lamp_correction(&cfg, rig_path)?;
    if lamp.is_none() {
        eprintln!(
            "btfrig demo: rig {} names no light calibration ([lamp] calibration): relative units (make one with \
             `btfrig calibrate light`)",
            cfg.rig.name
        );
    }
    Ok(lamp.map(|(correction, _)| correction))
}
