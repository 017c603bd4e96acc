//! The run engine: executes a schedule of captures on a rig's devices.
//!
//! Brief overview: [`Engine::spawn`] starts ONE tokio task that alone owns the [`Devices`];
//! everything else talks to it through the returned [`RunHandle`] (commands in, [`Event`]s and
//! a [`RunState`] out, captured frames through a bounded channel). Each step moves robot and
//! rail at the same time, sets the exposure if it changes, triggers and reads the frame; the
//! read-out of step `i` overlaps the move to step `i + 1`. Errors whose kind is retryable are
//! retried with exponential backoff up to a limit (a `Disconnected` device is reconnected
//! first); anything else, or an exhausted retry budget, PAUSES the run with a message naming
//! the step and the device error, and `resume` retries that step. No rendering, no file I/O.
//! Design, policies and measured figures: `docs/engine.md`.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread", start_paused = true)]
//! # async fn main() {
//! use std::collections::HashSet;
//! use std::sync::Arc;
//! use btfrig_core::{config::RigConfig, kinematics::JointState};
//! use btfrig_engine::{Devices, Engine, EngineSettings, EngineStep, RunOutcome, StepKey};
//! use btfrig_hw::TokioClock;
//! use btfrig_sim::{capture::prepare, FaultScenario, FlatFrameSource, SimRig};
//!
//! let cfg = RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "rig").unwrap();
//! let clock = TokioClock::shared();
//! let source = Arc::new(FlatFrameSource::new(8, 6, 1000.0));
//! let mut rig = SimRig::from_rig_config(&cfg, &FaultScenario::none(), clock.clone(), source).unwrap();
//! prepare(&mut rig).await.unwrap(); // home, lamp warm-up
//! let devices = Devices { robot: rig.robot, rail: rig.rail, camera: rig.camera, clock };
//! let steps: Vec<EngineStep> = (0..3)
//!     .map(|i| EngineStep {
//!         key: StepKey { light: i, view: 0 },
//!         joints: JointState { rail: 0.5 + 0.1 * i as f64, robot: [0.0, 0.2, 0.0], turntable: 0.0 },
//!         exposure_s: 0.01,
//!     })
//!     .collect();
//! let (tx, mut rx) = tokio::sync::mpsc::channel(2);
//! let run = Engine::spawn(devices, steps, HashSet::new(), EngineSettings::default(), tx);
//! let consumer = tokio::spawn(async move {
//!     let mut keys = Vec::new();
//!     while let Some(f) = rx.recv().await {
//!         keys.push(f.key.light);
//!     }
//!     keys
//! });
//! let RunOutcome::Finished(summary) = run.join().await else { panic!() };
//! assert_eq!(consumer.await.unwrap(), vec![0, 1, 2]);
//! assert_eq!((summary.captured, summary.retries), (3, 0));
//! # }
//! ```
#![warn(missing_docs)]

use std::collections::HashSet;
use std::fmt;

use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::{Camera, ErrorKind, Rail, Robot, SharedClock};
use btfrig_planner::Schedule;
use tokio::sync::{broadcast, mpsc, watch};

pub mod dome;
mod run;

/// Identifies a capture: its light and view indices (as `btfrig_store::StepId`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StepKey {
    /// Index into the light sampling.
    pub light: u32,
    /// Index into the view sampling.
    pub view: u32,
}

impl fmt::Display for StepKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "light {}, view {}", self.light, self.view)
    }
}

/// What a step does, by the kind of rig: the one vocabulary events and pause reasons use for
/// every rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepKind {
    /// A gonioreflectometer capture: robot and rail to `joints`, one camera.
    Gonio {
        /// Commanded joint state.
        joints: JointState,
    },
    /// A dome (or camera-array) step: the turntable to `rotation`, the LEDs (flashes) to
    /// `shot`, every camera triggered together.
    Dome {
        /// Turntable rotation index (0 on a camera array).
        rotation: u32,
        /// Its angle, rad.
        turntable_rad: f64,
        /// The pattern or reference light fired.
        shot: btfrig_planner::dome::DomeShot,
    },
}

