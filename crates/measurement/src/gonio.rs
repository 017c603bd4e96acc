//! A gonioreflectometer run: the dataset, the plan's schedule, the engine and the pipeline of one session, and report.json over all sessions.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use btfrig_acquire::{
    Engine, EngineSettings, EngineStep, Event, GonioDevices, PauseReason, RunOutcome as EngineOutcome,
};
use btfrig_core::capture::StepKey;
use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::ValidatedPlan;
use btfrig_planner::{plan as plan_schedule, PairSelection, PlanRequest};
use btfrig_process::{ProcessSettings, Processor};
use btfrig_store::{Dataset, RunReport, StoreError};
use serde_json::json;
use tokio::sync::mpsc;

use crate::control::Command;
use crate::hdr::journal_hdr;
use crate::report::Session;
use crate::runtime::FRAME_CHANNEL;
use crate::summary::peak_rss_mib;
use crate::{backend, hdr, light, model, plan, report, reprocess, sinks};
use crate::{
    DarkFlatInput, Fault, ProcessingInfo, RunControl, RunError, RunEvent, RunOutcome, RunRequest, RunSummary, Signal,
};

/// Runs `req` to its end, to a pause that ends the session, or to an abort; see the crate
/// documentation. Builds and drives its own virtual-time runtime: call it from a plain
/// thread (a daemon: `spawn_blocking`). `on_event` is called on that thread. The compressed
/// model the request asks for is streamed while the run captures and built once it has
/// finished ([`sinks`], [`RunSummary::compression`]).
pub fn run(
    req: &RunRequest,
    control: &RunControl,
    on_event: &mut dyn FnMut(&RunEvent),
) -> Result<RunSummary, RunError> {
    let model = sinks::CompressionSink::start(req)?;
    let mut summary = run_capture(req, model.as_ref().map(|m| m.texture_sink()), control, on_event)?;
    summary.compression = model.map(|m| m.finish(&summary.outcome));
    Ok(summary)
}

