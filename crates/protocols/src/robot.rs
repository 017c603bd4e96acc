//! The sample robot's line protocol (a btfrig design; see `docs/protocols/robot.md`).
//!
//! Every line is `<tag> <body>*<CS>\n`: `tag` a decimal number 1..=65535 the host picks
//! per request and the controller echoes (so a late reply to an abandoned request is
//! recognised and dropped), `CS` two hex digits, the XOR of every byte before `*` (NMEA
//! style: a damaged line is detected, not acted on). Tag 0 marks a reply the controller
//! could not attribute (it could not read the request's tag). Angles are radians as the
//! shortest decimal that reads back to the same `f64`, so host and controller agree on the
//! target bit for bit. Moves are accepted at once (`OK`); the host polls `STATUS` until
//! `IDLE`, as with GRBL.

use btfrig_hw::ErrorKind;

use crate::checksum::xor8;
use crate::line::{ascii, decimal, format_decimal, LineDecoder};
use crate::{DecodeError, EncodeError};

/// Longest line, bytes (without the line end).
pub const MAX_LINE: usize = 256;
/// Largest angle magnitude sent, radians.
pub const MAX_ANGLE: f64 = 1e3;
/// Tag of replies the controller cannot attribute to a request.
pub const UNATTRIBUTED_TAG: u16 = 0;

/// What the host asks.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// `ID`: model, serial, firmware.
    Id,
    /// `LIMITS`: per joint min, max (radians) and top speed (rad/s).
    Limits,
    /// `HOME`: start the homing cycle.
    Home,
    /// `MOVE j0 j1 j2`: start a move to these joint angles, radians.
    Move([f64; 3]),
    /// `STATUS`: state, homed, joint position.
    Status,
    /// `STOP`: decelerate and stop now.
    Stop,
    /// `RESET`: clear a latched fault (after the cause is removed).
    Reset,
}

/// Motion state reported by `STATUS`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotState {
    /// Standing, ready for a command.
    Idle,
    /// Executing a move.
    Moving,
    /// Running the homing cycle.
    Homing,
    /// A latched fault (emergency stop, drive fault): `RESET` after fixing the cause.
    Fault,
}

impl RobotState {
    fn as_str(self) -> &'static str {
        match self {
            RobotState::Idle => "IDLE",
            RobotState::Moving => "MOVING",
            RobotState::Homing => "HOMING",
            RobotState::Fault => "FAULT",
        }
    }
}

/// A `STATUS` answer.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotStatus {
    /// Motion state.
    pub state: RobotState,
    /// Homed since power-up.
    pub homed: bool,
    /// Joint position the encoders report, radians (the commanded target once settled).
    pub joints_rad: [f64; 3],
}

/// One joint's limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimit {
    /// Lowest angle, radians.
    pub min_rad: f64,
    /// Highest angle, radians.
    pub max_rad: f64,
    /// Top speed, rad/s.
    pub max_speed_rad_per_s: f64,
}

/// What the controller answers.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `OK`: command accepted.
    Ok,
    /// `OK ID <model> <serial> <firmware>`.
    Id {
        /// Model (no spaces).
        model: String,
        /// Serial number (no spaces).
        serial: String,
        /// Firmware version (no spaces).
        firmware: String,
    },
    /// `OK LIMITS min,max,speed min,max,speed min,max,speed`.
    Limits([JointLimit; 3]),
    /// `OK STATUS <state> <0|1> j0,j1,j2`.
    Status(RobotStatus),
    /// `ERR <code> <message>` (see [`error_kind`]).
    Error {
        /// Error code.
        code: u16,
        /// Human-readable text.
        message: String,
    },
}

/// A request or reply with its tag.
#[derive(Debug, Clone, PartialEq)]
pub struct Tagged<T> {
    /// The request's tag, echoed in the reply.
    pub tag: u16,
    /// The message.
    pub body: T,
}

/// Error codes of the controller.
pub mod codes {
    /// The line's checksum did not match (damaged on the wire).
    pub const BAD_CHECKSUM: u16 = 1;
    /// The line could not be parsed (damaged on the wire).
    pub const PARSE: u16 = 2;
    /// A well-formed line with an unknown verb.
    pub const UNKNOWN_COMMAND: u16 = 3;
    /// Moves need a homing cycle first.
    pub const NOT_HOMED: u16 = 10;
    /// A move or homing cycle is still running.
    pub const BUSY: u16 = 11;
    /// A joint target outside the soft limits.
    pub const OUT_OF_RANGE: u16 = 12;
    /// The emergency stop is pressed.
    pub const ESTOP: u16 = 20;
    /// A drive reported a fault (overcurrent, following error); latched until `RESET`.
    pub const DRIVE_FAULT: u16 = 21;
}

