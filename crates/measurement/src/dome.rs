//! A whole dome run (an LED dome, or a camera array whose flashes are the lights: light =
//! flash index, view = camera) as one library call: plan -> schedule (with the multiplexing
//! choice, planned for the lights' brightness from the LED calibration or the rig config's
//! nominal) -> the devices the rig's backend opens (`crate::backend`) -> engine
//! (`btfrig_acquire::Engine::spawn` on `RigDevices::Dome`, the gonio's engine) -> pipeline
//! (`btfrig_process::dome`: collect, demultiplex, fault detection, rectify, radiometry) -> dataset store, plus, where the backend offers a truth
//! probe (a simulated rig), the figures measured against its ground truth
//! (`docs/pipeline.md`, "LED dome").
//!
//! Measured gain: in the first view group of the first camera, `reference_leds` LEDs are also
//! captured alone (single-light frames at the single-light exposure, so both modes spend the
//! same time per LED). The noise of a demultiplexed single-LED image and of the single-light
//! frame of the same LED are the RMS differences from the noise-free render of that LED
//! (`DomeTruthProbe::noise_free_dn`, photosites imaging the sample); the gain is the ratio of
//! their SNRs. Reference frames are only measured, not stored.
//!
//! Raw frames (`[outputs] raw_frames = true`): every pattern frame of every view group, all
//! cameras, is written as it arrives and journaled in one `frames` record before the group's
//! textures (`Consumer`; `docs/dataset-format.md`, "Raw frames of view groups"), with the
//! schedule in the manifest's `raw_groups`, so `btfrig reprocess` can demultiplex them again
//! (`crate::dome_reprocess`).
//!
//! Steering ([`run_controlled`]): a [`RunControl`] pauses, resumes, aborts or interrupts the
//! engine between steps through its `RunHandle`, as a gonio session does, and the run reports
//! [`RunEvent`]s: `Started`, `Progress` with an ETA, warnings, pauses (also on a device fault),
//! resumes and `Stopping`. A dome's step is one frame
//! per camera (a pattern at a rotation), so `Progress` counts steps, not textures; textures are
//! committed per view group, which [`RunEvent::TexturesCommitted`] reports (once at the start,
//! then after every view group), with `preview.png` replaced by the group's brightest texture
//! when the request asks for a preview. An aborted or interrupted session, or one that stops on
//! a device fault (status `paused`, with `paused_step` naming the step, device and error),
//! keeps the view groups it committed, its report says so (`status`), and the same request
//! resumes it.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use btfrig_acquire::dome::DomeCapture;
use btfrig_acquire::{
    CommandError, Engine, EngineSettings, EngineStep, Event, PauseReason, RigDevices, RunHandle,
    RunOutcome as EngineOutcome, StepKind,
};
use btfrig_core::capture::StepKey;
use btfrig_core::plan::dome::{DomePlan, ValidatedDomePlan};
use btfrig_hw::truth::DomeTruthProbe;
use btfrig_hw::MoveOptions;
use btfrig_imaging::rectify::Filter;
use btfrig_planner::dome::{plan_dome, DomeMode, DomeShot};
use btfrig_process::dome::{DomeProcessing, GroupCode, GroupPose, GroupStack, LedLight};
use btfrig_process::{PoseSource, TexelErrorTotals};
use btfrig_store::{
    Dataset, DirectionDeg, FileRecord, Manifest, RigInfo, RunReport, Samplings, StepId, StepTiming, StoreError,
    TextureFormat, TextureRegion, TextureSpec,
};
use serde_json::json;
use tokio::sync::mpsc;

use crate::backend::{DomeOpenRequest, OpenedDome};
use crate::control::Command;
use crate::{RunControl, RunError, RunEvent, RunOutcome};

/// A dome run: the plan text (a dome plan, `docs/plan-format.md`), where its relative names
/// resolve, and the dataset directory.
#[derive(Debug, Clone)]
pub struct DomeRunRequest {
    /// The plan text.
    pub plan_text: String,
    /// The plan file (names the plan in errors; relative rig configs and fault files resolve
    /// from its directory).
    pub plan_path: PathBuf,
    /// The dataset directory.
    pub out: PathBuf,
    /// Replaces the plan's fault scenario (not part of the plan hash).
    pub faults: Option<String>,
    /// Keep a live preview: after every committed view group, `preview.png` in the dataset
    /// (8-bit sRGB, not data, not journaled) shows that group's brightest texture (the daemon
    /// sets it; `btfrig run` does not).
    pub preview: bool,
    /// The compressed model to build while the run captures, instead of the plan's
    /// `outputs.compressed_model` (`btfrig run --compress`, `btfrig demo`); `None`: the plan's.
    /// The run builds its sink ([`crate::sinks::CompressionSink`]) as a gonio run does.
    pub compressed_model: Option<btfrig_core::plan::CompressedModel>,
}

/// One view group's predicted multiplex gain (`DomeRunSummary::multiplex_gain_per_group`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GroupGain {
    /// The dataset's view id of the group.
    pub view: u32,
    /// Arc camera index.
    pub camera: usize,
    /// Rotation index.
    pub rotation: u32,
    /// Predicted SNR gain over single light.
    pub gain: f64,
    /// Lights solved for (dead ones are not).
    pub lights: usize,
    /// Faults the demultiplexer found in the group.
    pub faults: usize,
}

