//! Device traits of a BTF rig, and the clock they run on.
//!
//! Brief overview: the run engine drives a rig only through the traits here —
//! [`Robot`], [`Rail`] and [`Turntable`] (moves that return when settled), [`Lamp`] and
//! [`LedArray`] (light), [`Camera`] (settings, trigger, raw frames with metadata) — each a
//! [`Device`] with identity and health. Every failure is a [`DeviceError`] whose
//! [`ErrorKind`] tells the engine whether a retry can help. Devices never sleep on their own:
//! they wait on a shared [`Clock`], which is tokio time (virtual in tests) or a sped-up wall
//! clock. Backends: the simulator in `btfrig-sim`; serial/USB drivers will live here under
//! `src/<device>/<model>/`. See `docs/devices.md`.
//!
//! ```
//! use btfrig_hw::{ErrorKind, DeviceError};
//! let e = DeviceError::new("camera", ErrorKind::Timeout, "no frame within 20 s");
//! assert!(e.is_retryable());
//! assert_eq!(e.to_string(), "camera: timeout: no frame within 20 s");
//! ```
#![warn(missing_docs)]

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