/// [`run`] without building the model: `sink` receives every committed texture.
fn run_capture(
    req: &RunRequest,
    sink: Option<Arc<dyn btfrig_process::TextureSink>>,
    control: &RunControl,
    on_event: &mut dyn FnMut(&RunEvent),
) -> Result<RunSummary, RunError> {
    let wall = Instant::now();
    let started_unix_s =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0);
    let file = req.plan_path.as_path();
    let backends = req.backends.as_ref().map_or_else(backend::installed, |b| b.0.clone());
    let (plan, v) = plan::load_text_with(&req.plan_text, file, &backends)?;
    let list = v.capture_list();
    if list.captures.is_empty() {
        return Err(RunError::Empty { plan: file.into() });
    }
    // Checked before anything is created; the device backend loads them again.
    let faults = match (&req.faults, &plan.run.fault_scenario) {
        (Some(name), _) => Some((name.as_str(), Path::new("."), "--faults")),
        (None, Some(name)) => Some((name.as_str(), file.parent().unwrap_or(Path::new(".")), "run.fault_scenario")),
        (None, None) => None,
    };
    let material = plan::material_name(&plan, &v, file);
    backends.for_rig(&v.rig)?.check_scene(&backend::SceneOptions { material: material.as_deref(), faults })?;
    // Every device asked who it is, how it feels and whether it is homed before anything is
    // created: an unplugged port is refused here, naming the device and the port.
    let time = backend::RigTime::for_run(&v.rig, req.wall_clock || plan.run.clock == btfrig_core::plan::RunClock::Wall);
    let preflight =
        crate::preflight::check_devices(&v.rig, &crate::preflight::run_roles(&v.rig), &backends)?.into_result()?;
    let exposure_s = plan::exposure_s(&plan, &v, file, req.light.as_ref())?;
    let hdr = match &v.exposure {
        btfrig_core::plan::ExposurePolicy::Auto { hdr, .. } if hdr.is_on() => Some(hdr.clone()),
        _ => None,
    };

    if let Some(d) = &req.dark_flat {
        // Refused before the dataset exists: a calibration of another camera corrects nothing.
        let (w, h) = (v.rig.camera.width_px, v.rig.camera.height_px);
        let (cw, ch) = (d.calibration.dark.width, d.calibration.dark.height);
        if (cw, ch) != (w, h) {
            return Err(RunError::Input {
                what: format!("dark/flat calibration {}", d.source),
                message: format!(
                    "it is of a {cw}x{ch} sensor, the rig's camera {} is {w}x{h}: calibrate this rig's camera (btfrig calibrate radiometric --rig ...)",
                    v.rig.rig.name
                ),
            });
        }
    }
    // Planned before the dataset exists: a signal during planning (the longest phase before
    // the first capture) leaves nothing behind.
    on_event(&RunEvent::Planning { captures: list.captures.len() });
    let gonio = Gonio::new(v.rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    let request = PlanRequest::new(&gonio, &v.light, &v.view, &v.rig.timing, exposure_s, plan::frame_bytes(&v))
        .with_pairs(PairSelection::List(list.captures.clone()))
        .with_cancel(&control.cancel);
    let schedule = match plan_schedule(&request) {
        Err(btfrig_planner::PlanError::Cancelled) => {
            return Err(RunError::Interrupted(control.signal().unwrap_or(Signal::Int)))
        }
        r => r?,
    };
    let steps = EngineStep::from_schedule(&schedule);
    // The devices can take every step (a recorded rig: its recording has each), checked
    // before anything is created.
    backends.for_rig(&v.rig)?.check_steps(&backend::StepsCheck {
        rig: &v.rig,
        rig_file: plan.rig_config_path(file).as_deref(),
        steps: &steps,
        exposures_fixed: hdr.is_none(),
    })?;
    // The dataset: new, or the same plan's to resume; anything else is refused by the store.
    let mut manifest = plan::manifest(&plan, &v, &req.plan_text, file, &list)?;
    let color_file = btfrig_calibrate::color::processing_color(&v.rig, plan.rig_config_path(file).as_deref())
        .map_err(|e| RunError::Rig(format!("the rig's colour calibration: {e}")))?;
    manifest.calibration =
        Some(calibration_record(&v.rig, color_file.as_ref(), req.light.as_ref(), req.dark_flat.as_ref()));
    let ds_err = |source| RunError::Dataset { dir: req.out.clone(), source };
    if control.cancel.is_cancelled() {
        return Err(RunError::Interrupted(control.signal().unwrap_or(Signal::Int)));
    }
    let mut new_dataset = NewDatasetGuard { dir: req.out.clone(), existed: req.out.exists(), armed: false };
    let (dataset, resumed, run_skips, repaired) = match Dataset::create(&req.out, manifest) {
        Ok(d) => {
            new_dataset.armed = true;
            (d, false, BTreeMap::new(), None)
        }
        Err(StoreError::AlreadyExists { .. }) => {
            let (d, r) =
                Dataset::open_for_resume(&req.out, &btfrig_store::plan_hash(&req.plan_text)).map_err(ds_err)?;
            let mut notes = Vec::new();
            if let Some(t) = &r.torn_tail {
                notes.push(format!("torn journal tail dropped: {t}"));
            }
            if !r.removed_orphans.is_empty() {
                notes.push(format!("{} unjournaled file(s) removed", r.removed_orphans.len()));
            }
            notes.extend(r.retaken.iter().map(|(step, what)| format!("{what}: step {step} is captured again")));
            let repaired = (!notes.is_empty()).then(|| notes.join("; "));
            (d, true, r.skipped.clone(), repaired)
        }
        Err(e) => return Err(ds_err(e)),
    };
    let mut skipped = plan::skip_map(&list.skipped);
    for reason in run_skips.values() {
        *skipped.entry(reason.clone()).or_insert(0) += 1;
    }

    let done: HashSet<StepKey> =
        dataset.completed().iter().chain(run_skips.keys()).map(|s| StepKey { light: s.light, view: s.view }).collect();
    let to_do = steps.iter().filter(|s| !done.contains(&s.key)).count();
    let previous = report::previous_sessions(&req.out);
    let fixed = Fixed {
        dataset: req.out.clone(),
        planned: steps.len() as u64,
        skipped,
        critical_path_s: schedule.critical_path_s,
        naive_order_hardware_s: schedule.naive_order_hardware_s,
        // The colour calibration's held-out CIEDE2000.
        color_held_out: color_file.as_ref().map(|f| (f.statistics.held_out_mean, f.statistics.held_out_max)),
        per_exposure_overhead_s: btfrig_imaging::exposure::per_exposure_overhead_s(
            &v.rig.timing.camera,
            plan::frame_bytes(&v),
        ),
    };
    if to_do == 0 {
        return Ok(summarise(&fixed, &dataset, &previous, None, RunOutcome::NothingToDo));
    }
    on_event(&RunEvent::Started {
        dataset: req.out.clone(),
        resumed,
        done_before: done.len(),
        to_do,
        total: steps.len(),
        planned_hardware_s: schedule.timing.hardware_s,
        critical_path_s: schedule.critical_path_s,
        repaired,
    });

    let settings = EngineSettings {
        max_retries: v.run.max_retries,
        backoff_s: v.run.backoff_s,
        move_timeout_s: v.run.move_timeout_s,
        trigger_timeout_s: v.run.capture_timeout_s,
        ..EngineSettings::default()
    };
    let process = reprocess::process_settings(&v);

    // What frames are processed with: the rig config and the calibration files it names, the
    // run's own light and dark/flat calibrations (`docs/pipeline.md`, "The processing model").
    let model = model::gonio_model(
        &v.rig,
        plan.rig_config_path(file).as_deref(),
        req.light.clone(),
        req.dark_flat.as_ref().map(|d| d.calibration.clone()),
    )?;
    let processing = ProcessingInfo::of(&model);
    let light_cos: std::collections::HashMap<StepKey, f64> = schedule
        .captures
        .iter()
        .map(|c| (StepKey { light: c.light_index as u32, view: c.view_index as u32 }, c.light.theta.cos()))
        .collect();
    let commands = control.take().ok_or_else(|| RunError::Rig("this RunControl already drives a run".into()))?;
    let dataset = Arc::new(dataset);
    let rt = time.runtime()?;
    let session = rt.block_on(session(SessionInput {
        time,
        rig: &v.rig,
        backends: &backends,
        plan: &plan,
        validated: &v,
        plan_file: file,
        fault_override: req.faults.as_deref(),
        steps,
        done,
        settings,
        process,
        model,
        // From the dataset's manifest (the plan's for a new one): a dataset resumed from an
        // older build may say otherwise, and the store refuses files its manifest does not ask for.
        outputs: btfrig_process::Outputs {
            textures: dataset.manifest().textures,
            raw_frames: dataset.manifest().raw_frames,
            texture_previews: dataset.manifest().texture_previews,
            preview: v.outputs.preview.then(btfrig_process::PreviewSettings::default),
        },
        dataset: dataset.clone(),
        commands,
        stop_on_fault: req.stop_on_fault,
        compare_nominal: req.compare_nominal,
        sink,
        hdr: hdr.map(|settings| SessionHdr { settings, reference_s: exposure_s, light_cos }),
        on_event,
    }));
    if !dataset.completed().is_empty() {
        // Something is captured: the dataset stays, whatever happens next.
        new_dataset.armed = false;
    }
    let SessionResult {
        outcome,
        hardware_s,
        engine_retries,
        warnings,
        totals,
        links,
        motion_wait_wall_s,
        link_added_wall_s,
        events_dropped,
        identities,
        frame_queue,
    } = session?;
    let totals = totals?;
    let mut warnings = warnings;
    warnings.extend(req.light.as_ref().and_then(|l| totals.lamp.warning(l.warn_drift)));
    let mut dataset =
        Arc::try_unwrap(dataset).map_err(|_| RunError::Rig("dataset still shared after the run".into()))?;
    let finished = dataset.completed().len() as u64 >= fixed.planned;
    // A pause or interrupt that came after the last capture still leaves a complete dataset.
    let outcome = match outcome {
        _ if finished => RunOutcome::Finished,
        // The engine ended early without a recorded cause: say so rather than "finished".
        RunOutcome::Finished => RunOutcome::Aborted,
        o => o,
    };
    let this = Session {
        started_unix_s,
        status: outcome.status().to_string(),
        reason: outcome.reason(),
        captures: totals.committed,
        wall_s: wall.elapsed().as_secs_f64(),
        hardware_s,
        retries: engine_retries,
        sq_err: totals.sq_err,
        sq_truth: totals.sq_truth,
        without_truth: totals.without_truth,
        warnings,
        sq_err_nominal: totals.sq_err_nominal,
        sq_truth_nominal: totals.sq_truth_nominal,
        texel_err: totals.texel_err,
        nominal_texel_err: totals.nominal_texel_err,
    };
    let mut summary = summarise(&fixed, &dataset, &previous, Some(&this), outcome);
    // Brightness against the nominal-lamp truth is measured on every simulated run; factors
    // only with a light calibration.
    summary.lamp = (req.light.is_some() || !totals.lamp.steps.is_empty()).then(|| totals.lamp.clone());
    summary.links = links;
    summary.processing = Some(processing);
    summary.motion_wait_wall_s = motion_wait_wall_s;
    summary.frame_queue = Some(frame_queue);
    summary.link_added_wall_s = link_added_wall_s;
    summary.events_dropped = events_dropped;
    summary.rig_time = Some(time);
    summary.devices = identities;
    summary.preflight = preflight.devices;
    let mut sessions: Vec<serde_json::Value> = previous.iter().map(Session::to_json).collect();
    sessions.push(this.to_json());
    dataset.finish(&report_of(&summary, &previous, &this, sessions)).map_err(RunError::Report)?;
    new_dataset.armed = false;
    Ok(summary)
}