/// What a dome run did and measured.
#[derive(Debug, Clone, Default)]
pub struct DomeRunSummary {
    /// The dataset directory.
    pub dataset: PathBuf,
    /// `"led_dome"` or `"camera_array"` (the rig's `[rig] kind`).
    pub rig_kind: &'static str,
    /// What a light is: `"LED"` or `"flash"`.
    pub light: &'static str,
    /// Single-LED textures committed (light = LED, view = rotation x cameras + camera).
    pub textures: u64,
    /// Frames captured (per camera), reference frames included.
    pub frames: u64,
    /// LEDs.
    pub leds: usize,
    /// Views captured (camera, rotation).
    pub views: usize,
    /// `"s-matrix 199"`, `"groups 29 x 7"` (29 groups of 7 LEDs) or `"single-light"`.
    pub mode: String,
    /// The planner's one-line reason (`multiplexing with ...` / `multiplexing skipped: ...`).
    pub multiplex_reason: String,
    /// Predicted SNR gain of the mode used over single light (1 for single light).
    pub multiplex_gain_predicted: f64,
    /// Measured SNR gain against the simulator's noise-free images (`None` without
    /// multiplexing or reference LEDs).
    pub multiplex_gain_measured: Option<f64>,
    /// Per multiplexed view group, the predicted gain after the faults its demultiplexing
    /// found: `multiplex_gain_predicted` times the mean over the lights it solved for of the
    /// fault-free code's noise over this group's (1 in a group without faults). From the
    /// frames only (no truth); empty for single light.
    pub multiplex_gain_per_group: Vec<GroupGain>,
    /// Exposure time saved against single-light capture reaching the same SNR (predicted).
    pub time_saved_fraction: f64,
    /// Rig time of the run (virtual), s.
    pub hardware_s: f64,
    /// Rig time spent exposing, s.
    pub exposure_time_s: f64,
    /// Relative RMS error of the stored textures against the ground truth, pooled over every
    /// texture but those of LEDs reported faulty.
    pub texture_rel_rmse: Option<f64>,
    /// Pooled brightness error of the stored textures against the ground truth:
    /// `sum(texture) / sum(truth) - 1` over the same texels as `texture_rel_rmse`. Noise
    /// averages out of it, so it shows a calibration's scale error (LED powers, flat) that the
    /// RMSE of dim LEDs' noisy textures hides.
    pub texture_brightness_err: Option<f64>,
    /// `texture_rel_rmse` over the interior texels: the outermost ring of texels left out. At
    /// a dome camera's resolution (2.5 pixels per texel in the demo) the pixels that make an
    /// edge texel straddle the sample's edge and mix in the plate (a brighter, neutral grey):
    /// the full figures carry that, the interior ones show the pipeline on the sample alone.
    pub texture_rel_rmse_interior: Option<f64>,
    /// `texture_brightness_err` over the interior texels (see `texture_rel_rmse_interior`).
    pub texture_brightness_err_interior: Option<f64>,
    /// The same per channel (linear sRGB R, G, B): a colour calibration's balance error shows
    /// here (grey's channels apart), where the sum over channels hides it.
    pub texture_channel_err_interior: Option<[f64; 3]>,
    /// The same for the single-light reference textures (first view group).
    pub reference_texture_rel_rmse: Option<f64>,
    /// The same for the demultiplexed textures of the reference LEDs (same LEDs, same view).
    pub reference_mux_texture_rel_rmse: Option<f64>,
    /// View groups rectified with the pose registered from the plate's markers.
    pub registered: u64,
    /// View groups rectified with the nominal pose because registration failed (each one's
    /// reason is a warning).
    pub fallbacks: u64,
    /// Pattern frames that did not need their own registration: a view group is registered
    /// once, from the sum of its frames (issue 27's skip counts).
    pub registrations_reused: u64,
    /// Mean texel position error of the poses used against the true poses, texels (mean over
    /// view groups of the mean over texels; simulated rig).
    pub registration_mean_texel_err: Option<f64>,
    /// Largest texel position error of the poses used, texels.
    pub registration_max_texel_err: Option<f64>,
    /// Mean texel position error of the nominal poses, texels.
    pub nominal_mean_texel_err: Option<f64>,
    /// Largest texel position error of the nominal poses, texels.
    pub nominal_max_texel_err: Option<f64>,
    /// Dead and stuck LEDs the demultiplexer found, e.g. `camera 0 rotation 0: LED 3 stuck`.
    pub faults: Vec<String>,
    /// Warnings (faults solved around, retries, skipped demultiplexing).
    pub warnings: Vec<String>,
    /// Largest memory one view group's stack held, bytes.
    pub group_bytes: usize,
    /// Wall time, s.
    pub wall_s: f64,
    /// Views skipped because a previous session committed them.
    pub views_resumed: usize,
    /// Peak resident memory of the process at the end of the run (Linux `VmHWM`), MiB.
    pub peak_rss_mib: Option<f64>,
    /// Basis terms of the denoising projection (`[dome] denoise_terms`; `None`: off).
    pub denoise_terms: Option<usize>,
    /// Per denoised view group, the fraction of its textures' energy the basis kept.
    pub denoise_energy_kept: Vec<f64>,
    /// Wall time of rectifying and projecting the denoised groups, s.
    pub denoise_s: f64,
    /// Engine events dropped because the session's listener fell behind the event queue
    /// (a warning says so); progress only, frames and journal are complete.
    pub events_dropped: u64,
    /// How the session ended before the last step (aborted or interrupted through its
    /// [`RunControl`], or paused on a failed step when the session stops on faults); `None`
    /// when it captured every step.
    pub stopped: Option<RunOutcome>,
    /// What became of the compressed model the request or the plan asks for (`None`: none
    /// asked for); built after the dataset's report, as a gonio run's.
    pub compression: Option<crate::sinks::CompressionOutcome>,
}

impl DomeRunSummary {
    /// The summary as JSON (what `btfrig demo --rig dome --json` prints).
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = json!({
            "status": self.stopped.as_ref().map_or("finished", RunOutcome::status),
            "reason": self.stopped.as_ref().and_then(RunOutcome::reason),
            "dataset": self.dataset.display().to_string(),
            "rig": self.rig_kind,
            "light": self.light,
            "captures": self.textures,
            "frames": self.frames,
            "leds": self.leds,
            "views": self.views,
            "mode": self.mode,
            "multiplex_reason": self.multiplex_reason,
            "multiplex_gain_predicted": self.multiplex_gain_predicted,
            "multiplex_gain_measured": self.multiplex_gain_measured,
            "multiplex_gain_per_group": self.multiplex_gain_per_group,
            "time_saved_fraction": self.time_saved_fraction,
            "hardware_s": self.hardware_s,
            "exposure_time_s": self.exposure_time_s,
            "texture_rel_rmse": self.texture_rel_rmse,
            "texture_brightness_err": self.texture_brightness_err,
            "texture_rel_rmse_interior": self.texture_rel_rmse_interior,
            "texture_brightness_err_interior": self.texture_brightness_err_interior,
            "texture_channel_err_interior": self.texture_channel_err_interior,
            "reference_texture_rel_rmse": self.reference_texture_rel_rmse,
            "reference_mux_texture_rel_rmse": self.reference_mux_texture_rel_rmse,
            "registered": self.registered,
            "fallbacks": self.fallbacks,
            "registrations_reused": self.registrations_reused,
            "registration_mean_texel_err": self.registration_mean_texel_err,
            "registration_max_texel_err": self.registration_max_texel_err,
            "nominal_mean_texel_err": self.nominal_mean_texel_err,
            "nominal_max_texel_err": self.nominal_max_texel_err,
            "faults": self.faults,
            "warnings": self.warnings,
            "group_bytes": self.group_bytes,
            "views_resumed": self.views_resumed,
            "peak_rss_mib": self.peak_rss_mib,
            "denoise_terms": self.denoise_terms,
            "denoise_energy_kept": self.denoise_energy_kept,
            "denoise_s": self.denoise_s,
            "events_dropped": self.events_dropped,
            "wall_s": self.wall_s,
        });
        if let (Some(c), Some(o)) = (&self.compression, v.as_object_mut()) {
            // As a gonio run's summary: the model's `peak_rss_mib` is the whole process's,
            // read after the model was written; the capture's stays as `run_peak_rss_mib`.
            o.insert("run_peak_rss_mib".into(), json!(self.peak_rss_mib));
            if let Some(fields) = c.to_json().as_object() {
                o.extend(fields.clone());
            }
        }
        v
    }
}

fn input(what: &str, e: impl std::fmt::Display) -> RunError {
    RunError::Input { what: what.into(), message: e.to_string() }
}

/// Squared error and squared truth summed over a texture: pooled over many textures, their
/// ratio's root is the relative RMSE (dim grazing LEDs do not dominate it as a mean of
/// per-texture ratios would).
fn sq_err(a: &[[f32; 3]], truth: &[[f32; 3]]) -> (f64, f64) {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, t) in a.iter().zip(truth) {
        for c in 0..3 {
            num += f64::from(x[c] - t[c]).powi(2);
            den += f64::from(t[c]).powi(2);
        }
    }
    (num, den)
}

/// The texels of a `size x size` texture without its outermost ring.
fn interior(t: &[[f32; 3]], size: usize) -> Vec<[f32; 3]> {
    t.chunks(size.max(1))
        .take(size.saturating_sub(1))
        .skip(1)
        .flat_map(|row| row.iter().take(size.saturating_sub(1)).skip(1).copied())
        .collect()
}

/// Sum over texels and channels.
fn sum_texels(t: &[[f32; 3]]) -> f64 {
    t.iter().map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])).sum()
}

fn pooled(v: &[(f64, f64)]) -> Option<f64> {
    let (n, d) = v.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    (d > 0.0).then(|| (n / d).sqrt())
}