/// How the host should treat an `ERR` code.
pub fn error_kind(code: u16) -> ErrorKind {
    match code {
        codes::BAD_CHECKSUM | codes::PARSE => ErrorKind::CorruptData,
        codes::NOT_HOMED => ErrorKind::NotHomed,
        codes::BUSY => ErrorKind::Busy,
        codes::OUT_OF_RANGE => ErrorKind::OutOfRange,
        _ => ErrorKind::Other,
    }
}

fn token_ok(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_graphic() && b != b'*')
}

fn text_err(field: &'static str, value: &str) -> EncodeError {
    EncodeError::Text { field, value: value.to_string(), allowed: "printable ASCII without '*' (tokens: no spaces)" }
}

fn frame(tag: u16, body: &str) -> Result<Vec<u8>, EncodeError> {
    let head = format!("{tag} {body}");
    let line = format!("{head}*{:02X}", xor8(head.as_bytes()));
    if line.len() > MAX_LINE {
        return Err(EncodeError::TooLong { what: "line", len: line.len(), limit: MAX_LINE });
    }
    Ok((line + "\n").into_bytes())
}

fn angles(field: &'static str, v: &[f64]) -> Result<String, EncodeError> {
    let parts: Result<Vec<String>, _> = v.iter().map(|&a| format_decimal(field, a, MAX_ANGLE)).collect();
    Ok(parts?.join(","))
}

impl Tagged<Request> {
    /// The line on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let body = match &self.body {
            Request::Id => "ID".to_string(),
            Request::Limits => "LIMITS".to_string(),
            Request::Home => "HOME".to_string(),
            Request::Status => "STATUS".to_string(),
            Request::Stop => "STOP".to_string(),
            Request::Reset => "RESET".to_string(),
            Request::Move(j) => {
                let parts: Result<Vec<String>, _> = j.iter().map(|&a| format_decimal("joint", a, MAX_ANGLE)).collect();
                format!("MOVE {}", parts?.join(" "))
            }
        };
        frame(self.tag, &body)
    }
}

impl Tagged<Reply> {
    /// The line on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let body = match &self.body {
            Reply::Ok => "OK".to_string(),
            Reply::Id { model, serial, firmware } => {
                for (f, v) in [("model", model), ("serial", serial), ("firmware", firmware)] {
                    if !token_ok(v) {
                        return Err(text_err(f, v));
                    }
                }
                format!("OK ID {model} {serial} {firmware}")
            }
            Reply::Limits(l) => {
                let parts: Result<Vec<String>, _> =
                    l.iter().map(|j| angles("limit", &[j.min_rad, j.max_rad, j.max_speed_rad_per_s])).collect();
                format!("OK LIMITS {}", parts?.join(" "))
            }
            Reply::Status(s) => {
                format!("OK STATUS {} {} {}", s.state.as_str(), u8::from(s.homed), angles("joint", &s.joints_rad)?)
            }
            Reply::Error { code, message } => {
                if message.bytes().any(|b| !(0x20..0x7f).contains(&b) || b == b'*') {
                    return Err(text_err("message", message));
                }
                if message.is_empty() {
                    format!("ERR {code}")
                } else {
                    format!("ERR {code} {message}")
                }
            }
        };
        frame(self.tag, &body)
    }
}

/// Checks the checksum and splits `<tag> <body>`.
fn unframe(line: &[u8]) -> Result<(u16, &str), DecodeError> {
    let text = ascii("robot line", line)?;
    let (head, cs) =
        text.rsplit_once('*').ok_or_else(|| DecodeError::malformed("robot line", "no '*' checksum", line))?;
    if cs.len() != 2 {
        return Err(DecodeError::malformed("robot line", "checksum must be 2 hex digits", line));
    }
    let received =
        u8::from_str_radix(cs, 16).map_err(|_| DecodeError::malformed("robot line", "bad checksum digits", line))?;
    let computed = xor8(head.as_bytes());
    if received != computed {
        return Err(DecodeError::Checksum { received: received.into(), computed: computed.into() });
    }
    let (tag, body) = head.split_once(' ').ok_or_else(|| DecodeError::malformed("robot line", "no tag", line))?;
    let tag = tag.parse().map_err(|_| DecodeError::malformed("robot line", "bad tag", line))?;
    Ok((tag, body))
}

fn three(what: &'static str, s: &str, line: &[u8]) -> Result<[f64; 3], DecodeError> {
    let v: Vec<&str> = s.split(',').collect();
    if v.len() != 3 {
        return Err(DecodeError::malformed(what, "expected 3 comma-separated numbers", line));
    }
    Ok([decimal(what, v[0])?, decimal(what, v[1])?, decimal(what, v[2])?])
}

