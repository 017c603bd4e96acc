//! Runs a measurement plan on a rig into a dataset, resumable: the one entry point that the
//! `btfrig` CLI (`btfrig run`, `btfrig demo`) uses, and that the HTTP daemon wraps.
//!
//! [`run`] loads and validates the plan, creates the dataset or resumes the same plan's,
//! plans the schedule, builds the simulated rig on a virtual-time tokio runtime, spawns the
//! engine, runs the processing pipeline and writes `report.json`. The caller watches
//! [`RunEvent`]s through a callback and steers the run from any thread with a
//! [`RunControl`]. However a session ends (finished, paused by a fault, interrupted,
//! aborted), the frames already captured are processed and committed first and the report
//! says how it ended; the dataset stays resumable with the same request.

#![warn(missing_docs)]

pub mod backend;
pub mod check;
pub mod dome;
pub mod dome_dry_run;
pub mod dome_reprocess;
pub mod dry_run;
pub mod emulated;
mod hdr;
mod light;
pub mod model;
pub mod plan;
pub mod report;
pub mod reprocess;
pub mod sinks;

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::ValidatedPlan;
use btfrig_acquire::{
    Engine, EngineSettings, EngineStep, Event, GonioDevices, PauseReason, RunOutcome as EngineOutcome, StepKey,
};
use btfrig_process::{ProcessSettings, Processor};
use btfrig_planner::{plan as plan_schedule, PairSelection, PlanRequest};
use btfrig_store::{Dataset, RunReport, StoreError};
use serde_json::json;
use tokio::sync::mpsc;

pub use crate::hdr::{journal_hdr, HdrFigures};
use crate::report::Session;
pub use btfrig_planner::Cancel;

/// Frames the engine may hold ready ahead of the pipeline (back-pressure beyond that).
const FRAME_CHANNEL: usize = 4;