/// Removes the dataset a session created when the session fails before anything is
/// captured, so that a failed start leaves no empty dataset directory behind (a directory
/// that existed before, necessarily empty, is emptied again rather than removed). Disarmed
/// once a capture is journaled or the session ends normally.
struct NewDatasetGuard {
    dir: PathBuf,
    existed: bool,
    armed: bool,
}

impl Drop for NewDatasetGuard {
    fn drop(&mut self) {
        if !self.armed {
            return;
        }
        if !self.existed {
            let _ = std::fs::remove_dir_all(&self.dir);
        } else if let Ok(entries) = std::fs::read_dir(&self.dir) {
            for e in entries.flatten() {
                let p = e.path();
                let _ = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
            }
        }
    }
}

/// Figures that do not depend on the session.
struct Fixed {
    dataset: PathBuf,
    planned: u64,
    skipped: BTreeMap<String, u64>,
    critical_path_s: f64,
    naive_order_hardware_s: f64,
    /// Held-out CIEDE2000 (mean, max) of the colour calibration in use.
    color_held_out: Option<(f64, f64)>,
    /// What one more exposure costs the camera beyond its own time, seconds.
    per_exposure_overhead_s: f64,
}

/// What the manifest records of the calibrations a run processes its frames with
/// (`docs/dataset-format.md`): which geometric and colour calibration the rig config names,
/// the colour model and its held-out error, the light calibration; `null` where the run uses
/// the rig model's own values.
fn calibration_record(
    rig: &btfrig_core::config::RigConfig,
    color: Option<&btfrig_calibrate::color::ColorCalibrationFile>,
    light: Option<&btfrig_process::light::LightCorrection>,
    dark_flat: Option<&DarkFlatInput>,
) -> serde_json::Value {
    json!({
        "geometry": rig.camera.calibration,
        "color": color.map(|f| json!({
            "reference": rig.camera.color_calibration,
            "model": f.model,
            "output": f.output,
            "white_balance": f.white_balance,
            "charts": f.source.charts.iter().map(|c| serde_json::to_value(c).unwrap_or_default()).collect::<Vec<_>>(),
            "fit_patches": f.source.fit_patches,
            "held_out_patches": f.source.held_out_patches,
            "held_out_delta_e00_mean": f.statistics.held_out_mean,
            "held_out_delta_e00_max": f.statistics.held_out_max,
        })),
        "light": light.map(|l| json!({
            "light": l.reference.light,
            "white_rate_e_per_s": l.reference.white_rate,
            "plate_albedo": l.reference.plate_albedo,
            "drift_corrected": l.correct_drift,
        })),
        "dark_flat": dark_flat.map(|d| json!({
            "source": d.source,
            "width": d.calibration.dark.width,
            "height": d.calibration.dark.height,
            "defects": d.calibration.dark.defects(),
            "f_numbers": d.calibration.flats.iter().map(|f| f.f_number).collect::<Vec<_>>(),
        })),
    })
}

