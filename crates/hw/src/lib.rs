//! Device traits of a BTF rig, and the clock they run on.
//!
//! Brief overview: the run engine drives a rig only through the traits here —
//! [`Robot`], [`Rail`] and [`Turntable`] (moves that return when settled), [`Lamp`] and
//! [`LedArray`] (light), [`Camera`] (settings, trigger, raw frames with metadata) — each a
//! [`Device`] with identity and health. Every failure is a [`DeviceError`] whose
//! [`ErrorKind`] tells the engine whether a retry can help. Devices never sleep on their own:
//! they wait on a shared [`Clock`], which is tokio time (virtual in tests) or a sped-up wall
//! clock. Backends: the simulator (`btfrig-sim`), serial controllers (`btfrig-serial`) and the
//! PTP camera (`btfrig-ptp`); a run gets them through `btfrig_measurement::backend`. See
//! `docs/devices.md`.
//!
//! ```
//! use btfrig_hw::{ErrorKind, DeviceError};
//! let e = DeviceError::new("camera", ErrorKind::Timeout, "no frame within 20 s");
//! assert!(e.is_retryable());
//! assert_eq!(e.to_string(), "camera: timeout: no frame within 20 s");
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - motion: Robot, Rail, Turntable
// - light:  Lamp, LedArray
// - camera: Camera (settings, trigger, read-out)
// - device: what every device has in common (identity, health, reconnect)
// - error:  DeviceError and ErrorKind, which decide retries
// - clock:  the clock devices and the engine wait on
// - truth:  the truth probes a simulated backend offers, for a report's error figures only

pub mod camera;
pub mod clock;
pub mod device;
pub mod error;
pub mod light;
pub mod motion;
pub mod truth;

pub use camera::{frame_checksum, verify_frame, Camera, CameraCapabilities, CaptureSettings};
pub use clock::{Clock, ScaledClock, SharedClock, TokioClock};
pub use device::{Device, DeviceInfo, Health};
pub use error::{DeviceError, ErrorKind};
pub use light::{Lamp, LampCapabilities, LampStatus, LedArray, LedCapabilities, LedPattern, WarmUp};
pub use motion::{AxisLimits, MoveOptions, Rail, Robot, Turntable};
pub use truth::{ExposureTruth, SampleRegion, TruthProbe};