impl StepKind {
    /// The step as people name it: `light 3, view 2` (gonio: its key) or `rotation 1, Pattern(29)`.
    pub fn label(&self, key: StepKey) -> String {
        match self {
            StepKind::Gonio { .. } => key.to_string(),
            StepKind::Dome { rotation, shot, .. } => format!("rotation {rotation}, {shot:?}"),
        }
    }
}

/// One step of a run: where the devices go and how long the camera exposes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EngineStep {
    /// Which capture this is.
    pub key: StepKey,
    /// Commanded joint state (robot and rail; the turntable is not driven yet).
    pub joints: JointState,
    /// Exposure time, seconds.
    pub exposure_s: f64,
}

impl EngineStep {
    /// The captures of a planned schedule, in its execution order.
    pub fn from_schedule(schedule: &Schedule) -> Vec<EngineStep> {
        schedule
            .order
            .iter()
            .map(|&i| {
                let c = &schedule.captures[i];
                EngineStep {
                    key: StepKey { light: c.light_index as u32, view: c.view_index as u32 },
                    joints: c.joints,
                    exposure_s: c.exposure_s,
                }
            })
            .collect()
    }
}

/// The devices a run drives. The engine's task owns them for the whole run and gives them
/// back through [`RunHandle::join_with_devices`]. They must be homed (and the lamp warmed
/// up) beforehand, e.g. with `btfrig_sim::capture::prepare`.
pub struct Devices {
    /// The robot that orients the sample.
    pub robot: Box<dyn Robot>,
    /// The camera rail.
    pub rail: Box<dyn Rail>,
    /// The camera.
    pub camera: Box<dyn Camera>,
    /// The rig's clock: backoff waits, guards and time stamps use it.
    pub clock: SharedClock,
}

/// Timeouts, retry policy and overlap.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineSettings {
    /// Timeout of a robot or rail move, seconds (passed to the device).
    pub move_timeout_s: f64,
    /// Timeout of a trigger beyond the exposure time, seconds.
    pub trigger_timeout_s: f64,
    /// Timeout of a frame read-out, seconds (must exceed the transfer time).
    pub read_timeout_s: f64,
    /// The engine also abandons any device call that has not returned `guard_margin_s`
    /// after its own timeout (a device that ignores its timeout), as a `Timeout`.
    pub guard_margin_s: f64,
    /// Retries per operation before the step fails and the run pauses.
    pub max_retries: u32,
    /// First backoff, seconds; retry `k` (from 0) waits `backoff_s * 2^k`.
    pub backoff_s: f64,
    /// Upper bound of one backoff wait, seconds.
    pub max_backoff_s: f64,
    /// Move to the next pose while the previous frame transfers (`false`: strictly
    /// sequential steps, for comparison).
    pub overlap: bool,
    /// Number of recent measured step times the ETA averages.
    pub eta_window: usize,
    /// Events the broadcast keeps for a listener that has not read them yet. A listener that
    /// falls further behind loses the oldest ones (it gets `Lagged(n)`); the engine never
    /// waits for listeners and counts every event it overwrote unseen
    /// ([`RunSummary::events_dropped`]). Rounded up to a power of two (tokio's broadcast).
    pub event_capacity: usize,
}

impl Default for EngineSettings {
    fn default() -> Self {
        EngineSettings {
            move_timeout_s: 60.0,
            trigger_timeout_s: 10.0,
            read_timeout_s: 30.0,
            guard_margin_s: 5.0,
            max_retries: 5,
            backoff_s: 0.5,
            max_backoff_s: 30.0,
            overlap: true,
            eta_window: 20,
            event_capacity: 4096,
        }
    }
}

impl EngineSettings {
    /// Wait before retry `k` (0 = first retry), seconds: `backoff_s * 2^k`, capped.
    pub fn backoff_for(&self, k: u32) -> f64 {
        (self.backoff_s * 2f64.powi(k.min(60) as i32)).min(self.max_backoff_s)
    }
}

