//! The task that owns the devices and executes the steps.

use std::collections::{HashMap, HashSet, VecDeque};
use std::future::Future;

use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::{Camera, DeviceError, ErrorKind, MoveOptions, Rail, Robot, SharedClock};
use tokio::sync::{broadcast, mpsc, watch};

use crate::{
    CapturedFrame, Command, Devices, EngineSettings, EngineStep, Event, ExposureControl, PauseReason, RunOutcome,
    RunState, RunSummary, StepKey, StepKind, StepTimes, MAX_EXPOSURES_PER_STEP,
};

/// Device calls without a timeout argument (settings, reconnect) are guarded with this many
/// seconds plus the margin; real controllers answer such commands within a few seconds.
const COMMAND_TIMEOUT_S: f64 = 5.0;

/// Retries and warnings of one operation, merged into the run's counters afterwards (the
/// operations of one step run concurrently, so each keeps its own log).
#[derive(Debug, Default)]
struct OpLog {
    retries: u32,
    warnings: Vec<String>,
}

impl OpLog {
    fn merge(&mut self, other: OpLog) {
        self.retries += other.retries;
        self.warnings.extend(other.warnings);
    }
}

/// A step that could not be done.
struct Failure {
    index: usize,
    error: DeviceError,
}

enum Stop {
    Failed(Failure),
    ConsumerGone,
}

/// A step whose last exposure is triggered but not yet read out.
struct Pending {
    index: usize,
    times: StepTimes,
    /// Its earlier exposures, already read.
    frames: Vec<RawFrame>,
}

/// Runs `fut`, but gives up `limit_s` (rig clock) later with a `Timeout` of `device`.
async fn guard<T>(
    clock: &SharedClock,
    limit_s: f64,
    device: &str,
    fut: impl Future<Output = Result<T, DeviceError>>,
) -> Result<T, DeviceError> {
    tokio::select! {
        biased;
        r = fut => r,
        () = clock.sleep_s(limit_s) => Err(DeviceError::new(
            device,
            ErrorKind::Timeout,
            format!("no answer within {limit_s} s (engine guard)"),
        )),
    }
}

/// Repeats `$call` (an expression on `$dev`) while it fails with a retryable error, at most
/// `max_retries` times, with exponential backoff; reconnects a disconnected device first.
/// A macro because the call borrows the device mutably anew on every attempt.
macro_rules! retrying {
    ($s:expr, $clock:expr, $log:expr, $dev:expr, $limit_s:expr, $call:expr) => {{
        let name = $dev.name().to_string();
        let mut k: u32 = 0;
        loop {
            match guard($clock, $limit_s, &name, $call).await {
                Ok(v) => break Ok(v),
                Err(e) if e.is_retryable() && k < $s.max_retries => {
                    let wait = $s.backoff_for(k);
                    $log.warnings.push(format!("{e}; retry {} of {} in {wait:.2} s", k + 1, $s.max_retries));
                    if e.kind() == ErrorKind::Disconnected {
                        let limit = COMMAND_TIMEOUT_S + $s.guard_margin_s;
                        if let Err(r) = guard($clock, limit, &name, $dev.reconnect()).await {
                            $log.warnings.push(format!("reconnect failed: {r}"));
                        }
                    }
                    $clock.sleep_s(wait).await;
                    k += 1;
                    $log.retries += 1;
                }
                Err(e) => break Err(e),
            }
        }
    }};
}

async fn move_robot(
    s: &EngineSettings,
    clock: &SharedClock,
    robot: &mut dyn Robot,
    target: [f64; 3],
) -> (Result<(), DeviceError>, OpLog) {
    let mut log = OpLog::default();
    let opts = MoveOptions::with_timeout_s(s.move_timeout_s);
    let r = retrying!(s, clock, log, robot, s.move_timeout_s + s.guard_margin_s, robot.move_to_rad(target, opts));
    (r.map(|_| ()), log)
}

async fn move_rail(
    s: &EngineSettings,
    clock: &SharedClock,
    rail: &mut dyn Rail,
    target: f64,
) -> (Result<(), DeviceError>, OpLog) {
    let mut log = OpLog::default();
    let opts = MoveOptions::with_timeout_s(s.move_timeout_s);
    let r = retrying!(s, clock, log, rail, s.move_timeout_s + s.guard_margin_s, rail.move_to_rad(target, opts));
    (r.map(|_| ()), log)
}

