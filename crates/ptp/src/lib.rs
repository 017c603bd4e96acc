//! The PTP camera: a backend of the `Camera` trait over a transport trait, and an
//! in-process PTP responder that serves any `Camera` behind that trait.
//!
//! Brief overview: [`transport::PtpTransport`] is the three pipes of a USB Still Image
//! device (bulk-out, bulk-in, interrupt-in) as byte transfers; [`camera::PtpCamera`] speaks
//! the PTP subset of `docs/protocols/ptp.md` over it with the codec of
//! `btfrig_protocols::ptp`, waiting on the injected rig clock; [`responder::PtpResponder`]
//! plays the camera firmware in-process (in tests and the serial demo rig: the simulator's
//! camera), with faults to inject (an ObjectAdded event that never comes, a damaged
//! download). [`usb::UsbPtpTransport`] is the transport over a real camera (nusb); untested without one (`docs/serial.md`).
#![warn(missing_docs)]

pub mod camera;
pub mod responder;
pub mod transport;
pub mod usb;
