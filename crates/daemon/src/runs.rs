//! The one run the rig can hold at a time, and the runs before it.
//!
//! A run is [`btfrig_measurement::run`] (a gonio plan) or [`btfrig_measurement::dome::run_controlled`]
//! (a dome plan) — the same calls `btfrig run` makes — on a plain thread of its own
//! (rendering and processing are CPU-heavy; the async threads only answer requests). Its
//! events update a [`RunStatus`] that handlers read, and are broadcast to the event streams.
//! A gonio run's `done`/`total` count captures, a dome run's count steps (a pattern at a
//! rotation, a frame per camera: what the dome engine's progress and ETA count), with the
//! textures it committed view group by view group beside them ([`ProgressUnit`]). The daemon
//! keeps the engine paused on a fault (`stop_on_fault = false`) so an operator can resume it;
//! SIGTERM interrupts the run, which commits the frames in flight (a dome: the view groups
//! completed) and leaves the dataset resumable with the same plan and dataset name.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use btfrig_measurement::check::PlanKind;
use btfrig_measurement::{RunControl, RunEvent, RunOutcome, RunRequest};
use serde::Serialize;
use tokio::sync::broadcast;
use utoipa::ToSchema;

use crate::metrics::Metrics;
use crate::problem::Problem;

/// Warnings kept per run in its status (the report keeps all).
const RECENT_WARNINGS: usize = 20;

/// Where a run is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum RunState {
    /// Accepted; the dataset is being created and the schedule planned.
    Starting,
    /// Capturing.
    Running,
    /// Paused on request or on a fault; resume or abort.
    Paused,
    /// Ending: the frames in flight are being committed.
    Stopping,
    /// Every capture done.
    Finished,
    /// Aborted on request; resumable by starting the same plan into the same dataset.
    Aborted,
    /// Interrupted by the daemon's shutdown (SIGTERM); resumable the same way.
    Interrupted,
    /// Could not run (the message says why); what was captured is kept.
    Failed,
}

impl RunState {
    /// True once the run's thread is done.
    pub fn is_over(self) -> bool {
        matches!(self, RunState::Finished | RunState::Aborted | RunState::Interrupted | RunState::Failed)
    }
}

/// What a run's `done` and `total` count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ProgressUnit {
    /// A gonioreflectometer run: (light, view) captures, one texture each.
    Captures,
    /// A dome run (LED dome or camera array): steps of the dome engine, one pattern (or
    /// single reference light) at one rotation, a frame per camera; the textures are
    /// committed per view group (`textures`).
    Steps,
}

impl ProgressUnit {
    /// The unit's name as the API spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            ProgressUnit::Captures => "captures",
            ProgressUnit::Steps => "steps",
        }
    }
}

/// A run as the API shows it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RunStatus {
    /// The run's id (`r1`, `r2`, ...), unique while the daemon runs.
    pub id: String,
    /// Where it is.
    pub state: RunState,
    /// The name of the token that started it.
    pub owner: String,
    /// The plan's name.
    pub plan: String,
    /// The dataset's name (a directory under the daemon's data directory).
    pub dataset: String,
    /// What `done` and `total` count: `captures` (a gonio run) or `steps` (a dome run: one
    /// pattern at one rotation, a frame per camera).
    pub unit: ProgressUnit,
    /// Captures (a dome run: steps) done, this session and earlier ones. A dome run's steps
    /// of a view group not yet committed are captured again if the session ends before it is.
    pub done: u64,
    /// Captures (a dome run: steps) of the whole plan (0 until planned).
    pub total: u64,
    /// `done / total` (0 until planned).
    pub fraction: f64,
    /// Remaining rig time from the measured step times, seconds.
    pub eta_s: Option<f64>,
    /// A dome run: textures committed to the dataset, earlier sessions included (every
    /// light's texture of one camera at one rotation is committed at once, after the view
    /// group's last step); `null` for a gonio run, whose captures are its textures.
    pub textures: Option<u64>,
    /// A dome run: textures of the whole plan (lights x views); `null` for a gonio run.
    pub textures_total: Option<u64>,
    /// Recent warnings, oldest first.
    pub warnings: Vec<String>,
    /// Why it is paused, stopping or over, when it is.
    pub message: Option<String>,
    /// Increments every time a new preview is written: of the latest capture (a gonio run
    /// whose plan asks for `outputs.preview`), or of the brightest texture of the latest
    /// committed view group (a dome run).
    pub preview_seq: u64,
    /// Start time, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// The run's summary (as `report.json`) once it is over.
    #[schema(value_type = Option<Object>)]
    pub summary: Option<serde_json::Value>,
}