/// Why a run could not start or went wrong (not a pause: that is a [`RunOutcome`]).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The plan does not parse or validate (every problem, each naming its field).
    #[error("{0}")]
    Plan(#[from] btfrig_core::plan::PlanErrors),
    /// Something the plan or the request names is unusable (rig config, material, faults).
    #[error("{what}: {message}")]
    Input {
        /// What was named, and where.
        what: String,
        /// What is wrong, and what is allowed.
        message: String,
    },
    /// The plan is for another kind of rig, or another rig, than the one that is to run it
    /// ([`check::check_for_rig`]).
    #[error(
        "the plan is a {plan_kind} for rig {plan_rig}, and the rig here is {rig:?} ({rig_kind}): \
         allowed here are {allowed} for rig {rig:?}"
    )]
    WrongRig {
        /// The plan's format ([`check::PlanKind::describe`]).
        plan_kind: &'static str,
        /// The rig the plan names: `"name" (kind)`, or its `rig.config` as written.
        plan_rig: String,
        /// The name of the rig that is to run it.
        rig: String,
        /// Its kind (`[rig] kind`).
        rig_kind: &'static str,
        /// The plans that rig runs ([`check::PlanKind::allowed`]).
        allowed: &'static str,
    },
    /// The plan captures nothing.
    #[error("{}: the plan captures nothing", plan.display())]
    Empty {
        /// The plan file.
        plan: PathBuf,
    },
    /// The dataset directory cannot be created or resumed (e.g. it holds another dataset).
    #[error("--out {}: {source}", dir.display())]
    Dataset {
        /// The directory.
        dir: PathBuf,
        /// The store's reason.
        source: StoreError,
    },
    /// The planner cannot schedule the plan.
    #[error("planning: {0}")]
    Planner(#[from] btfrig_planner::PlanError),
    /// The rig could not be built or prepared.
    #[error("rig: {0}")]
    Rig(String),
    /// Processing or writing a capture failed; the captures committed before it are kept.
    #[error("pipeline: {0}")]
    Pipeline(#[from] btfrig_process::PipelineError),
    /// Writing the report failed.
    #[error("writing the report: {0}")]
    Report(StoreError),
    /// The async runtime could not be built.
    #[error("runtime: {0}")]
    Runtime(std::io::Error),
    /// A signal ([`RunControl::interrupt`]) stopped the run while it was planning, before
    /// the dataset was created: nothing was written.
    #[error("interrupted by {} while planning, before the dataset was created: nothing was written", .0.name())]
    Interrupted(Signal),
    /// A [`btfrig_planner::Cancel`] flag stopped the work (a dry run whose client went
    /// away, a time limit).
    #[error("cancelled: {0}")]
    Cancelled(String),
}

/// What to run.
#[derive(Debug, Clone)]
pub struct RunRequest {
    /// The plan's TOML text (stored in the manifest; its hash identifies the dataset).
    pub plan_text: String,
    /// The plan's file: names it in messages; its directory anchors relative paths in it.
    /// For text without a file, any path in the directory the relative paths refer to.
    pub plan_path: PathBuf,
    /// The dataset directory (created, or a dataset of the same plan resumed).
    pub out: PathBuf,
    /// Fault scenario of the simulated rig instead of the plan's `run.fault_scenario`: an
    /// embedded name or a file (relative to the working directory). Fault injection belongs
    /// to the simulated rig, not to the measurement, so the plan hash does not change: a
    /// run that paused on a fatal fault resumes with the fault gone.
    pub faults: Option<String>,
    /// When a step fails with an error no retry helps: end the session, report `paused`
    /// and return (true, the CLI: nobody is there to fix the cause), or keep the engine
    /// paused and wait for [`RunControl::resume`] or [`RunControl::abort`] (false, a daemon
    /// with an operator).
    pub stop_on_fault: bool,
    /// On a simulated rig, also rectify every registered frame with the nominal pose and
    /// compare it with the truth (`texture_rel_rmse_nominal`): a second rectification per
    /// frame, so off by default (`btfrig demo` turns it on).
    pub compare_nominal: bool,
    /// The light calibration frames are converted with, and whether the lamp's drift is
    /// measured on the plate and corrected (`btfrig_process::light`); `None`: the lamp's
    /// power and colour come from the rig model.
    pub light: Option<btfrig_process::light::LightCorrection>,
    /// A measured dark model and master flats every frame is corrected with before
    /// demosaicing (`docs/dark-flat.md`); `None`: the sensor model's black level, dark current
    /// and the lens model's vignetting.
    pub dark_flat: Option<DarkFlatInput>,
    /// The compressed model to build while the run captures, instead of the plan's
    /// `outputs.compressed_model` (`btfrig run --compress`, `btfrig demo`); `None`: the
    /// plan's. The runner builds its sink ([`sinks::CompressionSink`]).
    pub compressed_model: Option<btfrig_core::plan::CompressedModel>,
    /// Faults injected into the emulated firmware of an emulated rig right after its backends
    /// connect, before the rig is prepared (fault tests, `crates/measurement/tests/serial_faults.rs`;
    /// see [`emulated::LinkFault`]). Like [`RunRequest::faults`] it is not part of the plan,
    /// so the same request without them resumes a dataset they paused. Empty by default;
    /// a fault for a device that is not emulated is an error.
    pub link_faults: Vec<emulated::LinkFault>,
    /// The device backends to open the rig with; `None`: the process's
    /// ([`backend::installed`]).
    pub backends: Option<BackendsHandle>,
}

/// A [`backend::BackendRegistry`] in a [`RunRequest`].
#[derive(Clone)]
pub struct BackendsHandle(pub backend::BackendRegistry);

impl std::fmt::Debug for BackendsHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BackendRegistry")
    }
}

/// A dark/flat calibration for a run, with where it came from (recorded in the manifest).
#[derive(Debug, Clone)]
pub struct DarkFlatInput {
    /// Where the calibration was read from (e.g. the directory `btfrig calibrate radiometric` wrote).
    pub source: String,
    /// The dark model and master flats.
    pub calibration: Arc<btfrig_process::dark_flat::DarkFlat>,
}

impl RunRequest {
    /// A request for the plan file `plan` into `out`.
    pub fn from_file(plan: &Path, out: &Path) -> Result<RunRequest, RunError> {
        let plan_text = std::fs::read_to_string(plan).map_err(|source| RunError::Read { path: plan.into(), source })?;
        Ok(RunRequest::from_text(plan_text, plan, out))
    }

