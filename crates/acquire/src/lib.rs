//! The run engine: executes a schedule of captures on a rig's devices.
//!
//! Brief overview: [`Engine::spawn`] starts ONE tokio task that alone owns the rig's devices
//! ([`RigDevices`]: a gonioreflectometer's, or a dome's or camera array's); everything else
//! talks to it through the returned [`RunHandle`] (commands in, [`Event`]s and a [`RunState`]
//! out, captured frames through a bounded channel). The steps say what each capture does
//! ([`StepKind`]). A gonio step moves robot and rail at the same time, sets the exposure if it
//! changes, triggers and reads the frame; the read-out of step `i` overlaps the move to step
//! `i + 1`. A dome step turns the table, sets an LED pattern and triggers every camera at once
//! ([`dome`]). For every rig alike: errors whose kind is retryable are retried with
//! exponential backoff up to a limit (a `Disconnected` device is reconnected first); anything
//! else, or an exhausted retry budget, PAUSES the run with a message naming the step and the
//! device error, and `resume` retries that step. No rendering, no file I/O. Design, policies
//! and measured figures: `docs/engine.md`.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread", start_paused = true)]
//! # async fn main() {
//! use std::collections::HashSet;
//! use std::sync::Arc;
//! use btfrig_core::{capture::StepKey, config::RigConfig, kinematics::JointState};
//! use btfrig_acquire::{Engine, EngineSettings, EngineStep, GonioDevices, RunOutcome, StepKind};
//! use btfrig_hw::TokioClock;
//! use btfrig_sim::{capture::prepare, FaultScenario, FlatFrameSource, SimRig};
//!
//! let cfg = RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "rig").unwrap();
//! let clock = TokioClock::shared();
//! let source = Arc::new(FlatFrameSource::new(8, 6, 1000.0));
//! let mut rig = SimRig::from_rig_config(&cfg, &FaultScenario::none(), clock.clone(), source).unwrap();
//! prepare(&mut rig).await.unwrap(); // home, lamp warm-up
//! let devices = GonioDevices { robot: rig.robot, rail: rig.rail, camera: rig.camera, clock };
//! let steps: Vec<EngineStep> = (0..3)
//!     .map(|i| EngineStep {
//!         key: StepKey { light: i, view: 0 },
//!         kind: StepKind::Gonio {
//!             joints: JointState { rail: 0.5 + 0.1 * i as f64, robot: [0.0, 0.2, 0.0], turntable: 0.0 },
//!         },
//!         exposure_s: 0.01,
//!     })
//!     .collect();
//! let (tx, mut rx) = tokio::sync::mpsc::channel::<btfrig_core::capture::CapturedFrame>(2);
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

// The files, one job each:
// - lib:     the vocabulary every rig shares (steps, devices, events, commands, settings) and Engine::spawn
// - run:     the one task that owns the devices: the loop over the steps, stopping, pausing
// - session: the run's state but the devices: commands, pauses, skipped steps, retries, progress, summary
// - gonio:   a gonioreflectometer step: robot and rail, exposures, read-out overlapped with the next move
// - dome:    a dome or camera-array step: turntable, LED pattern, every camera triggered at once
// - calls:   device calls with the engine's timeouts, guards and retry policy

use std::collections::HashSet;
use std::fmt;

use btfrig_core::capture::{CapturedFrame, StepKey};
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::{Camera, ErrorKind, Rail, Robot, SharedClock};
use btfrig_planner::dome::{DomeSchedule, DomeShot};
use btfrig_planner::Schedule;
use tokio::sync::{broadcast, mpsc, watch};

mod calls;
pub mod dome;
mod gonio;
mod run;
mod session;

use dome::{DomeCapture, DomeDevices};

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

/// One step of a run: what the devices do (by the kind of rig) and how long the cameras
/// expose. Steps whose key is in the run's `done` set are skipped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EngineStep {
    /// Which capture this is.
    pub key: StepKey,
    /// What the step does: a gonio pose (robot and rail; the turntable is not driven on a
    /// gonio yet) or a dome's (rotation, shot).
    pub kind: StepKind,
    /// Exposure time, seconds.
    pub exposure_s: f64,
}

