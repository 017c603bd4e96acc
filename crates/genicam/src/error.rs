//! The library's errors, each with the [`btfrig_hw::ErrorKind`] that decides whether a run
//! retries it.

use btfrig_hw::{DeviceError, ErrorKind};

/// What went wrong with a GenICam camera.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// No buffer arrived in time: the frame was dropped (counted in
    /// [`crate::StreamStats::timeouts`]). Retryable: trigger again.
    #[error("no frame arrived within {timeout_s} s (a dropped buffer)")]
    Timeout {
        /// The wait, seconds.
        timeout_s: f64,
    },
    /// A buffer arrived incomplete or damaged (missing packets, wrong size, aborted);
    /// counted in [`crate::StreamStats::failures`]. Retryable: trigger again.
    #[error("frame {frame_id} arrived incomplete: {status}")]
    Incomplete {
        /// The camera's (16-bit) frame id.
        frame_id: u64,
        /// Aravis's buffer status, or what did not fit.
        status: String,
    },
    /// The camera does not answer on its control channel, or it was never reached.
    /// Retryable after [`crate::GenicamCamera::reconnect`].
    #[error("camera {target} is disconnected: {message}")]
    Disconnected {
        /// The address or id it was opened by.
        target: String,
        /// What failed.
        message: String,
    },
    /// The camera has no such feature or value (a pixel format it does not offer, no
    /// software trigger).
    #[error("{what} is not supported by the camera: {message}")]
    Unsupported {
        /// The feature or value.
        what: String,
        /// What the camera offers instead.
        message: String,
    },
    /// A value outside the camera's range.
    #[error("{what} = {value} is outside the camera's range {allowed}")]
    OutOfRange {
        /// The setting.
        what: String,
        /// The value asked for.
        value: String,
        /// The range the camera reports.
        allowed: String,
    },
    /// Opening by a device id would broadcast a discovery on every network interface.
    #[error(
        "opening camera {id:?} by id needs a GenICam discovery, which broadcasts on every network interface: \
         open it by IP address (e.g. 192.168.1.20), or allow discovery (btfrig hw probe --discover)"
    )]
    DiscoveryNotAllowed {
        /// The device id asked for.
        id: String,
    },
    /// Anything else Aravis reported.
    #[error("{0}")]
    Other(String),
}

impl Error {
    /// The kind the run engine decides retries from.
    pub fn kind(&self) -> ErrorKind {
        match self {
            Error::Timeout { .. } => ErrorKind::Timeout,
            Error::Incomplete { .. } => ErrorKind::CorruptData,
            Error::Disconnected { .. } => ErrorKind::Disconnected,
            Error::Unsupported { .. } | Error::DiscoveryNotAllowed { .. } => ErrorKind::Unsupported,
            Error::OutOfRange { .. } => ErrorKind::OutOfRange,
            Error::Other(_) => ErrorKind::Other,
        }
    }

    /// As a device error of the device named `device`.
    pub fn into_device_error(self, device: &str) -> DeviceError {
        DeviceError::new(device, self.kind(), self.to_string()).with_source(self)
    }
}