/// Parses a request line (controller side).
pub fn parse_request(line: &[u8]) -> Result<Tagged<Request>, DecodeError> {
    let (tag, body) = unframe(line)?;
    let words: Vec<&str> = body.split(' ').collect();
    let body = match words.as_slice() {
        ["ID"] => Request::Id,
        ["LIMITS"] => Request::Limits,
        ["HOME"] => Request::Home,
        ["STATUS"] => Request::Status,
        ["STOP"] => Request::Stop,
        ["RESET"] => Request::Reset,
        ["MOVE", a, b, c] => Request::Move([decimal("joint", a)?, decimal("joint", b)?, decimal("joint", c)?]),
        _ => return Err(DecodeError::malformed("robot request", "unknown verb or wrong argument count", line)),
    };
    Ok(Tagged { tag, body })
}

/// Parses a reply line (host side).
pub fn parse_reply(line: &[u8]) -> Result<Tagged<Reply>, DecodeError> {
    let (tag, body) = unframe(line)?;
    let words: Vec<&str> = body.split(' ').collect();
    let body = match words.as_slice() {
        ["OK"] => Reply::Ok,
        ["OK", "ID", m, s, f] => Reply::Id { model: m.to_string(), serial: s.to_string(), firmware: f.to_string() },
        ["OK", "LIMITS", a, b, c] => {
            let j = |s: &str| {
                three("limits", s, line).map(|v| JointLimit { min_rad: v[0], max_rad: v[1], max_speed_rad_per_s: v[2] })
            };
            Reply::Limits([j(a)?, j(b)?, j(c)?])
        }
        ["OK", "STATUS", state, homed, joints] => {
            let state = match *state {
                "IDLE" => RobotState::Idle,
                "MOVING" => RobotState::Moving,
                "HOMING" => RobotState::Homing,
                "FAULT" => RobotState::Fault,
                _ => return Err(DecodeError::malformed("robot status", "unknown state", line)),
            };
            let homed = match *homed {
                "0" => false,
                "1" => true,
                _ => return Err(DecodeError::malformed("robot status", "homed must be 0 or 1", line)),
            };
            Reply::Status(RobotStatus { state, homed, joints_rad: three("joints", joints, line)? })
        }
        ["ERR", code, ..] => {
            let code = code.parse().map_err(|_| DecodeError::malformed("robot error", "bad code", line))?;
            let message = body.splitn(3, ' ').nth(2).unwrap_or("").to_string();
            Reply::Error { code, message }
        }
        _ => return Err(DecodeError::malformed("robot reply", "unknown reply", line)),
    };
    Ok(Tagged { tag, body })
}

/// Host-side decoder of replies.
pub type ReplyDecoder = LineDecoder<Tagged<Reply>>;
/// Controller-side decoder of requests.
pub type RequestDecoder = LineDecoder<Tagged<Request>>;

/// A host-side reply decoder with the [`MAX_LINE`] limit.
pub fn reply_decoder() -> ReplyDecoder {
    LineDecoder::with_parser(MAX_LINE, parse_reply)
}

