//! The virtual-time runtime of a simulated session and the frame channel's depth.

use crate::RunError;

/// Frames the engine may hold ready ahead of the pipeline (back-pressure beyond that).
pub(crate) const FRAME_CHANNEL: usize = 4;

/// A virtual-time runtime: a current-thread tokio runtime on paused time, so simulated
/// hardware time passes instantly; rendering parallelises inside rayon.
pub fn virtual_time_runtime() -> Result<tokio::runtime::Runtime, RunError> {
    tokio::runtime::Builder::new_current_thread().enable_time().start_paused(true).build().map_err(RunError::Runtime)
}