    /// A request for plan text; `plan_path` as in [`RunRequest::plan_path`].
    pub fn from_text(plan_text: impl Into<String>, plan_path: &Path, out: &Path) -> RunRequest {
        RunRequest {
            plan_text: plan_text.into(),
            plan_path: plan_path.into(),
            out: out.into(),
            faults: None,
            stop_on_fault: true,
            compare_nominal: false,
            light: None,
            dark_flat: None,
            compressed_model: None,
            link_faults: Vec::new(),
            backends: None,
        }
    }

    /// With a compressed model instead of the plan's (see [`RunRequest::compressed_model`]).
    pub fn with_compressed_model(mut self, model: Option<btfrig_core::plan::CompressedModel>) -> RunRequest {
        self.compressed_model = model;
        self
    }

    /// With a dark/flat calibration (see [`RunRequest::dark_flat`]).
    pub fn with_dark_flat(mut self, dark_flat: Option<DarkFlatInput>) -> RunRequest {
        self.dark_flat = dark_flat;
        self
    }

    /// With a light calibration (see [`RunRequest::light`]).
    pub fn with_light(mut self, light: Option<btfrig_process::light::LightCorrection>) -> RunRequest {
        self.light = light;
        self
    }

    /// With the nominal-pose comparison on or off (see [`RunRequest::compare_nominal`]).
    pub fn with_nominal_comparison(mut self, on: bool) -> RunRequest {
        self.compare_nominal = on;
        self
    }

    /// With a fault-scenario override (see [`RunRequest::faults`]).
    pub fn with_faults(mut self, faults: Option<String>) -> RunRequest {
        self.faults = faults;
        self
    }

    /// With these device backends (see [`RunRequest::backends`]).
    pub fn with_backends(mut self, backends: backend::BackendRegistry) -> RunRequest {
        self.backends = Some(BackendsHandle(backends));
        self
    }

    /// With faults for the emulated firmware (see [`RunRequest::link_faults`]).
    pub fn with_link_faults(mut self, faults: Vec<emulated::LinkFault>) -> RunRequest {
        self.link_faults = faults;
        self
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Command {
    Pause,
    Resume,
    Abort,
    Interrupt(Signal),
}

/// The signal that interrupted a run ([`RunControl::interrupt`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signal {
    /// SIGINT (Ctrl-C).
    Int,
    /// SIGTERM (a service manager, `kill`, the daemon's shutdown).
    Term,
}

impl Signal {
    /// The signal's name, e.g. `SIGTERM`.
    pub fn name(self) -> &'static str {
        match self {
            Signal::Int => "SIGINT",
            Signal::Term => "SIGTERM",
        }
    }

    /// The exit code of a process this signal stopped: 128 + its number (the shell's
    /// convention): 130 for SIGINT, 143 for SIGTERM.
    pub fn exit_code(self) -> u8 {
        match self {
            Signal::Int => 128 + 2,
            Signal::Term => 128 + 15,
        }
    }
}

/// Commands a [`RunControl`] holds before the session reads them. Commands are tiny and
/// rare (an operator's pause, resume or abort, a signal); the session forwards them to the
/// engine as they come, so a full queue means a caller floods a run: the command fails with
/// [`ControlError::Full`] instead of waiting or growing the queue.
pub const CONTROL_CAPACITY: usize = 16;

/// Why a command did not reach the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ControlError {
    /// [`CONTROL_CAPACITY`] commands are waiting unread.
    #[error("the run already holds {CONTROL_CAPACITY} unread commands; wait for it to act on them")]
    Full,
    /// The session has ended; there is nothing to steer.
    #[error("the run has ended")]
    Ended,
}

/// Steers a run from outside, from any thread: clone it, hand one clone to [`run`].
/// Commands sent before the engine starts take effect when it does (at most
/// [`CONTROL_CAPACITY`] of them wait).
#[derive(Debug, Clone)]
pub struct RunControl {
    tx: mpsc::Sender<Command>,
    rx: Arc<Mutex<Option<mpsc::Receiver<Command>>>>,
    /// Set by [`RunControl::interrupt`]: stops the planning, which runs before the engine
    /// reads commands.
    cancel: btfrig_planner::Cancel,
    signal: Arc<Mutex<Option<Signal>>>,
}

impl Default for RunControl {
    fn default() -> Self {
        Self::new()
    }
}

