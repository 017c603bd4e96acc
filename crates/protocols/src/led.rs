//! The LED dome controller's framed binary protocol (a btfrig design; see
//! `docs/protocols/led.md`).
//!
//! A frame is `A5 5A | kind u8 | seq u8 | len u16 LE | payload (len bytes) | CRC u16 LE`,
//! the CRC-16/CCITT-FALSE of kind..payload. Replies echo the request's `seq`. The decoder
//! scans for the sync bytes, so it resynchronises after garbage; a length over
//! [`MAX_PAYLOAD`] or a bad CRC drops one byte and scans on (a real frame may begin inside
//! the damaged one). Intensities are integers `0..steps` (`steps` from `Info`).

use btfrig_hw::ErrorKind;

use crate::checksum::crc16_ccitt;
use crate::{DecodeError, EncodeError};

/// The two sync bytes that open every frame.
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Header bytes: sync, kind, seq, length.
pub const HEADER: usize = 6;
/// Largest payload, bytes (a pattern of up to 511 LEDs).
pub const MAX_PAYLOAD: usize = 1024;
/// Largest number of LEDs a pattern can carry.
pub const MAX_LEDS: usize = (MAX_PAYLOAD - 2) / 2;

/// Message kinds.
pub mod kinds {
    /// Host: ask for count, steps, firmware.
    pub const GET_INFO: u8 = 0x01;
    /// Host: stage a pattern (does not light it yet).
    pub const SET_PATTERN: u8 = 0x02;
    /// Host: light the staged pattern, all LEDs at once.
    pub const TRIGGER: u8 = 0x03;
    /// Host: ask for status flags.
    pub const GET_STATUS: u8 = 0x04;
    /// Host: ask for the driver board temperature.
    pub const GET_TEMPERATURE: u8 = 0x05;
    /// Host: ask for the pattern now lit.
    pub const GET_PATTERN: u8 = 0x06;
    /// Controller: info.
    pub const INFO: u8 = 0x81;
    /// Controller: done.
    pub const ACK: u8 = 0x82;
    /// Controller: refused, with a code.
    pub const NACK: u8 = 0x83;
    /// Controller: status.
    pub const STATUS: u8 = 0x84;
    /// Controller: temperature.
    pub const TEMPERATURE: u8 = 0x85;
    /// Controller: the lit pattern.
    pub const PATTERN: u8 = 0x86;
}

/// `Nack` codes.
pub mod codes {
    /// The request's CRC was wrong (damaged on the wire).
    pub const BAD_CRC: u8 = 1;
    /// The payload length does not fit the kind (damaged on the wire).
    pub const BAD_LENGTH: u8 = 2;
    /// Unknown kind.
    pub const UNKNOWN_KIND: u8 = 3;
    /// Pattern length is not the LED count.
    pub const WRONG_COUNT: u8 = 4;
    /// An intensity at or above the step count.
    pub const VALUE_TOO_HIGH: u8 = 5;
    /// Driver board over temperature; LEDs are off until it cools.
    pub const OVER_TEMPERATURE: u8 = 6;
    /// `Trigger` with nothing staged.
    pub const NOTHING_STAGED: u8 = 7;
    /// Still lighting the previously triggered pattern; retry after a status poll.
    pub const BUSY: u8 = 8;
    /// Lighting the triggered pattern failed (a driver channel fault); the answer to the
    /// request after the trigger.
    pub const DRIVER_FAULT: u8 = 9;
}

/// How the host should treat a `Nack` code.
pub fn nack_kind(code: u8) -> ErrorKind {
    match code {
        codes::BAD_CRC | codes::BAD_LENGTH => ErrorKind::CorruptData,
        codes::WRONG_COUNT | codes::VALUE_TOO_HIGH => ErrorKind::OutOfRange,
        codes::OVER_TEMPERATURE | codes::BUSY => ErrorKind::Busy,
        _ => ErrorKind::Other,
    }
}

/// A frame: kind, sequence number, payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Message kind ([`kinds`]).
    pub kind: u8,
    /// Sequence number; replies echo it.
    pub seq: u8,
    /// Payload.
    pub payload: Vec<u8>,
}

