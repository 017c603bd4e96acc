//! The lamp controller's line protocol (a btfrig design in SCPI style; see
//! `docs/protocols/lamp.md`).
//!
//! One request line, one reply line. Requests: `*IDN?`, `CAP?`, `OUTP ON|OFF`, `OUTP?`,
//! `SHUT OPEN|CLOSE`, `SHUT?`, `INT <fraction>`, `INT?`, `HOUR?`, `STAT?`. Replies name
//! what they carry so they decode without knowing the request: `OK`, `IDN ...`, `CAP ...`,
//! `OUTP 0|1`, `SHUT 0|1`, `INT <f>`, `HOUR <h>`, `STAT <on> <shutter> <int> <warm>`,
//! `ERR <code> <text>`. Warm-up is `OFF`, `READY` or `WARM <seconds left>`.

use btfrig_hw::ErrorKind;

use crate::line::{ascii, decimal, format_decimal, LineDecoder};
use crate::{DecodeError, EncodeError};

/// Longest line, bytes.
pub const MAX_LINE: usize = 128;

/// What the host asks.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// `*IDN?`: maker, model, serial, firmware.
    Identify,
    /// `CAP?`: shutter, dimming range, warm-up time.
    Capabilities,
    /// `OUTP ON` / `OUTP OFF`: ignite or extinguish.
    SetOn(bool),
    /// `OUTP?`.
    QueryOn,
    /// `SHUT OPEN` / `SHUT CLOSE`.
    SetShutterOpen(bool),
    /// `SHUT?`.
    QueryShutter,
    /// `INT <fraction>`: intensity setpoint, fraction of full output.
    SetIntensity(f64),
    /// `INT?`.
    QueryIntensity,
    /// `HOUR?`: burner hours.
    QueryHours,
    /// `STAT?`: on, shutter, setpoint, warm-up at once.
    Status,
}

/// Warm-up state on the wire.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Warm {
    /// Off.
    Off,
    /// Warming up; seconds left.
    Warming(f64),
    /// Stable.
    Ready,
}

/// A `STAT?` answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampState {
    /// Burning.
    pub on: bool,
    /// Shutter open.
    pub shutter_open: bool,
    /// Intensity setpoint, fraction.
    pub intensity: f64,
    /// Warm-up state.
    pub warm: Warm,
}

/// A `CAP?` answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampCaps {
    /// Has a shutter.
    pub shutter: bool,
    /// Dimming range (fractions), or `None` for a fixed output.
    pub dim_range: Option<(f64, f64)>,
    /// Warm-up time, seconds.
    pub warm_up_s: f64,
}

/// What the controller answers.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `OK`: a setting was applied.
    Ok,
    /// `IDN <maker>,<model>,<serial>,<firmware>`.
    Identity(Vec<String>),
    /// `CAP <shutter 0|1> <min>,<max>|FIXED <warm-up s>`.
    Capabilities(LampCaps),
    /// `OUTP 0|1`.
    On(bool),
    /// `SHUT 0|1`.
    ShutterOpen(bool),
    /// `INT <f>`.
    Intensity(f64),
    /// `HOUR <h>`.
    Hours(f64),
    /// `STAT ...`.
    Status(LampState),
    /// `ERR <code> <text>`.
    Error {
        /// Code (see [`error_kind`]).
        code: u16,
        /// Text.
        message: String,
    },
}

/// Error codes of the lamp controller.
pub mod codes {
    /// The line could not be parsed (damaged on the wire).
    pub const SYNTAX: u16 = 1;
    /// A value out of range (intensity outside the dimming range).
    pub const OUT_OF_RANGE: u16 = 2;
    /// The lamp lacks this feature (shutter, dimmer).
    pub const UNSUPPORTED: u16 = 3;
    /// Ignition failed (burner at end of life).
    pub const IGNITION_FAILED: u16 = 4;
    /// Over temperature; the lamp switched itself off.
    pub const OVER_TEMPERATURE: u16 = 5;
    /// Hot-restrike lockout: an HMI burner cannot be re-ignited until it cools down.
    pub const RESTRIKE_LOCKOUT: u16 = 6;
}