/// SNR of `measured` against `truth` over the photosites in `sample` (those imaging the
/// sample: the noise model's gain is the sample's, and a brightness threshold would pick the
/// marker plate's white around a dark sample): mean signal over RMS error.
fn snr(measured: &[f32], truth: &[f32], sample: &[bool]) -> f64 {
    let (mut s, mut e, mut n) = (0.0f64, 0.0f64, 0usize);
    for ((m, t), _) in measured.iter().zip(truth).zip(sample).filter(|(_, &k)| k) {
        s += f64::from(*t);
        e += f64::from(m - t).powi(2);
        n += 1;
    }
    if n == 0 {
        return f64::NAN;
    }
    (s / n as f64) / (e / n as f64).sqrt()
}

/// A texture's texels, row-major RGB.
type Texture = Vec<[f32; 3]>;

/// Projects one view group's textures (one per light, `size² x 3` values each) onto their own
/// leading `terms` light-basis vectors (`btfrig_mux::denoise`); `skip` lights (faulty) are
/// left out of the fit and unchanged. The projection runs on the textures divided by
/// `scales` (each texel's DN-to-texture factor of that light): there the demultiplexing noise
/// is about equal for every light, while in the textures a grazing LED's is many times a
/// facing one's, and the noisiest lights would take the leading basis vectors for themselves.
fn denoise_group(
    texes: Vec<Texture>,
    scales: &[Texture],
    terms: usize,
    skip: &[bool],
) -> Result<(Vec<Texture>, btfrig_mux::Projection), btfrig_mux::MuxError> {
    let n = texes.len();
    let safe = |s: f32| if s.is_finite() && s > 0.0 { s } else { 1.0 };
    let mut rows: Vec<f32> = texes
        .iter()
        .zip(scales)
        .flat_map(|(t, s)| t.iter().zip(s).flat_map(|(p, q)| (0..3).map(move |c| p[c] / safe(q[c]))))
        .collect();
    drop(texes);
    let p = btfrig_mux::project_onto_own_basis(&mut rows, n, terms, skip)?;
    let t = rows.len() / n.max(1);
    let out = (0..n)
        .map(|j| {
            rows[j * t..(j + 1) * t]
                .chunks_exact(3)
                .zip(&scales[j])
                .map(|(v, q)| std::array::from_fn(|c| v[c] * safe(q[c])))
                .collect()
        })
        .collect();
    Ok((out, p))
}

/// Runs a dome plan to its end (see the module docs); a device fault no retry helps ends the
/// session paused ([`DomeRunSummary::stopped`]), resumable.
pub fn run(req: &DomeRunRequest, on_line: &mut dyn FnMut(&str)) -> Result<DomeRunSummary, RunError> {
    run_controlled(req, &RunControl::new(), true, on_line, &mut |_| {})
}