fn summarise(
    fixed: &Fixed,
    dataset: &Dataset,
    previous: &[Session],
    this: Option<&Session>,
    outcome: RunOutcome,
) -> RunSummary {
    let mut all = previous.to_vec();
    all.extend(this.cloned());
    let t = report::totals(&all);
    let (stage_s, retries) = report::journal_stage_s(dataset);
    let poses = report::journal_poses(dataset);
    let captures = dataset.completed().len() as u64;
    RunSummary {
        outcome,
        dataset: fixed.dataset.clone(),
        captures,
        captures_this_session: this.map_or(0, |s| s.captures),
        planned_captures: fixed.planned,
        skipped: fixed.skipped.clone(),
        hardware_s: t.hardware_s,
        critical_path_s: fixed.critical_path_s,
        naive_order_hardware_s: fixed.naive_order_hardware_s,
        wall_s: t.wall_s,
        stage_s,
        texture_rel_rmse: t.texture_rel_rmse,
        texture_rel_rmse_nominal: t.texture_rel_rmse_nominal,
        color_delta_e00_mean: fixed.color_held_out.map(|c| c.0),
        color_delta_e00_max: fixed.color_held_out.map(|c| c.1),
        registered: poses.registered,
        fallbacks: poses.fallbacks,
        nominal_by_plan: poses.nominal_by_plan,
        registration_mean_texel_err: t.texel_err.mean(),
        registration_max_texel_err: t.texel_err.max(),
        nominal_mean_texel_err: t.nominal_texel_err.mean(),
        nominal_max_texel_err: t.nominal_texel_err.max(),
        retries,
        warnings: t.warnings,
        sessions: all.len(),
        unreported_captures: captures.saturating_sub(t.captures),
        peak_rss_mib: peak_rss_mib(),
        lamp: None,
        hdr: journal_hdr(dataset, fixed.per_exposure_overhead_s),
        skips: report::journal_skips(dataset),
        processing_s_per_capture: report::journal_mean_step_wall_s(dataset),
        frame_queue: None,
        links: Vec::new(),
        processing: None,
        motion_wait_wall_s: 0.0,
        link_added_wall_s: None,
        events_dropped: 0,
        compression: None,
        rig_time: None,
        devices: Vec::new(),
        preflight: Vec::new(),
    }
}

