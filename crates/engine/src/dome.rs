//! Driving a dome rig: turntable, LED array and the cameras of the arc (`docs/engine.md`,
//! "LED dome"); a camera array is the same without the turntable, its flash triggers driven as
//! the LED array.
//!
//! A step is (rotation, pattern): turn the table when the rotation changes, set the LED
//! pattern, trigger every camera at once (they expose together, so a pattern costs one
//! exposure whatever the number of cameras), then read every camera. Each camera is its own
//! device (`Box<dyn Camera>`, one per arc position): a real dome has one link per camera, and
//! a failing camera is retried and named on its own. Frames leave through a bounded channel
//! (back-pressure: the engine waits before the next pattern when the pipeline is behind).
//!
//! Retries: a retryable error (`ErrorKind::is_retryable`) repeats the whole step (pattern,
//! trigger, read: a read-out failure cannot be read again), at most `max_retries` times with
//! doubling backoff; anything else ends the run with [`DomeRunError::StepFailed`] naming the
//! step and device, or, with [`DomeSettings::pause_on_fault`] and a command channel, pauses
//! it until it is resumed (the step is tried again) or aborted. Resume: the unit a dome
//! commits is a view group (all patterns of one rotation); rotations in `done` are skipped, a
//! partly captured rotation is captured again.
//!
//! Steering and watching with the gonio engine's vocabulary ([`Command`], [`Event`],
//! [`PauseReason`], [`RunSummary`], [`StepKind::Dome`]): pause and abort take effect between
//! steps (the step under way is delivered first), a paused run waits for resume or abort, and
//! events report every delivered step, progress with an ETA
//! (the mean of the last `eta_window` measured step times, pauses excluded, times the steps
//! left), retries, pauses and resumes.

use std::collections::{HashSet, VecDeque};
use std::future::Future;
use std::pin::Pin;
use std::task::Poll;

use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, DeviceError, LedArray, LedPattern, MoveOptions, SharedClock, Turntable};
use btfrig_planner::dome::{DomeShot, DomeStep};
use tokio::sync::{broadcast, mpsc};

use crate::{Command, Event, PauseReason, RunOutcome, RunSummary, StepKey, StepKind};

/// The devices of a dome run.
pub struct DomeDevices {
    /// The turntable under the sample (`None` on a camera array, whose steps all have
    /// rotation 0).
    pub turntable: Option<Box<dyn Turntable>>,
    /// The LED array.
    pub leds: Box<dyn LedArray>,
    /// The cameras, one per arc position used (the order of `DomeCapture::frames`).
    pub cameras: Vec<Box<dyn Camera>>,
    /// The rig clock.
    pub clock: SharedClock,
}

/// Timeouts and retries of a dome run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DomeSettings {
    /// Turntable move timeout, s.
    pub move_timeout_s: f64,
    /// Trigger timeout beyond the exposure, s.
    pub trigger_timeout_s: f64,
    /// Read-out timeout, s.
    pub read_timeout_s: f64,
    /// Retries per step.
    pub max_retries: u32,
    /// Backoff before the first retry, s (doubling).
    pub backoff_s: f64,
    /// When a step fails for good: pause and wait for [`Command::Resume`] (the step is tried
    /// again) or [`Command::Abort`] (true; needs a command channel), or end the run with
    /// [`DomeRunError::StepFailed`] (false, the default: nobody is there to fix the cause).
    pub pause_on_fault: bool,
    /// Number of recent measured step times the ETA averages.
    pub eta_window: usize,
    /// Events the broadcast keeps for a listener (as `EngineSettings::event_capacity`).
    pub event_capacity: usize,
}

impl Default for DomeSettings {
    fn default() -> Self {
        DomeSettings {
            move_timeout_s: 60.0,
            trigger_timeout_s: 10.0,
            read_timeout_s: 30.0,
            max_retries: 5,
            backoff_s: 0.5,
            pause_on_fault: false,
            eta_window: 20,
            event_capacity: 4096,
        }
    }
}