/// [`run`], steered by `control` from any thread (pause, resume, abort, interrupt: between
/// steps) and watched through `on_event` (module docs; both callbacks are called on this
/// thread). `stop_on_fault`: a step failing with an error no retry helps ends the session as
/// paused (true, `btfrig run`: the report's status is `paused`, the same request resumes and
/// tries the step again), or pauses the engine until `control` resumes it (the step is tried
/// again) or aborts it (false, a daemon with an operator).
pub fn run_controlled(
    req: &DomeRunRequest,
    control: &RunControl,
    stop_on_fault: bool,
    on_line: &mut dyn FnMut(&str),
    on_event: &mut dyn FnMut(&RunEvent),
) -> Result<DomeRunSummary, RunError> {
    let wall = Instant::now();
    let (v, rig, rig_text) = crate::plan::load_dome(&req.plan_text, &req.plan_path)?;
    let base = req.plan_path.parent().unwrap_or(Path::new("."));
    let fault_name = req.faults.clone().unwrap_or_else(|| v.plan.fault_scenario.clone());
    // The scene's options are the backend's to check, before anything is created.
    let backend = crate::backend::installed().for_rig(&rig)?;
    let material = crate::plan::dome_material_name(v.plan.rig.material.as_deref(), &req.plan_path);
    backend.check_scene(&crate::backend::SceneOptions {
        material: material.as_deref(),
        faults: Some((&fault_name, base, "fault_scenario")),
    })?;
    // Every device asked before anything is created (`crate::preflight`); a rig with real
    // devices runs on the wall clock.
    let time = crate::backend::RigTime::for_rig(&rig);
    let preflight =
        crate::preflight::check_devices(&rig, &crate::preflight::run_roles(&rig), &crate::backend::installed())?
            .into_result()?;
    let dome = rig.require_dome("a dome run").map_err(|e| input("rig.config", e))?.clone();
    // The plan's own `outputs.compressed_model` was checked by its validation; an override
    // is checked here, before anything is captured.
    if req.compressed_model == Some(btfrig_core::plan::CompressedModel::PcmfShared) {
        let textures = dome.led_count() * v.cameras.len() * v.rotations.len();
        if let Some(e) = btfrig_core::plan::dome::shared_basis_problem(textures) {
            return Err(input("compressed model", e));
        }
    }
    let rig_path = (!v.plan.rig.config.starts_with("builtin:")).then(|| base.join(&v.plan.rig.config));
    let brightness = crate::dome_dry_run::planning_brightness(&rig, rig_path.as_deref())?;
    let schedule = plan_dome(&rig, &v, brightness.e_per_s).map_err(|e| input("dome planning", e))?;
    let (what, light) = if dome.is_flash() { ("camera-array", "flash") } else { ("dome", "LED") };
    on_line(&format!(
        "{what} plan: {} {light}{} x {} views; {}",
        schedule.leds,
        if dome.is_flash() { "es" } else { "s" },
        v.cameras.len() * v.rotations.len(),
        schedule.reason
    ));
    on_line(&brightness.line());

    // Dataset: light = LED (or flash), view = rotation x cameras + camera over all the rig's
    // cameras (a camera array has one rotation: view = camera).
    let ncams = dome.camera_count();
    let size = v.plan.texture_size;
    let views: Vec<(usize, u32)> = v.rotations.iter().flat_map(|&k| v.cameras.iter().map(move |&c| (c, k))).collect();
    let view_id = |c: usize, k: u32| DomePlan::view_index(ncams, c, k);
    let mut pairs = Vec::new();
    for &(c, k) in &views {
        for j in 0..schedule.leds {
            pairs.push(StepId { light: j as u32, view: view_id(c, k) });
        }
    }
    // The processing model before the dataset: a missing calibration stops the run with
    // nothing written.
    let (processing, calibration, notes) = dome_processing(&rig, rig_path.as_deref(), size)?;
    for n in &notes {
        on_line(n);
    }
    let samplings = Samplings {
        // World directions of the LEDs (= sample frame at rotation 0); the exact per-capture
        // sample-frame directions are in the report's `dome.directions`.
        light: dome.led_directions().into_iter().map(DirectionDeg::from).collect(),
        view: (0..dome.rotations)
            .flat_map(|k| (0..ncams).map(move |c| (c, k)))
            .map(|(c, k)| DirectionDeg::from(dome.sample_directions(c, dome.rotation_rad(k), 0).1))
            .collect(),
        pairs: Some(pairs.clone()),
        skipped: Vec::new(),
    };
    let side = rig.plate.sample_side_m;
    let texture = TextureSpec {
        width: size as u32,
        height: size as u32,
        region: TextureRegion { center_m: [0.0, 0.0], size_m: [side, side] },
        format: TextureFormat::ExrFloat,
    };
    let manifest = Manifest::new(
        RigInfo { name: rig.rig.name.clone(), config_toml: rig_text },
        &req.plan_text,
        samplings,
        texture,
        false,
        rig.rig.seed,
    );
    let mut manifest = manifest;
    if v.plan.outputs.raw_frames {
        manifest.raw_groups = Some(crate::raw_schedule::RawSchedule::of(&schedule, &views, view_id).to_json());
    }
    let hash = manifest.plan.hash.clone();
    // The model's compressor before the dataset, so every committed texture reaches it; it
    // reads the manifest at the first texture.
    let compression = req
        .compressed_model
        .or(v.compressed_model)
        .map(|m| crate::sinks::CompressionSink::new(m, &req.out))
        .transpose()?;
    let (dataset, resumed, repaired) = match Dataset::create(&req.out, manifest) {
        Ok(d) => (d, false, None),
        Err(StoreError::AlreadyExists { .. }) => {
            let (d, r) = Dataset::open_for_resume(&req.out, &hash)
                .map_err(|source| RunError::Dataset { dir: req.out.clone(), source })?;
            // As a gonio run says it: what resuming found and repaired, each damaged texture
            // named (its view group is captured again).
            let mut notes = Vec::new();
            if let Some(t) = &r.torn_tail {
                notes.push(format!("torn journal tail dropped: {t}"));
            }
            if !r.removed_orphans.is_empty() {
                notes.push(format!("{} unjournaled file(s) removed", r.removed_orphans.len()));
            }
            notes.extend(r.retaken.iter().map(|(step, what)| format!("{what}: step {step} is captured again")));
            (d, true, (!notes.is_empty()).then(|| notes.join("; ")))
        }
        Err(source) => return Err(RunError::Dataset { dir: req.out.clone(), source }),
    };
    let completed = dataset.completed();
    // A rotation is done when every (LED, camera) of it is committed: the engine skips it.
    let done: HashSet<u32> = v
        .rotations
        .iter()
        .copied()
        .filter(|&k| {
            v.cameras.iter().all(|&c| {
                (0..schedule.leds).all(|j| completed.contains(&StepId { light: j as u32, view: view_id(c, k) }))
            })
        })
        .collect();

    let code = group_code(schedule.mode, &processing, schedule.pattern_scale)?;
    if matches!(code, GroupCode::Single) {
        on_line(&format!("demultiplexing skipped: single-light capture ({})", schedule.reason));
    }

    let commands = control.take().ok_or_else(|| RunError::Rig("this RunControl already drives a run".into()))?;
    let steps = EngineStep::from_dome_schedule(&schedule);
    // The engine skips the steps of the rotations done (a step's key names its rotation).
    let done: HashSet<StepKey> = steps.iter().map(|st| st.key).filter(|k| done.contains(&k.view)).collect();
    let done_before = done.len();
    let planned_s = crate::dome_dry_run::schedule_rig_time_s(&rig, &dome, &schedule);
    on_event(&RunEvent::Started {
        dataset: req.out.clone(),
        resumed,
        done_before,
        to_do: schedule.steps.len() - done_before,
        total: schedule.steps.len(),
        planned_hardware_s: planned_s,
        // The dome's estimate leaves out the serial round trips: it is the bound.
        critical_path_s: planned_s,
        repaired,
    });
    let textures_total = pairs.len() as u64;
    let textures_before = pairs.iter().filter(|p| completed.contains(p)).count() as u64;
    on_event(&RunEvent::TexturesCommitted {
        textures: textures_before,
        total: textures_total,
        previews: 0,
        stage_s: BTreeMap::new(),
    });

    let rt = time.runtime()?;
    // The consumer's latest `TexturesCommitted` (cumulative, so the newest says all: a full
    // queue of one keeps the latest).
    let (commit_tx, mut commit_rx) = tokio::sync::watch::channel::<Option<RunEvent>>(None);
    let mut state = Consumer::new(&v, schedule.leds, &processing, &code, schedule.pattern_scale, &dataset, view_id);
    state.sink = compression.as_ref().map(|c| c.texture_sink());
    state.commits = Some(Committing {
        tx: commit_tx,
        textures: textures_before,
        total: textures_total,
        previews: 0,
        preview: req.preview,
        stage_s: BTreeMap::new(),
    });
    let mut stop_links = Vec::new();
    let outcome: Result<(EngineOutcome, Stop), RunError> = rt.block_on(async {
        let opened = backend
            .open_dome(DomeOpenRequest {
                rig: &rig,
                plan: &v,
                plan_file: &req.plan_path,
                fault_scenario: &fault_name,
                time,
            })
            .await?;
        let OpenedDome { mut devices, truth, links } = opened;
        // The truth behind the frames, for the report's error figures only (a real rig has none).
        state.truth = truth;
        if let Some(t) = devices.turntable.as_mut() {
            t.home(MoveOptions::default()).await.map_err(|e| RunError::Rig(e.to_string()))?;
        }
        let (tx, rx) = mpsc::channel::<DomeCapture>(4);
        let devices = RigDevices::Dome { devices, patterns: schedule.patterns.clone() };
        // The engine pauses on a fault; a session that stops on faults ends there (`listen`),
        // with the report's status "paused", as a gonio run does.
        let mut handle = Engine::spawn(devices, steps, done, EngineSettings::default(), tx);
        let events = handle.events();
        let consume = async {
            // Owned here: a consumer that fails drops its receiver, and the engine stops.
            let mut rx = rx;
            while let Some(cap) = rx.recv().await {
                state.take(cap)?;
            }
            Ok::<(), RunError>(())
        };
        let listen = listen(commands, &handle, events, &mut commit_rx, stop_on_fault, on_event);
        let (c, stop) = tokio::join!(consume, listen);
        let engine = handle.join().await;
        c?;
        // What each device link cost (a GenICam camera's frames, bytes, wall time and dropped
        // buffers; serial firmware's exchanges); `links` is dropped after the devices.
        stop_links = links.link_use();
        Ok((engine, stop))
    });
    // The view groups committed after the engine's last event (the last one always is).
    if commit_rx.has_changed().unwrap_or(true) {
        if let Some(e) = commit_rx.borrow_and_update().clone() {
            on_event(&e);
        }
    }
    let (engine, stop) = outcome?;
    let (engine, aborted) = match engine {
        EngineOutcome::Finished(summary) => (summary, false),
        EngineOutcome::Aborted { summary, .. } => (summary, true),
    };
    let mut s = state.finish();
    s.warnings.splice(0..0, stop.warnings.iter().cloned());
    s.warnings.splice(0..0, notes.iter().cloned());
    s.dataset = req.out.clone();
    s.rig_kind = rig.rig.kind.as_str();
    s.light = light;
    s.leds = schedule.leds;
    s.views = views.len();
    s.mode = schedule.mode.describe();
    s.multiplex_reason = schedule.reason.clone();
    s.denoise_terms = v.plan.dome.denoise_terms;
    s.multiplex_gain_predicted = schedule.predicted_gain;
    s.multiplex_gain_per_group.iter_mut().for_each(|g| g.gain *= schedule.predicted_gain);
    s.time_saved_fraction = schedule.time_saved_fraction;
    s.hardware_s = engine.hardware_s;
    // What the session's listener lost (it fell behind the engine's event queue).
    s.events_dropped = stop.events_dropped;
    if stop.events_dropped > 0 {
        s.warnings.push(format!(
            "{} engine event(s) dropped: the run's listener fell behind the event queue; progress lines and \
             retry warnings were lost, frames and the journal are complete",
            stop.events_dropped
        ));
    }
    s.exposure_time_s = engine.exposure_s;
    s.frames = engine.captured as u64;
    s.views_resumed = engine.skipped_done / schedule.steps.len().div_ceil(v.rotations.len()).max(1);
    s.wall_s = wall.elapsed().as_secs_f64();
    s.peak_rss_mib = crate::peak_rss_mib();
    // A stop asked for after the last step leaves a complete run.
    s.stopped = aborted.then(|| stop.outcome.clone().unwrap_or(RunOutcome::Aborted));

    let mut extra = BTreeMap::new();
    // RunReport's own fields are not repeated in its flattened extra.
    for (k, val) in s.to_json().as_object().expect("an object") {
        if !["captures", "wall_s", "hardware_s", "warnings", "retries", "skipped", "stage_s"].contains(&k.as_str()) {
            extra.insert(k.clone(), val.clone());
        }
    }
    extra.insert(
        "dome".into(),
        json!({
            "views": views.iter().map(|&(c, k)| json!({
                "view": view_id(c, k), "camera": c, "rotation": k,
                "turntable_deg": 360.0 * f64::from(k) / f64::from(dome.rotations),
            })).collect::<Vec<_>>(),
            "directions": "light j, view v: DomeConfig::sample_directions(camera, turntable, j) (sample frame)",
        }),
    );
    extra.insert("calibration".into(), calibration);
    extra.insert("rig_time".into(), json!(time.name()));
    extra.insert(
        "preflight".into(),
        preflight.devices.iter().map(crate::preflight::DeviceCheck::to_json).collect::<serde_json::Value>(),
    );
    if !stop_links.is_empty() {
        extra.insert("links".into(), stop_links.iter().map(crate::backend::LinkUse::to_json).collect());
    }
    extra.insert("planning_brightness".into(), json!({ "e_per_s": brightness.e_per_s, "source": brightness.source }));
    // Like the gonio report: every texture of the dataset, and this session's apart.
    extra.insert("captures_this_session".into(), json!(s.textures));
    if let (Some(RunOutcome::Paused { .. }), Some(step)) = (&s.stopped, stop.paused_step) {
        extra.insert("paused_step".into(), step);
    }
    let report = RunReport {
        captures: textures_before + s.textures,
        wall_s: s.wall_s,
        hardware_s: Some(s.hardware_s),
        stage_s: BTreeMap::new(),
        skipped: BTreeMap::new(),
        retries: u64::from(engine.retries),
        warnings: s.warnings.clone(),
        extra,
    };
    let mut dataset = dataset;
    dataset.finish(&report).map_err(RunError::Report)?;
    drop(dataset);
    // As after a gonio run: a finished session builds, writes, measures and journals the
    // model (or finds it journaled intact); one that stopped leaves it to its resume.
    s.compression = compression.map(|c| c.finish(s.stopped.as_ref().unwrap_or(&RunOutcome::Finished)));
    Ok(s)
}