fn report_of(s: &RunSummary, previous: &[Session], this: &Session, sessions: Vec<serde_json::Value>) -> RunReport {
    let mut extra = BTreeMap::new();
    let without_truth: u64 = previous.iter().chain([this]).map(|s| s.without_truth).sum();
    let mut put = |k: &str, v: serde_json::Value| {
        extra.insert(k.to_string(), v);
    };
    put("status", json!(s.outcome.status()));
    put("reason", json!(s.outcome.reason()));
    if let RunOutcome::Paused { fault: Some(f), .. } = &s.outcome {
        put(
            "paused_step",
            json!({"index": f.index, "light": f.light, "view": f.view, "device": f.device, "kind": f.kind, "message": f.message}),
        );
    }
    if let Some(p) = &s.processing {
        put("processing", p.to_json());
    }
    put("texture_rel_rmse", json!(s.texture_rel_rmse));
    put("texture_rel_rmse_nominal", json!(s.texture_rel_rmse_nominal));
    put("color_delta_e00_mean", json!(s.color_delta_e00_mean));
    put("color_delta_e00_max", json!(s.color_delta_e00_max));
    if let Some(l) = &s.lamp {
        put("lamp", light::lamp_json(l));
    }
    if let Some(h) = &s.hdr {
        put("hdr", h.to_json());
    }
    put(
        "registration",
        json!({
            "registered": s.registered,
            "fallbacks": s.fallbacks,
            "nominal_by_plan": s.nominal_by_plan,
            "registration_mean_texel_err": s.registration_mean_texel_err,
            "registration_max_texel_err": s.registration_max_texel_err,
            "nominal_mean_texel_err": s.nominal_mean_texel_err,
            "nominal_max_texel_err": s.nominal_max_texel_err,
        }),
    );
    put("skips", s.skips.to_json());
    put("pipeline", s.pipeline_json());
    put("critical_path_s", json!(s.critical_path_s));
    put("naive_order_hardware_s", json!(s.naive_order_hardware_s));
    put("planned_captures", json!(s.planned_captures));
    put("captures_this_session", json!(this.captures));
    put("captures_without_truth", json!(without_truth));
    put("unreported_captures", json!(s.unreported_captures));
    put("peak_rss_mib", json!(s.peak_rss_mib));
    put("motion_wait_wall_s", json!(s.motion_wait_wall_s));
    put("events_dropped", json!(s.events_dropped));
    if let Some(t) = s.rig_time {
        put("rig_time", json!(t.name()));
    }
    if !s.devices.is_empty() {
        put("devices", crate::preflight::identities_json(&s.devices));
    }
    if !s.preflight.is_empty() {
        put("preflight", s.preflight.iter().map(crate::preflight::DeviceCheck::to_json).collect());
    }
    if !s.links.is_empty() {
        put("link_added_wall_s", json!(s.link_added_wall_s));
        put("links", s.links.iter().map(backend::LinkUse::to_json).collect());
    }
    put("engine_retries", json!(previous.iter().chain([this]).map(|s| s.retries).sum::<u64>()));
    put("sessions", serde_json::Value::Array(sessions));
    RunReport {
        captures: s.captures,
        wall_s: s.wall_s,
        hardware_s: Some(s.hardware_s),
        stage_s: s.stage_s.clone(),
        skipped: s.skipped.clone(),
        retries: s.retries,
        warnings: s.warnings.clone(),
        extra,
    }
}