impl RunControl {
    /// A new control, not yet attached to a run.
    pub fn new() -> RunControl {
        let (tx, rx) = mpsc::channel(CONTROL_CAPACITY);
        RunControl {
            tx,
            rx: Arc::new(Mutex::new(Some(rx))),
            cancel: btfrig_planner::Cancel::new(),
            signal: Arc::new(Mutex::new(None)),
        }
    }

    fn send(&self, c: Command) -> Result<(), ControlError> {
        self.tx.try_send(c).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => ControlError::Full,
            mpsc::error::TrySendError::Closed(_) => ControlError::Ended,
        })
    }

    /// Pause after the step under way; the session waits for resume or abort.
    pub fn pause(&self) -> Result<(), ControlError> {
        self.send(Command::Pause)
    }

    /// Resume a paused run (a failed step is tried again).
    pub fn resume(&self) -> Result<(), ControlError> {
        self.send(Command::Resume)
    }

    /// End the session after the step under way; report status `aborted`, resumable.
    pub fn abort(&self) -> Result<(), ControlError> {
        self.send(Command::Abort)
    }

    /// As [`RunControl::abort`], reported as `interrupted` by `signal`. During planning
    /// (before the dataset is created) the run stops at once with
    /// [`RunError::Interrupted`], leaving nothing behind (that part cannot fail).
    pub fn interrupt(&self, signal: Signal) -> Result<(), ControlError> {
        self.signal.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(signal);
        self.cancel.cancel();
        self.send(Command::Interrupt(signal))
    }

    /// The first signal [`RunControl::interrupt`] was called with.
    fn signal(&self) -> Option<Signal> {
        *self.signal.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn take(&self) -> Option<mpsc::Receiver<Command>> {
        self.rx.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// What a run tells its observer.
#[derive(Debug, Clone, PartialEq)]
pub enum RunEvent {
    /// The plan validated; the schedule of this many captures is being planned (before
    /// the dataset is created).
    Planning {
        /// Captures of the whole plan.
        captures: usize,
    },
    /// The dataset is open and the schedule planned; the rig is being prepared.
    Started {
        /// The dataset directory.
        dataset: PathBuf,
        /// True when an existing dataset of the same plan is resumed.
        resumed: bool,
        /// Captures done before this session.
        done_before: usize,
        /// Captures this session has to do.
        to_do: usize,
        /// Captures of the whole plan.
        total: usize,
        /// The planner's hardware time for the whole plan, seconds.
        planned_hardware_s: f64,
        /// The planner's lower bound, seconds.
        critical_path_s: f64,
        /// What resuming found and repaired (torn journal tail, orphans), if anything.
        repaired: Option<String>,
    },
    /// A capture was delivered by the engine.
    StepDone {
        /// Light index.
        light: u32,
        /// View index.
        view: u32,
        /// 1 + retries.
        attempts: u32,
    },
    /// Progress of the whole plan.
    Progress {
        /// Captures done (before and in this session).
        done: usize,
        /// Captures of the whole plan.
        total: usize,
        /// Remaining rig time from measured step times, seconds.
        eta_s: Option<f64>,
    },
    /// Something was retried or went wrong, but the run goes on.
    Warning(String),
    /// The engine is paused.
    Paused {
        /// Why.
        reason: String,
        /// The failed step, when a step failed.
        fault: Option<Fault>,
    },
    /// The engine goes on after a pause.
    Resumed,
    /// The pipeline committed a capture (textures, journal, preview written).
    Committed {
        /// Captures committed by this session so far.
        committed: u64,
        /// Previews written by this session so far (`preview.png` replaced each time).
        previews: u64,
        /// Captures delivered by the engine and not yet committed (the pipeline's queue).
        queued: u64,
        /// Seconds per pipeline stage summed over this session's commits.
        stage_s: BTreeMap<String, f64>,
    },
    /// The session is ending: the frames in flight are processed and committed first.
    Stopping {
        /// Why.
        reason: String,
    },
    /// A dome run's step was delivered by the engine: one pattern (or reference light) at one
    /// rotation, a frame per camera ([`dome::run_controlled`]; gonio runs send `StepDone`).
    DomeStepDone {
        /// Position in the schedule.
        index: usize,
        /// The turntable rotation index (0 on a camera array).
        rotation: u32,
        /// 1 + retries.
        attempts: u32,
    },
    /// What a dome run's dataset holds: sent once when the session starts (what earlier
    /// sessions committed) and after every view group it commits (every light's texture of
    /// one camera at one rotation, committed at once after demultiplexing).
    TexturesCommitted {
        /// Textures in the dataset, earlier sessions included.
        textures: u64,
        /// Textures of the whole plan (lights x views).
        total: u64,
        /// Previews written by this session so far (`preview.png` replaced after each view
        /// group when [`dome::DomeRunRequest::preview`] asks for it).
        previews: u64,
        /// Seconds per processing stage summed over this session's view groups.
        stage_s: BTreeMap<String, f64>,
    },
}

/// A step that failed with an error no retry helps (or that ran out of retries).
#[derive(Debug, Clone, PartialEq)]
pub struct Fault {
    /// Position of the step in the schedule.
    pub index: usize,
    /// Light index of the capture.
    pub light: u32,
    /// View index of the capture.
    pub view: u32,
    /// The device that failed.
    pub device: String,
    /// The error's kind (`timeout`, `other`, ...).
    pub kind: String,
    /// The device error and what the engine did.
    pub message: String,
}

/// How a session ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// Every capture of the plan is done.
    Finished,
    /// Every capture was already done; nothing was run and the report is unchanged.
    NothingToDo,
    /// A step failed in a way no retry helps; fix the cause and run again to resume.
    Paused {
        /// Why, as one line.
        reason: String,
        /// The failed step.
        fault: Option<Fault>,
    },
    /// Interrupted by a signal (Ctrl-C, SIGTERM); resumable.
    Interrupted(Signal),
    /// Aborted on request; resumable.
    Aborted,
}

impl RunOutcome {
    /// The `status` written to `report.json`.
    pub fn status(&self) -> &'static str {
        match self {
            RunOutcome::Finished | RunOutcome::NothingToDo => "finished",
            RunOutcome::Paused { .. } => "paused",
            RunOutcome::Interrupted(_) => "interrupted",
            RunOutcome::Aborted => "aborted",
        }
    }

    /// Why the run did not finish.
    pub fn reason(&self) -> Option<String> {
        match self {
            RunOutcome::Paused { reason, .. } => Some(reason.clone()),
            RunOutcome::Interrupted(signal) => Some(format!("interrupted ({})", signal.name())),
            RunOutcome::Aborted => Some("aborted on request".into()),
            _ => None,
        }
    }
}