/// Replaces the dataset's `preview.png` with `tex` (`size x size`), tone-mapped as the gonio
/// pipeline's live preview is (`btfrig_process::tone_map_preview`, at least 256 px); false
/// when it could not be written (a preview is not data: the run goes on).
fn write_preview(dataset: &Dataset, tex: &[[f32; 3]], size: usize) -> bool {
    let (width, height, rgb) = btfrig_process::tone_map_preview(tex, size, size, 256);
    btfrig_imageio::encode_srgb8_png(Path::new(btfrig_store::PREVIEW_FILE), width, height, &rgb)
        .ok()
        .is_some_and(|png| dataset.write_preview(&png).is_ok())
}

/// How a session was asked to stop, if it was.
#[derive(Default)]
struct Stop {
    outcome: Option<RunOutcome>,
    /// The failed step a session that stops on faults paused on (`paused_step` in the report).
    paused_step: Option<serde_json::Value>,
    /// The engine's warnings (retries with their cause).
    warnings: Vec<String>,
    /// Engine events the listener lost (`Lagged`).
    events_dropped: u64,
}

/// Forwards `control`'s commands to the engine, and the engine's events and the consumer's
/// commits to `on_event`, until the engine ends. `stop_on_fault`: a step that failed (the
/// engine pauses on it) ends the session as paused, resumable by running the plan again.
async fn listen(
    mut control: mpsc::Receiver<Command>,
    engine: &RunHandle,
    mut events: tokio::sync::broadcast::Receiver<Event>,
    commits: &mut tokio::sync::watch::Receiver<Option<RunEvent>>,
    stop_on_fault: bool,
    on_event: &mut dyn FnMut(&RunEvent),
) -> Stop {
    let mut stop = Stop::default();
    let mut control_open = true;
    let mut commits_open = true;
    // A command the engine's queue refused (full) is a warning; after the engine ended there
    // is nothing to steer.
    let send = |r: Result<(), CommandError>, on_event: &mut dyn FnMut(&RunEvent)| {
        if let Err(e @ CommandError::Full { .. }) = r {
            on_event(&RunEvent::Warning(format!("engine: {e}")));
        }
    };
    loop {
        tokio::select! {
            ev = events.recv() => match ev {
                // The engine is done (it dropped its sender).
                Err(tokio::sync::broadcast::error::RecvError::Closed)
                | Ok(Event::Finished(_) | Event::Aborted(_)) => return stop,
                // Events are advisory: counted and reported, frames and journal unaffected.
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => stop.events_dropped += n,
                Ok(Event::Progress { done, total, eta_s }) => on_event(&RunEvent::Progress { done, total, eta_s }),
                Ok(Event::Warning(w)) => {
                    on_event(&RunEvent::Warning(w.clone()));
                    stop.warnings.push(w);
                }
                Ok(Event::Paused { reason }) => {
                    on_event(&RunEvent::Paused { reason: reason.to_string(), fault: None });
                    if let PauseReason::StepFailed {
                        index,
                        step: StepKind::Dome { rotation, shot, .. },
                        device,
                        kind,
                        message,
                        ..
                    } = &reason
                    {
                        if stop_on_fault && stop.outcome.is_none() {
                            on_event(&RunEvent::Stopping { reason: reason.to_string() });
                            stop.outcome = Some(RunOutcome::Paused { reason: reason.to_string(), fault: None });
                            stop.paused_step = Some(json!({
                                "index": index, "rotation": rotation, "shot": format!("{shot:?}"),
                                "device": device, "kind": kind.to_string(), "message": message,
                            }));
                            // The engine is paused on the failed step: end it there.
                            send(engine.abort(), on_event);
                        }
                    }
                }
                Ok(Event::Resumed) => on_event(&RunEvent::Resumed),
                // A step is a pattern at a rotation, not a (light, view) capture.
                Ok(Event::StepDone { index, step: StepKind::Dome { rotation, .. }, attempts, .. }) => {
                    on_event(&RunEvent::DomeStepDone { index, rotation, attempts })
                }
                Ok(Event::StepDone { .. }) => {}
            },
            r = commits.changed(), if commits_open => match r {
                Ok(()) => {
                    if let Some(e) = commits.borrow_and_update().clone() {
                        on_event(&e);
                    }
                }
                Err(_) => commits_open = false,
            },
            c = control.recv(), if control_open => {
                let sent = match c {
                    None => {
                        control_open = false;
                        continue;
                    }
                    Some(Command::Pause) => engine.pause(),
                    Some(Command::Resume) => engine.resume(),
                    Some(c @ (Command::Abort | Command::Interrupt(_))) => {
                        let end = match c {
                            Command::Interrupt(signal) => RunOutcome::Interrupted(signal),
                            _ => RunOutcome::Aborted,
                        };
                        if stop.outcome.is_none() {
                            on_event(&RunEvent::Stopping { reason: end.reason().unwrap_or_default() });
                            stop.outcome = Some(end);
                        }
                        engine.abort()
                    }
                };
                send(sent, on_event);
            }
        }
    }
}

