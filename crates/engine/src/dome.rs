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
//! step and device. Resume: the unit a dome commits is a view group (all patterns of one
//! rotation); rotations in `done` are skipped, a partly captured rotation is captured again.

use std::collections::HashSet;
use std::future::Future;
use std::pin::Pin;
use std::task::Poll;

use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, DeviceError, LedArray, LedPattern, MoveOptions, SharedClock, Turntable};
use btfrig_planner::dome::{DomeShot, DomeStep};
use tokio::sync::mpsc;

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
}

impl Default for DomeSettings {
    fn default() -> Self {
        DomeSettings { move_timeout_s: 60.0, trigger_timeout_s: 10.0, read_timeout_s: 30.0, max_retries: 5, backoff_s: 0.5 }
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

/// What a finished dome run did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DomeRunSummary {
    /// Steps captured.
    pub captured: usize,
    /// Steps skipped because their rotation was done.
    pub skipped_done: usize,
    /// Retries over all steps.
    pub retries: u32,
    /// Rig time of the run, s.
    pub hardware_s: f64,
    /// Rig time spent exposing (pattern and reference frames), s.
    pub exposure_s: f64,
    /// Warnings (retries with their cause).
    pub warnings: Vec<String>,
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

/// Runs `steps` on `devices`: pattern frames at `exposure_s`, reference frames at
/// `reference_exposure_s`. The devices must be homed.
#[allow(clippy::too_many_arguments)]
pub async fn run_dome(
    devices: &mut DomeDevices,
    steps: &[DomeStep],
    patterns: &[Vec<f64>],
    exposure_s: f64,
    reference_exposure_s: f64,
    done: &HashSet<u32>,
    settings: DomeSettings,
    frames: mpsc::Sender<DomeCapture>,
) -> Result<DomeRunSummary, DomeRunError> {
    let start = devices.clock.now_s();
    let leds = devices.leds.capabilities().count;
    let mut summary = DomeRunSummary::default();
    let mut table_at: Option<u32> = None;
    for (index, step) in steps.iter().enumerate() {
        if done.contains(&step.rotation) {
            summary.skipped_done += 1;
            continue;
        }
        let exposure = match step.shot {
            DomeShot::Pattern(_) => exposure_s,
            DomeShot::Reference(_) => reference_exposure_s,
        };
        let pattern = pattern_of(step, patterns, leds);
        let mut attempt = 0u32;
        let captured = loop {
            attempt += 1;
            match capture_step(devices, step, &pattern, exposure, &mut table_at, &settings).await {
                Ok(f) => break f,
                Err(e) if e.is_retryable() && attempt <= settings.max_retries => {
                    summary.warnings.push(format!(
                        "step {index} (rotation {}, {:?}): {e}; retry {attempt} of {}",
                        step.rotation, step.shot, settings.max_retries
                    ));
                    // The table may have been left anywhere: move it again.
                    table_at = None;
                    devices.clock.sleep_s(settings.backoff_s * 2f64.powi(attempt as i32 - 1)).await;
                }
                Err(error) => {
                    return Err(DomeRunError::StepFailed { index, rotation: step.rotation, shot: step.shot, error })
                }
            }
        };
        summary.retries += attempt - 1;
        summary.captured += 1;
        summary.exposure_s += exposure;
        let cap = DomeCapture { index, step: *step, frames: captured, attempts: attempt, time_s: devices.clock.now_s() };
        if frames.send(cap).await.is_err() {
            return Err(DomeRunError::ConsumerGone);
        }
    }
    summary.hardware_s = devices.clock.now_s() - start;
    Ok(summary)
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