impl EngineStep {
    /// The captures of a planned gonio schedule, in its execution order.
    pub fn from_schedule(schedule: &Schedule) -> Vec<EngineStep> {
        schedule
            .order
            .iter()
            .map(|&i| {
                let c = &schedule.captures[i];
                EngineStep {
                    key: StepKey { light: c.light_index as u32, view: c.view_index as u32 },
                    kind: StepKind::Gonio { joints: c.joints },
                    exposure_s: c.exposure_s,
                }
            })
            .collect()
    }

    /// The steps of a dome schedule, in its order: key `light` = position in the schedule,
    /// `view` = rotation; pattern frames at the schedule's `exposure_s`, single-LED reference
    /// frames at its `single_exposure_s`.
    pub fn from_dome_schedule(schedule: &DomeSchedule) -> Vec<EngineStep> {
        schedule
            .steps
            .iter()
            .enumerate()
            .map(|(i, st)| EngineStep {
                key: StepKey { light: i as u32, view: st.rotation },
                kind: StepKind::Dome { rotation: st.rotation, turntable_rad: st.turntable_rad, shot: st.shot },
                exposure_s: match st.shot {
                    DomeShot::Pattern(_) => schedule.exposure_s,
                    DomeShot::Reference(_) => schedule.single_exposure_s,
                },
            })
            .collect()
    }

    /// The commanded joint state of a gonio step (`None` for a dome step).
    pub fn joints(&self) -> Option<JointState> {
        match self.kind {
            StepKind::Gonio { joints } => Some(joints),
            StepKind::Dome { .. } => None,
        }
    }

    /// The step as people name it ([`StepKind::label`]).
    pub fn label(&self) -> String {
        self.kind.label(self.key)
    }
}

/// A gonioreflectometer's devices. They must be homed (and the lamp warmed up) beforehand,
/// e.g. with `btfrig_sim::capture::prepare`.
pub struct GonioDevices {
    /// The robot that orients the sample.
    pub robot: Box<dyn Robot>,
    /// The camera rail.
    pub rail: Box<dyn Rail>,
    /// The camera.
    pub camera: Box<dyn Camera>,
    /// The rig's clock: backoff waits, guards and time stamps use it.
    pub clock: SharedClock,
}

/// The devices a run drives, by the kind of rig. The engine's task owns them for the whole
/// run and gives them back through [`RunHandle::join_with_devices`].
pub enum RigDevices {
    /// A gonioreflectometer: every step is a [`StepKind::Gonio`], frames are
    /// [`CapturedFrame`]s.
    Gonio(GonioDevices),
    /// An LED dome or a camera array: every step is a [`StepKind::Dome`], frames are
    /// [`DomeCapture`]s (one frame per camera). The turntable must be homed beforehand.
    Dome {
        /// Turntable, LED array (flash triggers) and cameras.
        devices: DomeDevices,
        /// The LED intensities of each pattern: `DomeShot::Pattern(p)` fires `patterns[p]`
        /// (as a real dome's controller holds a pattern table); `Reference(j)` fires LED `j`.
        patterns: Vec<Vec<f64>>,
    },
}

impl From<GonioDevices> for RigDevices {
    fn from(d: GonioDevices) -> Self {
        RigDevices::Gonio(d)
    }
}

impl RigDevices {
    /// The rig's clock.
    pub fn clock(&self) -> &SharedClock {
        match self {
            RigDevices::Gonio(d) => &d.clock,
            RigDevices::Dome { devices, .. } => &devices.clock,
        }
    }
}

/// Where a run's frames go, by the kind of rig (bounded: the engine waits for a slow
/// consumer). Built from the channel's sender with `.into()`.
#[derive(Debug)]
pub enum FrameSender {
    /// A gonio run's frames.
    Gonio(mpsc::Sender<CapturedFrame>),
    /// A dome run's steps, one frame per camera each.
    Dome(mpsc::Sender<DomeCapture>),
}