impl Frame {
    /// The bytes on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        if self.payload.len() > MAX_PAYLOAD {
            return Err(EncodeError::TooLong { what: "frame payload", len: self.payload.len(), limit: MAX_PAYLOAD });
        }
        let mut out = Vec::with_capacity(HEADER + self.payload.len() + 2);
        out.extend_from_slice(&SYNC);
        out.push(self.kind);
        out.push(self.seq);
        out.extend_from_slice(&(self.payload.len() as u16).to_le_bytes());
        out.extend_from_slice(&self.payload);
        let crc = crc16_ccitt(&out[2..]);
        out.extend_from_slice(&crc.to_le_bytes());
        Ok(out)
    }
}

/// Incremental frame decoder that resynchronises on the sync bytes.
#[derive(Debug, Clone, Default)]
pub struct FrameDecoder {
    buf: Vec<u8>,
}

impl FrameDecoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Drops everything buffered.
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// The next frame, a decode error (the bad bytes are already skipped), or `None` when
    /// more bytes are needed.
    #[allow(clippy::should_implement_trait)] // `None` means "need more bytes"
    pub fn next(&mut self) -> Option<Result<Frame, DecodeError>> {
        // Skip to the sync; a lone trailing A5 may be the start of one.
        let start = self.buf.windows(2).position(|w| w == SYNC).unwrap_or_else(|| {
            if self.buf.last() == Some(&SYNC[0]) {
                self.buf.len() - 1
            } else {
                self.buf.len()
            }
        });
        if start > 0 {
            self.buf.drain(..start);
            return Some(Err(DecodeError::Garbage { count: start }));
        }
        if self.buf.len() < HEADER {
            return None;
        }
        let len = usize::from(u16::from_le_bytes([self.buf[4], self.buf[5]]));
        if len > MAX_PAYLOAD {
            self.buf.drain(..1);
            return Some(Err(DecodeError::Oversized { what: "frame", limit: MAX_PAYLOAD }));
        }
        let total = HEADER + len + 2;
        if self.buf.len() < total {
            return None;
        }
        let computed = crc16_ccitt(&self.buf[2..HEADER + len]);
        let received = u16::from_le_bytes([self.buf[HEADER + len], self.buf[HEADER + len + 1]]);
        if computed != received {
            self.buf.drain(..1);
            return Some(Err(DecodeError::Checksum { received: received.into(), computed: computed.into() }));
        }
        let frame = Frame { kind: self.buf[2], seq: self.buf[3], payload: self.buf[HEADER..HEADER + len].to_vec() };
        self.buf.drain(..total);
        Some(Ok(frame))
    }
}

/// What the host asks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// Count, steps, firmware.
    GetInfo,
    /// Stage a pattern: one intensity per LED, `0..steps`.
    SetPattern(Vec<u16>),
    /// Light the staged pattern.
    Trigger,
    /// Status flags.
    GetStatus,
    /// Board temperature.
    GetTemperature,
    /// The lit pattern.
    GetPattern,
}

/// Status flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LedStatus {
    /// A pattern is staged but not yet triggered.
    pub staged: bool,
    /// Over temperature (LEDs forced off).
    pub over_temperature: bool,
    /// A driver channel reported an open or short circuit.
    pub driver_fault: bool,
    /// How many LEDs are lit.
    pub lit: u16,
}

/// What the controller answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// LED count, intensity steps, firmware major.minor.
    Info {
        /// Number of LEDs.
        count: u16,
        /// Intensity steps per LED (values `0..steps`).
        steps: u32,
        /// Firmware version (major, minor).
        firmware: (u8, u8),
    },
    /// Done.
    Ack,
    /// Refused ([`codes`]).
    Nack(u8),
    /// Status.
    Status(LedStatus),
    /// Board temperature, hundredths of a degree Celsius.
    Temperature(i16),
    /// The lit pattern.
    Pattern(Vec<u16>),
}

