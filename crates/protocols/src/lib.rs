//! Wire codecs of the rig's controllers. Pure: no I/O, no async, no clock.
//!
//! Brief overview: each protocol is a module with typed messages, an encoder (message ->
//! bytes) and an incremental decoder (bytes pushed in any chunking -> messages). Decoders
//! never panic: garbage yields a [`DecodeError`] and the decoder resynchronises at the next
//! line end ([`line`] protocols) or the next sync pattern (binary protocols); oversized
//! lines and frames are rejected with the limit named. Device-reported error codes map to
//! [`btfrig_hw::ErrorKind`], so a transport knows whether a retry can help.
//!
//! | module | device | framing |
//! |---|---|---|
//! | [`grbl`] | rail, turntable (GRBL 1.1 style G-code) | lines, realtime bytes `?` `!` `~` |
//! | [`robot`] | sample robot (btfrig design) | tagged lines with an XOR checksum |
//! | [`lamp`] | lamp controller (btfrig design, SCPI-like) | lines |
//! | [`led`] | LED dome controller (btfrig design) | binary, sync + length + CRC-16 |
//! | [`ptp`] | still camera, PTP (ISO 15740) over USB | length-prefixed containers |
//!
//! Each is documented in `docs/protocols/<name>.md`.
//!
//! ```
//! use btfrig_protocols::grbl::{Command, Response, ResponseDecoder};
//! assert_eq!(Command::Home.encode().unwrap(), b"$H\n");
//! let mut d = ResponseDecoder::new();
//! d.push(b"\x00\xffjunk\nok\r\n");
//! assert!(d.next().unwrap().is_err()); // the garbage line
//! assert_eq!(d.next().unwrap().unwrap(), Response::Ok);
//! assert!(d.next().is_none());
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - grbl, robot, lamp, led: one controller's codec each
// - ptp:      PTP containers and the raw-frame object (ptp/)
// - line:     line framing of the text protocols; checksum: the framed protocols' checksums
// - error:    DecodeError, EncodeError

pub mod checksum;
pub mod error;
pub mod grbl;
pub mod lamp;
pub mod led;
pub mod line;
pub mod ptp;
pub mod robot;

pub use error::{DecodeError, EncodeError};