/// What the event stream of a run carries.
#[derive(Debug, Clone)]
pub enum ServerEvent {
    /// The status changed.
    Status(Box<RunStatus>),
    /// A warning; the run goes on.
    Warning(String),
    /// The run is over; its final status.
    End(Box<RunStatus>),
}

/// One run.
pub struct Run {
    id: String,
    status: Mutex<RunStatus>,
    warnings: Mutex<VecDeque<String>>,
    control: RunControl,
    events: broadcast::Sender<ServerEvent>,
    dataset_dir: PathBuf,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Run {
    /// The current status.
    pub fn status(&self) -> RunStatus {
        self.status.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The run's id.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// Where the run is, without copying the status (status requests come hundreds a second).
    pub fn state(&self) -> RunState {
        self.status.lock().unwrap_or_else(|e| e.into_inner()).state
    }

    /// The dataset directory.
    pub fn dataset_dir(&self) -> &Path {
        &self.dataset_dir
    }

    /// Events from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<ServerEvent> {
        self.events.subscribe()
    }

    fn update(&self, f: impl FnOnce(&mut RunStatus)) -> RunStatus {
        let mut s = self.status.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut s);
        s.warnings = self.warnings.lock().unwrap_or_else(|e| e.into_inner()).iter().cloned().collect();
        s.clone()
    }

    fn on_event(&self, e: &RunEvent, metrics: &Metrics) {
        let changed = match e {
            RunEvent::Planning { .. } => None,
            RunEvent::Started { done_before, total, .. } => Some(self.update(|s| {
                s.state = RunState::Running;
                s.done = *done_before as u64;
                s.total = *total as u64;
                s.fraction = fraction(s.done, s.total);
            })),
            RunEvent::StepDone { attempts, .. } => {
                metrics.step_done(*attempts);
                None
            }
            RunEvent::Progress { done, total, eta_s } => Some(self.update(|s| {
                s.done = *done as u64;
                s.total = *total as u64;
                s.fraction = fraction(s.done, s.total);
                s.eta_s = *eta_s;
            })),
            RunEvent::Warning(w) => {
                metrics.warning();
                {
                    let mut ws = self.warnings.lock().unwrap_or_else(|e| e.into_inner());
                    ws.push_back(w.clone());
                    while ws.len() > RECENT_WARNINGS {
                        ws.pop_front();
                    }
                }
                let _ = self.events.send(ServerEvent::Warning(w.clone()));
                Some(self.update(|_| {}))
            }
            RunEvent::Paused { reason, .. } => Some(self.update(|s| {
                s.state = RunState::Paused;
                s.message = Some(reason.clone());
            })),
            RunEvent::Resumed => Some(self.update(|s| {
                s.state = RunState::Running;
                s.message = None;
            })),
            RunEvent::Committed { previews, queued, stage_s, .. } => {
                metrics.committed(*queued, stage_s);
                let seq = self.status().preview_seq;
                (*previews != seq).then(|| self.update(|s| s.preview_seq = *previews))
            }
            RunEvent::Stopping { reason } => Some(self.update(|s| {
                s.state = RunState::Stopping;
                s.message = Some(reason.clone());
            })),
            RunEvent::DomeStepDone { attempts, .. } => {
                metrics.dome_step_done(*attempts);
                None
            }
            RunEvent::TexturesCommitted { textures, total, previews, stage_s } => {
                metrics.stages(stage_s);
                Some(self.update(|s| {
                    s.textures = Some(*textures);
                    s.textures_total = Some(*total);
                    s.preview_seq = *previews;
                }))
            }
        };
        if let Some(s) = changed {
            let _ = self.events.send(ServerEvent::Status(Box::new(s)));
        }
    }

