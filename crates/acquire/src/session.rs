//! Everything about a run but the devices, for every kind of rig: the schedule, the
//! steering (commands, pauses), skipped done steps, retries counted per step, progress with
//! the ETA, and the summary. The run loop (`crate::run`) and each rig's step
//! (`crate::gonio`, `crate::dome`) share it.

use std::collections::{HashMap, HashSet, VecDeque};

use btfrig_core::capture::StepKey;
use btfrig_hw::{DeviceError, SharedClock};
use tokio::sync::{broadcast, mpsc, watch};

use crate::calls::OpLog;
use crate::{Command, EngineSettings, EngineStep, Event, PauseReason, RunOutcome, RunState, RunSummary};

/// A step that could not be done.
pub(crate) struct Failure {
    pub(crate) index: usize,
    pub(crate) error: DeviceError,
}

pub(crate) enum Stop {
    Failed(Failure),
    ConsumerGone,
}

impl Stop {
    pub(crate) fn failed(index: usize) -> impl Fn(DeviceError) -> Stop {
        move |error| Stop::Failed(Failure { index, error })
    }
}

/// Everything about a run but the devices: the schedule, the steering, the counters.
pub(crate) struct Core {
    pub(crate) steps: Vec<EngineStep>,
    pub(crate) done: HashSet<StepKey>,
    pub(crate) s: EngineSettings,
    pub(crate) clock: SharedClock,
    events: broadcast::Sender<Event>,
    state: watch::Sender<RunState>,
    cmd: mpsc::Receiver<Command>,
    captured: usize,
    pub(crate) skipped: usize,
    retries: u32,
    step_retries: HashMap<usize, u32>,
    warnings: usize,
    recent: VecDeque<f64>,
    measured_sum_s: f64,
    measured_n: usize,
    pub(crate) last_mark_s: f64,
    pub(crate) start_s: f64,
    pub(crate) pause_req: bool,
    pub(crate) abort_req: bool,
    pub(crate) motion_wait_wall_s: f64,
    pub(crate) frame_queue: crate::FrameQueueFigures,
    events_dropped: u64,
    exposure_s: f64,
}

impl Core {
    pub(crate) fn new(
        steps: Vec<EngineStep>,
        done: HashSet<StepKey>,
        s: EngineSettings,
        clock: SharedClock,
        events: broadcast::Sender<Event>,
        state: watch::Sender<RunState>,
        cmd: mpsc::Receiver<Command>,
    ) -> Self {
        Core {
            steps,
            done,
            s,
            clock,
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
            motion_wait_wall_s: 0.0,
            frame_queue: crate::FrameQueueFigures::default(),
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

    pub(crate) fn warn(&mut self, msg: String) {
        tracing::warn!("{msg}");
        self.warnings += 1;
        self.emit(Event::Warning(msg));
    }

    pub(crate) fn now(&self) -> f64 {
        self.clock.now_s()
    }

    /// Reads every waiting command without blocking.
    pub(crate) fn poll_commands(&mut self) {
        while let Ok(c) = self.cmd.try_recv() {
            match c {
                Command::Pause => self.pause_req = true,
                Command::Resume => self.pause_req = false,
                Command::Abort => self.abort_req = true,
            }
        }
    }

    /// Waits while paused; `true` to go on, `false` on abort (or every handle gone).
    pub(crate) async fn pause(&mut self, reason: PauseReason) -> bool {
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
        let step = &self.steps[f.index];
        PauseReason::StepFailed {
            index: f.index,
            key: step.key,
            step: step.kind,
            device: e.device().to_string(),
            kind: e.kind(),
            message,
        }
    }

    /// Charges an operation's retries and warnings to the step it served.
    pub(crate) fn absorb(&mut self, index: usize, log: OpLog) {
        self.retries += log.retries;
        *self.step_retries.entry(index).or_default() += log.retries;
        let label = self.steps[index].label();
        for w in log.warnings {
            self.warn(format!("step {index} ({label}): {w}"));
        }
    }

    pub(crate) fn note_retry(&mut self, index: usize, msg: String) {
        self.absorb(index, OpLog { retries: 1, warnings: vec![msg] });
    }

    /// 1 + the retries charged to step `index` so far.
    pub(crate) fn attempts(&self, index: usize) -> u32 {
        1 + self.step_retries.get(&index).copied().unwrap_or(0)
    }

    fn done_count(&self) -> usize {
        self.captured + self.skipped
    }

    pub(crate) fn progress(&mut self) {
        let remaining = self.steps.len() - self.done_count();
        let eta_s = (!self.recent.is_empty())
            .then(|| self.recent.iter().sum::<f64>() / self.recent.len() as f64 * remaining as f64);
        self.emit(Event::Progress { done: self.done_count(), total: self.steps.len(), eta_s });
    }

    /// Step `index` was handed to the consumer, its frames on the host at `end_s` (rig
    /// clock) after `exposed_s` of exposure: counters, the step's measured time (between
    /// successive deliveries, pauses excluded), `StepDone` and `Progress`.
    pub(crate) fn delivered(&mut self, index: usize, exposed_s: f64, end_s: f64) {
        let step = self.steps[index];
        self.captured += 1;
        self.exposure_s += exposed_s;
        self.done.insert(step.key);
        let dt = end_s - self.last_mark_s;
        self.last_mark_s = end_s;
        self.recent.push_back(dt);
        while self.recent.len() > self.s.eta_window.max(1) {
            self.recent.pop_front();
        }
        self.measured_sum_s += dt;
        self.measured_n += 1;
        let attempts = self.attempts(index);
        self.emit(Event::StepDone { index, key: step.key, step: step.kind, attempts });
        self.progress();
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
            frame_queue: self.frame_queue,
        }
    }

    pub(crate) fn aborted(mut self) -> RunOutcome {
        let mut summary = self.summary();
        self.state.send_replace(RunState::Aborted);
        self.emit(Event::Aborted(summary.clone()));
        // The last event may have overwritten one too.
        summary.events_dropped = self.events_dropped;
        RunOutcome::Aborted { done: std::mem::take(&mut self.done), summary }
    }

    pub(crate) fn finished(mut self) -> RunOutcome {
        let mut summary = self.summary();
        self.state.send_replace(RunState::Finished);
        self.emit(Event::Finished(summary.clone()));
        summary.events_dropped = self.events_dropped;
        RunOutcome::Finished(summary)
    }

    /// Handles a stop: pauses on a failed step (`next` becomes that step) or on a lost
    /// consumer. Returns `false` when the run must end (abort).
    pub(crate) async fn on_stop(&mut self, stop: Stop, next: &mut usize) -> bool {
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
}
