//! `btfrig run --plan FILE --out DIR`: a measurement plan on the simulated gonioreflectometer,
//! into a dataset, resumable. Display and wiring only; the work is in the planner, the
//! engine, the pipeline and the store.

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::{OutputFormat, Plan, ResampleFilter, ValidatedPlan, BUILTIN_FAULT_SCENARIOS, BUILTIN_RIGS};
use btfrig_engine::{Devices, Engine, EngineSettings, EngineStep, Event, PauseReason, RunOutcome, StepKey};
use btfrig_hw::TokioClock;
use btfrig_pipeline::{ProcessSettings, Processor, TruthLog};
use btfrig_planner::{plan as plan_schedule, PairSelection, PlanRequest};
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::{FaultScenario, RenderedFrameSource, SimRig};
use btfrig_store::{
    Dataset, DirectionDeg, Manifest, RigInfo, RunReport, Samplings, SkippedStep, StepId, StoreError, TextureFormat,
    TextureRegion, TextureSpec,
};

use crate::args::RunArgs;

/// Frames the engine may hold ready ahead of the pipeline (back-pressure beyond that).
const FRAME_CHANNEL: usize = 4;

/// The embedded fault scenarios, by the names plans use.
const FAULT_FILES: &[(&str, &str)] = &[
    ("none", include_str!("../../../sim/faults/none.toml")),
    ("flaky", include_str!("../../../sim/faults/flaky.toml")),
    ("lamp-drift", include_str!("../../../sim/faults/lamp-drift.toml")),
    ("stuck-led", include_str!("../../../sim/faults/stuck-led.toml")),
];