struct SessionInput<'a> {
    /// The time the devices run on (the runtime's).
    time: backend::RigTime,
    rig: &'a btfrig_core::config::RigConfig,
    /// Where the devices come from.
    backends: &'a backend::BackendRegistry,
    plan: &'a btfrig_core::plan::Plan,
    validated: &'a ValidatedPlan,
    plan_file: &'a Path,
    fault_override: Option<&'a str>,
    steps: Vec<EngineStep>,
    done: HashSet<StepKey>,
    settings: EngineSettings,
    process: ProcessSettings,
    /// What frames are processed with.
    model: btfrig_process::ProcessingModel,
    outputs: btfrig_process::Outputs,
    dataset: Arc<Dataset>,
    commands: mpsc::Receiver<Command>,
    stop_on_fault: bool,
    compare_nominal: bool,
    sink: Option<Arc<dyn btfrig_process::TextureSink>>,
    hdr: Option<SessionHdr>,
    on_event: &'a mut dyn FnMut(&RunEvent),
}

/// HDR on: the plan's settings, the white-reference exposure (the first guess at each view)
/// and each step's light cosine.
struct SessionHdr {
    settings: btfrig_core::plan::HdrSettings,
    reference_s: f64,
    light_cos: std::collections::HashMap<StepKey, f64>,
}