/// The figures of a run over all its sessions (as in `report.json`).
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    /// How this session ended.
    pub outcome: RunOutcome,
    /// The dataset directory.
    pub dataset: PathBuf,
    /// Captures done (the journal's count).
    pub captures: u64,
    /// Captures committed by this session.
    pub captures_this_session: u64,
    /// Captures of the whole plan.
    pub planned_captures: u64,
    /// Pairs not captured, by reason (the plan's skips and steps skipped in the run).
    pub skipped: BTreeMap<String, u64>,
    /// Simulated hardware (rig-clock) time summed over the reported sessions, seconds.
    pub hardware_s: f64,
    /// The planner's lower bound for the whole schedule, seconds.
    pub critical_path_s: f64,
    /// The whole schedule's captures in the naive nested-loop order, seconds.
    pub naive_order_hardware_s: f64,
    /// Wall time summed over the reported sessions, seconds.
    pub wall_s: f64,
    /// Seconds per pipeline stage over every journaled capture.
    pub stage_s: BTreeMap<String, f64>,
    /// Rectified textures against ground truth over the reported sessions' captures.
    pub texture_rel_rmse: Option<f64>,
    /// The same had the nominal pose been used (only from sessions that compared:
    /// [`RunRequest::compare_nominal`]).
    pub texture_rel_rmse_nominal: Option<f64>,
    /// Mean CIEDE2000 on the held-out chart patches of the colour calibration the textures
    /// were converted with (`docs/color.md`); `None` without one.
    pub color_delta_e00_mean: Option<f64>,
    /// Largest CIEDE2000 on those patches.
    pub color_delta_e00_max: Option<f64>,
    /// Journaled textures rectified with a pose registered from the markers.
    pub registered: u64,
    /// Journaled textures rectified with the nominal pose because registration failed.
    pub fallbacks: u64,
    /// Journaled textures rectified with the nominal pose because the plan says so.
    pub nominal_by_plan: u64,
    /// Mean texel position error of the poses used against the true poses, texels, over the
    /// reported sessions' captures (simulated rig).
    pub registration_mean_texel_err: Option<f64>,
    /// Largest texel position error of the poses used, texels.
    pub registration_max_texel_err: Option<f64>,
    /// Mean texel position error of the nominal poses, texels.
    pub nominal_mean_texel_err: Option<f64>,
    /// Largest texel position error of the nominal poses, texels.
    pub nominal_max_texel_err: Option<f64>,
    /// Retries of the journaled captures (attempts beyond the first).
    pub retries: u64,
    /// Warnings of all reported sessions.
    pub warnings: Vec<String>,
    /// Sessions in the report (this one included).
    pub sessions: usize,
    /// Captures journaled by sessions that left no report (killed): their hardware and wall
    /// time and texture error are not in the figures.
    pub unreported_captures: u64,
    /// Peak resident memory of this process so far (Linux `VmHWM`), MiB; `None` where the
    /// system does not say. Shows that memory stays bounded by frames in flight, not captures.
    pub peak_rss_mib: Option<f64>,
    /// This session's lamp figures, with a light calibration only (`RunRequest::light`).
    pub lamp: Option<btfrig_process::light::LampTotals>,
    /// HDR figures over every journaled capture, with HDR on (`[exposure] hdr = "adaptive"`
    /// or `mode = "bracket"`).
    pub hdr: Option<HdrFigures>,
    /// This session's cost of each emulated device's link (serial and PTP backends against
    /// emulated firmware); empty on a rig of in-process simulated devices.
    pub links: Vec<emulated::LinkUse>,
    /// What frames were processed with: each part of the processing model and where it came
    /// from (`camera`, `sensor`, `color`, `light`, `dark_flat`), and what the output lacks
    /// because a calibration is absent (`docs/pipeline.md`, "The processing model").
    pub processing: Option<ProcessingInfo>,
    /// Wall seconds the engine waited on robot and rail moves this session beyond the camera
    /// work that overlaps them ([`btfrig_acquire::RunSummary::motion_wait_wall_s`]).
    pub motion_wait_wall_s: f64,
    /// Wall seconds the emulated links added to this session: the motion wait (near zero
    /// for in-process simulated devices, whose moves take rig time only) plus the camera's
    /// PTP coding; `None` without emulated devices (docs/serial.md).
    pub link_added_wall_s: Option<f64>,
    /// Engine events this session's listener lost because it fell behind the engine's event
    /// queue (a warning says so); advisory progress only, frames and journal are complete.
    pub events_dropped: u64,
    /// What became of the compressed model the run was asked for (`outputs.compressed_model`
    /// or [`RunRequest::compressed_model`]); `None` when none was.
    pub compression: Option<sinks::CompressionOutcome>,
}

