//! Device calls with the engine's timeouts, guards and retry policy, shared by every rig's
//! steps (`docs/engine.md`, "Retries, timeouts, pauses").

use std::future::Future;

use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, DeviceError, ErrorKind, SharedClock};

use crate::EngineSettings;

/// Device calls without a timeout argument (settings, patterns, reconnect) are guarded with
/// this many seconds plus the margin; real controllers answer such commands within a few
/// seconds.
pub(crate) const COMMAND_TIMEOUT_S: f64 = 5.0;

/// Retries and warnings of one operation, merged into the run's counters afterwards (the
/// operations of one step run concurrently, so each keeps its own log).
#[derive(Debug, Default)]
pub(crate) struct OpLog {
    pub(crate) retries: u32,
    pub(crate) warnings: Vec<String>,
}

impl OpLog {
    pub(crate) fn merge(&mut self, other: OpLog) {
        self.retries += other.retries;
        self.warnings.extend(other.warnings);
    }
}

/// Runs `fut`, but gives up `limit_s` (rig clock) later with a `Timeout` of `device`.
pub(crate) async fn guard<T>(
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
            match $crate::calls::guard($clock, $limit_s, &name, $call).await {
                Ok(v) => break Ok(v),
                Err(e) if e.is_retryable() && k < $s.max_retries => {
                    let wait = $s.backoff_for(k);
                    $log.warnings.push(format!("{e}; retry {} of {} in {wait:.2} s", k + 1, $s.max_retries));
                    if e.kind() == btfrig_hw::ErrorKind::Disconnected {
                        let limit = $crate::calls::COMMAND_TIMEOUT_S + $s.guard_margin_s;
                        if let Err(r) = $crate::calls::guard($clock, limit, &name, $dev.reconnect()).await {
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
pub(crate) use retrying;

pub(crate) async fn set_exposure(
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

pub(crate) async fn trigger(
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
pub(crate) async fn read_once(
    s: &EngineSettings,
    clock: &SharedClock,
    camera: &mut dyn Camera,
) -> Result<RawFrame, DeviceError> {
    let name = camera.name().to_string();
    guard(clock, s.read_timeout_s + s.guard_margin_s, &name, camera.read_frame(s.read_timeout_s)).await
}

/// After a failed read-out: a disconnected camera is reconnected before the recapture; a
/// failed reconnect is returned as a warning (the recapture then shows whether it is back).
pub(crate) async fn reconnect_if(
    s: &EngineSettings,
    clock: &SharedClock,
    camera: &mut dyn Camera,
    e: &DeviceError,
) -> Option<String> {
    if e.kind() != ErrorKind::Disconnected {
        return None;
    }
    let name = camera.name().to_string();
    let limit = COMMAND_TIMEOUT_S + s.guard_margin_s;
    guard(clock, limit, &name, camera.reconnect()).await.err().map(|r| format!("reconnect failed: {r}"))
}