/// Chooses the exposures of each step (HDR brackets, `docs/hdr.md`). The engine asks for the
/// step's planned exposures before the first trigger and, if the control [`inspects`], shows
/// it the step's frames once they are read and takes more exposures while it asks for them.
///
/// An inspected step still overlaps its last read-out with the move to the next pose: the
/// frames are inspected when they arrive, and if more exposures are needed the devices go back
/// to the step's pose for them (a return trip, counted in [`StepTimes::bracket_s`]), so a step
/// that one exposure holds costs no more than without inspection. Calls run on the engine's
/// task: keep them cheap (metering a footprint, not processing a frame).
///
/// [`inspects`]: ExposureControl::inspects
pub trait ExposureControl: Send {
    /// The exposures (seconds) to take at the step's pose before any frame is inspected, in
    /// order; the first is the base exposure the step's frame is converted with. Empty is
    /// taken as the step's own `exposure_s`.
    fn planned(&mut self, step: &EngineStep) -> Vec<f64>;

    /// Whether [`ExposureControl::next`] is called at all.
    fn inspects(&self) -> bool {
        false
    }

    /// With every frame of the step read so far (in the order taken): the next exposure, or
    /// `None` when the step is complete. The engine stops asking after
    /// [`MAX_EXPOSURES_PER_STEP`] frames.
    fn next(&mut self, step: &EngineStep, frames: &[RawFrame]) -> Option<f64> {
        let _ = (step, frames);
        None
    }
}

/// Most frames the engine takes for one step, whatever the [`ExposureControl`] asks.
pub const MAX_EXPOSURES_PER_STEP: usize = 16;

/// One exposure per step, the step's own `exposure_s`: the default control.
#[derive(Debug, Clone, Copy, Default)]
pub struct SingleExposure;

impl ExposureControl for SingleExposure {
    fn planned(&mut self, step: &EngineStep) -> Vec<f64> {
        vec![step.exposure_s]
    }
}

/// When the parts of one step happened, seconds on the rig clock.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepTimes {
    /// Move to this step's pose started (last attempt).
    pub move_start_s: f64,
    /// Both devices settled.
    pub move_end_s: f64,
    /// Trigger sent (last attempt).
    pub trigger_start_s: f64,
    /// Exposure and sensor read-out done.
    pub trigger_end_s: f64,
    /// Frame on the host.
    pub transfer_end_s: f64,
    /// Rig time the step's exposures beyond the first took: their triggers and read-outs, and
    /// the return trips to the step's pose for exposures asked for after inspection, seconds
    /// (0 for one exposure).
    pub bracket_s: f64,
}

/// A frame the engine delivers, exactly once per step.
#[derive(Debug, Clone)]
pub struct CapturedFrame {
    /// Position of the step in the schedule given to [`Engine::spawn`].
    pub index: usize,
    /// Which capture.
    pub key: StepKey,
    /// The raw frame with its metadata: the step's first (base) exposure.
    pub frame: RawFrame,
    /// The step's further exposures, in the order taken (empty for one exposure): an HDR
    /// bracket of the same pose, see [`ExposureControl`].
    pub bracket: Vec<RawFrame>,
    /// 1 + retries spent on this step (any operation).
    pub attempts: u32,
    /// The joint state the devices were commanded to.
    pub joints: JointState,
    /// Hardware time stamps.
    pub times: StepTimes,
}

/// Why a run is paused.
#[derive(Debug, Clone, PartialEq)]
pub enum PauseReason {
    /// [`RunHandle::pause`] was called.
    Requested,
    /// A step failed with an error a retry cannot help, or ran out of retries.
    StepFailed {
        /// Position of the step in the schedule.
        index: usize,
        /// Which capture.
        key: StepKey,
        /// What the step does.
        step: StepKind,
        /// The device that failed.
        device: String,
        /// The error's kind.
        kind: ErrorKind,
        /// The device error as displayed (`device: kind: what`), plus what the engine did.
        message: String,
    },
    /// The frame consumer stopped taking frames (its receiver was dropped).
    ConsumerGone,
}

impl fmt::Display for PauseReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PauseReason::Requested => f.write_str("paused on request"),
            PauseReason::StepFailed { index, key, step, message, .. } => write!(
                f,
                "step {index} ({}) failed: {message}; fix the cause and resume to retry the step",
                step.label(*key)
            ),
            PauseReason::ConsumerGone => f.write_str("the frame consumer is gone"),
        }
    }
}