/// The process's peak resident set size in MiB, from `/proc/self/status` (Linux).
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Where a run's processing model came from, and its notes.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessingInfo {
    /// `(part, source)`.
    pub sources: Vec<(String, String)>,
    /// What the output lacks (e.g. "no light calibration: textures in relative units ...").
    pub notes: Vec<String>,
}

impl ProcessingInfo {
    /// Of `model`.
    pub fn of(model: &btfrig_process::ProcessingModel) -> Self {
        ProcessingInfo {
            sources: model.sources.iter().map(|s| (s.part.to_string(), s.source.clone())).collect(),
            notes: model.notes.clone(),
        }
    }

    /// As a JSON object: `{"sources": {part: source}, "notes": [...]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let sources: serde_json::Map<String, serde_json::Value> =
            self.sources.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
        json!({"sources": sources, "notes": self.notes})
    }
}

impl RunSummary {
    /// The summary as one JSON object (the fields `btfrig demo --json` prints).
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = json!({
            "status": self.outcome.status(),
            "reason": self.outcome.reason(),
            "captures": self.captures,
            "captures_this_session": self.captures_this_session,
            "planned_captures": self.planned_captures,
            "skipped": self.skipped,
            "hardware_s": self.hardware_s,
            "critical_path_s": self.critical_path_s,
            "naive_order_hardware_s": self.naive_order_hardware_s,
            "wall_s": self.wall_s,
            "stage_s": self.stage_s,
            "texture_rel_rmse": self.texture_rel_rmse,
            "texture_rel_rmse_nominal": self.texture_rel_rmse_nominal,
            "color_delta_e00_mean": self.color_delta_e00_mean,
            "color_delta_e00_max": self.color_delta_e00_max,
            "registered": self.registered,
            "fallbacks": self.fallbacks,
            "nominal_by_plan": self.nominal_by_plan,
            "registration_mean_texel_err": self.registration_mean_texel_err,
            "registration_max_texel_err": self.registration_max_texel_err,
            "nominal_mean_texel_err": self.nominal_mean_texel_err,
            "nominal_max_texel_err": self.nominal_max_texel_err,
            "retries": self.retries,
            "warnings": self.warnings.len(),
            "sessions": self.sessions,
            "unreported_captures": self.unreported_captures,
            "peak_rss_mib": self.peak_rss_mib,
            "motion_wait_wall_s": self.motion_wait_wall_s,
            "link_added_wall_s": self.link_added_wall_s,
            "events_dropped": self.events_dropped,
            "dataset": self.dataset.display().to_string(),
            "processing_notes": self.processing.as_ref().map(|p| p.notes.clone()),
        });
        light::add_summary_fields(&mut v, self.lamp.as_ref());
        if let (Some(c), Some(o)) = (&self.compression, v.as_object_mut()) {
            // A model's `peak_rss_mib` is the whole process's, read after the model was
            // written; the figure at the end of the capture stays as `run_peak_rss_mib`.
            o.insert("run_peak_rss_mib".into(), json!(self.peak_rss_mib));
            if let Some(fields) = c.to_json().as_object() {
                o.extend(fields.clone());
            }
        }
        if let (Some(h), Some(o)) = (&self.hdr, v.as_object_mut()) {
            if let Some(fields) = h.to_json().as_object() {
                o.extend(fields.clone());
            }
        }
        v
    }
}