/// How the host should treat an `ERR` code.
pub fn error_kind(code: u16) -> ErrorKind {
    match code {
        codes::SYNTAX => ErrorKind::CorruptData,
        codes::OUT_OF_RANGE => ErrorKind::OutOfRange,
        codes::UNSUPPORTED => ErrorKind::Unsupported,
        codes::RESTRIKE_LOCKOUT => ErrorKind::Busy,
        _ => ErrorKind::Other,
    }
}

fn line(text: String) -> Result<Vec<u8>, EncodeError> {
    if text.len() > MAX_LINE {
        return Err(EncodeError::TooLong { what: "line", len: text.len(), limit: MAX_LINE });
    }
    Ok((text + "\n").into_bytes())
}

fn num(field: &'static str, v: f64) -> Result<String, EncodeError> {
    format_decimal(field, v, 1e9)
}

impl Request {
    /// The line on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let on_off = |b: bool, t: &str, f: &str| if b { t.to_string() } else { f.to_string() };
        line(match self {
            Request::Identify => "*IDN?".into(),
            Request::Capabilities => "CAP?".into(),
            Request::SetOn(on) => format!("OUTP {}", on_off(*on, "ON", "OFF")),
            Request::QueryOn => "OUTP?".into(),
            Request::SetShutterOpen(open) => format!("SHUT {}", on_off(*open, "OPEN", "CLOSE")),
            Request::QueryShutter => "SHUT?".into(),
            Request::SetIntensity(f) => format!("INT {}", num("intensity", *f)?),
            Request::QueryIntensity => "INT?".into(),
            Request::QueryHours => "HOUR?".into(),
            Request::Status => "STAT?".into(),
        })
    }
}

fn printable(field: &'static str, s: &str, also_forbidden: &[u8]) -> Result<(), EncodeError> {
    if s.bytes().all(|b| (0x20..0x7f).contains(&b) && !also_forbidden.contains(&b)) {
        Ok(())
    } else {
        Err(EncodeError::Text { field, value: s.to_string(), allowed: "printable ASCII (no ',' in identity fields)" })
    }
}

impl Reply {
    /// The line on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let bit = |b: bool| u8::from(b);
        line(match self {
            Reply::Ok => "OK".into(),
            Reply::Identity(fields) => {
                for f in fields {
                    printable("identity", f, b",")?;
                }
                format!("IDN {}", fields.join(","))
            }
            Reply::Capabilities(c) => {
                let dim = match c.dim_range {
                    Some((lo, hi)) => format!("{},{}", num("dim min", lo)?, num("dim max", hi)?),
                    None => "FIXED".into(),
                };
                format!("CAP {} {dim} {}", bit(c.shutter), num("warm-up", c.warm_up_s)?)
            }
            Reply::On(b) => format!("OUTP {}", bit(*b)),
            Reply::ShutterOpen(b) => format!("SHUT {}", bit(*b)),
            Reply::Intensity(f) => format!("INT {}", num("intensity", *f)?),
            Reply::Hours(h) => format!("HOUR {}", num("hours", *h)?),
            Reply::Status(s) => {
                let warm = match s.warm {
                    Warm::Off => "OFF".into(),
                    Warm::Ready => "READY".into(),
                    Warm::Warming(left) => format!("WARM {}", num("warm-up left", left)?),
                };
                format!("STAT {} {} {} {warm}", bit(s.on), bit(s.shutter_open), num("intensity", s.intensity)?)
            }
            Reply::Error { code, message } => {
                printable("message", message, b"")?;
                format!("ERR {code} {message}").trim_end().to_string()
            }
        })
    }
}

fn flag(s: &str, line: &[u8]) -> Result<bool, DecodeError> {
    match s {
        "0" => Ok(false),
        "1" => Ok(true),
        _ => Err(DecodeError::malformed("lamp reply", "expected 0 or 1", line)),
    }
}