/// `btfrig run`.
pub fn run(a: &RunArgs) -> anyhow::Result<()> {
    let wall = Instant::now();
    let (plan, v) = crate::plan_cmd::load(&a.plan)?;
    let text = std::fs::read_to_string(&a.plan).with_context(|| format!("cannot read plan {}", a.plan.display()))?;
    let list = v.capture_list();
    anyhow::ensure!(!list.captures.is_empty(), "{}: the plan captures nothing", a.plan.display());
    let faults = fault_scenario(&plan, &a.plan)?;
    let material = crate::plan_cmd::material(&plan, &v, &a.plan)?;
    let exposure_s = crate::plan_cmd::exposure_s(&plan, &v, &a.plan)?;

    // The dataset: new, or the same plan's to resume; anything else is refused by the store.
    let manifest = manifest(&plan, &v, &text, &a.plan, &list)?;
    let (dataset, completed) = match Dataset::create(&a.out, manifest) {
        Ok(d) => {
            eprintln!("new dataset in {}", a.out.display());
            (d, BTreeSet::new())
        }
        Err(StoreError::AlreadyExists { .. }) => {
            let (d, r) = Dataset::open_for_resume(&a.out, &btfrig_store::plan_hash(&text))?;
            eprintln!(
                "resuming the dataset in {}: {} done, {} skipped, {} to do{}",
                a.out.display(),
                r.completed.len(),
                r.skipped.len(),
                r.remaining.len(),
                r.torn_tail.as_ref().map(|t| format!(" (torn journal tail dropped: {t:?})")).unwrap_or_default()
            );
            let mut done = r.completed.clone();
            done.extend(r.skipped.keys().copied());
            (d, done)
        }
        Err(e) => return Err(e).with_context(|| format!("--out {}", a.out.display())),
    };

    let gonio = Gonio::new(v.rig.geometry.clone())?;
    let request =
        PlanRequest::new(&gonio, &v.light, &v.view, &v.rig.timing, exposure_s, crate::plan_cmd::frame_bytes(&v))
            .with_pairs(PairSelection::List(list.captures.clone()));
    let schedule = plan_schedule(&request)?;
    let steps = EngineStep::from_schedule(&schedule);
    let done: HashSet<StepKey> = completed.iter().map(|s| StepKey { light: s.light, view: s.view }).collect();
    let to_do = steps.iter().filter(|s| !done.contains(&s.key)).count();
    if to_do == 0 {
        println!("{}: all {} captures already done; nothing to do", a.out.display(), completed.len());
        return Ok(());
    }
    eprintln!(
        "{} captures to do of {} (planned hardware time {:.0} s, lower bound {:.0} s)",
        to_do,
        steps.len(),
        schedule.timing.hardware_s,
        schedule.critical_path_s
    );

    let settings = EngineSettings {
        max_retries: v.run.max_retries,
        backoff_s: v.run.backoff_s,
        move_timeout_s: v.run.move_timeout_s,
        trigger_timeout_s: v.run.capture_timeout_s,
        ..EngineSettings::default()
    };
    let process = ProcessSettings {
        size: v.texture.size,
        region: btfrig_calib::Region {
            x_min: v.texture.region.x_min_m,
            x_max: v.texture.region.x_max_m,
            y_min: v.texture.region.y_min_m,
            y_max: v.texture.region.y_max_m,
        },
        filter: match v.texture.filter {
            ResampleFilter::Bilinear => btfrig_calib::Filter::Bilinear,
            ResampleFilter::Supersample => btfrig_calib::Filter::Footprint { max: 8 },
        },
    };

    let dataset = Arc::new(dataset);
    let rt = crate::session::virtual_time_runtime()?;
    let (outcome, totals) = rt.block_on(async {
        let scene = Arc::new(RigScene::new(&v.rig, &material)?);
        let source = Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default()));
        let truth = Arc::new(TruthLog::new(source));
        let mut rig = SimRig::from_rig_config(&v.rig, &faults, TokioClock::shared(), truth.clone())?;
        btfrig_sim::capture::prepare(&mut rig).await.context("preparing the simulated rig")?;
        let devices = Devices { robot: rig.robot, rail: rig.rail, camera: rig.camera, clock: rig.world.clock().clone() };
        let _lamp = rig.lamp; // stays on for the whole run
        let (tx, rx) = tokio::sync::mpsc::channel(FRAME_CHANNEL);
        let mut handle = Engine::spawn(devices, steps, done, settings, tx);
        let mut events = handle.events();
        // From the dataset's manifest (the plan's for a new one): a dataset resumed from an
        // older build may say otherwise, and the store refuses files its manifest does not ask for.
        let processor = Arc::new(Processor::new(scene, process).with_outputs(btfrig_pipeline::Outputs {
            textures: dataset.manifest().textures,
            raw_frames: dataset.manifest().raw_frames,
            preview: v.outputs.preview.then(btfrig_pipeline::PreviewSettings::default),
        }));
        let lookup: btfrig_pipeline::TruthLookup = Arc::new(move |f| truth.take(f.frame.meta.timestamp_s));
        let pipeline = btfrig_pipeline::run(dataset.clone(), processor, rx, lookup, |_| {});
        let listen = async {
            let mut failure = None;
            let mut warnings = Vec::new();
            let mut current = String::new();
            loop {
                match events.recv().await {
                    Ok(Event::StepDone { key, .. }) => current = format!("light {} view {}", key.light, key.view),
                    Ok(Event::Progress { done, total, eta_s }) => {
                        let eta = eta_s.map(|s| format!("{s:.0} s")).unwrap_or_else(|| "?".into());
                        let mut err = std::io::stderr().lock();
                        let _ = write!(err, "\rcaptures {done}/{total}, ETA {eta} (rig time), last {current}   ");
                        let _ = err.flush();
                    }
                    Ok(Event::Paused { reason: r @ PauseReason::StepFailed { .. } }) => {
                        // Nobody is at the console to fix the cause: stop; the run stays
                        // resumable (every delivered step is journaled).
                        failure = Some(r.to_string());
                        handle.abort();
                    }
                    Ok(Event::Warning(w)) => {
                        eprintln!("\nwarning: {w}");
                        warnings.push(w);
                    }
                    Ok(Event::Finished(_) | Event::Aborted(_)) => break,
                    Ok(_) => {}
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
                }
            }
            eprintln!();
            (failure, warnings)
        };
        let (totals, (failure, warnings)) = tokio::join!(pipeline, listen);
        let outcome = handle.join().await;
        anyhow::Ok((outcome, totals.map(|t| (t, failure, warnings))))
    })?;
    let (totals, failure, warnings) = totals?;

    let summary = match &outcome {
        RunOutcome::Finished(s) => s,
        RunOutcome::Aborted { summary, .. } => summary,
    };
    let mut dataset = Arc::try_unwrap(dataset).map_err(|_| anyhow::anyhow!("dataset still shared after the run"))?;
    let captures = dataset.completed().len() as u64;
    let mut skipped: BTreeMap<String, u64> = BTreeMap::new();
    for (_, r) in &list.skipped {
        *skipped.entry(r.label()).or_insert(0) += 1;
    }
    let wall_s = wall.elapsed().as_secs_f64();
    let mut extra = BTreeMap::new();
    if let Some(r) = totals.texture_rel_rmse() {
        extra.insert("texture_rel_rmse".to_string(), serde_json::json!(r));
    }
    extra.insert("captures_this_session".to_string(), serde_json::json!(totals.committed));
    extra.insert("captures_without_truth".to_string(), serde_json::json!(totals.without_truth));
    if v.outputs.preview {
        extra.insert("previews_this_session".to_string(), serde_json::json!(totals.previews));
    }
    extra.insert("critical_path_s".to_string(), serde_json::json!(schedule.critical_path_s));
    extra.insert("naive_order_hardware_s".to_string(), serde_json::json!(schedule.naive_order_hardware_s));
    let report = RunReport {
        captures,
        wall_s,
        hardware_s: Some(summary.hardware_s),
        stage_s: totals.stage_s.clone(),
        skipped,
        retries: u64::from(summary.retries),
        warnings,
        extra,
    };
    dataset.finish(&report)?;
    let stages: Vec<String> = totals.stage_s.iter().map(|(k, s)| format!("{k} {s:.2} s")).collect();
    println!(
        "{}: {} captures ({} this run), {} skipped by the plan, {} retries; rig time {:.0} s, wall {:.1} s; stages: {}; texture rel. RMSE {}",
        a.out.display(),
        captures,
        totals.committed,
        list.skipped.len(),
        summary.retries,
        summary.hardware_s,
        wall_s,
        stages.join(", "),
        totals.texture_rel_rmse().map(|r| format!("{r:.4}")).unwrap_or_else(|| "n/a".into())
    );
    if let Some(f) = failure {
        anyhow::bail!("{f}; run the same command again to resume");
    }
    anyhow::ensure!(
        matches!(outcome, RunOutcome::Finished(_)),
        "{}: the run stopped before the end; run the same command again to resume",
        a.out.display()
    );
    Ok(())
}

