//! Why processing failed.

use btfrig_imaging::RectifyError;
use btfrig_registration::FrameError;
use btfrig_store::{StepId, StoreError};

/// Why processing failed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Rectification or radiometric conversion refused its input.
    #[error("step {step}: {source}")]
    Rectify {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: RectifyError,
    },
    /// Registration failed and the plan says `on_failure = "fail"`.
    #[error("step {step}: registration failed: {reason}")]
    Registration {
        /// Which capture.
        step: StepId,
        /// Why (the registrar's error: too few markers, degenerate geometry, ...).
        reason: String,
    },
    /// The registrar could not be built from the rig's plate (e.g. an unknown dictionary).
    #[error("registration: {0}")]
    Registrar(#[from] FrameError),
    /// The dataset refused a write or commit.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The dark/flat calibration does not fit the frame (size, f-number).
    #[error("step {step}: dark/flat correction: {source}")]
    DarkFlat {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: btfrig_imaging::dark_flat::DarkFlatError,
    },
    /// A dark/flat calibration given to
    /// [`ProcessingModel::with_dark_flat`](crate::ProcessingModel::with_dark_flat) does not fit
    /// the camera.
    #[error("dark/flat calibration: {0}")]
    DarkFlatSetup(btfrig_imaging::dark_flat::DarkFlatError),
    /// An HDR bracket could not be merged.
    #[error("step {step}: HDR merge: {source}")]
    Hdr {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: btfrig_imaging::hdr::HdrError,
    },
    /// The light calibration is unusable.
    #[error("light calibration: {0}")]
    Light(#[from] btfrig_imaging::light::LightError),
    /// A processing thread panicked or was cancelled.
    #[error("step {step}: processing thread failed: {reason}")]
    Join {
        /// Which capture.
        step: StepId,
        /// The join error.
        reason: String,
    },
}