/// The code a view group's patterns were captured with, its demultiplexers given the lights'
/// calibrated power (`processing.leds`) at the power the patterns fire them at
/// (`pattern_scale`): a run's and a reprocessing's.
pub(crate) fn group_code(
    mode: DomeMode,
    processing: &DomeProcessing,
    pattern_scale: f64,
) -> Result<GroupCode, RunError> {
    let fired: Vec<f64> = processing.leds.power.iter().map(|p| p * pattern_scale).collect();
    Ok(match mode {
        DomeMode::Single => GroupCode::Single,
        DomeMode::Multiplexed { order } => {
            GroupCode::multiplexed(order, &fired).map_err(|e| input("demultiplexer", e))?
        }
        DomeMode::Grouped { order, groups } => {
            GroupCode::grouped(order, groups, &fired).map_err(|e| input("demultiplexer", e))?
        }
    })
}

/// The dome pipeline's processing model from the rig config and the calibration files it
/// names, never the simulator: the model every rig shares (`crate::model::rig_model`: the lens
/// from `[camera] calibration`, the colour model from `[camera] color_calibration`, dark/flat
/// from `[camera] dark_flat`), and LED powers and colours from `[dome] led_calibration` (else
/// equal lights, relative units). Returns it, the report's `calibration` record, and one line
/// per missing calibration (the report's warnings say what the textures are then).
pub(crate) fn dome_processing(
    rig: &btfrig_core::config::RigConfig,
    rig_path: Option<&Path>,
    size: usize,
) -> Result<(DomeProcessing, serde_json::Value, Vec<String>), RunError> {
    let dome = rig.require_dome("a dome run").map_err(|e| input("rig.config", e))?.clone();
    let leds = btfrig_calibrate::leds::processing_leds(rig, rig_path).map_err(|e| input("LED calibration", e))?;
    let mut model = crate::model::rig_model(rig, rig_path, None)?;
    let light = if dome.is_flash() { "flash" } else { "LED" };
    // The gonio lamp's note does not apply: a dome's light is its per-LED calibration.
    model.notes.retain(|n| n != btfrig_process::model::NO_LIGHT_NOTE);
    if leds.is_none() {
        model.notes.insert(
            0,
            format!(
                "no {light} calibration: textures in relative units (every {light} counted equal; name one with \
                 [dome] led_calibration)"
            ),
        );
    }
    if model.dark_flat.is_none() {
        model.notes.push(
            "no dark/flat calibration: the mean dark current is subtracted and the lens model's vignetting divided \
             out (name one with [camera] dark_flat)"
                .to_string(),
        );
    }
    let model =
        model.with_source("light", dome.led_calibration.clone().unwrap_or_else(|| "none: relative units".to_string()));
    let record = json!({
        "camera": rig.camera.calibration,
        "leds": dome.led_calibration,
        "colour": rig.camera.color_calibration,
        "dark_flat": model.dark_flat.as_ref().map(|d| json!({
            "reference": rig.camera.dark_flat,
            "source": model.sources.iter().find(|s| s.part == "dark_flat").map(|s| s.source.clone()),
            "defects": d.dark.defects(),
            "f_numbers": d.flats.iter().map(|f| f.f_number).collect::<Vec<_>>(),
        })),
        "units": if leds.is_some() { "radiance factor" } else { "relative" },
    });
    let notes = model.notes.clone();
    let leds = leds.map(|f| LedLight { power: f.powers(), colour: f.colours(), nominal_irradiance: f.reference_rate });
    let processing = DomeProcessing::new(model, dome, rig.sensor.cfa.bayer(), leds, size, Filter::Footprint { max: 4 })
        .map_err(|e| input("dome processing model", e))?;
    Ok((processing, record, notes))
}

/// The pipeline side of a dome run (and of a reprocessing, `crate::dome_reprocess`): collects
/// frames per view group, keeps them when the dataset does (`raw_groups`), demultiplexes,
/// stores.
pub(crate) struct Consumer<'a, F: Fn(usize, u32) -> u32> {
    v: &'a ValidatedDomePlan,
    /// Lights.
    leds: usize,
    processing: &'a DomeProcessing,
    code: &'a GroupCode,
    /// The patterns' power relative to the calibrated (`group_code`).
    pattern_scale: f64,
    dataset: &'a Dataset,
    /// The truth behind the frames, consulted only for the report's error figures.
    truth: Option<Arc<dyn DomeTruthProbe>>,
    /// The streaming compression model's sink: every texture committed, as it is stored.
    sink: Option<Arc<dyn btfrig_process::TextureSink>>,
    view_id: F,
    stacks: HashMap<usize, GroupStack>,
    references: Vec<(usize, f64, Vec<f32>)>,
    /// The first camera's first group: its mosaics, photosites per mosaic, exposure, gain,
    /// pose used and the true turntable angle (for the reference figures).
    first_group: Option<(Vec<f32>, usize, f64, f64, GroupPose, f64)>,
    out: DomeRunSummary,
    rmse: Vec<(f64, f64)>,
    /// Sums of the stored textures and of their truths (brightness error).
    brightness: (f64, f64),
    /// `rmse` and `brightness` over the interior texels.
    rmse_interior: Vec<(f64, f64)>,
    /// Per channel, the sums of the interior texels of the textures and of their truths.
    brightness_interior: [(f64, f64); 3],
    texel_err: TexelErrorTotals,
    nominal_texel_err: TexelErrorTotals,
    commits: Option<Committing>,
    /// Per camera slot, the raw frames of its group written so far (when the dataset keeps
    /// them), journaled with the group's textures.
    frames: HashMap<usize, Vec<FileRecord>>,
}

/// What the consumer reports after each view group it commits.
struct Committing {
    tx: tokio::sync::watch::Sender<Option<RunEvent>>,
    /// Textures in the dataset (earlier sessions included).
    textures: u64,
    total: u64,
    previews: u64,
    /// Write `preview.png` after each view group.
    preview: bool,
    stage_s: BTreeMap<String, f64>,
}

impl<'a, F: Fn(usize, u32) -> u32> Consumer<'a, F> {
    pub(crate) fn new(
        v: &'a ValidatedDomePlan,
        leds: usize,
        processing: &'a DomeProcessing,
        code: &'a GroupCode,
        pattern_scale: f64,
        dataset: &'a Dataset,
        view_id: F,
    ) -> Self {
        Consumer {
            v,
            leds,
            processing,
            code,
            pattern_scale,
            dataset,
            truth: None,
            sink: None,
            view_id,
            stacks: HashMap::new(),
            references: Vec::new(),
            first_group: None,
            out: DomeRunSummary::default(),
            rmse: Vec::new(),
            brightness: (0.0, 0.0),
            rmse_interior: Vec::new(),
            brightness_interior: [(0.0, 0.0); 3],
            texel_err: TexelErrorTotals::default(),
            nominal_texel_err: TexelErrorTotals::default(),
            commits: None,
            frames: HashMap::new(),
        }
    }