/// The plan's fault scenario: an embedded name, or a file relative to the plan.
fn fault_scenario(plan: &Plan, file: &Path) -> anyhow::Result<FaultScenario> {
    let Some(name) = plan.run.fault_scenario.as_deref() else { return Ok(FaultScenario::none()) };
    if let Some((_, text)) = FAULT_FILES.iter().find(|(n, _)| *n == name) {
        return Ok(FaultScenario::from_toml(text, &format!("<embedded sim/faults/{name}.toml>"))?);
    }
    let path = file.parent().unwrap_or(Path::new(".")).join(name);
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!("run.fault_scenario {name:?}: cannot read {}; allowed: {} or a file", path.display(), BUILTIN_FAULT_SCENARIOS.join(", "))
    })?;
    Ok(FaultScenario::from_toml(&text, &path.display().to_string())?)
}

/// The manifest of a new dataset of this plan.
fn manifest(
    plan: &Plan,
    v: &ValidatedPlan,
    text: &str,
    file: &Path,
    list: &btfrig_core::plan::CaptureList,
) -> anyhow::Result<Manifest> {
    let config_toml = match plan.rig.config.strip_prefix("builtin:") {
        Some(name) => BUILTIN_RIGS.iter().find(|(n, _)| *n == name).map(|(_, t)| t.to_string()).unwrap_or_default(),
        None => {
            let p = plan.rig_config_path(file).unwrap_or_else(|| plan.rig.config.clone().into());
            std::fs::read_to_string(&p).with_context(|| format!("cannot read rig config {}", p.display()))?
        }
    };
    let id = |(l, v): (usize, usize)| StepId { light: l as u32, view: v as u32 };
    let samplings = Samplings {
        light: v.light.directions().iter().map(|&d| DirectionDeg::from(d)).collect(),
        view: v.view.directions().iter().map(|&d| DirectionDeg::from(d)).collect(),
        pairs: Some(list.captures.iter().chain(list.skipped.iter().map(|(p, _)| p)).map(|&p| id(p)).collect()),
        skipped: list.skipped.iter().map(|&(p, r)| SkippedStep { step: id(p), reason: r.label() }).collect(),
    };
    let r = &v.texture.region;
    let texture = TextureSpec {
        width: v.texture.size as u32,
        height: v.texture.size as u32,
        region: TextureRegion {
            center_m: [(r.x_min_m + r.x_max_m) / 2.0, (r.y_min_m + r.y_max_m) / 2.0],
            size_m: [r.x_max_m - r.x_min_m, r.y_max_m - r.y_min_m],
        },
        format: match v.outputs.format {
            OutputFormat::ExrHalf => TextureFormat::ExrHalf,
            OutputFormat::ExrFloat => TextureFormat::ExrFloat,
        },
    };
    let rig = RigInfo { name: v.rig.rig.name.clone(), config_toml };
    let mut m = Manifest::new(rig, text, samplings, texture, v.outputs.raw_frames, v.rig.rig.seed);
    m.textures = v.outputs.textures;
    Ok(m)
}