/// A virtual-time runtime: a current-thread tokio runtime on paused time, so simulated
/// hardware time passes instantly; rendering parallelises inside rayon.
pub fn virtual_time_runtime() -> Result<tokio::runtime::Runtime, RunError> {
    tokio::runtime::Builder::new_current_thread().enable_time().start_paused(true).build().map_err(RunError::Runtime)
}

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

    let steps = EngineStep::from_schedule(&schedule);
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
    let rt = virtual_time_runtime()?;
    let session = rt.block_on(session(SessionInput {
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
        link_faults: &req.link_faults,
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
    summary.link_added_wall_s = link_added_wall_s;
    summary.events_dropped = events_dropped;
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
        links: Vec::new(),
        processing: None,
        motion_wait_wall_s: 0.0,
        link_added_wall_s: None,
        events_dropped: 0,
        compression: None,
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
    put("critical_path_s", json!(s.critical_path_s));
    put("naive_order_hardware_s", json!(s.naive_order_hardware_s));
    put("planned_captures", json!(s.planned_captures));
    put("captures_this_session", json!(this.captures));
    put("captures_without_truth", json!(without_truth));
    put("unreported_captures", json!(s.unreported_captures));
    put("peak_rss_mib", json!(s.peak_rss_mib));
    put("motion_wait_wall_s", json!(s.motion_wait_wall_s));
    put("events_dropped", json!(s.events_dropped));
    if !s.links.is_empty() {
        put("link_added_wall_s", json!(s.link_added_wall_s));
        put("links", s.links.iter().map(emulated::LinkUse::to_json).collect());
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
    link_faults: &'a [emulated::LinkFault],
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
    links: Vec<emulated::LinkUse>,
    motion_wait_wall_s: f64,
    link_added_wall_s: Option<f64>,
    /// Engine events the session's listener lost (it fell behind the event queue).
    events_dropped: u64,
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
        link_faults,
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
                link_faults,
            })
            .await?;
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
    prepare.await.map_err(|e| RunError::Rig(format!("preparing the simulated rig: {e}")))?;
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
    })
}