/// The frames of one step: one per camera.
#[derive(Debug, Clone)]
pub struct DomeCapture {
    /// Position of the step in the schedule.
    pub index: usize,
    /// The step.
    pub step: DomeStep,
    /// One frame per camera, in [`DomeDevices::cameras`] order.
    pub frames: Vec<RawFrame>,
    /// Attempts the step took (1 = no retry).
    pub attempts: u32,
    /// Rig clock at the end of the step, s.
    pub time_s: f64,
}

/// Why a dome run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum DomeRunError {
    /// A step failed and no retry helped.
    #[error("step {index} (rotation {rotation}, {shot:?}) failed: {error}; fix the cause and run again to resume")]
    StepFailed {
        /// Position in the schedule.
        index: usize,
        /// Its rotation.
        rotation: u32,
        /// What it captured.
        shot: DomeShot,
        /// The device error.
        error: DeviceError,
    },
    /// The frame receiver was dropped.
    #[error("the pipeline stopped taking frames")]
    ConsumerGone,
}

/// Polls every future together (all cameras expose at once) and returns their outputs in order.
async fn join_all<'a, T>(futs: Vec<Pin<Box<dyn Future<Output = T> + Send + 'a>>>) -> Vec<T> {
    let mut futs: Vec<Option<Pin<Box<dyn Future<Output = T> + Send + 'a>>>> = futs.into_iter().map(Some).collect();
    let mut out: Vec<Option<T>> = futs.iter().map(|_| None).collect();
    std::future::poll_fn(|cx| {
        for (f, o) in futs.iter_mut().zip(out.iter_mut()) {
            if let Some(fut) = f {
                if let Poll::Ready(v) = fut.as_mut().poll(cx) {
                    *o = Some(v);
                    *f = None;
                }
            }
        }
        if futs.iter().all(Option::is_none) {
            Poll::Ready(())
        } else {
            Poll::Pending
        }
    })
    .await;
    out.into_iter().map(|o| o.expect("every future finished")).collect()
}

/// Pattern of a step: the plan's intensities, or one LED for a reference frame.
fn pattern_of(step: &DomeStep, patterns: &[Vec<f64>], leds: usize) -> LedPattern {
    match step.shot {
        DomeShot::Pattern(p) => LedPattern { intensities: patterns[p].clone() },
        DomeShot::Reference(j) => LedPattern::single(leds, j),
    }
}

/// A dome step's kind and key (`view` = its rotation, `light` = its position in the schedule).
fn describe(index: usize, step: &DomeStep) -> (StepKey, StepKind) {
    (
        StepKey { light: index as u32, view: step.rotation },
        StepKind::Dome { rotation: step.rotation, turntable_rad: step.turntable_rad, shot: step.shot },
    )
}