fn pattern_payload(values: &[u16]) -> Result<Vec<u8>, EncodeError> {
    if values.len() > MAX_LEDS {
        return Err(EncodeError::TooLong { what: "pattern", len: values.len(), limit: MAX_LEDS });
    }
    let mut p = (values.len() as u16).to_le_bytes().to_vec();
    for v in values {
        p.extend_from_slice(&v.to_le_bytes());
    }
    Ok(p)
}

fn parse_pattern(f: &Frame) -> Result<Vec<u16>, DecodeError> {
    let p = &f.payload;
    if p.len() < 2 || p.len() != 2 + 2 * usize::from(u16::from_le_bytes([p[0], p[1]])) {
        return Err(DecodeError::malformed("led pattern", "length does not match the LED count", &[]));
    }
    Ok(p[2..].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
}

fn expect_len(f: &Frame, n: usize, what: &'static str) -> Result<(), DecodeError> {
    if f.payload.len() == n {
        Ok(())
    } else {
        Err(DecodeError::malformed(what, format!("payload of {} bytes, expected {n}", f.payload.len()), &[]))
    }
}

impl Request {
    /// The frame with sequence number `seq`.
    pub fn to_frame(&self, seq: u8) -> Result<Frame, EncodeError> {
        let (kind, payload) = match self {
            Request::GetInfo => (kinds::GET_INFO, vec![]),
            Request::SetPattern(v) => (kinds::SET_PATTERN, pattern_payload(v)?),
            Request::Trigger => (kinds::TRIGGER, vec![]),
            Request::GetStatus => (kinds::GET_STATUS, vec![]),
            Request::GetTemperature => (kinds::GET_TEMPERATURE, vec![]),
            Request::GetPattern => (kinds::GET_PATTERN, vec![]),
        };
        Ok(Frame { kind, seq, payload })
    }

    /// The bytes on the wire.
    pub fn encode(&self, seq: u8) -> Result<Vec<u8>, EncodeError> {
        self.to_frame(seq)?.encode()
    }

    /// The request a frame carries.
    pub fn from_frame(f: &Frame) -> Result<Request, DecodeError> {
        let empty = |r: Request, what| expect_len(f, 0, what).map(|()| r);
        match f.kind {
            kinds::GET_INFO => empty(Request::GetInfo, "get info"),
            kinds::SET_PATTERN => parse_pattern(f).map(Request::SetPattern),
            kinds::TRIGGER => empty(Request::Trigger, "trigger"),
            kinds::GET_STATUS => empty(Request::GetStatus, "get status"),
            kinds::GET_TEMPERATURE => empty(Request::GetTemperature, "get temperature"),
            kinds::GET_PATTERN => empty(Request::GetPattern, "get pattern"),
            k => Err(DecodeError::malformed("led request", format!("unknown kind {k:#04x}"), &[])),
        }
    }
}

impl Reply {
    /// The frame answering the request with sequence number `seq`.
    pub fn to_frame(&self, seq: u8) -> Result<Frame, EncodeError> {
        let (kind, payload) = match self {
            Reply::Info { count, steps, firmware } => {
                let mut p = count.to_le_bytes().to_vec();
                p.extend_from_slice(&steps.to_le_bytes());
                p.extend_from_slice(&[firmware.0, firmware.1]);
                (kinds::INFO, p)
            }
            Reply::Ack => (kinds::ACK, vec![]),
            Reply::Nack(code) => (kinds::NACK, vec![*code]),
            Reply::Status(s) => {
                let flags = u8::from(s.staged) | u8::from(s.over_temperature) << 1 | u8::from(s.driver_fault) << 2;
                let mut p = vec![flags];
                p.extend_from_slice(&s.lit.to_le_bytes());
                (kinds::STATUS, p)
            }
            Reply::Temperature(c) => (kinds::TEMPERATURE, c.to_le_bytes().to_vec()),
            Reply::Pattern(v) => (kinds::PATTERN, pattern_payload(v)?),
        };
        Ok(Frame { kind, seq, payload })
    }

    /// The bytes on the wire.
    pub fn encode(&self, seq: u8) -> Result<Vec<u8>, EncodeError> {
        self.to_frame(seq)?.encode()
    }

    /// The reply a frame carries.
    pub fn from_frame(f: &Frame) -> Result<Reply, DecodeError> {
        let p = &f.payload;
        match f.kind {
            kinds::INFO => {
                expect_len(f, 8, "info")?;
                Ok(Reply::Info {
                    count: u16::from_le_bytes([p[0], p[1]]),
                    steps: u32::from_le_bytes([p[2], p[3], p[4], p[5]]),
                    firmware: (p[6], p[7]),
                })
            }
            kinds::ACK => expect_len(f, 0, "ack").map(|()| Reply::Ack),
            kinds::NACK => expect_len(f, 1, "nack").map(|()| Reply::Nack(p[0])),
            kinds::STATUS => {
                expect_len(f, 3, "status")?;
                if p[0] & !0b111 != 0 {
                    return Err(DecodeError::malformed("led status", format!("unknown flag bits {:#04x}", p[0]), &[]));
                }
                Ok(Reply::Status(LedStatus {
                    staged: p[0] & 1 != 0,
                    over_temperature: p[0] & 2 != 0,
                    driver_fault: p[0] & 4 != 0,
                    lit: u16::from_le_bytes([p[1], p[2]]),
                }))
            }
            kinds::TEMPERATURE => {
                expect_len(f, 2, "temperature").map(|()| Reply::Temperature(i16::from_le_bytes([p[0], p[1]])))
            }
            kinds::PATTERN => parse_pattern(f).map(Reply::Pattern),
            k => Err(DecodeError::malformed("led reply", format!("unknown kind {k:#04x}"), &[])),
        }
    }
}

/// Frame decoder plus typed parsing, yielding `(seq, message)`.
#[derive(Debug, Clone)]
pub struct Decoder<T> {
    frames: FrameDecoder,
    parse: fn(&Frame) -> Result<T, DecodeError>,
}

impl<T> Decoder<T> {
    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.frames.push(bytes);
    }

    /// Drops everything buffered.
    pub fn clear(&mut self) {
        self.frames.clear();
    }

    /// The next `(seq, message)`, a decode error, or `None` when more bytes are needed.
    #[allow(clippy::should_implement_trait)] // `None` means "need more bytes"
    pub fn next(&mut self) -> Option<Result<(u8, T), DecodeError>> {
        self.frames.next().map(|r| r.and_then(|f| (self.parse)(&f).map(|m| (f.seq, m))))
    }
}