    pub(crate) fn take(&mut self, cap: DomeCapture) -> Result<(), RunError> {
        let leds = self.leds;
        let frames_per_group = self.code.frames(leds);
        let step = cap.step;
        match step.shot {
            DomeShot::Reference(j) => {
                // Only the first camera's reference frame is measured.
                let f = &cap.frames[0];
                let sig = self.processing.signal(f).map_err(|e| input("dome pipeline", e))?;
                self.references.push((j, f.meta.exposure_s, sig));
                if self.references.len() == self.v.plan.dome.reference_leds.min(leds) {
                    self.measure(self.v.cameras[0])?;
                }
            }
            DomeShot::Pattern(p) => {
                for (slot, frame) in cap.frames.iter().enumerate() {
                    let c = self.v.cameras[slot];
                    let stack = self.stacks.entry(slot).or_insert_with(|| {
                        GroupStack::new(
                            c,
                            step.rotation,
                            step.turntable_rad,
                            frames_per_group,
                            frame.width,
                            frame.height,
                        )
                    });
                    self.processing.add(stack, p, frame).map_err(|e| input("dome pipeline", e))?;
                    self.out.group_bytes = self.out.group_bytes.max(stack.bytes());
                    // A group journaled by an earlier session is complete, textures and all
                    // (resuming retakes any other: `Dataset::open_for_resume`).
                    let view = (self.view_id)(c, step.rotation);
                    if self.dataset.manifest().raw_groups.is_some() && self.dataset.frames_record(view).is_none() {
                        let file = self.dataset.write_group_frame(view, p, frame).map_err(|e| input("dataset", e))?;
                        self.frames.entry(slot).or_default().push(file);
                    }
                }
                if p + 1 == frames_per_group {
                    for slot in 0..cap.frames.len() {
                        let stack = self.stacks.remove(&slot).expect("a stack per camera");
                        let frames = self.frames.remove(&slot);
                        self.finish_group(stack, frames, slot == 0, cap.attempts)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// Registers, demultiplexes and stores a complete group; `frames`, its raw frames written
    /// this session, are journaled first, then its textures one by one: a crash in between
    /// leaves frames without all their textures, which resuming takes again as a whole.
    fn finish_group(
        &mut self,
        stack: GroupStack,
        frames: Option<Vec<FileRecord>>,
        first_camera: bool,
        attempts: u32,
    ) -> Result<(), RunError> {
        if !stack.is_complete() {
            return Err(input(
                "dome pipeline",
                format!("camera {} rotation {}: group incomplete", stack.camera, stack.rotation),
            ));
        }
        let (c, k, rad, exp, gain) = (stack.camera, stack.rotation, stack.turntable_rad, stack.exposure_s, stack.gain);
        let t0 = Instant::now();
        let pose = self.processing.register(&stack);
        let register_s = t0.elapsed().as_secs_f64();
        self.out.registrations_reused += stack.frames().saturating_sub(1) as u64;
        match pose.source {
            PoseSource::Markers => self.out.registered += 1,
            _ => {
                self.out.fallbacks += 1;
                self.out.warnings.push(format!(
                    "camera {c} rotation {k}: registration failed ({}), the nominal pose is used",
                    pose.reason.as_deref().unwrap_or("no reason")
                ));
            }
        }
        // The truth of the view: the turntable's true angle (the sim's positioning error).
        let true_rad = self.truth.as_ref().map_or(rad, |t| t.true_turntable(c, stack.timestamp_s).unwrap_or(rad));
        if let Some(truth) = &self.truth {
            let true_pose = truth.pose(c, true_rad);
            let (cam, region) = (&self.processing.model.camera, self.processing.region());
            let size = self.v.plan.texture_size;
            let err = |p| {
                btfrig_registration::texel_position_error_with_cameras(&true_pose, truth.camera(), p, cam, region, size)
            };
            self.texel_err.add(err(&pose.pose));
            self.nominal_texel_err.add(err(&pose.nominal));
        }
        let started = Instant::now();
        let result = self.processing.demultiplex(stack, self.code).map_err(|e| input("demultiplexing", e))?;
        if let Some(report) = &result.report {
            for f in &report.faults {
                if f.source >= self.leds {
                    continue;
                }
                let light = if self.processing.dome.is_flash() { "flash" } else { "LED" };
                let line = format!(
                    "camera {c} rotation {k}: {light} {} {} (z = {:.1}{}), solved around by least squares",
                    f.source,
                    f.kind.name(),
                    f.evidence.z,
                    if f.evidence.ambiguous { ", ambiguous" } else { "" }
                );
                self.out.faults.push(format!("camera {c} rotation {k}: {light} {} {}", f.source, f.kind.name()));
                self.out.warnings.push(line);
            }
        }
        let demux_s = started.elapsed().as_secs_f64();
        if let Some(report) = &result.report {
            let gain = self.group_noise_ratio(report);
            let view = (self.view_id)(c, k);
            let faults = report.faults.iter().filter(|f| f.source < self.leds).count();
            self.out.multiplex_gain_per_group.push(GroupGain { view, camera: c, rotation: k, faults, ..gain });
        }
        // A stuck LED's own image is recovered only on average (docs/multiplexing.md): it is
        // stored, but left out of the texture error, which speaks for the healthy LEDs.
        let faulty: Vec<usize> =
            result.report.as_ref().map_or(Vec::new(), |r| r.faults.iter().map(|f| f.source).collect());
        let leds = self.leds;
        let size = self.v.plan.texture_size;
        let texture = |j: usize| self.processing.texture(result.mosaic(j), &pose.pose, j, exp, gain);
        // Denoising projects the whole group's textures at once; otherwise they stream one by
        // one (the group's memory is then one texture, not `leds`).
        let mut denoised: Option<Vec<Vec<[f32; 3]>>> = None;
        let mut denoise_s = 0.0;
        if let Some(terms) = self.v.plan.dome.denoise_terms {
            let t0 = Instant::now();
            let texes: Vec<Vec<[f32; 3]>> =
                (0..leds).map(texture).collect::<Result<_, _>>().map_err(|e| input("dome pipeline", e))?;
            let skip: Vec<bool> = (0..leds).map(|j| faulty.contains(&j)).collect();
            // The pipeline is linear, so a mosaic of ones gives each texel's DN-to-texture factor.
            let ones = vec![1.0f32; result.cols];
            let scales: Vec<Vec<[f32; 3]>> = (0..leds)
                .map(|j| self.processing.texture(&ones, &pose.pose, j, exp, gain))
                .collect::<Result<_, _>>()
                .map_err(|e| input("dome pipeline", e))?;
            let (texes, p) = denoise_group(texes, &scales, terms, &skip).map_err(|e| input("denoising", e))?;
            self.out.denoise_energy_kept.push(p.energy_kept);
            denoise_s = t0.elapsed().as_secs_f64();
            self.out.denoise_s += denoise_s;
            denoised = Some(texes);
        }
        let textures_started = Instant::now();
        if let Some(files) = frames {
            self.dataset.commit_frames((self.view_id)(c, k), files).map_err(|e| input("dataset", e))?;
        }
        let want_preview = self.commits.as_ref().is_some_and(|c| c.preview);
        // The preview: the group's brightest texture (mean over texels and channels) of a
        // light not reported faulty.
        let mut brightest: Option<(f64, Vec<[f32; 3]>)> = None;
        let mut written = 0u64;
        for j in 0..leds {
            let id = StepId { light: j as u32, view: (self.view_id)(c, k) };
            if self.dataset.completed().contains(&id) {
                continue;
            }
            let t0 = Instant::now();
            let tex = match &mut denoised {
                Some(all) => std::mem::take(&mut all[j]),
                None => texture(j).map_err(|e| input("dome pipeline", e))?,
            };
            if let Some(truth) = self.truth.as_ref().filter(|_| !faulty.contains(&j)) {
                let gt = truth.texture(c, true_rad, j, size);
                self.rmse.push(sq_err(&tex, &gt));
                self.brightness.0 += sum_texels(&tex);
                self.brightness.1 += sum_texels(&gt);
                let (tex_in, gt_in) = (interior(&tex, size), interior(&gt, size));
                self.rmse_interior.push(sq_err(&tex_in, &gt_in));
                for (a, t) in tex_in.iter().zip(&gt_in) {
                    for (c, sums) in self.brightness_interior.iter_mut().enumerate() {
                        sums.0 += f64::from(a[c]);
                        sums.1 += f64::from(t[c]);
                    }
                }
            }
            let file = self.dataset.write_texture(id, &tex, size, size).map_err(|e| input("dataset", e))?;
            let timing = StepTiming {
                started_unix_s: 0.0,
                wall_s: t0.elapsed().as_secs_f64(),
                hardware_s: None,
                stage_s: [("demultiplex".to_string(), demux_s / self.leds as f64)].into_iter().collect(),
            };
            self.dataset.commit_step(id, vec![file], attempts, timing).map_err(|e| input("dataset", e))?;
            if let Some(sink) = &self.sink {
                sink.accept(id, &tex);
            }
            self.out.textures += 1;
            written += 1;
            if want_preview && !faulty.contains(&j) {
                let mean = tex.iter().map(|t| f64::from(t[0] + t[1] + t[2])).sum::<f64>() / tex.len().max(1) as f64;
                if mean.is_finite() && brightest.as_ref().is_none_or(|(m, _)| mean > *m) {
                    brightest = Some((mean, tex));
                }
            }
        }
        let textures_s = textures_started.elapsed().as_secs_f64();
        if first_camera && self.first_group.is_none() {
            self.first_group = Some((result.mosaics, result.cols, exp, gain, pose, true_rad));
        }
        if let Some(commits) = self.commits.as_mut() {
            commits.textures += written;
            *commits.stage_s.entry("register".into()).or_insert(0.0) += register_s;
            *commits.stage_s.entry("demultiplex".into()).or_insert(0.0) += demux_s;
            *commits.stage_s.entry("textures".into()).or_insert(0.0) += textures_s;
            if self.v.plan.dome.denoise_terms.is_some() {
                *commits.stage_s.entry("denoise".into()).or_insert(0.0) += denoise_s;
            }
            if let Some((_, tex)) = brightest {
                let t0 = Instant::now();
                if write_preview(self.dataset, &tex, size) {
                    commits.previews += 1;
                }
                *commits.stage_s.entry("preview".into()).or_insert(0.0) += t0.elapsed().as_secs_f64();
            }
            // The listener may be gone (the session is ending): the commit stands regardless.
            commits.tx.send_replace(Some(RunEvent::TexturesCommitted {
                textures: commits.textures,
                total: commits.total,
                previews: commits.previews,
                stage_s: commits.stage_s.clone(),
            }));
        }
        Ok(())
    }

    /// A group's fault-free code noise over its own, averaged over the lights solved for (the
    /// run multiplies it by the predicted gain; view, camera and rotation left 0).
    fn group_noise_ratio(&self, report: &btfrig_mux::lsq::DemuxReport) -> GroupGain {
        // The fast path's noise per unit frame noise is 2√n/(n+1)/a_j (btfrig_mux::lsq).
        let order = match self.code {
            GroupCode::Single => 1,
            GroupCode::Multiplexed(d) => d.s().order(),
            GroupCode::Grouped(ds) => ds.first().map_or(1, |d| d.s().order()),
        } as f64;
        let base = 2.0 * order.sqrt() / (order + 1.0);
        let ratios: Vec<f64> = (0..self.leds)
            .filter_map(|j| {
                let (sigma, a) = (*report.noise_gain.get(j)?, self.processing.leds.power.get(j)? * self.pattern_scale);
                (sigma > 0.0 && a > 0.0).then(|| base / (a * sigma))
            })
            .collect();
        let gain = if ratios.is_empty() { 0.0 } else { ratios.iter().sum::<f64>() / ratios.len() as f64 };
        GroupGain { view: 0, camera: 0, rotation: 0, gain, lights: ratios.len(), faults: 0 }
    }

    /// The measured gain and the reference textures' error (module docs).
    fn measure(&mut self, c: usize) -> Result<(), RunError> {
        let Some((mosaics, cols, exp, gain, pose, true_rad)) = self.first_group.as_ref() else { return Ok(()) };
        let Some(probe) = self.truth.as_ref() else { return Ok(()) };
        let (leds, rad) = (self.leds, *true_rad);
        let stuck_on = probe.stuck_on();
        // The measured signals are flat-fielded when the model has a flat: the noise-free
        // references are divided by the same flat, so the SNRs compare noise, not vignetting.
        let flat = self.processing.model.dark_flat.as_ref().and_then(|d| d.flat_for(None).ok());
        let fielded = |mut t: Vec<f32>| {
            if let Some(f) = flat {
                t.iter_mut().zip(&f.gain).filter(|(_, g)| **g > 0.0).for_each(|(v, g)| *v /= g);
            }
            t
        };
        let sample =
            btfrig_imaging::exposure::sample_footprint(probe.camera(), &probe.pose(c, rad), self.processing.region())
                .mask;
        let (mut g, mut ref_err, mut mux_err) = (Vec::new(), Vec::new(), Vec::new());
        for (j, ref_exp, sig) in &self.references {
            let mut single = vec![0.0; leds];
            single[*j] = 1.0;
            let truth_mux = fielded(probe.noise_free_dn(c, rad, &single, *exp, *gain));
            // The reference frame saw the stuck LEDs too.
            for &s in &stuck_on {
                single[s] = 1.0;
            }
            let truth_ref = fielded(probe.noise_free_dn(c, rad, &single, *ref_exp, *gain));
            let demuxed = &mosaics[j * cols..(j + 1) * cols];
            g.push(snr(demuxed, &truth_mux, &sample) / snr(sig, &truth_ref, &sample));
            let tex =
                self.processing.texture(sig, &pose.pose, *j, *ref_exp, *gain).map_err(|e| input("dome pipeline", e))?;
            let truth = probe.texture(c, rad, *j, self.v.plan.texture_size);
            ref_err.push(sq_err(&tex, &truth));
            let tex =
                self.processing.texture(demuxed, &pose.pose, *j, *exp, *gain).map_err(|e| input("dome pipeline", e))?;
            mux_err.push(sq_err(&tex, &truth));
        }
        if !g.is_empty() {
            self.out.multiplex_gain_measured = Some(g.iter().sum::<f64>() / g.len() as f64);
            self.out.reference_texture_rel_rmse = pooled(&ref_err);
            self.out.reference_mux_texture_rel_rmse = pooled(&mux_err);
        }
        Ok(())
    }

    pub(crate) fn finish(mut self) -> DomeRunSummary {
        self.out.texture_rel_rmse = pooled(&self.rmse);
        let (b, t) = self.brightness;
        self.out.texture_brightness_err = (t > 0.0).then(|| b / t - 1.0);
        self.out.texture_rel_rmse_interior = pooled(&self.rmse_interior);
        let [r, g, b] = self.brightness_interior;
        let (sum, truth) = (r.0 + g.0 + b.0, r.1 + g.1 + b.1);
        self.out.texture_brightness_err_interior = (truth > 0.0).then(|| sum / truth - 1.0);
        self.out.texture_channel_err_interior =
            [r, g, b].iter().all(|c| c.1 > 0.0).then(|| [r, g, b].map(|(s, t)| s / t - 1.0));
        self.out.registration_mean_texel_err = self.texel_err.mean();
        self.out.registration_max_texel_err = self.texel_err.max();
        self.out.nominal_mean_texel_err = self.nominal_texel_err.mean();
        self.out.nominal_max_texel_err = self.nominal_texel_err.max();
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interior_drops_the_outermost_ring() {
        let t: Vec<[f32; 3]> = (0..16).map(|i| [i as f32; 3]).collect();
        let inner: Vec<f32> = interior(&t, 4).iter().map(|p| p[0]).collect();
        assert_eq!(inner, vec![5.0, 6.0, 9.0, 10.0]);
        assert!(interior(&t[..4], 2).is_empty());
    }
}
