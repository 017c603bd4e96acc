//! A gonioreflectometer step: robot and rail to the pose, exposures, read-outs overlapped with
//! the next move, brackets and recaptures (`docs/engine.md`, "A step, and the overlap").

use btfrig_core::capture::{CapturedFrame, StepTimes};
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::{DeviceError, MoveOptions, Rail, Robot, SharedClock};
use tokio::sync::mpsc;

use crate::calls::{read_once, reconnect_if, retrying, set_exposure, trigger, OpLog};
use crate::session::{Core, Failure, Stop};
use crate::{EngineSettings, EngineStep, ExposureControl, GonioDevices, MAX_EXPOSURES_PER_STEP};

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

/// A step whose last exposure is triggered but not yet read out.
pub(crate) struct Pending {
    index: usize,
    times: StepTimes,
    /// Its earlier exposures, already read.
    frames: Vec<RawFrame>,
}

/// A gonio rig's devices, its frame channel, its exposure control and each step's pose.
pub(crate) struct Gonio {
    pub(crate) dev: GonioDevices,
    pub(crate) frames: mpsc::Sender<CapturedFrame>,
    pub(crate) exposure: Box<dyn ExposureControl>,
    /// Each step's commanded joint state (the schedule's `StepKind::Gonio`, checked at spawn).
    pub(crate) joints: Vec<JointState>,
}

impl Gonio {
    async fn reconnect_camera_if(&mut self, c: &mut Core, index: usize, e: &DeviceError) {
        if let Some(w) = reconnect_if(&c.s, &c.clock, &mut *self.dev.camera, e).await {
            c.warn(format!("step {index}: {w}"));
        }
    }

    /// Hands the step's frames (first exposure first) to the consumer.
    async fn deliver(
        &mut self,
        c: &mut Core,
        index: usize,
        frames: Vec<RawFrame>,
        times: StepTimes,
    ) -> Result<(), Stop> {
        let exposed: f64 = frames.iter().map(|f| f.meta.exposure_s).sum();
        let mut frames = frames.into_iter();
        let frame = frames.next().expect("a step delivers at least one frame");
        let cf = CapturedFrame {
            index,
            key: c.steps[index].key,
            frame,
            bracket: frames.collect(),
            attempts: c.attempts(index),
            joints: self.joints[index],
            times,
        };
        let clock = c.clock.clone();
        if c.frame_queue.send(&self.frames, &clock, cf).await.is_err() {
            return Err(Stop::ConsumerGone);
        }
        c.delivered(index, exposed, times.transfer_end_s);
        Ok(())
    }

    /// The step's planned exposures (at least one, at most [`MAX_EXPOSURES_PER_STEP`]).
    fn planned(&mut self, step: &EngineStep) -> Vec<f64> {
        let mut planned = self.exposure.planned(step);
        if planned.is_empty() {
            planned.push(step.exposure_s);
        }
        planned.truncate(MAX_EXPOSURES_PER_STEP);
        planned
    }