/// Runs `steps` on `devices`: pattern frames at `exposure_s`, reference frames at
/// `reference_exposure_s`. Steered through `commands` (bounded, [`crate::COMMAND_CAPACITY`];
/// `None`: nobody steers) and watched through `events` (the engine's [`Event`]s, counted
/// drops as [`crate::Engine`]'s). The devices must be homed. An abort returns
/// [`RunOutcome::Aborted`] with the keys of the steps delivered.
#[allow(clippy::too_many_arguments)]
pub async fn run_dome(
    devices: &mut DomeDevices,
    steps: &[DomeStep],
    patterns: &[Vec<f64>],
    exposure_s: f64,
    reference_exposure_s: f64,
    done: &HashSet<u32>,
    settings: DomeSettings,
    commands: Option<mpsc::Receiver<Command>>,
    events: broadcast::Sender<Event>,
    frames: mpsc::Sender<DomeCapture>,
) -> Result<RunOutcome, DomeRunError> {
    let mut run = Steering {
        commands,
        events,
        event_capacity: settings.event_capacity.max(1).next_power_of_two(),
        events_dropped: 0,
        pause_req: false,
        abort_req: false,
        recent: VecDeque::new(),
        eta_window: settings.eta_window.max(1),
        last_mark_s: devices.clock.now_s(),
        done: 0,
        total: steps.len(),
    };
    let start = devices.clock.now_s();
    let leds = devices.leds.capabilities().count;
    let mut summary = RunSummary { total: steps.len(), ..RunSummary::default() };
    let mut delivered = HashSet::new();
    let mut measured_sum_s = 0.0;
    let mut aborted = false;
    let mut table_at: Option<u32> = None;
    for (index, step) in steps.iter().enumerate() {
        let (key, kind) = describe(index, step);
        if done.contains(&step.rotation) {
            summary.skipped_done += 1;
            run.done += 1;
            run.progress();
            continue;
        }
        if !run.between_steps(&devices.clock).await {
            aborted = true;
            break;
        }
        let exposure = match step.shot {
            DomeShot::Pattern(_) => exposure_s,
            DomeShot::Reference(_) => reference_exposure_s,
        };
        let pattern = pattern_of(step, patterns, leds);
        let mut attempt = 0u32;
        // Retries of earlier rounds (a failed round paused and was resumed).
        let mut retried = 0u32;
        let captured = loop {
            attempt += 1;
            match capture_step(devices, step, &pattern, exposure, &mut table_at, &settings).await {
                Ok(f) => break Some(f),
                Err(e) if e.is_retryable() && attempt <= settings.max_retries => {
                    let w =
                        format!("step {index} ({}): {e}; retry {attempt} of {}", kind.label(key), settings.max_retries);
                    tracing::warn!("{w}");
                    summary.warnings += 1;
                    run.emit(Event::Warning(w));
                    // The table may have been left anywhere: move it again.
                    table_at = None;
                    devices.clock.sleep_s(settings.backoff_s * 2f64.powi(attempt as i32 - 1)).await;
                }
                Err(error) if settings.pause_on_fault && run.commands.is_some() => {
                    let message = if error.is_retryable() {
                        format!("{error} (retryable, gave up after {} retries)", settings.max_retries)
                    } else {
                        format!("{error} (not retryable)")
                    };
                    let reason = PauseReason::StepFailed {
                        index,
                        key,
                        step: kind,
                        device: error.device().to_string(),
                        kind: error.kind(),
                        message,
                    };
                    if !run.pause(reason, &devices.clock).await {
                        break None;
                    }
                    // Resumed: the step again, with fresh retries, from the table's move.
                    retried += attempt;
                    attempt = 0;
                    table_at = None;
                }
                Err(error) => {
                    return Err(DomeRunError::StepFailed { index, rotation: step.rotation, shot: step.shot, error })
                }
            }
        };
        let Some(captured) = captured else {
            aborted = true;
            break;
        };
        let attempts = retried + attempt;
        summary.retries += attempts - 1;
        if attempts > 1 {
            summary.retried_steps.push((key, attempts - 1));
        }
        summary.captured += 1;
        summary.exposure_s += exposure;
        let now = devices.clock.now_s();
        let cap = DomeCapture { index, step: *step, frames: captured, attempts, time_s: now };
        if frames.send(cap).await.is_err() {
            return Err(DomeRunError::ConsumerGone);
        }
        delivered.insert(key);
        measured_sum_s += run.measured(now);
        run.emit(Event::StepDone { index, key, step: kind, attempts });
        run.done += 1;
        run.progress();
    }
    summary.hardware_s = devices.clock.now_s() - start;
    summary.mean_step_s = if summary.captured > 0 { measured_sum_s / summary.captured as f64 } else { 0.0 };
    summary.events_dropped = run.events_dropped;
    Ok(if aborted { RunOutcome::Aborted { done: delivered, summary } } else { RunOutcome::Finished(summary) })
}