/// Parses a request line (controller side). Keywords are case-insensitive, as in SCPI.
pub fn parse_request(line: &[u8]) -> Result<Request, DecodeError> {
    let text = ascii("lamp request", line)?.trim().to_ascii_uppercase();
    let words: Vec<&str> = text.split_whitespace().collect();
    Ok(match words.as_slice() {
        ["*IDN?"] => Request::Identify,
        ["CAP?"] => Request::Capabilities,
        ["OUTP", "ON"] => Request::SetOn(true),
        ["OUTP", "OFF"] => Request::SetOn(false),
        ["OUTP?"] => Request::QueryOn,
        ["SHUT", "OPEN"] => Request::SetShutterOpen(true),
        ["SHUT", "CLOSE"] => Request::SetShutterOpen(false),
        ["SHUT?"] => Request::QueryShutter,
        ["INT", v] => Request::SetIntensity(decimal("intensity", v)?),
        ["INT?"] => Request::QueryIntensity,
        ["HOUR?"] => Request::QueryHours,
        ["STAT?"] => Request::Status,
        _ => return Err(DecodeError::malformed("lamp request", "unknown command", line)),
    })
}

/// Parses a reply line (host side).
pub fn parse_reply(line: &[u8]) -> Result<Reply, DecodeError> {
    let text = ascii("lamp reply", line)?;
    let (head, rest) = text.split_once(' ').unwrap_or((text, ""));
    let words: Vec<&str> = rest.split(' ').filter(|w| !w.is_empty()).collect();
    let bad = |d: &str| DecodeError::malformed("lamp reply", d, line);
    Ok(match (head, words.as_slice()) {
        ("OK", []) => Reply::Ok,
        ("IDN", _) if !rest.is_empty() => Reply::Identity(rest.split(',').map(str::to_string).collect()),
        ("CAP", [shutter, dim, warm]) => {
            let dim_range = if *dim == "FIXED" {
                None
            } else {
                let (lo, hi) = dim.split_once(',').ok_or_else(|| bad("dimming range must be min,max or FIXED"))?;
                Some((decimal("dim min", lo)?, decimal("dim max", hi)?))
            };
            Reply::Capabilities(LampCaps {
                shutter: flag(shutter, line)?,
                dim_range,
                warm_up_s: decimal("warm-up", warm)?,
            })
        }
        ("OUTP", [b]) => Reply::On(flag(b, line)?),
        ("SHUT", [b]) => Reply::ShutterOpen(flag(b, line)?),
        ("INT", [v]) => Reply::Intensity(decimal("intensity", v)?),
        ("HOUR", [v]) => Reply::Hours(decimal("hours", v)?),
        ("STAT", [on, sh, int, warm @ ..]) => {
            let warm = match warm {
                ["OFF"] => Warm::Off,
                ["READY"] => Warm::Ready,
                ["WARM", left] => Warm::Warming(decimal("warm-up left", left)?),
                _ => return Err(bad("warm-up must be OFF, READY or WARM <s>")),
            };
            Reply::Status(LampState {
                on: flag(on, line)?,
                shutter_open: flag(sh, line)?,
                intensity: decimal("intensity", int)?,
                warm,
            })
        }
        ("ERR", [code, ..]) => Reply::Error {
            code: code.parse().map_err(|_| bad("bad error code"))?,
            message: rest.split_once(' ').map(|(_, m)| m).unwrap_or("").to_string(),
        },
        _ => return Err(bad("unknown reply")),
    })
}

/// Host-side decoder of replies.
pub fn reply_decoder() -> LineDecoder<Reply> {
    LineDecoder::with_parser(MAX_LINE, parse_reply)
}