struct SessionResult {
    outcome: RunOutcome,
    hardware_s: f64,
    engine_retries: u64,
    warnings: Vec<String>,
    totals: Result<btfrig_process::Totals, btfrig_process::PipelineError>,
    links: Vec<backend::LinkUse>,
    motion_wait_wall_s: f64,
    link_added_wall_s: Option<f64>,
    /// Engine events the session's listener lost (it fell behind the event queue).
    events_dropped: u64,
    /// The opened devices' identities by role.
    identities: Vec<(&'static str, btfrig_hw::DeviceInfo)>,
    /// The frame channel between the engine and the pipeline, as the engine saw it.
    frame_queue: btfrig_acquire::FrameQueueFigures,
}

fn fault_of(r: &PauseReason) -> Option<Fault> {
    match r {
        PauseReason::StepFailed { index, key, device, kind, message, .. } => Some(Fault {
            index: *index,
            light: key.light,
            view: key.view,
            device: device.clone(),
            kind: kind.to_string(),
            message: message.clone(),
        }),
        _ => None,
    }
}

/// One engine run with its pipeline, on the current (virtual-time) runtime.
async fn session(input: SessionInput<'_>) -> Result<SessionResult, RunError> {
    let SessionInput {
        time,
        rig,
        backends,
        plan,
        validated,
        plan_file,
        fault_override,
        steps,
        done,
        settings,
        process,
        model,
        outputs,
        dataset,
        mut commands,
        stop_on_fault,
        compare_nominal,
        sink,
        hdr,
        on_event,
    } = input;
    // The devices, from the backend the rig's device kinds select (`backend`): the run never
    // builds a device itself.
    let backend = backends.for_rig(rig)?;
    let backend::OpenedGonio { mut robot, mut rail, mut lamp, camera: rig_camera, clock, truth, links: firmware } =
        backend
            .open_gonio(backend::GonioOpenRequest {
                rig,
                plan,
                validated,
                plan_file,
                fault_override,
                read_timeout_s: settings.read_timeout_s,
                time,
            })
            .await?;
    let identities = vec![
        ("robot", robot.info().clone()),
        ("rail", rail.info().clone()),
        ("lamp", lamp.info().clone()),
        ("camera", rig_camera.info().clone()),
    ];
    // Home, ignite and warm up (as btfrig_sim::capture::prepare), through the backends.
    let prepare = async {
        let opts = btfrig_hw::MoveOptions::default();
        let (r, t) = tokio::join!(robot.home(opts), rail.home(opts));
        r?;
        t?;
        lamp.set_on(true).await?;
        let warm_up = lamp.capabilities().warm_up_s;
        lamp.wait_ready(warm_up + 60.0).await
    };
    prepare.await.map_err(|e| RunError::Rig(format!("preparing the rig: {e}")))?;
    let devices = GonioDevices { robot, rail, camera: rig_camera, clock };
    let _lamp = lamp; // stays on for the whole run
    let exposure_control: Box<dyn btfrig_acquire::ExposureControl> = match &hdr {
        Some(h) => {
            let sensor = model.sensor;
            let hdr_rig = hdr::HdrRig {
                camera: model.camera.clone(),
                gonio: Gonio::new(rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?,
                region: process.region,
                noise: btfrig_imaging::hdr::NoiseModel {
                    electrons_per_dn: sensor.electrons_per_dn,
                    read_noise_e: sensor.read_noise_e,
                },
                nominal: btfrig_imaging::hdr::NominalCalibration {
                    dark_current_e_per_s: sensor.dark_current_e_per_s,
                    electrons_per_dn: sensor.electrons_per_dn,
                },
                exposure_range_s: devices.camera.capabilities().exposure_range_s,
            };
            Box::new(hdr::HdrControl::new(&h.settings, hdr_rig, h.reference_s, h.light_cos.clone()))
        }
        None => Box::new(btfrig_acquire::SingleExposure),
    };
    let processor = Arc::new(
        Processor::new(model, process)
            .map_err(|e| RunError::Rig(e.to_string()))?
            .with_truth(truth)
            .with_outputs(outputs)
            .with_sink(sink)
            .with_nominal_comparison(compare_nominal)
            .with_hdr_recording(
                hdr.as_ref().map(|h| btfrig_process::HdrRecording { always_stops: hdr::always_stops(&h.settings) }),
            ),
    );
    let index_of: std::collections::HashMap<StepKey, usize> =
        steps.iter().enumerate().map(|(i, s)| (s.key, i)).collect();
    let (tx, rx) = mpsc::channel(FRAME_CHANNEL);
    let event_capacity = settings.event_capacity;
    let mut handle = Engine::spawn_with_exposure(devices, steps, done, settings, tx, exposure_control);
    let mut events = handle.events();
    // The pipeline's totals as of its last commit (kept if it stops at an error), as a watch:
    // the listener reports the newest (a full queue of one keeps the latest), and the totals
    // are cumulative, so a listener that falls behind skips intermediate figures only: every
    // registration fallback is still warned about, and the last commit always reported.
    let (totals_tx, mut totals_rx) = tokio::sync::watch::channel(btfrig_process::Totals::default());
    let pipeline = btfrig_process::run(dataset, processor, rx, move |t| {
        totals_tx.send_replace(t.clone());
    });
    let mut delivered: u64 = 0;
    let mut fallbacks_warned = 0usize;
    // What changed in the totals since the listener last looked: new fallbacks as warnings,
    // then the commit.
    let mut report_totals = |t: &btfrig_process::Totals,
                             delivered: u64,
                             warnings: &mut Vec<String>,
                             on_event: &mut dyn FnMut(&RunEvent)| {
        for (step, reason) in t.fallback_steps.iter().skip(fallbacks_warned) {
            let w = format!("step {step}: registration failed, rectified with the nominal pose: {reason}");
            on_event(&RunEvent::Warning(w.clone()));
            warnings.push(w);
        }
        fallbacks_warned = t.fallback_steps.len();
        on_event(&RunEvent::Committed {
            committed: t.committed,
            previews: t.previews,
            queued: delivered.saturating_sub(t.committed),
            stage_s: t.stage_s.clone(),
        });
    };
    // A command the engine refused (its queue full) is a warning; one sent after the engine
    // ended has nothing to steer.
    let refused = |r: Result<(), btfrig_acquire::CommandError>, warnings: &mut Vec<String>| {
        if let Err(e @ btfrig_acquire::CommandError::Full { .. }) = r {
            warnings.push(format!("engine: {e}"));
        }
    };
    let mut events_dropped: u64 = 0;
    let listen = async {
        let mut stop: Option<RunOutcome> = None;
        let mut warnings = Vec::new();
        let mut commands_open = true;
        let mut totals_open = true;
        loop {
            tokio::select! {
                ev = events.recv() => match ev {
                    Ok(Event::StepDone { key, attempts, .. }) => {
                        delivered += 1;
                        on_event(&RunEvent::StepDone { light: key.light, view: key.view, attempts })
                    }
                    Ok(Event::Progress { done, total, eta_s }) => on_event(&RunEvent::Progress { done, total, eta_s }),
                    Ok(Event::Warning(w)) => {
                        on_event(&RunEvent::Warning(w.clone()));
                        warnings.push(w);
                    }
                    Ok(Event::Paused { reason }) => {
                        let fault = fault_of(&reason);
                        on_event(&RunEvent::Paused { reason: reason.to_string(), fault: fault.clone() });
                        let end = match &reason {
                            PauseReason::StepFailed { .. } if stop_on_fault => {
                                Some(RunOutcome::Paused { reason: reason.to_string(), fault })
                            }
                            // The pipeline stopped (its error is returned): nothing more can be stored.
                            PauseReason::ConsumerGone => Some(RunOutcome::Aborted),
                            _ => None,
                        };
                        if let Some(end) = end {
                            if stop.is_none() {
                                on_event(&RunEvent::Stopping { reason: reason.to_string() });
                                stop = Some(end);
                            }
                            refused(handle.abort(), &mut warnings);
                        }
                    }
                    Ok(Event::Resumed) => on_event(&RunEvent::Resumed),
                    Ok(Event::Finished(_) | Event::Aborted(_)) => break,
                    // Events are advisory: the listener fell behind the engine's queue and
                    // lost the oldest. Counted and reported; frames and journal are unaffected.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => events_dropped += n,
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
                },
                r = totals_rx.changed(), if totals_open => match r {
                    Ok(()) => {
                        let t = totals_rx.borrow_and_update().clone();
                        report_totals(&t, delivered, &mut warnings, on_event);
                    }
                    // The pipeline has ended; its last totals are reported after the join.
                    Err(_) => totals_open = false,
                },
                c = commands.recv(), if commands_open => match c {
                    None => commands_open = false,
                    Some(Command::Pause) => refused(handle.pause(), &mut warnings),
                    Some(Command::Resume) => refused(handle.resume(), &mut warnings),
                    Some(c @ (Command::Abort | Command::Interrupt(_))) => {
                        let end = match c {
                            Command::Interrupt(signal) => RunOutcome::Interrupted(signal),
                            _ => RunOutcome::Aborted,
                        };
                        if stop.is_none() {
                            on_event(&RunEvent::Stopping { reason: end.reason().unwrap_or_default() });
                            stop = Some(end);
                        }
                        refused(handle.abort(), &mut warnings);
                    }
                },
            }
        }
        (stop, warnings)
    };
    let (totals, (mut stop, mut warnings)) = tokio::join!(pipeline, listen);
    // Fallbacks and commits of the frames committed after the engine finished.
    if totals_rx.has_changed().unwrap_or(true) {
        let t = totals_rx.borrow_and_update().clone();
        report_totals(&t, delivered, &mut warnings, on_event);
    }
    if events_dropped > 0 {
        let w = format!(
            "{events_dropped} engine event(s) dropped: the run's listener fell behind the engine's event queue \
             ({} events); progress lines were lost, frames and the journal are complete",
            event_capacity
        );
        on_event(&RunEvent::Warning(w.clone()));
        warnings.push(w);
    }
    // A registration failure under `on_failure = "fail"` ends the session like a device
    // fault: paused on that step, resumable, the report written.
    let totals = match totals {
        Err(btfrig_process::PipelineError::Registration { step, reason }) => {
            let key = StepKey { light: step.light, view: step.view };
            let fault = Fault {
                index: index_of.get(&key).copied().unwrap_or(0),
                light: step.light,
                view: step.view,
                device: "registration".into(),
                kind: "registration".into(),
                message: format!("registration failed: {reason}"),
            };
            let why = format!("step {step}: registration failed and the plan says on_failure = \"fail\": {reason}");
            on_event(&RunEvent::Paused { reason: why.clone(), fault: Some(fault.clone()) });
            stop = Some(RunOutcome::Paused { reason: why, fault: Some(fault) });
            Ok(totals_rx.borrow().clone())
        }
        other => other,
    };
    let summary = match handle.join().await {
        EngineOutcome::Finished(s) => s,
        EngineOutcome::Aborted { summary, .. } => summary,
    };
    // Garbage the serial backends skipped (an emulated rig): worth a look at the cabling.
    for (role, n) in firmware.skipped_lines() {
        let w = format!("{role}: {n} undecodable line(s) skipped on the serial link (noise on the line?)");
        on_event(&RunEvent::Warning(w.clone()));
        warnings.push(w);
    }
    Ok(SessionResult {
        outcome: stop.unwrap_or(RunOutcome::Finished),
        hardware_s: summary.hardware_s,
        engine_retries: u64::from(summary.retries),
        warnings,
        totals,
        links: firmware.link_use(),
        motion_wait_wall_s: summary.motion_wait_wall_s,
        link_added_wall_s: (firmware.count() > 0)
            .then(|| summary.motion_wait_wall_s + firmware.camera_coding_wall_s().unwrap_or(0.0)),
        events_dropped,
        identities,
        frame_queue: summary.frame_queue,
    })
}
