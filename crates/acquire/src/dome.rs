//! A dome step: an LED dome's turntable, LED array and the cameras of the arc (`docs/engine.md`,
//! "LED dome"); a camera array is the same without the turntable, its flash triggers driven as
//! the LED array. The run around the steps (commands, pauses, retries counted per step,
//! progress and ETA) is the one every rig shares (`crate::session`).
//!
//! A step is (rotation, pattern): turn the table when the rotation changes, set the LED
//! pattern, set the exposure where it differs, trigger every camera at once (they expose
//! together, so a pattern costs one exposure whatever the number of cameras), then read every
//! camera. Each camera is its own device (`Box<dyn Camera>`, one per arc position): a real dome
//! has one link per camera, and a failing camera is retried and named on its own. Every call
//! is guarded and retried as a gonio step's are (`crate::calls`); a read-out that failed is
//! captured again from that camera's trigger, the LEDs still showing the pattern. Frames leave
//! through a bounded channel (back-pressure: the engine waits before the next pattern when the
//! pipeline is behind).

use std::future::Future;
use std::pin::Pin;
use std::task::Poll;
use std::time::Instant;

use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, DeviceError, LedArray, LedPattern, MoveOptions, SharedClock, Turntable};
use btfrig_planner::dome::{DomeShot, DomeStep};
use tokio::sync::mpsc;

use crate::calls::{read_once, reconnect_if, retrying, set_exposure, trigger, OpLog, COMMAND_TIMEOUT_S};
use crate::session::{Core, Stop};
use crate::EngineSettings;

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