/// Controller-side decoder of requests.
pub fn request_decoder() -> LineDecoder<Request> {
    LineDecoder::with_parser(MAX_LINE, parse_request)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_byte_vectors() {
        let cases: [(Request, &[u8]); 12] = [
            (Request::Identify, b"*IDN?\n"),
            (Request::Capabilities, b"CAP?\n"),
            (Request::SetOn(true), b"OUTP ON\n"),
            (Request::SetOn(false), b"OUTP OFF\n"),
            (Request::QueryOn, b"OUTP?\n"),
            (Request::SetShutterOpen(true), b"SHUT OPEN\n"),
            (Request::SetShutterOpen(false), b"SHUT CLOSE\n"),
            (Request::QueryShutter, b"SHUT?\n"),
            (Request::SetIntensity(0.75), b"INT 0.75\n"),
            (Request::QueryIntensity, b"INT?\n"),
            (Request::QueryHours, b"HOUR?\n"),
            (Request::Status, b"STAT?\n"),
        ];
        for (r, bytes) in cases {
            assert_eq!(r.encode().unwrap(), bytes);
            let mut d = request_decoder();
            d.push(bytes);
            assert_eq!(d.next(), Some(Ok(r)));
        }
        assert_eq!(parse_request(b"outp on").unwrap(), Request::SetOn(true));
    }

    #[test]
    fn reply_byte_vectors() {
        let cases: Vec<(Reply, &[u8])> = vec![
            (Reply::Ok, b"OK\n"),
            (
                Reply::Identity(vec!["Osram".into(), "HMI-575".into(), "S1".into(), "1.0".into()]),
                b"IDN Osram,HMI-575,S1,1.0\n",
            ),
            (
                Reply::Capabilities(LampCaps { shutter: true, dim_range: Some((0.5, 1.0)), warm_up_s: 600.0 }),
                b"CAP 1 0.5,1 600\n",
            ),
            (Reply::Capabilities(LampCaps { shutter: false, dim_range: None, warm_up_s: 0.0 }), b"CAP 0 FIXED 0\n"),
            (Reply::On(true), b"OUTP 1\n"),
            (Reply::ShutterOpen(false), b"SHUT 0\n"),
            (Reply::Intensity(0.5), b"INT 0.5\n"),
            (Reply::Hours(1234.5), b"HOUR 1234.5\n"),
            (
                Reply::Status(LampState { on: true, shutter_open: true, intensity: 1.0, warm: Warm::Warming(12.5) }),
                b"STAT 1 1 1 WARM 12.5\n",
            ),
            (
                Reply::Status(LampState { on: false, shutter_open: false, intensity: 0.5, warm: Warm::Off }),
                b"STAT 0 0 0.5 OFF\n",
            ),
            (
                Reply::Status(LampState { on: true, shutter_open: false, intensity: 0.5, warm: Warm::Ready }),
                b"STAT 1 0 0.5 READY\n",
            ),
            (
                Reply::Error { code: codes::RESTRIKE_LOCKOUT, message: "burner hot, 120 s".into() },
                b"ERR 6 burner hot, 120 s\n",
            ),
        ];
        for (r, bytes) in cases {
            assert_eq!(r.encode().unwrap(), bytes, "{r:?}");
            let mut d = reply_decoder();
            d.push(bytes);
            assert_eq!(d.next(), Some(Ok(r)));
        }
    }

    #[test]
    fn malformed_truncated_oversized() {
        for bad in [&b"OUTP MAYBE"[..], b"INT", b"INT x", b"INT 1e3", b"FOO?", b"SHUT OPEN NOW"] {
            assert!(parse_request(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
        for bad in [
            &b"OUTP 2"[..],
            b"STAT 1 1 1",
            b"STAT 1 1 1 WARM",
            b"CAP 1 0.5 600",
            b"ERR",
            b"OK extra",
            b"IDN",
            b"\x01OK",
        ] {
            assert!(parse_reply(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
        let mut d = reply_decoder();
        d.push(b"STAT 1 1");
        assert!(d.next().is_none());
        d.push(b" 1 READY\n");
        assert!(matches!(d.next(), Some(Ok(Reply::Status(_)))));
        let mut long = vec![b'9'; MAX_LINE + 1];
        long.extend(b"\nOK\n");
        d.push(&long);
        assert_eq!(d.next(), Some(Err(DecodeError::Oversized { what: "line", limit: MAX_LINE })));
        assert_eq!(d.next(), Some(Ok(Reply::Ok)));
    }

    #[test]
    fn kinds() {
        assert!(error_kind(codes::SYNTAX).is_retryable());
        assert!(error_kind(codes::RESTRIKE_LOCKOUT).is_retryable());
        assert_eq!(error_kind(codes::UNSUPPORTED), ErrorKind::Unsupported);
        assert!(!error_kind(codes::IGNITION_FAILED).is_retryable());
    }
}