/// Robot and rail at the same time (distinct devices); the first error wins.
async fn move_both(
    s: &EngineSettings,
    clock: &SharedClock,
    robot: &mut dyn Robot,
    rail: &mut dyn Rail,
    joints: &JointState,
) -> (Result<(), DeviceError>, OpLog) {
    let ((a, mut log), (b, log_b)) =
        tokio::join!(move_robot(s, clock, robot, joints.robot), move_rail(s, clock, rail, joints.rail));
    log.merge(log_b);
    (a.and(b), log)
}

async fn set_exposure(
    s: &EngineSettings,
    clock: &SharedClock,
    camera: &mut dyn Camera,
    exposure_s: f64,
) -> (Result<(), DeviceError>, OpLog) {
    let mut log = OpLog::default();
    if camera.settings().exposure_s == exposure_s {
        return (Ok(()), log);
    }
    let r = retrying!(s, clock, log, camera, COMMAND_TIMEOUT_S + s.guard_margin_s, camera.set_exposure_s(exposure_s));
    (r, log)
}

async fn trigger(
    s: &EngineSettings,
    clock: &SharedClock,
    camera: &mut dyn Camera,
    exposure_s: f64,
) -> (Result<u64, DeviceError>, OpLog) {
    let mut log = OpLog::default();
    let timeout = s.trigger_timeout_s + exposure_s;
    let r = retrying!(s, clock, log, camera, timeout + s.guard_margin_s, camera.trigger(timeout));
    (r, log)
}

/// One read-out, no retry: a failed read-out needs a new trigger at the step's pose.
async fn read_once(s: &EngineSettings, clock: &SharedClock, camera: &mut dyn Camera) -> Result<RawFrame, DeviceError> {
    let name = camera.name().to_string();
    guard(clock, s.read_timeout_s + s.guard_margin_s, &name, camera.read_frame(s.read_timeout_s)).await
}

pub(crate) struct Runner {
    dev: Devices,
    steps: Vec<EngineStep>,
    done: HashSet<StepKey>,
    s: EngineSettings,
    frames: mpsc::Sender<CapturedFrame>,
    events: broadcast::Sender<Event>,
    state: watch::Sender<RunState>,
    cmd: mpsc::Receiver<Command>,
    captured: usize,
    skipped: usize,
    retries: u32,
    step_retries: HashMap<usize, u32>,
    warnings: usize,
    recent: VecDeque<f64>,
    measured_sum_s: f64,
    measured_n: usize,
    last_mark_s: f64,
    start_s: f64,
    pause_req: bool,
    abort_req: bool,
    exposure: Box<dyn ExposureControl>,
    motion_wait_wall_s: f64,
    events_dropped: u64,
    exposure_s: f64,
}