/// Totals of a run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunSummary {
    /// Steps in the schedule.
    pub total: usize,
    /// Steps captured and delivered by this run.
    pub captured: usize,
    /// Steps skipped because they were already done.
    pub skipped_done: usize,
    /// Retries of all operations.
    pub retries: u32,
    /// Steps that needed retries, with their retry counts, in schedule order.
    pub retried_steps: Vec<(StepKey, u32)>,
    /// Warnings emitted.
    pub warnings: usize,
    /// Rig-clock time from the start of the run to its end, seconds (pauses included).
    pub hardware_s: f64,
    /// Rig time the delivered steps spent exposing (every frame of a step counted once, the
    /// cameras of a dome step exposing together), seconds.
    pub exposure_s: f64,
    /// Mean measured time per captured step, seconds.
    pub mean_step_s: f64,
    /// Wall-clock seconds the engine waited on robot and rail moves beyond the camera work
    /// that overlaps them. Near zero on simulated devices (moves take rig time only); on
    /// serial backends it is what their exchanges add to the run (docs/serial.md).
    pub motion_wait_wall_s: f64,
    /// Events overwritten in the broadcast before a listener alive at the time had read them
    /// (a listener that does not keep up, e.g. one that never reads; the handle's first
    /// receiver counts as one until [`RunHandle::events`] takes it). Events are advisory: the
    /// run and its frames do not depend on them.
    pub events_dropped: u64,
}

/// What the engine tells its listeners.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A frame was delivered.
    StepDone {
        /// Position in the schedule.
        index: usize,
        /// Which capture.
        key: StepKey,
        /// What the step did.
        step: StepKind,
        /// 1 + retries of this step.
        attempts: u32,
    },
    /// Progress after a step (captured or skipped).
    Progress {
        /// Steps done (captured by this run or skipped as done).
        done: usize,
        /// Steps in the schedule.
        total: usize,
        /// Remaining time from the moving average of measured step times; `None` before
        /// the first measurement.
        eta_s: Option<f64>,
    },
    /// Something was retried or went wrong but the run goes on.
    Warning(String),
    /// The run is paused; it waits for resume or abort.
    Paused {
        /// Why.
        reason: PauseReason,
    },
    /// The run goes on after a pause.
    Resumed,
    /// Every step is done.
    Finished(RunSummary),
    /// The run stopped on abort.
    Aborted(RunSummary),
}

/// The run's current state, as a `watch` value.
#[derive(Debug, Clone, PartialEq)]
pub enum RunState {
    /// Executing steps.
    Running,
    /// Waiting for resume or abort.
    Paused(PauseReason),
    /// Every step done.
    Finished,
    /// Stopped on abort.
    Aborted,
}

/// How a run ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// Every step is done.
    Finished(RunSummary),
    /// Stopped on abort (after finishing the step under way).
    Aborted {
        /// Every step done: the `done` set given at spawn plus the steps captured since.
        done: HashSet<StepKey>,
        /// Totals so far.
        summary: RunSummary,
    },
}

/// How a run is steered ([`RunHandle::pause`], [`RunHandle::resume`], [`RunHandle::abort`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Pause after the step under way.
    Pause,
    /// Resume a paused run (a failed step is tried again).
    Resume,
    /// End the run after the step under way (at once when paused).
    Abort,
}

/// Commands a run holds unread. Commands are tiny and rare and the engine reads them between
/// steps, so a full queue means a caller is flooding a run that is busy with one long step:
/// [`RunHandle`]'s methods then fail with [`CommandError::Full`] rather than wait or grow.
pub const COMMAND_CAPACITY: usize = 16;

/// Why a command did not reach the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    /// The queue holds [`COMMAND_CAPACITY`] unread commands.
    #[error("{command:?} refused: the run already holds {COMMAND_CAPACITY} unread commands (it reads them between steps); wait for it to act on them")]
    Full {
        /// The command refused.
        command: Command,
    },
    /// The run has ended; there is nothing to steer.
    #[error("{command:?} refused: the run has ended")]
    Ended {
        /// The command refused.
        command: Command,
    },
}