/// Commands, pauses, events, step times and progress of a dome run.
struct Steering {
    commands: Option<mpsc::Receiver<Command>>,
    events: broadcast::Sender<Event>,
    /// The broadcast's real length.
    event_capacity: usize,
    events_dropped: u64,
    pause_req: bool,
    abort_req: bool,
    /// The last `eta_window` measured step times, s.
    recent: VecDeque<f64>,
    eta_window: usize,
    /// Rig time of the last delivery (or resume), s.
    last_mark_s: f64,
    /// Steps done (captured or skipped).
    done: usize,
    total: usize,
}

impl Steering {
    /// As the gonio engine: the broadcast never waits; an event overwritten before a live
    /// receiver read it is counted.
    fn emit(&mut self, e: Event) {
        if self.events.receiver_count() > 0 && self.events.len() >= self.event_capacity {
            self.events_dropped += 1;
        }
        let _ = self.events.send(e);
    }

    /// Reads the waiting commands; waits while a pause is asked for. `false` on abort.
    async fn between_steps(&mut self, clock: &SharedClock) -> bool {
        if let Some(rx) = self.commands.as_mut() {
            while let Ok(c) = rx.try_recv() {
                match c {
                    Command::Pause => self.pause_req = true,
                    Command::Resume => self.pause_req = false,
                    Command::Abort => self.abort_req = true,
                }
            }
        }
        if self.abort_req {
            return false;
        }
        if self.pause_req {
            return self.pause(PauseReason::Requested, clock).await;
        }
        true
    }

    /// Waits for resume (`true`) or abort (`false`; also when no sender is left).
    async fn pause(&mut self, reason: PauseReason, clock: &SharedClock) -> bool {
        tracing::info!("dome run paused: {reason}");
        self.pause_req = false;
        self.emit(Event::Paused { reason });
        loop {
            let Some(rx) = self.commands.as_mut() else {
                self.abort_req = true;
                return false;
            };
            match rx.recv().await {
                Some(Command::Resume) => {
                    self.emit(Event::Resumed);
                    // The pause is not a step time.
                    self.last_mark_s = clock.now_s();
                    return true;
                }
                Some(Command::Pause) => {}
                Some(Command::Abort) | None => {
                    self.abort_req = true;
                    return false;
                }
            }
        }
    }

    /// A step delivered at `now_s`: its time since the last delivery (or resume), returned.
    fn measured(&mut self, now_s: f64) -> f64 {
        let dt = now_s - self.last_mark_s;
        self.recent.push_back(dt);
        self.last_mark_s = now_s;
        while self.recent.len() > self.eta_window {
            self.recent.pop_front();
        }
        dt
    }

    fn progress(&mut self) {
        let left = self.total - self.done;
        let eta_s =
            (!self.recent.is_empty()).then(|| self.recent.iter().sum::<f64>() / self.recent.len() as f64 * left as f64);
        self.emit(Event::Progress { done: self.done, total: self.total, eta_s });
    }
}

async fn capture_step(
    d: &mut DomeDevices,
    step: &DomeStep,
    pattern: &LedPattern,
    exposure_s: f64,
    table_at: &mut Option<u32>,
    s: &DomeSettings,
) -> Result<Vec<RawFrame>, DeviceError> {
    if *table_at != Some(step.rotation) {
        if let Some(t) = d.turntable.as_mut() {
            t.move_to_rad(step.turntable_rad, MoveOptions::with_timeout_s(s.move_timeout_s)).await?;
        }
        *table_at = Some(step.rotation);
    }
    d.leds.set_pattern(pattern).await?;
    for cam in d.cameras.iter_mut() {
        if (cam.settings().exposure_s - exposure_s).abs() > 1e-12 {
            cam.set_exposure_s(exposure_s).await?;
        }
    }
    let timeout = s.trigger_timeout_s + exposure_s;
    let triggers = join_all(d.cameras.iter_mut().map(|c| c.trigger(timeout)).collect()).await;
    triggers.into_iter().collect::<Result<Vec<u64>, DeviceError>>()?;
    let reads = join_all(d.cameras.iter_mut().map(|c| c.read_frame(s.read_timeout_s)).collect()).await;
    reads.into_iter().collect()
}
