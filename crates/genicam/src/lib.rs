//! GenICam cameras (GigE Vision, USB3 Vision) over Aravis, for btfrig's rigs.
//!
//! Brief overview: [`GenicamCamera`] opens a camera by IP address or device id
//! ([`Target`]) on a thread of its own, sets its [`ImageFormat`] (mono and Bayer, 8/12/16
//! bits: [`PixelFormat`]), exposure, gain and [`Trigger`], and streams [`Frame`]s with their
//! time stamps and unwrapped frame ids, counting what was dropped ([`StreamStats`]).
//! [`GenicamDevice`] puts it behind `btfrig_hw::Camera` for the run engine, with retryable
//! error kinds for dropped and incomplete buffers and for a lost camera. [`FedFakeCamera`]
//! serves Aravis's GigE Vision fake camera from this process with our own pixels (tests, and
//! the simulated rig seen through a real GenICam stream). The only unsafe code is `ffi.rs`.
//!
//! ```no_run
//! use btfrig_genicam::{GenicamCamera, ImageFormat, OpenOptions, PixelFormat, Target, Trigger};
//! let cam = GenicamCamera::open(OpenOptions::new(Target::parse("192.168.1.20")))?;
//! cam.set_image_format(ImageFormat { width: 1600, height: 1200, pixel_format: PixelFormat::from_name("BayerRG12").unwrap() })?;
//! cam.set_exposure_us(20_000.0)?;
//! cam.set_trigger(Trigger::Software)?;
//! cam.start()?;
//! let frame = cam.trigger_software(std::time::Duration::from_secs(2))?;
//! # Ok::<(), btfrig_genicam::Error>(())
//! ```
#![warn(missing_docs)]

mod camera;
mod device;
mod error;
pub mod fake;
#[allow(unsafe_code)]
mod ffi;
pub mod format;
mod frame_id;

pub use camera::{CameraInfo, Frame, GenicamCamera, ImageFormat, OpenOptions, StreamStats, Target, Trigger};
pub use device::{DeviceOptions, GainUnit, GenicamDevice};
pub use error::Error;
pub use fake::{FedFakeCamera, Feed, FeedFrame};
pub use ffi::Discovered;
pub use format::PixelFormat;
pub use frame_id::FrameIdUnwrapper;

/// Enables Aravis's in-process fake interface (`Fake_1`), which broadcasts nothing.
pub fn enable_fake_interface() {
    ffi::enable_interface("Fake");
}

/// Disables the GigE Vision interface, so that nothing in this process can broadcast a
/// discovery (opening by address needs it enabled again: [`enable_gige_interface`]).
pub fn disable_gige_interface() {
    ffi::disable_interface("GigEVision");
}

/// Enables the GigE Vision interface (Aravis's default).
pub fn enable_gige_interface() {
    ffi::enable_interface("GigEVision");
}

/// Lists the cameras on every enabled interface. This BROADCASTS a GigE Vision discovery
/// on every network interface: only on the user's explicit request.
pub fn discover() -> Vec<Discovered> {
    ffi::discover()
}