/// The event queue's real length: `event_capacity` as tokio's broadcast rounds it.
pub(crate) fn event_queue_len(s: &EngineSettings) -> usize {
    s.event_capacity.max(1).next_power_of_two()
}

/// Starts runs.
pub struct Engine;

impl Engine {
    /// Spawns the task that executes `schedule` on `devices`, skipping the steps whose keys
    /// are in `done`, one exposure per step ([`SingleExposure`]). Frames go into `frames`
    /// (bounded: the engine waits for a slow consumer). Must be called inside a tokio runtime.
    pub fn spawn(
        devices: Devices,
        schedule: Vec<EngineStep>,
        done: HashSet<StepKey>,
        settings: EngineSettings,
        frames: mpsc::Sender<CapturedFrame>,
    ) -> RunHandle {
        Self::spawn_with_exposure(devices, schedule, done, settings, frames, Box::new(SingleExposure))
    }

    /// [`Engine::spawn`] with the exposures of each step chosen by `exposure`.
    pub fn spawn_with_exposure(
        devices: Devices,
        schedule: Vec<EngineStep>,
        done: HashSet<StepKey>,
        settings: EngineSettings,
        frames: mpsc::Sender<CapturedFrame>,
        exposure: Box<dyn ExposureControl>,
    ) -> RunHandle {
        let (cmd_tx, cmd_rx) = mpsc::channel(COMMAND_CAPACITY);
        let (ev_tx, ev_rx) = broadcast::channel(event_queue_len(&settings));
        let (state_tx, state_rx) = watch::channel(RunState::Running);
        let runner =
            run::Runner::new(devices, schedule, done, settings, frames, ev_tx.clone(), state_tx, cmd_rx, exposure);
        let task = tokio::spawn(runner.run());
        RunHandle { cmd: cmd_tx, events: ev_tx, first_events: Some(ev_rx), state: state_rx, task }
    }
}

/// The caller's side of a run.
pub struct RunHandle {
    cmd: mpsc::Sender<Command>,
    events: broadcast::Sender<Event>,
    first_events: Option<broadcast::Receiver<Event>>,
    state: watch::Receiver<RunState>,
    task: tokio::task::JoinHandle<(RunOutcome, Devices)>,
}

impl RunHandle {
    /// Sends `command` without waiting: fails when the queue is full ([`COMMAND_CAPACITY`])
    /// or the run has ended.
    pub fn command(&self, command: Command) -> Result<(), CommandError> {
        self.cmd.try_send(command).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => CommandError::Full { command },
            mpsc::error::TrySendError::Closed(_) => CommandError::Ended { command },
        })
    }

    /// Asks the run to pause after the step under way.
    pub fn pause(&self) -> Result<(), CommandError> {
        self.command(Command::Pause)
    }

    /// Resumes a paused run (retrying the failed step, if one failed).
    pub fn resume(&self) -> Result<(), CommandError> {
        self.command(Command::Resume)
    }

    /// Asks the run to stop after the step under way (or at once when paused).
    pub fn abort(&self) -> Result<(), CommandError> {
        self.command(Command::Abort)
    }

    /// Events from now on; the first call also gets every event since spawn.
    pub fn events(&mut self) -> broadcast::Receiver<Event> {
        self.first_events.take().unwrap_or_else(|| self.events.subscribe())
    }

    /// The run's state, updated as it changes.
    pub fn state(&self) -> watch::Receiver<RunState> {
        self.state.clone()
    }

    /// Waits for the run to end.
    pub async fn join(self) -> RunOutcome {
        self.join_with_devices().await.0
    }

    /// Waits for the run to end and takes the devices back. Dropping the last handle of a
    /// paused run aborts it.
    pub async fn join_with_devices(self) -> (RunOutcome, Devices) {
        let RunHandle { cmd, task, .. } = self;
        // Keep the command channel open while waiting: closing it means abort when paused.
        let out = task.await;
        drop(cmd);
        match out {
            Ok(v) => v,
            Err(e) if e.is_panic() => std::panic::resume_unwind(e.into_panic()),
            Err(e) => panic!("engine task cancelled: {e}"),
        }
    }
}