    fn end(&self, result: Result<btfrig_measurement::RunSummary, btfrig_measurement::RunError>) {
        let s = self.update(|s| match result {
            Ok(summary) => {
                s.state = match &summary.outcome {
                    RunOutcome::Finished | RunOutcome::NothingToDo => RunState::Finished,
                    RunOutcome::Aborted => RunState::Aborted,
                    RunOutcome::Interrupted(_) => RunState::Interrupted,
                    // The daemon keeps paused runs waiting, so a session that ends paused
                    // ended on a fault the engine could not wait out.
                    RunOutcome::Paused { .. } => RunState::Failed,
                };
                s.message = summary.outcome.reason();
                s.done = summary.captures;
                s.total = summary.planned_captures;
                s.fraction = fraction(s.done, s.total);
                if s.state == RunState::Finished {
                    s.eta_s = Some(0.0);
                }
                // Every capture is in, but the model the plan asks for is not: the run did not
                // give what it was asked for. The same plan into the same dataset builds it.
                if let Some(btfrig_measurement::sinks::CompressionOutcome::Failed(e)) = &summary.compression {
                    s.state = RunState::Failed;
                    s.message = Some(format!(
                        "the compressed model (outputs.compressed_model) was not built: {e}; the dataset is complete: \
                         start the same plan into the same dataset to build it"
                    ));
                }
                s.summary = Some(summary.to_json());
            }
            // Stopped by the daemon's shutdown while planning: nothing was written.
            Err(e @ btfrig_measurement::RunError::Interrupted(_)) => {
                s.state = RunState::Interrupted;
                s.message = Some(e.to_string());
            }
            Err(e) => {
                s.state = RunState::Failed;
                s.message = Some(e.to_string());
            }
        });
        let _ = self.events.send(ServerEvent::End(Box::new(s)));
    }

    /// [`Run::end`] of a dome run: its steps stay as its last progress said (all of them when
    /// it finished), its textures as its last commit said.
    fn end_dome(&self, result: Result<btfrig_measurement::dome::DomeRunSummary, btfrig_measurement::RunError>) {
        let s = self.update(|s| match result {
            Ok(summary) => {
                s.state = match &summary.stopped {
                    None | Some(RunOutcome::Finished | RunOutcome::NothingToDo) => RunState::Finished,
                    Some(RunOutcome::Aborted) => RunState::Aborted,
                    Some(RunOutcome::Interrupted(_)) => RunState::Interrupted,
                    // A dome session does not end paused (the daemon keeps the engine waiting).
                    Some(RunOutcome::Paused { .. }) => RunState::Failed,
                };
                s.message = summary.stopped.as_ref().and_then(RunOutcome::reason);
                if s.state == RunState::Finished {
                    s.done = s.total;
                    s.fraction = fraction(s.done, s.total);
                    s.eta_s = Some(0.0);
                }
                // As a gonio run's (`Run::end`): a model asked for and not built fails the run.
                if let Some(btfrig_measurement::sinks::CompressionOutcome::Failed(e)) = &summary.compression {
                    s.state = RunState::Failed;
                    s.message = Some(format!(
                        "the compressed model (outputs.compressed_model) was not built: {e}; the dataset is complete: \
                         start the same plan into the same dataset to build it"
                    ));
                }
                s.summary = Some(summary.to_json());
            }
            Err(e) => {
                s.state = RunState::Failed;
                s.message = Some(e.to_string());
            }
        });
        let _ = self.events.send(ServerEvent::End(Box::new(s)));
    }
}