    /// One exposure of step `index` at the pose the devices are at: exposure setting,
    /// trigger and read-out; a failed read-out is repeated from the trigger.
    async fn capture_here(
        &mut self,
        c: &mut Core,
        index: usize,
        exposure_s: f64,
        times: &mut StepTimes,
    ) -> Result<RawFrame, Stop> {
        let s = c.s.clone();
        let clock = c.clock.clone();
        let fail = Stop::failed(index);
        let (r, log) = set_exposure(&s, &clock, &mut *self.dev.camera, exposure_s).await;
        c.absorb(index, log);
        r.map_err(&fail)?;
        let mut k = 0;
        loop {
            times.trigger_start_s = clock.now_s();
            let (r, log) = trigger(&s, &clock, &mut *self.dev.camera, exposure_s).await;
            times.trigger_end_s = clock.now_s();
            c.absorb(index, log);
            r.map_err(&fail)?;
            match read_once(&s, &clock, &mut *self.dev.camera).await {
                Ok(frame) => {
                    times.transfer_end_s = clock.now_s();
                    return Ok(frame);
                }
                Err(e) if e.is_retryable() && k < s.max_retries => {
                    let wait = s.backoff_for(k);
                    c.note_retry(index, format!("{e}; capture again in {wait:.2} s"));
                    self.reconnect_camera_if(c, index, &e).await;
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
        c: &mut Core,
        index: usize,
        frames: &mut Vec<RawFrame>,
        times: &mut StepTimes,
    ) -> Result<(), Stop> {
        let step = c.steps[index];
        while self.exposure.inspects() && frames.len() < MAX_EXPOSURES_PER_STEP {
            let Some(e) = self.exposure.next(&step, frames) else { break };
            let started = c.now();
            let frame = self.capture_here(c, index, e, times).await?;
            frames.push(frame);
            times.bracket_s += c.now() - started;
        }
        Ok(())
    }

    /// Move, then every exposure of step `index` one after the other (trigger and read).
    pub(crate) async fn sequential_step(&mut self, c: &mut Core, index: usize) -> Result<(), Stop> {
        let step = c.steps[index];
        let s = c.s.clone();
        let clock = c.clock.clone();
        let mut times = StepTimes { move_start_s: clock.now_s(), ..StepTimes::default() };
        let wall = std::time::Instant::now();
        let (r, log) = move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &self.joints[index]).await;
        c.motion_wait_wall_s += wall.elapsed().as_secs_f64();
        times.move_end_s = clock.now_s();
        c.absorb(index, log);
        r.map_err(Stop::failed(index))?;
        let planned = self.planned(&step);
        let mut frames = Vec::with_capacity(planned.len());
        let mut first_end = None;
        for e in planned {
            frames.push(self.capture_here(c, index, e, &mut times).await?);
            first_end.get_or_insert(times.trigger_end_s);
        }
        times.bracket_s = times.trigger_end_s - first_end.unwrap_or(times.trigger_end_s);
        self.inspect_here(c, index, &mut frames, &mut times).await?;
        self.deliver(c, index, frames, times).await
    }

    /// Reads out the pending frame (the devices are still at its pose), takes the exposures an
    /// inspection asks for; on a retryable failure captures the step again.
    pub(crate) async fn finish_pending(&mut self, c: &mut Core, p: Pending) -> Result<(), Stop> {
        let s = c.s.clone();
        let clock = c.clock.clone();
        match read_once(&s, &clock, &mut *self.dev.camera).await {
            Ok(frame) => {
                let mut times = StepTimes { transfer_end_s: clock.now_s(), ..p.times };
                let mut frames = p.frames;
                frames.push(frame);
                self.inspect_here(c, p.index, &mut frames, &mut times).await?;
                self.deliver(c, p.index, frames, times).await
            }
            Err(e) if e.is_retryable() => {
                c.note_retry(p.index, format!("{e}; capturing step {} again", p.index));
                self.reconnect_camera_if(c, p.index, &e).await;
                self.sequential_step(c, p.index).await
            }
            Err(error) => Err(Stop::Failed(Failure { index: p.index, error })),
        }
    }

    /// Step `index` with overlap: the read-out of `pending` runs while robot and rail move
    /// to this step's pose; if the exposure control asks for more exposures of the pending
    /// step once it sees its frames, the devices go back to that step's pose for them and
    /// then return here. Then this step's planned exposures: all but the last are read at the
    /// pose, the last is triggered and returned as pending.
    pub(crate) async fn overlapped_step(
        &mut self,
        c: &mut Core,
        index: usize,
        pending: Option<Pending>,
    ) -> Result<Pending, Stop> {
        let step = c.steps[index];
        let joints = self.joints[index];
        let s = c.s.clone();
        let clock = c.clock.clone();
        let fail = Stop::failed(index);
        let planned = self.planned(&step);
        let first_exposure = planned[0];
        let mut times = StepTimes { move_start_s: clock.now_s(), ..StepTimes::default() };

        let GonioDevices { robot, rail, camera, .. } = &mut self.dev;
        let wall = std::time::Instant::now();
        let moving = async {
            let r = move_both(&s, &clock, &mut **robot, &mut **rail, &joints).await;
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
        c.motion_wait_wall_s += moved_at.saturating_duration_since(camera_done_at.max(wall)).as_secs_f64();
        times.move_end_s = move_end;
        c.absorb(index, move_log);

        let mut moved = moved;
        let mut exposure = exposure;
        if let (Some(p), Some(read)) = (pending, read) {
            let back_here = match read {
                Ok((frame, t)) => {
                    let mut p_times = StepTimes { transfer_end_s: t, ..p.times };
                    let mut frames = p.frames;
                    frames.push(frame);
                    let p_step = c.steps[p.index];
                    let more = if self.exposure.inspects() && frames.len() < MAX_EXPOSURES_PER_STEP {
                        self.exposure.next(&p_step, &frames)
                    } else {
                        None
                    };
                    if let Some(e) = more {
                        // The return trip: back to the pending step's pose for the exposures
                        // its frames turned out to need, then here again.
                        let (started, before) = (clock.now_s(), p_times.bracket_s);
                        let p_joints = self.joints[p.index];
                        let (r, log) =
                            move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &p_joints).await;
                        c.absorb(p.index, log);
                        r.map_err(Stop::failed(p.index))?;
                        frames.push(self.capture_here(c, p.index, e, &mut p_times).await?);
                        self.inspect_here(c, p.index, &mut frames, &mut p_times).await?;
                        times.move_start_s = clock.now_s();
                        let (r, log) = move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &joints).await;
                        times.move_end_s = clock.now_s();
                        c.absorb(index, log);
                        moved = r;
                        exposure = Some(set_exposure(&s, &clock, &mut *self.dev.camera, first_exposure).await);
                        // The whole trip (inspect_here counted its own captures already).
                        p_times.bracket_s = before + clock.now_s() - started;
                    }
                    self.deliver(c, p.index, frames, p_times).await?;
                    false
                }
                Err(e) if e.is_retryable() => {
                    c.note_retry(p.index, format!("{e}; capturing step {} again", p.index));
                    self.reconnect_camera_if(c, p.index, &e).await;
                    self.sequential_step(c, p.index).await?;
                    true
                }
                Err(error) => return Err(Stop::Failed(Failure { index: p.index, error })),
            };
            if back_here {
                // Back to this step's pose, now without overlap.
                times.move_start_s = clock.now_s();
                let (r, log) = move_both(&s, &clock, &mut *self.dev.robot, &mut *self.dev.rail, &joints).await;
                times.move_end_s = clock.now_s();
                c.absorb(index, log);
                moved = r;
                exposure = Some(set_exposure(&s, &clock, &mut *self.dev.camera, first_exposure).await);
            }
        }
        moved.map_err(&fail)?;
        if let Some((r, log)) = exposure {
            c.absorb(index, log);
            r.map_err(&fail)?;
        }
        // Every planned exposure but the last is read at the pose; the last is left pending.
        let (&last, earlier) = planned.split_last().expect("at least one planned exposure");
        let mut frames = Vec::with_capacity(planned.len());
        let mut first_end = None;
        for &e in earlier {
            frames.push(self.capture_here(c, index, e, &mut times).await?);
            first_end.get_or_insert(times.trigger_end_s);
        }
        if !earlier.is_empty() {
            let (r, log) = set_exposure(&s, &clock, &mut *self.dev.camera, last).await;
            c.absorb(index, log);
            r.map_err(&fail)?;
        }
        times.trigger_start_s = clock.now_s();
        let (r, log) = trigger(&s, &clock, &mut *self.dev.camera, last).await;
        times.trigger_end_s = clock.now_s();
        c.absorb(index, log);
        r.map_err(&fail)?;
        times.bracket_s = times.trigger_end_s - first_end.unwrap_or(times.trigger_end_s);
        Ok(Pending { index, times, frames })
    }
}