/// A controller-side request decoder with the [`MAX_LINE`] limit.
pub fn request_decoder() -> RequestDecoder {
    LineDecoder::with_parser(MAX_LINE, parse_request)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(tag: u16, body: Request) -> Tagged<Request> {
        Tagged { tag, body }
    }

    fn rep(tag: u16, body: Reply) -> Tagged<Reply> {
        Tagged { tag, body }
    }

    /// `line` with its checksum appended, as the spec computes it.
    fn signed(head: &str) -> Vec<u8> {
        format!("{head}*{:02X}\n", xor8(head.as_bytes())).into_bytes()
    }

    #[test]
    fn request_byte_vectors() {
        assert_eq!(req(7, Request::Home).encode().unwrap(), signed("7 HOME"));
        assert_eq!(xor8(b"7 HOME"), 0x37 ^ 0x20 ^ 0x48 ^ 0x4F ^ 0x4D ^ 0x45);
        let cases = [
            (req(1, Request::Id), "1 ID"),
            (req(2, Request::Limits), "2 LIMITS"),
            (req(3, Request::Move([0.5, -0.25, 3.0])), "3 MOVE 0.5 -0.25 3"),
            (req(4, Request::Status), "4 STATUS"),
            (req(5, Request::Stop), "5 STOP"),
            (req(65535, Request::Reset), "65535 RESET"),
        ];
        for (r, head) in cases {
            let bytes = signed(head);
            assert_eq!(r.encode().unwrap(), bytes, "{r:?}");
            let mut d = request_decoder();
            d.push(&bytes);
            assert_eq!(d.next(), Some(Ok(r)));
        }
    }

    #[test]
    fn reply_byte_vectors() {
        let lim = JointLimit { min_rad: -3.0, max_rad: 3.0, max_speed_rad_per_s: 0.5 };
        let cases = [
            (rep(1, Reply::Ok), "1 OK"),
            (
                rep(2, Reply::Id { model: "BR-3".into(), serial: "0042".into(), firmware: "2.1".into() }),
                "2 OK ID BR-3 0042 2.1",
            ),
            (rep(3, Reply::Limits([lim; 3])), "3 OK LIMITS -3,3,0.5 -3,3,0.5 -3,3,0.5"),
            (
                rep(
                    4,
                    Reply::Status(RobotStatus { state: RobotState::Moving, homed: true, joints_rad: [0.1, 0.0, -1.5] }),
                ),
                "4 OK STATUS MOVING 1 0.1,0,-1.5",
            ),
            (
                rep(
                    5,
                    Reply::Error {
                        code: codes::OUT_OF_RANGE,
                        message: "joint 1 target 2 outside [-1.57, 1.57]".into(),
                    },
                ),
                "5 ERR 12 joint 1 target 2 outside [-1.57, 1.57]",
            ),
            (rep(0, Reply::Error { code: codes::BAD_CHECKSUM, message: String::new() }), "0 ERR 1"),
        ];
        for (r, head) in cases {
            let bytes = signed(head);
            assert_eq!(r.encode().unwrap(), bytes, "{r:?}");
            let mut d = reply_decoder();
            d.push(&bytes);
            assert_eq!(d.next(), Some(Ok(r)));
        }
    }

    #[test]
    fn damaged_lines_are_detected() {
        let good = signed("3 MOVE 0.5 -0.25 3");
        // One flipped bit anywhere before the '*' breaks the checksum (or the framing).
        for i in 0..good.len() - 4 {
            let mut bad = good.clone();
            bad[i] ^= 0x01;
            let mut d = request_decoder();
            d.push(&bad);
            assert!(matches!(d.next(), Some(Err(_))), "flip at {i} went unnoticed");
        }
        for bad in [&b"1 HOME"[..], b"1 HOME*", b"1 HOME*G0", b"HOME*00", b"x HOME*00", b"1 HOME*0"] {
            assert!(parse_request(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
        // Well-framed but wrong content.
        for head in ["1 MOVE 1 2", "1 MOVE a b c", "1 FLY", "1 MOVE 1 2 3 4"] {
            let l = signed(head);
            assert!(parse_request(&l[..l.len() - 1]).is_err(), "{head}");
        }
        for head in
            ["1 OK STATUS RUNNING 1 0,0,0", "1 OK STATUS IDLE 2 0,0,0", "1 OK STATUS IDLE 1 0,0", "1 ERR x", "1 NOPE"]
        {
            let l = signed(head);
            assert!(parse_reply(&l[..l.len() - 1]).is_err(), "{head}");
        }
    }

    #[test]
    fn truncated_oversized_and_garbage() {
        let mut d = reply_decoder();
        let good = signed("9 OK");
        d.push(&good[..3]);
        assert!(d.next().is_none());
        let mut rest = good[3..].to_vec();
        rest.extend(vec![b'#'; MAX_LINE + 5]);
        rest.extend(b"\n\x00\xff\x10\n");
        rest.extend(&good);
        d.push(&rest);
        assert_eq!(d.next(), Some(Ok(rep(9, Reply::Ok))));
        assert_eq!(d.next(), Some(Err(DecodeError::Oversized { what: "line", limit: MAX_LINE })));
        assert!(matches!(d.next(), Some(Err(DecodeError::Malformed { .. }))));
        assert_eq!(d.next(), Some(Ok(rep(9, Reply::Ok))));
        assert!(d.next().is_none());
    }

    #[test]
    fn angles_survive_the_wire_bit_for_bit() {
        let j = [45f64.to_radians(), -1.0 / 3.0, std::f64::consts::PI];
        let bytes = req(1, Request::Move(j)).encode().unwrap();
        let back = parse_request(&bytes[..bytes.len() - 1]).unwrap();
        assert_eq!(back.body, Request::Move(j));
    }

    #[test]
    fn encoder_refuses_bad_fields() {
        assert!(req(1, Request::Move([f64::INFINITY, 0.0, 0.0])).encode().is_err());
        assert!(rep(1, Reply::Id { model: "a b".into(), serial: "1".into(), firmware: "1".into() }).encode().is_err());
        assert!(rep(1, Reply::Error { code: 2, message: "a*b".into() }).encode().is_err());
    }

    #[test]
    fn kinds() {
        assert_eq!(error_kind(codes::BAD_CHECKSUM), ErrorKind::CorruptData);
        assert_eq!(error_kind(codes::BUSY), ErrorKind::Busy);
        assert_eq!(error_kind(codes::NOT_HOMED), ErrorKind::NotHomed);
        assert!(!error_kind(codes::ESTOP).is_retryable());
        assert!(!error_kind(codes::DRIVE_FAULT).is_retryable());
    }
}