/// The frames of one step: one per camera.
#[derive(Debug, Clone)]
pub struct DomeCapture {
    /// Position of the step in the schedule.
    pub index: usize,
    /// The step.
    pub step: DomeStep,
    /// One frame per camera, in [`DomeDevices::cameras`] order.
    pub frames: Vec<RawFrame>,
    /// 1 + the retries spent on this step (any operation, any camera).
    pub attempts: u32,
    /// Rig clock at the end of the step, s.
    pub time_s: f64,
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

/// A dome rig's devices, its patterns and frame channel, and each step's (rotation, shot).
pub(crate) struct Dome {
    pub(crate) dev: DomeDevices,
    pub(crate) patterns: Vec<Vec<f64>>,
    pub(crate) frames: mpsc::Sender<DomeCapture>,
    /// Each step as the schedule's `StepKind::Dome` gives it (checked at spawn).
    pub(crate) steps: Vec<DomeStep>,
    /// The rotation the table is known to be at (`None`: move it before the next step).
    pub(crate) table_at: Option<u32>,
}

impl Dome {
    /// Step `index`: the device work ([`dome_step`]), then its frames into the channel.
    pub(crate) async fn step(&mut self, c: &mut Core, index: usize) -> Result<(), Stop> {
        let step = self.steps[index];
        let exposure_s = c.steps[index].exposure_s;
        let pattern = pattern_of(&step, &self.patterns, self.dev.leds.capabilities().count);
        let (s, clock) = (c.s.clone(), c.clock.clone());
        let mut log = OpLog::default();
        let r = dome_step(&s, &clock, &mut self.dev, &step, &pattern, exposure_s, &mut self.table_at, &mut log).await;
        c.absorb(index, log);
        let frames = match r {
            Ok((frames, motion_wall_s)) => {
                c.motion_wait_wall_s += motion_wall_s;
                frames
            }
            Err(e) => {
                // After a pause on this failure the table may have been touched: move it again.
                self.table_at = None;
                return Err(Stop::failed(index)(e));
            }
        };
        let time_s = clock.now_s();
        let cap = DomeCapture { index, step, frames, attempts: c.attempts(index), time_s };
        if c.frame_queue.send(&self.frames, &clock, cap).await.is_err() {
            return Err(Stop::ConsumerGone);
        }
        c.delivered(index, exposure_s, time_s);
        Ok(())
    }
}

/// The device work of one dome step, with the engine's timeouts, guards and retries: the
/// table to the step's rotation (when `table_at` is another), the pattern, the exposure on
/// every camera, every camera triggered at once and read; a camera whose read-out failed
/// (dropped or damaged frame) is triggered and read again on its own. Returns one frame per
/// camera and the wall time spent waiting on the table; retries and warnings go to `log`.
#[allow(clippy::too_many_arguments)]
pub(crate) async fn dome_step(
    s: &EngineSettings,
    clock: &SharedClock,
    d: &mut DomeDevices,
    step: &DomeStep,
    pattern: &LedPattern,
    exposure_s: f64,
    table_at: &mut Option<u32>,
    log: &mut OpLog,
) -> Result<(Vec<RawFrame>, f64), DeviceError> {
    let mut motion_wall_s = 0.0;
    if *table_at != Some(step.rotation) {
        if let Some(t) = d.turntable.as_mut() {
            let opts = MoveOptions::with_timeout_s(s.move_timeout_s);
            let wall = Instant::now();
            let r = retrying!(
                s,
                clock,
                log,
                t,
                s.move_timeout_s + s.guard_margin_s,
                t.move_to_rad(step.turntable_rad, opts)
            );
            motion_wall_s = wall.elapsed().as_secs_f64();
            r?;
        }
        *table_at = Some(step.rotation);
    }
    let leds = &mut d.leds;
    retrying!(s, clock, log, leds, COMMAND_TIMEOUT_S + s.guard_margin_s, leds.set_pattern(pattern))?;
    let set = join_all(
        d.cameras.iter_mut().map(|c| Box::pin(set_exposure(s, clock, &mut **c, exposure_s)) as Pin<Box<_>>).collect(),
    )
    .await;
    gather(set, log)?;
    let triggered = join_all(
        d.cameras.iter_mut().map(|c| Box::pin(trigger(s, clock, &mut **c, exposure_s)) as Pin<Box<_>>).collect(),
    )
    .await;
    gather(triggered, log)?;
    let reads =
        join_all(d.cameras.iter_mut().map(|c| Box::pin(read_once(s, clock, &mut **c)) as Pin<Box<_>>).collect()).await;
    let mut frames = Vec::with_capacity(reads.len());
    for (camera, r) in d.cameras.iter_mut().zip(reads) {
        frames.push(match r {
            Ok(f) => f,
            Err(e) => recapture(s, clock, &mut **camera, exposure_s, e, log).await?,
        });
    }
    Ok((frames, motion_wall_s))
}

/// The cameras' results of one operation: their logs merged, the first error returned.
fn gather<T>(results: Vec<(Result<T, DeviceError>, OpLog)>, log: &mut OpLog) -> Result<Vec<T>, DeviceError> {
    let mut out = Vec::with_capacity(results.len());
    let mut first_err = None;
    for (r, l) in results {
        log.merge(l);
        match r {
            Ok(v) => out.push(v),
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    first_err.map_or(Ok(out), Err)
}

/// A camera whose read-out failed with `e`: triggered and read again (the LEDs still show
/// the step's pattern), as a gonio step's frame is, while the error is retryable and the
/// retries last.
async fn recapture(
    s: &EngineSettings,
    clock: &SharedClock,
    camera: &mut dyn Camera,
    exposure_s: f64,
    mut e: DeviceError,
    log: &mut OpLog,
) -> Result<RawFrame, DeviceError> {
    let mut k = 0;
    loop {
        if !e.is_retryable() || k >= s.max_retries {
            return Err(e);
        }
        let wait = s.backoff_for(k);
        log.retries += 1;
        log.warnings.push(format!("{e}; capture again in {wait:.2} s"));
        if let Some(w) = reconnect_if(s, clock, camera, &e).await {
            log.warnings.push(w);
        }
        clock.sleep_s(wait).await;
        k += 1;
        let (r, l) = trigger(s, clock, camera, exposure_s).await;
        log.merge(l);
        r?;
        match read_once(s, clock, camera).await {
            Ok(f) => return Ok(f),
            Err(next) => e = next,
        }
    }
}