impl Runner {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        dev: Devices,
        steps: Vec<EngineStep>,
        done: HashSet<StepKey>,
        s: EngineSettings,
        frames: mpsc::Sender<CapturedFrame>,
        events: broadcast::Sender<Event>,
        state: watch::Sender<RunState>,
        cmd: mpsc::Receiver<Command>,
        exposure: Box<dyn ExposureControl>,
    ) -> Self {
        Runner {
            dev,
            steps,
            done,
            s,
            frames,
            events,
            state,
            cmd,
            captured: 0,
            skipped: 0,
            retries: 0,
            step_retries: HashMap::new(),
            warnings: 0,
            recent: VecDeque::new(),
            measured_sum_s: 0.0,
            measured_n: 0,
            last_mark_s: 0.0,
            start_s: 0.0,
            pause_req: false,
            abort_req: false,
            exposure,
            motion_wait_wall_s: 0.0,
            events_dropped: 0,
            exposure_s: 0.0,
        }
    }

    fn emit(&mut self, e: Event) {
        // The broadcast never waits: a full queue overwrites its oldest event, one that a
        // listener alive when it was sent has not read. Counted, as the policy for a full
        // event queue (docs/engine.md, "Tasks and messages").
        if self.events.receiver_count() > 0 && self.events.len() >= crate::event_queue_len(&self.s) {
            self.events_dropped += 1;
        }
        // No listener is fine: events are advisory.
        let _ = self.events.send(e);
    }

    fn warn(&mut self, msg: String) {
        tracing::warn!("{msg}");
        self.warnings += 1;
        self.emit(Event::Warning(msg));
    }

    fn now(&self) -> f64 {
        self.dev.clock.now_s()
    }

    /// Reads every waiting command without blocking.
    fn poll_commands(&mut self) {
        while let Ok(c) = self.cmd.try_recv() {
            match c {
                Command::Pause => self.pause_req = true,
                Command::Resume => self.pause_req = false,
                Command::Abort => self.abort_req = true,
            }
        }
    }

    /// Waits while paused; `true` to go on, `false` on abort (or every handle gone).
    async fn pause(&mut self, reason: PauseReason) -> bool {
        tracing::info!("run paused: {reason}");
        self.pause_req = false;
        self.state.send_replace(RunState::Paused(reason.clone()));
        self.emit(Event::Paused { reason });
        loop {
            match self.cmd.recv().await {
                Some(Command::Resume) => {
                    self.state.send_replace(RunState::Running);
                    self.emit(Event::Resumed);
                    // The pause is not a step time.
                    self.last_mark_s = self.now();
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

    fn failure_reason(&self, f: Failure) -> PauseReason {
        let e = f.error;
        let message = if e.is_retryable() {
            format!("{e} (retryable, gave up after {} retries)", self.s.max_retries)
        } else {
            format!("{e} (not retryable)")
        };
        PauseReason::StepFailed {
            index: f.index,
            key: self.steps[f.index].key,
            step: StepKind::Gonio { joints: self.steps[f.index].joints },
            device: e.device().to_string(),
            kind: e.kind(),
            message,
        }
    }

    fn absorb(&mut self, index: usize, log: OpLog) {
        self.retries += log.retries;
        *self.step_retries.entry(index).or_default() += log.retries;
        let key = self.steps[index].key;
        for w in log.warnings {
            self.warn(format!("step {index} ({key}): {w}"));
        }
    }

    fn note_retry(&mut self, index: usize, msg: String) {
        self.absorb(index, OpLog { retries: 1, warnings: vec![msg] });
    }

    /// After a failed read-out: a disconnected camera is reconnected before the recapture.
    async fn reconnect_camera_if(&mut self, index: usize, e: &DeviceError) {
        if e.kind() != ErrorKind::Disconnected {
            return;
        }
        let clock = self.dev.clock.clone();
        let limit = COMMAND_TIMEOUT_S + self.s.guard_margin_s;
        let name = self.dev.camera.name().to_string();
        if let Err(r) = guard(&clock, limit, &name, self.dev.camera.reconnect()).await {
            self.warn(format!("step {index}: reconnect failed: {r}"));
        }
    }

    fn done_count(&self) -> usize {
        self.captured + self.skipped
    }

    fn progress(&mut self) {
        let remaining = self.steps.len() - self.done_count();
        let eta_s = (!self.recent.is_empty())
            .then(|| self.recent.iter().sum::<f64>() / self.recent.len() as f64 * remaining as f64);
        self.emit(Event::Progress { done: self.done_count(), total: self.steps.len(), eta_s });
    }

    /// Hands the step's frames (first exposure first) to the consumer.
    async fn deliver(&mut self, index: usize, frames: Vec<RawFrame>, times: StepTimes) -> Result<(), Stop> {
        let step = self.steps[index];
        let attempts = 1 + self.step_retries.get(&index).copied().unwrap_or(0);
        let exposed: f64 = frames.iter().map(|f| f.meta.exposure_s).sum();
        let mut frames = frames.into_iter();
        let frame = frames.next().expect("a step delivers at least one frame");
        let cf = CapturedFrame {
            index,
            key: step.key,
            frame,
            bracket: frames.collect(),
            attempts,
            joints: step.joints,
            times,
        };
        if self.frames.send(cf).await.is_err() {
            return Err(Stop::ConsumerGone);
        }
        self.captured += 1;
        self.exposure_s += exposed;
        self.done.insert(step.key);
        // Measured step time: between successive deliveries (pauses excluded).
        let dt = times.transfer_end_s - self.last_mark_s;
        self.last_mark_s = times.transfer_end_s;
        self.recent.push_back(dt);
        while self.recent.len() > self.s.eta_window.max(1) {
            self.recent.pop_front();
        }
        self.measured_sum_s += dt;
        self.measured_n += 1;
        self.emit(Event::StepDone { index, key: step.key, step: StepKind::Gonio { joints: step.joints }, attempts });
        self.progress();
        Ok(())
    }

    /// The step's planned exposures (at least one, at most [`MAX_EXPOSURES_PER_STEP`]).
    fn planned(&mut self, index: usize) -> Vec<f64> {
        let step = self.steps[index];
        let mut planned = self.exposure.planned(&step);
        if planned.is_empty() {
            planned.push(step.exposure_s);
        }
        planned.truncate(MAX_EXPOSURES_PER_STEP);
        planned
    }

    /// One exposure of step `index` at the pose the devices are at: exposure setting,
    /// trigger and read-out; a failed read-out is repeated from the trigger.
    async fn capture_here(&mut self, index: usize, exposure_s: f64, times: &mut StepTimes) -> Result<RawFrame, Stop> {
        let s = self.s.clone();
        let clock = self.dev.clock.clone();
        let fail = |error| Stop::Failed(Failure { index, error });
        let (r, log) = set_exposure(&s, &clock, &mut *self.dev.camera, exposure_s).await;
        self.absorb(index, log);
        r.map_err(fail)?;
        let mut k = 0;
        loop {
            times.trigger_start_s = clock.now_s();
            let (r, log) = trigger(&s, &clock, &mut *self.dev.camera, exposure_s).await;
            times.trigger_end_s = clock.now_s();
            self.absorb(index, log);
            r.map_err(fail)?;
            match read_once(&s, &clock, &mut *self.dev.camera).await {
                Ok(frame) => {
                    times.transfer_end_s = clock.now_s();
                    return Ok(frame);
                }
                Err(e) if e.is_retryable() && k < s.max_retries => {
                    let wait = s.backoff_for(k);
                    self.note_retry(index, format!("{e}; capture again in {wait:.2} s"));
                    self.reconnect_camera_if(index, &e).await;
                    clock.sleep_s(wait).await;
                    k += 1;
                }
                Err(e) => return Err(fail(e)),
            }
        }
    }

    /// Shows the control the step's frames and takes the exposures it asks for, at the pose
    /// the devices are at, until it is satisfied.
    async fn inspect_here(
        &mut self,
        index: usize,
        frames: &mut Vec<RawFrame>,
        times: &mut StepTimes,
    ) -> Result<(), Stop> {
        let step = self.steps[index];
        while self.exposure.inspects() && frames.len() < MAX_EXPOSURES_PER_STEP {
            let Some(e) = self.exposure.next(&step, frames) else { break };
            let started = self.now();
            let frame = self.capture_here(index, e, times).await?;
            frames.push(frame);
            times.bracket_s += self.now() - started;
        }
        Ok(())
    }

    /// Move, then every exposure of step `index` one after the other (trigger and read).
    async fn sequential_step(&mut self, index: usize) -> Result<(), Stop> {
        let step = self.steps[index];
        let s = self.s.clone();
        let clock = self.dev.clock.clone();
        let fail = |error| Stop::Failed(Failure { index, error });
        let mut times = StepTimes { move_start_s: clock.now_s(), ..StepTimes::default() };
        let wall = std::time::Instant::now();
        let (r, log) = move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &step.joints).await;
        self.motion_wait_wall_s += wall.elapsed().as_secs_f64();
        times.move_end_s = clock.now_s();
        self.absorb(index, log);
        r.map_err(fail)?;
        let planned = self.planned(index);
        let mut frames = Vec::with_capacity(planned.len());
        let mut first_end = None;
        for e in planned {
            frames.push(self.capture_here(index, e, &mut times).await?);
            first_end.get_or_insert(times.trigger_end_s);
        }
        times.bracket_s = times.trigger_end_s - first_end.unwrap_or(times.trigger_end_s);
        self.inspect_here(index, &mut frames, &mut times).await?;
        self.deliver(index, frames, times).await
    }

    /// Reads out the pending frame (the devices are still at its pose), takes the exposures an
    /// inspection asks for; on a retryable failure captures the step again.
    async fn finish_pending(&mut self, p: Pending) -> Result<(), Stop> {
        let s = self.s.clone();
        let clock = self.dev.clock.clone();
        match read_once(&s, &clock, &mut *self.dev.camera).await {
            Ok(frame) => {
                let mut times = StepTimes { transfer_end_s: clock.now_s(), ..p.times };
                let mut frames = p.frames;
                frames.push(frame);
                self.inspect_here(p.index, &mut frames, &mut times).await?;
                self.deliver(p.index, frames, times).await
            }
            Err(e) if e.is_retryable() => {
                self.note_retry(p.index, format!("{e}; capturing step {} again", p.index));
                self.reconnect_camera_if(p.index, &e).await;
                self.sequential_step(p.index).await
            }
            Err(error) => Err(Stop::Failed(Failure { index: p.index, error })),
        }
    }

    /// Step `index` with overlap: the read-out of `pending` runs while robot and rail move
    /// to this step's pose; if the exposure control asks for more exposures of the pending
    /// step once it sees its frames, the devices go back to that step's pose for them and
    /// then return here. Then this step's planned exposures: all but the last are read at the
    /// pose, the last is triggered and returned as pending.
    async fn overlapped_step(&mut self, index: usize, pending: Option<Pending>) -> Result<Pending, Stop> {
        let step = self.steps[index];
        let s = self.s.clone();
        let clock = self.dev.clock.clone();
        let fail = |error| Stop::Failed(Failure { index, error });
        let planned = self.planned(index);
        let first_exposure = planned[0];
        let mut times = StepTimes { move_start_s: clock.now_s(), ..StepTimes::default() };

        let Devices { robot, rail, camera, .. } = &mut self.dev;
        let wall = std::time::Instant::now();
        let moving = async {
            let r = move_both(&s, &clock, &mut **robot, &mut **rail, &step.joints).await;
            (r, clock.now_s(), std::time::Instant::now())
        };
        let has_pending = pending.is_some();
        let camera_work = async {
            let mut read = None;
            if has_pending {
                let r = read_once(&s, &clock, &mut **camera).await;
                let failed = r.is_err();
                read = Some(r.map(|f| (f, clock.now_s())));
                if failed {
                    return (read, None);
                }
            }
            // The exposure command runs on the camera after the transfer, during the move.
            (read, Some(set_exposure(&s, &clock, &mut **camera, first_exposure).await))
        };
        let camera_work = async { (camera_work.await, std::time::Instant::now()) };
        let (((moved, move_log), move_end, moved_at), ((read, exposure), camera_done_at)) =
            tokio::join!(moving, camera_work);
        // Wall time the engine waited on the move after the camera was done with its work.
        self.motion_wait_wall_s += moved_at.saturating_duration_since(camera_done_at.max(wall)).as_secs_f64();
        times.move_end_s = move_end;
        self.absorb(index, move_log);

        let mut moved = moved;
        let mut exposure = exposure;
        if let (Some(p), Some(read)) = (pending, read) {
            let back_here = match read {
                Ok((frame, t)) => {
                    let mut p_times = StepTimes { transfer_end_s: t, ..p.times };
                    let mut frames = p.frames;
                    frames.push(frame);
                    let p_step = self.steps[p.index];
                    let more = if self.exposure.inspects() && frames.len() < MAX_EXPOSURES_PER_STEP {
                        self.exposure.next(&p_step, &frames)
                    } else {
                        None
                    };
                    if let Some(e) = more {
                        // The return trip: back to the pending step's pose for the exposures
                        // its frames turned out to need, then here again.
                        let (started, before) = (clock.now_s(), p_times.bracket_s);
                        let p_fail = |error| Stop::Failed(Failure { index: p.index, error });
                        let (r, log) =
                            move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &p_step.joints).await;
                        self.absorb(p.index, log);
                        r.map_err(p_fail)?;
                        frames.push(self.capture_here(p.index, e, &mut p_times).await?);
                        self.inspect_here(p.index, &mut frames, &mut p_times).await?;
                        times.move_start_s = clock.now_s();
                        let (r, log) =
                            move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &step.joints).await;
                        times.move_end_s = clock.now_s();
                        self.absorb(index, log);
                        moved = r;
                        exposure = Some(set_exposure(&s, &clock, &mut *self.dev.camera, first_exposure).await);
                        // The whole trip (inspect_here counted its own captures already).
                        p_times.bracket_s = before + clock.now_s() - started;
                    }
                    self.deliver(p.index, frames, p_times).await?;
                    false
                }
                Err(e) if e.is_retryable() => {
                    self.note_retry(p.index, format!("{e}; capturing step {} again", p.index));
                    self.reconnect_camera_if(p.index, &e).await;
                    self.sequential_step(p.index).await?;
                    true
                }
                Err(error) => return Err(Stop::Failed(Failure { index: p.index, error })),
            };
            if back_here {
                // Back to this step's pose, now without overlap.
                times.move_start_s = clock.now_s();
                let (r, log) = move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &step.joints).await;
                times.move_end_s = clock.now_s();
                self.absorb(index, log);
                moved = r;
                exposure = Some(set_exposure(&s, &clock, &mut *self.dev.camera, first_exposure).await);
            }
        }
        moved.map_err(fail)?;
        if let Some((r, log)) = exposure {
            self.absorb(index, log);
            r.map_err(fail)?;
        }
        // Every planned exposure but the last is read at the pose; the last is left pending.
        let (&last, earlier) = planned.split_last().expect("at least one planned exposure");
        let mut frames = Vec::with_capacity(planned.len());
        let mut first_end = None;
        for &e in earlier {
            frames.push(self.capture_here(index, e, &mut times).await?);
            first_end.get_or_insert(times.trigger_end_s);
        }
        if !earlier.is_empty() {
            let (r, log) = set_exposure(&s, &clock, &mut *self.dev.camera, last).await;
            self.absorb(index, log);
            r.map_err(fail)?;
        }
        times.trigger_start_s = clock.now_s();
        let (r, log) = trigger(&s, &clock, &mut *self.dev.camera, last).await;
        times.trigger_end_s = clock.now_s();
        self.absorb(index, log);
        r.map_err(fail)?;
        times.bracket_s = times.trigger_end_s - first_end.unwrap_or(times.trigger_end_s);
        Ok(Pending { index, times, frames })
    }

    fn summary(&self) -> RunSummary {
        let mut retried: Vec<(usize, u32)> =
            self.step_retries.iter().filter(|(_, &n)| n > 0).map(|(&i, &n)| (i, n)).collect();
        retried.sort_unstable();
        RunSummary {
            total: self.steps.len(),
            captured: self.captured,
            skipped_done: self.skipped,
            retries: self.retries,
            retried_steps: retried.into_iter().map(|(i, n)| (self.steps[i].key, n)).collect(),
            warnings: self.warnings,
            hardware_s: self.now() - self.start_s,
            exposure_s: self.exposure_s,
            mean_step_s: if self.measured_n > 0 { self.measured_sum_s / self.measured_n as f64 } else { 0.0 },
            motion_wait_wall_s: self.motion_wait_wall_s,
            events_dropped: self.events_dropped,
        }
    }

    fn aborted(mut self) -> (RunOutcome, Devices) {
        let mut summary = self.summary();
        self.state.send_replace(RunState::Aborted);
        self.emit(Event::Aborted(summary.clone()));
        // The last event may have overwritten one too.
        summary.events_dropped = self.events_dropped;
        let done = std::mem::take(&mut self.done);
        (RunOutcome::Aborted { done, summary }, self.dev)
    }

    fn finished(mut self) -> (RunOutcome, Devices) {
        let mut summary = self.summary();
        self.state.send_replace(RunState::Finished);
        self.emit(Event::Finished(summary.clone()));
        summary.events_dropped = self.events_dropped;
        (RunOutcome::Finished(summary), self.dev)
    }

    /// Handles a stop: pauses on a failed step (`next` becomes that step) or on a lost
    /// consumer. Returns `false` when the run must end (abort).
    async fn on_stop(&mut self, stop: Stop, next: &mut usize) -> bool {
        match stop {
            Stop::Failed(f) => {
                *next = f.index;
                let reason = self.failure_reason(f);
                self.pause(reason).await
            }
            Stop::ConsumerGone => {
                self.warn("the frame consumer closed its channel; stopping the run".to_string());
                false
            }
        }
    }

    pub(crate) async fn run(mut self) -> (RunOutcome, Devices) {
        self.start_s = self.now();
        self.last_mark_s = self.start_s;
        let n = self.steps.len();
        let mut next = 0;
        let mut pending: Option<Pending> = None;
        loop {
            self.poll_commands();
            let stopping = self.pause_req || self.abort_req;
            // Skip steps already done (resume); at the end, or when asked to stop, finish the
            // step under way (its frame) first.
            while !stopping && next < n && self.done.contains(&self.steps[next].key) {
                self.skipped += 1;
                next += 1;
                self.progress();
            }
            if stopping || next == n {
                if let Some(p) = pending.take() {
                    if let Err(stop) = self.finish_pending(p).await {
                        if !self.on_stop(stop, &mut next).await {
                            return self.aborted();
                        }
                        continue;
                    }
                }
                if self.abort_req {
                    return self.aborted();
                }
                if self.pause_req {
                    if !self.pause(PauseReason::Requested).await {
                        return self.aborted();
                    }
                    continue;
                }
                return self.finished();
            }
            let r = if self.s.overlap {
                self.overlapped_step(next, pending.take()).await.map(Some)
            } else {
                self.sequential_step(next).await.map(|()| None)
            };
            match r {
                Ok(p) => {
                    pending = p;
                    next += 1;
                }
                Err(stop) => {
                    if !self.on_stop(stop, &mut next).await {
                        return self.aborted();
                    }
                }
            }
        }
    }
}
