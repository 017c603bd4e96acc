//! Serial backends of the device traits, and firmware emulators on pseudo-terminals.
//!
//! Brief overview: a [`transport::Connector`] opens a [`transport::Transport`] (a real tty
//! through the `serialport` crate, or anything else that moves bytes); a backend such as
//! [`grbl::GrblAxis`] owns a [`transport::Link`] (the connector plus the open session and
//! its decoder from `btfrig-protocols`) and implements the `btfrig-hw` traits on it. Blocking
//! port I/O runs on tokio's blocking pool, so a device call never stalls the runtime. A lost
//! port is `Disconnected` (retryable); `reconnect` opens the path again. Garbage on the line
//! is skipped by the decoder and counted. Device error codes become the `ErrorKind`s the
//! protocol module maps them to.
//!
//! [`pty::PtyPort`] serves a firmware emulator ([`firmware::grbl`]) on a pseudo-terminal
//! behind a stable symlink (like `/dev/serial/by-id/...`), so the real serial code opens a
//! real tty; tests unplug it, inject garbage or raise alarms.
#![warn(missing_docs)]

// The files, one job each:
// - transport: byte transports and the link to a controller
// - grbl, robot, lamp, led: the device backends over their controllers
// - firmware:  firmware emulators (firmware/: one per controller)
// - pty:       pseudo-terminals for the emulators

pub mod firmware;
pub mod grbl;
pub mod lamp;
pub mod led;
pub mod pty;
pub mod robot;
pub mod transport;