fn fraction(done: u64, total: u64) -> f64 {
    if total == 0 {
        0.0
    } else {
        done as f64 / total as f64
    }
}

/// What to start.
pub struct StartRequest {
    /// The plan's text.
    pub plan_text: String,
    /// The plan's name (for the status).
    pub plan_name: String,
    /// Where the plan's relative paths point (a file path in that directory).
    pub plan_path: PathBuf,
    /// The dataset's name (validated by the caller).
    pub dataset: String,
    /// Who starts it.
    pub owner: String,
    /// The plan's format (checked against the rig by the caller): which runner runs it.
    pub kind: PlanKind,
}

/// Every run of this daemon; at most one not over.
pub struct Runs {
    data: PathBuf,
    metrics: Arc<Metrics>,
    inner: Mutex<Inner>,
}

struct Inner {
    next_id: u64,
    /// Oldest first.
    runs: Vec<Arc<Run>>,
}

impl Runs {
    /// No runs yet; datasets go under `data`.
    pub fn new(data: PathBuf, metrics: Arc<Metrics>) -> Runs {
        Runs { data, metrics, inner: Mutex::new(Inner { next_id: 1, runs: Vec::new() }) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The run holding the rig, if any.
    pub fn current(&self) -> Option<Arc<Run>> {
        self.lock().runs.iter().rev().find(|r| !r.state().is_over()).cloned()
    }

    /// The latest run, over or not.
    pub fn latest(&self) -> Option<Arc<Run>> {
        self.lock().runs.last().cloned()
    }

    /// Every run, oldest first.
    pub fn all(&self) -> Vec<Arc<Run>> {
        self.lock().runs.clone()
    }

    /// The run with `id`.
    pub fn get(&self, id: &str) -> Option<Arc<Run>> {
        self.lock().runs.iter().find(|r| r.id == id).cloned()
    }

    /// Runs `hold` (which marks the rig held by a calibration, or refuses) while no run can
    /// start; 409 if a run holds the rig.
    pub fn hold_for_calibration<T>(&self, hold: impl FnOnce() -> Result<T, Problem>) -> Result<T, Problem> {
        let inner = self.lock();
        if let Some(busy) = inner.runs.iter().find(|r| !r.state().is_over()) {
            let s = busy.status();
            return Err(Problem::conflict(format!("the rig is held by run {} of {}", s.id, s.owner)));
        }
        hold()
    }

    /// Starts a run, or 409 naming who holds the rig. `calibrating` names a calibration
    /// holding the rig, checked under the same lock as [`Runs::hold_for_calibration`].
    pub fn start(&self, req: StartRequest, calibrating: impl FnOnce() -> Option<String>) -> Result<Arc<Run>, Problem> {
        let mut inner = self.lock();
        if let Some(who) = calibrating() {
            return Err(Problem::conflict(format!("the rig is held by {who}; wait for it to end")));
        }
        if let Some(busy) = inner.runs.iter().find(|r| !r.state().is_over()) {
            let s = busy.status();
            return Err(Problem::conflict(format!(
                "the rig is held by run {} of {} (plan {}, {:?}, {}/{} {}); wait for it to end or abort it",
                s.id,
                s.owner,
                s.plan,
                s.state,
                s.done,
                s.total,
                s.unit.as_str()
            )));
        }
        let id = format!("r{}", inner.next_id);
        inner.next_id += 1;
        let dataset_dir = self.data.join(&req.dataset);
        let (events, _) = broadcast::channel(256);
        let run = Arc::new(Run {
            id: id.clone(),
            status: Mutex::new(RunStatus {
                id,
                state: RunState::Starting,
                owner: req.owner,
                plan: req.plan_name,
                dataset: req.dataset,
                unit: match req.kind {
                    PlanKind::Gonio => ProgressUnit::Captures,
                    PlanKind::Dome => ProgressUnit::Steps,
                },
                done: 0,
                total: 0,
                fraction: 0.0,
                eta_s: None,
                textures: None,
                textures_total: None,
                warnings: Vec::new(),
                message: None,
                preview_seq: 0,
                started_unix_s: unix_now(),
                summary: None,
            }),
            warnings: Mutex::new(VecDeque::new()),
            control: RunControl::new(),
            events,
            dataset_dir: dataset_dir.clone(),
            thread: Mutex::new(None),
        });
        let worker = run.clone();
        let metrics = self.metrics.clone();
        metrics.run_started();
        let (kind, plan_text, plan_path) = (req.kind, req.plan_text, req.plan_path);
        let thread = std::thread::Builder::new()
            .name(format!("run-{}", run.id))
            .spawn(move || {
                let control = worker.control.clone();
                let on_event = &mut |e: &RunEvent| worker.on_event(e, &metrics);
                match kind {
                    PlanKind::Gonio => {
                        let mut request = RunRequest::from_text(plan_text, &plan_path, &dataset_dir);
                        request.stop_on_fault = false;
                        let result = btfrig_measurement::run(&request, &control, on_event);
                        metrics.session_ended();
                        worker.end(result);
                    }
                    PlanKind::Dome => {
                        let request = btfrig_measurement::dome::DomeRunRequest {
                            plan_text,
                            plan_path,
                            out: dataset_dir,
                            faults: None,
                            preview: true,
                            compressed_model: None,
                        };
                        let id = worker.id.clone();
                        let on_line = &mut |l: &str| tracing::info!("run {id}: {l}");
                        let result =
                            btfrig_measurement::dome::run_controlled(&request, &control, false, on_line, on_event);
                        metrics.session_ended();
                        worker.end_dome(result);
                    }
                }
            })
            .map_err(|e| Problem::internal(format!("cannot start the run's thread: {e}")))?;
        *run.thread.lock().unwrap_or_else(|e| e.into_inner()) = Some(thread);
        inner.runs.push(run.clone());
        Ok(run)
    }

    /// Interrupts the current run (shutdown on `signal`) and waits until it has committed and
    /// reported.
    pub fn interrupt_and_wait(&self, signal: btfrig_measurement::Signal) {
        let Some(run) = self.current() else { return };
        // Shutdown must reach the run: while its bounded command queue is full (a client
        // flooding it), wait for the session to take a command, then send again.
        while run.control.interrupt(signal) == Err(btfrig_measurement::ControlError::Full) {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        // Stopping waits for the frames in flight; a paused engine takes the interrupt too.
        let t = run.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(t) = t {
            let _ = t.join();
        }
    }
}

/// Pausing, resuming and aborting: what each needs of the run's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    /// Pause after the step under way.
    Pause,
    /// Resume a paused run.
    Resume,
    /// End the session after the step under way.
    Abort,
}

impl Run {
    /// Sends `c` if the run's state allows it (409 otherwise) and returns the status.
    pub fn control(&self, c: Control) -> Result<RunStatus, Problem> {
        let s = self.status();
        let ok = match c {
            Control::Pause => matches!(s.state, RunState::Running | RunState::Starting),
            Control::Resume => s.state == RunState::Paused,
            Control::Abort => !s.state.is_over() && s.state != RunState::Stopping,
        };
        if !ok {
            let allowed = match c {
                Control::Pause => "a starting or running run",
                Control::Resume => "a paused run",
                Control::Abort => "a run that is not over or stopping",
            };
            return Err(Problem::conflict(format!("run {} is {:?}; {:?} applies only to {allowed}", s.id, s.state, c)));
        }
        let sent = match c {
            Control::Pause => self.control.pause(),
            Control::Resume => self.control.resume(),
            Control::Abort => self.control.abort(),
        };
        // The run's command queue is bounded (`btfrig_measurement::CONTROL_CAPACITY`): a full one
        // refuses rather than grows.
        sent.map_err(|e| Problem::conflict(format!("run {}: {:?} not sent: {e}", s.id, c)))?;
        Ok(s)
    }
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}
