//! Device errors: one error type for every backend, classified by [`ErrorKind`] so that the
//! run engine decides retries from the kind alone.

use std::fmt;

/// What went wrong, in the terms the run engine needs to react: retry, re-home, give up.
///
/// Backends map their own failure modes onto these kinds; new kinds may be added, so a
/// `match` needs a wildcard arm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The device did not answer or finish within the allowed time. Retryable.
    Timeout,
    /// The device is still executing an earlier command. Retryable (later).
    Busy,
    /// The axis has not been homed since power-up; call `home` first. Not retryable as is.
    NotHomed,
    /// A requested value lies outside the device's limits. Never retryable.
    OutOfRange,
    /// The link to the device is down. Retryable: the device may come back (the engine
    /// should cap the number of attempts, as a device may also stay away).
    Disconnected,
    /// Data arrived damaged (checksum or length mismatch). Retryable: repeat the operation
    /// that produced the data (for a camera: trigger and read again).
    CorruptData,
    /// The device lacks the requested capability (no shutter, fixed aperture). Never
    /// retryable.
    Unsupported,
    /// Anything else; not retryable, since nothing is known about it.
    Other,
}

impl ErrorKind {
    /// Whether repeating the failed operation (unchanged) can succeed.
    pub const fn is_retryable(self) -> bool {
        matches!(self, ErrorKind::Timeout | ErrorKind::Busy | ErrorKind::Disconnected | ErrorKind::CorruptData)
    }

    /// Short lower-case name, as used in messages and logs.
    pub const fn as_str(self) -> &'static str {
        match self {
            ErrorKind::Timeout => "timeout",
            ErrorKind::Busy => "busy",
            ErrorKind::NotHomed => "not homed",
            ErrorKind::OutOfRange => "out of range",
            ErrorKind::Disconnected => "disconnected",
            ErrorKind::CorruptData => "corrupt data",
            ErrorKind::Unsupported => "unsupported",
            ErrorKind::Other => "other",
        }
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A failed device operation: which device, what kind of failure, and what happened.
///
/// Displays as `robot: timeout: move_to_rad did not settle within 30 s`.
#[derive(Debug, thiserror::Error)]
#[error("{device}: {kind}: {message}")]
pub struct DeviceError {
    device: String,
    kind: ErrorKind,
    message: String,
    #[source]
    source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl DeviceError {
    /// A new error of `kind` from the device named `device`.
    pub fn new(device: impl Into<String>, kind: ErrorKind, message: impl Into<String>) -> Self {
        DeviceError { device: device.into(), kind, message: message.into(), source: None }
    }

    /// Attaches the lower-level cause (an I/O error, a protocol error).
    pub fn with_source(mut self, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        self.source = Some(Box::new(source));
        self
    }

    /// Shorthand for an [`ErrorKind::OutOfRange`] error naming the value and the allowed range.
    pub fn out_of_range(device: &str, what: &str, value: impl fmt::Display, allowed: impl fmt::Display) -> Self {
        DeviceError::new(device, ErrorKind::OutOfRange, format!("{what} = {value} is outside {allowed}"))
    }

    /// Shorthand for an [`ErrorKind::Unsupported`] error.
    pub fn unsupported(device: &str, what: &str) -> Self {
        DeviceError::new(device, ErrorKind::Unsupported, format!("{what} is not supported by this device"))
    }

    /// The kind of failure, from which the engine decides what to do.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }

    /// Whether repeating the operation can succeed (see [`ErrorKind::is_retryable`]).
    pub fn is_retryable(&self) -> bool {
        self.kind.is_retryable()
    }

    /// The name of the device that failed (its name in the rig config, e.g. `robot`).
    pub fn device(&self) -> &str {
        &self.device
    }

    /// What happened, without the device name and kind.
    pub fn message(&self) -> &str {
        &self.message
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retryability_per_kind() {
        let retry = [ErrorKind::Timeout, ErrorKind::Busy, ErrorKind::Disconnected, ErrorKind::CorruptData];
        let final_ = [ErrorKind::NotHomed, ErrorKind::OutOfRange, ErrorKind::Unsupported, ErrorKind::Other];
        for k in retry {
            assert!(k.is_retryable(), "{k}");
        }
        for k in final_ {
            assert!(!k.is_retryable(), "{k}");
        }
    }

    #[test]
    fn message_names_device_kind_and_what() {
        let e = DeviceError::out_of_range("rail", "target angle (deg)", 190.0, "[0, 180]");
        assert_eq!(e.to_string(), "rail: out of range: target angle (deg) = 190 is outside [0, 180]");
        assert_eq!(e.kind(), ErrorKind::OutOfRange);
        assert!(!e.is_retryable());
        assert_eq!(e.device(), "rail");
    }
}