impl From<mpsc::Sender<CapturedFrame>> for FrameSender {
    fn from(tx: mpsc::Sender<CapturedFrame>) -> Self {
        FrameSender::Gonio(tx)
    }
}

impl From<mpsc::Sender<DomeCapture>> for FrameSender {
    fn from(tx: mpsc::Sender<DomeCapture>) -> Self {
        FrameSender::Dome(tx)
    }
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
    /// sequential steps, for comparison). Gonio steps only: a dome step is sequential.
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
/// to the step's pose for them (a return trip, counted in
/// [`StepTimes::bracket_s`](btfrig_core::capture::StepTimes::bracket_s)), so a step
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
    /// The frame channel to the consumer, as the engine saw it when delivering.
    pub frame_queue: FrameQueueFigures,
}

/// The bounded frame channel between capture and processing, as the engine saw it: how full
/// it got and how long capture waited because it was full (docs/pipeline.md, "Channels and
/// back-pressure"). A consumer that keeps up never lets it fill.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameQueueFigures {
    /// Frames (gonio steps, dome captures) the channel holds at most.
    pub capacity: usize,
    /// Frames delivered into it.
    pub delivered: u64,
    /// The most frames it held, counted right after each delivery (`capacity`: it filled).
    pub max_fill: usize,
    /// Deliveries that found it full and waited for the consumer.
    pub full_waits: u64,
    /// Rig-clock seconds those deliveries waited (virtual time does not pass while the
    /// consumer's blocking work runs, so on a simulated rig only `full_wait_wall_s` counts).
    pub full_wait_s: f64,
    /// Wall seconds those deliveries waited.
    pub full_wait_wall_s: f64,
}

impl FrameQueueFigures {
    /// Sends `item` on `tx`, counting the fill and any wait for a free slot; `Err` when the
    /// consumer is gone.
    pub(crate) async fn send<T>(
        &mut self,
        tx: &mpsc::Sender<T>,
        clock: &btfrig_hw::SharedClock,
        item: T,
    ) -> Result<(), ()> {
        self.capacity = tx.max_capacity();
        let permit = match tx.try_reserve() {
            Ok(p) => p,
            Err(mpsc::error::TrySendError::Full(())) => {
                self.full_waits += 1;
                let (rig, wall) = (clock.now_s(), std::time::Instant::now());
                let p = tx.reserve().await.map_err(|_| ())?;
                self.full_wait_s += clock.now_s() - rig;
                self.full_wait_wall_s += wall.elapsed().as_secs_f64();
                p
            }
            Err(mpsc::error::TrySendError::Closed(())) => return Err(()),
        };
        permit.send(item);
        self.delivered += 1;
        // Only the engine reserves slots, so the slots taken are the frames waiting.
        self.max_fill = self.max_fill.max(tx.max_capacity() - tx.capacity());
        Ok(())
    }
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
    /// Spawns the task that executes `steps` on `devices` (a rig of any kind), skipping the
    /// steps whose keys are in `done`, one exposure per step ([`SingleExposure`]). Frames go
    /// into `frames` (bounded: the engine waits for a slow consumer). Must be called inside a
    /// tokio runtime.
    ///
    /// # Panics
    ///
    /// When the steps or the frame channel do not fit the rig: a step of another kind than
    /// the devices ([`StepKind`]), a dome pattern index beyond `patterns`, or a gonio channel
    /// for a dome's devices (or the reverse). The message names the step and what is allowed.
    pub fn spawn(
        devices: impl Into<RigDevices>,
        steps: Vec<EngineStep>,
        done: HashSet<StepKey>,
        settings: EngineSettings,
        frames: impl Into<FrameSender>,
    ) -> RunHandle {
        Self::spawn_rig(devices.into(), steps, done, settings, frames.into(), Box::new(SingleExposure))
    }