/// Host-side decoder of replies.
pub fn reply_decoder() -> Decoder<Reply> {
    Decoder { frames: FrameDecoder::new(), parse: Reply::from_frame }
}

/// Controller-side decoder of requests.
pub fn request_decoder() -> Decoder<Request> {
    Decoder { frames: FrameDecoder::new(), parse: Request::from_frame }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_byte_vector() {
        // Trigger, seq 7: CRC over [03 07 00 00].
        let bytes = Request::Trigger.encode(7).unwrap();
        let crc = crc16_ccitt(&[0x03, 0x07, 0x00, 0x00]).to_le_bytes();
        assert_eq!(bytes, vec![0xA5, 0x5A, 0x03, 0x07, 0x00, 0x00, crc[0], crc[1]]);
        // Set pattern of 2 LEDs [1, 0x0FFF], seq 1.
        let bytes = Request::SetPattern(vec![1, 0x0FFF]).encode(1).unwrap();
        assert_eq!(&bytes[..12], &[0xA5, 0x5A, 0x02, 0x01, 0x06, 0x00, 0x02, 0x00, 0x01, 0x00, 0xFF, 0x0F]);
        assert_eq!(bytes.len(), 14);
    }

    #[test]
    fn every_message_round_trips() {
        let reqs = [
            Request::GetInfo,
            Request::SetPattern(vec![0, 4095, 17]),
            Request::SetPattern(vec![]),
            Request::Trigger,
            Request::GetStatus,
            Request::GetTemperature,
            Request::GetPattern,
        ];
        for (i, r) in reqs.iter().enumerate() {
            let mut d = request_decoder();
            d.push(&r.encode(i as u8).unwrap());
            assert_eq!(d.next(), Some(Ok((i as u8, r.clone()))));
            assert!(d.next().is_none());
        }
        let reps = [
            Reply::Info { count: 198, steps: 4096, firmware: (1, 4) },
            Reply::Ack,
            Reply::Nack(codes::WRONG_COUNT),
            Reply::Status(LedStatus { staged: true, over_temperature: false, driver_fault: true, lit: 3 }),
            Reply::Temperature(-1250),
            Reply::Pattern(vec![5; 198]),
        ];
        for (i, r) in reps.iter().enumerate() {
            let mut d = reply_decoder();
            d.push(&r.encode(200 + i as u8).unwrap());
            assert_eq!(d.next(), Some(Ok((200 + i as u8, r.clone()))));
        }
    }

    #[test]
    fn garbage_bad_crc_and_split_at_every_offset() {
        let good = Reply::Pattern(vec![1, 2, 3]).encode(9).unwrap();
        let mut corrupt = Reply::Ack.encode(8).unwrap();
        let n = corrupt.len();
        corrupt[n - 1] ^= 0xFF;
        let mut stream = vec![0x00, 0xA5, 0x13, 0x5A];
        stream.extend(&corrupt);
        stream.extend(&good);
        for cut in 0..=stream.len() {
            let mut d = reply_decoder();
            let mut got = Vec::new();
            d.push(&stream[..cut]);
            got.extend(std::iter::from_fn(|| d.next()));
            d.push(&stream[cut..]);
            got.extend(std::iter::from_fn(|| d.next()));
            let oks: Vec<_> = got.iter().filter_map(|r| r.as_ref().ok()).collect();
            assert_eq!(oks, vec![&(9, Reply::Pattern(vec![1, 2, 3]))], "cut {cut}: {got:?}");
            assert!(got.iter().any(|r| matches!(r, Err(DecodeError::Checksum { .. }))), "cut {cut}");
        }
    }

    #[test]
    fn oversized_truncated_and_malformed() {
        let mut d = FrameDecoder::new();
        d.push(&[0xA5, 0x5A, 0x02, 0x00, 0xFF, 0xFF]);
        assert_eq!(d.next(), Some(Err(DecodeError::Oversized { what: "frame", limit: MAX_PAYLOAD })));
        // The rest of the header is scanned as garbage, then a good frame follows.
        d.push(&Reply::Ack.encode(1).unwrap());
        let got: Vec<_> = std::iter::from_fn(|| d.next()).collect();
        assert_eq!(got.last(), Some(&Ok(Frame { kind: kinds::ACK, seq: 1, payload: vec![] })));
        // Truncated: waits.
        let bytes = Reply::Temperature(2500).encode(3).unwrap();
        let mut d = reply_decoder();
        d.push(&bytes[..bytes.len() - 1]);
        assert!(d.next().is_none());
        d.push(&bytes[bytes.len() - 1..]);
        assert_eq!(d.next(), Some(Ok((3, Reply::Temperature(2500)))));
        // Valid frames with wrong payloads for their kind.
        for f in [
            Frame { kind: kinds::ACK, seq: 0, payload: vec![1] },
            Frame { kind: kinds::NACK, seq: 0, payload: vec![] },
            Frame { kind: kinds::STATUS, seq: 0, payload: vec![0x80, 0, 0] },
            Frame { kind: kinds::PATTERN, seq: 0, payload: vec![2, 0, 1, 0] },
            Frame { kind: 0x7F, seq: 0, payload: vec![] },
        ] {
            assert!(Reply::from_frame(&f).is_err(), "{f:?}");
        }
        assert!(Request::from_frame(&Frame { kind: kinds::TRIGGER, seq: 0, payload: vec![0] }).is_err());
        assert!(Request::SetPattern(vec![0; MAX_LEDS + 1]).encode(0).is_err());
    }

    #[test]
    fn kinds_of_nacks() {
        assert!(nack_kind(codes::BAD_CRC).is_retryable());
        assert_eq!(nack_kind(codes::VALUE_TOO_HIGH), ErrorKind::OutOfRange);
        assert!(!nack_kind(codes::NOTHING_STAGED).is_retryable());
        assert_eq!(nack_kind(codes::BUSY), ErrorKind::Busy);
    }
}