    /// [`Engine::spawn`] on a gonioreflectometer, with the exposures of each step chosen by
    /// `exposure` (HDR brackets; a dome step takes its own `exposure_s`).
    pub fn spawn_with_exposure(
        devices: GonioDevices,
        steps: Vec<EngineStep>,
        done: HashSet<StepKey>,
        settings: EngineSettings,
        frames: mpsc::Sender<CapturedFrame>,
        exposure: Box<dyn ExposureControl>,
    ) -> RunHandle {
        Self::spawn_rig(RigDevices::Gonio(devices), steps, done, settings, FrameSender::Gonio(frames), exposure)
    }

    fn spawn_rig(
        devices: RigDevices,
        steps: Vec<EngineStep>,
        done: HashSet<StepKey>,
        settings: EngineSettings,
        frames: FrameSender,
        exposure: Box<dyn ExposureControl>,
    ) -> RunHandle {
        let clock = devices.clock().clone();
        let rig = match wire(devices, frames, exposure, &steps) {
            Ok(rig) => rig,
            Err(e) => panic!("Engine::spawn: {e}"),
        };
        let (cmd_tx, cmd_rx) = mpsc::channel(COMMAND_CAPACITY);
        let (ev_tx, ev_rx) = broadcast::channel(event_queue_len(&settings));
        let (state_tx, state_rx) = watch::channel(RunState::Running);
        let core = session::Core::new(steps, done, settings, clock, ev_tx.clone(), state_tx, cmd_rx);
        let task = tokio::spawn(run::run(core, rig));
        RunHandle { cmd: cmd_tx, events: ev_tx, first_events: Some(ev_rx), state: state_rx, task }
    }
}

/// The rig's side of a run from its devices, frame channel and steps; an error names the
/// step or channel that does not fit the devices.
fn wire(
    devices: RigDevices,
    frames: FrameSender,
    exposure: Box<dyn ExposureControl>,
    steps: &[EngineStep],
) -> Result<run::Rig, String> {
    match (devices, frames) {
        (RigDevices::Gonio(dev), FrameSender::Gonio(frames)) => {
            let joints = steps
                .iter()
                .enumerate()
                .map(|(i, st)| {
                    st.joints().ok_or_else(|| {
                        format!("step {i} ({}) is a dome step; a gonio rig takes StepKind::Gonio steps", st.label())
                    })
                })
                .collect::<Result<_, _>>()?;
            Ok(run::Rig::Gonio(gonio::Gonio { dev, frames, exposure, joints }))
        }
        (RigDevices::Dome { devices, patterns }, FrameSender::Dome(frames)) => {
            let steps = steps
                .iter()
                .enumerate()
                .map(|(i, st)| match st.kind {
                    StepKind::Dome { rotation, turntable_rad, shot } => match shot {
                        DomeShot::Pattern(p) if p >= patterns.len() => Err(format!(
                            "step {i} fires pattern {p}, but the dome was given {} patterns (0..{})",
                            patterns.len(),
                            patterns.len()
                        )),
                        _ => Ok(btfrig_planner::dome::DomeStep { rotation, turntable_rad, shot }),
                    },
                    StepKind::Gonio { .. } => {
                        Err(format!("step {i} ({}) is a gonio step; a dome takes StepKind::Dome steps", st.label()))
                    }
                })
                .collect::<Result<_, _>>()?;
            Ok(run::Rig::Dome(dome::Dome { dev: devices, patterns, frames, steps, table_at: None }))
        }
        (RigDevices::Gonio(_), FrameSender::Dome(_)) => {
            Err("a gonio rig delivers CapturedFrame: pass an mpsc::Sender<CapturedFrame>".into())
        }
        (RigDevices::Dome { .. }, FrameSender::Gonio(_)) => {
            Err("a dome delivers DomeCapture (one frame per camera): pass an mpsc::Sender<DomeCapture>".into())
        }
    }
}

/// The caller's side of a run.
pub struct RunHandle {
    cmd: mpsc::Sender<Command>,
    events: broadcast::Sender<Event>,
    first_events: Option<broadcast::Receiver<Event>>,
    state: watch::Receiver<RunState>,
    task: tokio::task::JoinHandle<(RunOutcome, RigDevices)>,
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
    pub async fn join_with_devices(self) -> (RunOutcome, RigDevices) {
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
