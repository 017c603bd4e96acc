//! GRBL 1.1 style G-code for the single-axis motion controllers (rail, turntable).
//!
//! Host -> controller: lines (`G0 X12.5`, `G1 X12.5 F300`, `$H`, `$X`, `$130=180`) and
//! realtime bytes that act at once, outside the line stream (`?` status, `!` feed hold,
//! `~` resume, 0x18 soft reset). Controller -> host: `ok`, `error:N`, `ALARM:N`, status
//! reports `<Idle|MPos:12.500,0.000,0.000|FS:0,0>`, the welcome `Grbl 1.1h ['$' for help]`,
//! feedback `[MSG:...]` and settings `$130=180.000`. As in GRBL, `ok` means "accepted into
//! the planner", not "arrived": the host polls `?` until the state is `Idle`.
//! Axis units are degrees (the controller's steps per unit are set up that way).
//! See `docs/protocols/grbl.md`.

use btfrig_hw::ErrorKind;

use crate::line::{ascii, decimal, format_decimal, LineDecoder, LineFramer};
use crate::{DecodeError, EncodeError};

/// Longest line either side sends or accepts. GRBL's command buffer is 80 bytes; status
/// reports here carry positions at full `f64` precision (so host and controller agree bit
/// for bit), which takes up to about 140 bytes.
pub const MAX_LINE: usize = 160;
/// Largest coordinate or feed magnitude sent; beyond it the line is refused.
pub const MAX_VALUE: f64 = 1e6;

/// Realtime status query.
pub const REALTIME_STATUS: u8 = b'?';
/// Realtime feed hold: decelerate to a stop, keep the rest of the move.
pub const REALTIME_FEED_HOLD: u8 = b'!';
/// Realtime cycle start / resume after a feed hold.
pub const REALTIME_RESUME: u8 = b'~';
/// Realtime soft reset (Ctrl-X): stop at once, flush the planner.
pub const REALTIME_SOFT_RESET: u8 = 0x18;

/// Machine axis letters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Axis {
    /// X (the rail, and the turntable on a single-axis board).
    X,
    /// Y.
    Y,
    /// Z.
    Z,
    /// A (rotary).
    A,
}

impl Axis {
    /// All axes, in status-report order.
    pub const ALL: [Axis; 4] = [Axis::X, Axis::Y, Axis::Z, Axis::A];

    fn letter(self) -> char {
        match self {
            Axis::X => 'X',
            Axis::Y => 'Y',
            Axis::Z => 'Z',
            Axis::A => 'A',
        }
    }

    fn from_letter(c: u8) -> Option<Axis> {
        match c.to_ascii_uppercase() {
            b'X' => Some(Axis::X),
            b'Y' => Some(Axis::Y),
            b'Z' => Some(Axis::Z),
            b'A' => Some(Axis::A),
            _ => None,
        }
    }

    /// Index into a status report's `MPos`.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// What the host sends.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// `G0 X..` (rapid, `rapid = true`) or `G1 X.. F..` (feed move at `feed` units/min).
    Move {
        /// Rapid (`G0`) or linear feed (`G1`).
        rapid: bool,
        /// The axis.
        axis: Axis,
        /// Absolute target, degrees.
        target: f64,
        /// Feed rate, degrees per minute (`F` word); needed by `G1` unless set earlier.
        feed: Option<f64>,
    },
    /// `$H`: homing cycle.
    Home,
    /// `$X`: clear the alarm lock without homing.
    Unlock,
    /// `$N=V`: write a setting (`$20=1` soft limits on, `$130=180` max travel of X).
    Setting {
        /// Setting number.
        id: u16,
        /// Value.
        value: f64,
    },
    /// `$$`: list all settings.
    ListSettings,
    /// `?` (realtime): ask for a status report.
    StatusQuery,
    /// `!` (realtime): feed hold.
    FeedHold,
    /// `~` (realtime): resume.
    Resume,
    /// 0x18 (realtime): soft reset.
    SoftReset,
}

impl Command {
    /// Whether the command is a realtime byte (sent without a line end, acted on at once).
    pub fn is_realtime(&self) -> bool {
        matches!(self, Command::StatusQuery | Command::FeedHold | Command::Resume | Command::SoftReset)
    }

    /// The bytes on the wire: a line with `\n`, or one realtime byte.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let text = match self {
            Command::StatusQuery => return Ok(vec![REALTIME_STATUS]),
            Command::FeedHold => return Ok(vec![REALTIME_FEED_HOLD]),
            Command::Resume => return Ok(vec![REALTIME_RESUME]),
            Command::SoftReset => return Ok(vec![REALTIME_SOFT_RESET]),
            Command::Home => "$H".to_string(),
            Command::Unlock => "$X".to_string(),
            Command::ListSettings => "$$".to_string(),
            Command::Setting { id, value } => format!("${id}={}", format_decimal("setting value", *value, MAX_VALUE)?),
            Command::Move { rapid, axis, target, feed } => {
                let mut s = format!(
                    "{} {}{}",
                    if *rapid { "G0" } else { "G1" },
                    axis.letter(),
                    format_decimal("move target", *target, MAX_VALUE)?
                );
                if let Some(f) = feed {
                    if *f <= 0.0 {
                        return Err(EncodeError::Value { field: "feed", value: f.to_string(), allowed: "> 0" });
                    }
                    s += &format!(" F{}", format_decimal("feed", *f, MAX_VALUE)?);
                }
                s
            }
        };
        finish_line(text)
    }
}

fn finish_line(mut text: String) -> Result<Vec<u8>, EncodeError> {
    if text.len() > MAX_LINE {
        return Err(EncodeError::TooLong { what: "line", len: text.len(), limit: MAX_LINE });
    }
    text.push('\n');
    Ok(text.into_bytes())
}

/// Parses one command line (no line end, realtime bytes already taken out).
pub fn parse_command(line: &[u8]) -> Result<Command, DecodeError> {
    let text = ascii("command", line)?.trim();
    let upper = text.to_ascii_uppercase();
    match upper.as_str() {
        "$H" => return Ok(Command::Home),
        "$X" => return Ok(Command::Unlock),
        "$$" => return Ok(Command::ListSettings),
        _ => {}
    }
    if let Some(rest) = upper.strip_prefix('$') {
        let (id, value) =
            rest.split_once('=').ok_or_else(|| DecodeError::malformed("setting", "expected $N=V", line))?;
        let id = id.parse().map_err(|_| DecodeError::malformed("setting", "bad setting number", line))?;
        return Ok(Command::Setting { id, value: decimal("setting value", value)? });
    }
    // G-code words: a letter then a number, spaces optional (`G1X10F300` is valid GRBL).
    let mut words = Vec::new();
    let bytes: Vec<u8> = upper.bytes().filter(|b| *b != b' ').collect();
    let mut i = 0;
    while i < bytes.len() {
        let letter = bytes[i];
        if !letter.is_ascii_alphabetic() {
            return Err(DecodeError::malformed("g-code", "expected a word letter", line));
        }
        let start = i + 1;
        i = start;
        while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.' || bytes[i] == b'-' || bytes[i] == b'+')
        {
            i += 1;
        }
        // Only ASCII bytes here, so the slice is valid UTF-8.
        let number = std::str::from_utf8(&bytes[start..i]).unwrap_or("");
        words.push((letter, decimal("g-code word", number)?));
    }
    let (mut rapid, mut axis, mut feed) = (None, None, None);
    for (letter, value) in words {
        match letter {
            b'G' if value == 0.0 && rapid.is_none() => rapid = Some(true),
            b'G' if value == 1.0 && rapid.is_none() => rapid = Some(false),
            b'G' => return Err(DecodeError::malformed("g-code", format!("unsupported or repeated G{value}"), line)),
            b'F' if feed.is_none() => feed = Some(value),
            l => match Axis::from_letter(l) {
                Some(a) if axis.is_none() => axis = Some((a, value)),
                _ => return Err(DecodeError::malformed("g-code", format!("unexpected word {}", l as char), line)),
            },
        }
    }
    match (rapid, axis) {
        (Some(rapid), Some((axis, target))) => Ok(Command::Move { rapid, axis, target, feed }),
        (None, _) => Err(DecodeError::malformed("g-code", "no G0/G1", line)),
        (_, None) => Err(DecodeError::malformed("g-code", "no axis word", line)),
    }
}

/// Controller-side decoder: realtime bytes are taken out of the stream wherever they
/// appear (as GRBL does) and returned first; the rest is split into command lines.
#[derive(Debug, Clone)]
pub struct CommandDecoder {
    realtime: std::collections::VecDeque<Command>,
    framer: LineFramer,
}

impl Default for CommandDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl CommandDecoder {
    /// A decoder with the [`MAX_LINE`] limit.
    pub fn new() -> Self {
        CommandDecoder { realtime: Default::default(), framer: LineFramer::new(MAX_LINE) }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            match b {
                REALTIME_STATUS => self.realtime.push_back(Command::StatusQuery),
                REALTIME_FEED_HOLD => self.realtime.push_back(Command::FeedHold),
                REALTIME_RESUME => self.realtime.push_back(Command::Resume),
                REALTIME_SOFT_RESET => self.realtime.push_back(Command::SoftReset),
                _ => self.framer.push(&[b]),
            }
        }
    }

    /// The next command (realtime first), a decode error, or `None` for more bytes.
    #[allow(clippy::should_implement_trait)] // `None` means "need more bytes"
    pub fn next(&mut self) -> Option<Result<Command, DecodeError>> {
        if let Some(c) = self.realtime.pop_front() {
            return Some(Ok(c));
        }
        self.framer.next_line().map(|r| r.and_then(|l| parse_command(&l)))
    }
}

/// Machine state in a status report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Stopped, ready.
    Idle,
    /// Moving.
    Run,
    /// Feed hold (0 = complete, 1 = decelerating).
    Hold(u8),
    /// Jogging.
    Jog,
    /// Alarm lock: home (`$H`) or unlock (`$X`).
    Alarm,
    /// Safety door (substate).
    Door(u8),
    /// Check mode.
    Check,
    /// Homing cycle.
    Home,
    /// Sleep.
    Sleep,
}

impl State {
    fn encode(self) -> String {
        match self {
            State::Idle => "Idle".into(),
            State::Run => "Run".into(),
            State::Hold(n) => format!("Hold:{n}"),
            State::Jog => "Jog".into(),
            State::Alarm => "Alarm".into(),
            State::Door(n) => format!("Door:{n}"),
            State::Check => "Check".into(),
            State::Home => "Home".into(),
            State::Sleep => "Sleep".into(),
        }
    }

    fn parse(s: &str, line: &[u8]) -> Result<State, DecodeError> {
        let (name, sub) = match s.split_once(':') {
            Some((n, sub)) => {
                (n, Some(sub.parse::<u8>().map_err(|_| DecodeError::malformed("status", "bad substate", line))?))
            }
            None => (s, None),
        };
        Ok(match (name, sub) {
            ("Idle", None) => State::Idle,
            ("Run", None) => State::Run,
            ("Hold", n) => State::Hold(n.unwrap_or(0)),
            ("Jog", None) => State::Jog,
            ("Alarm", None) => State::Alarm,
            ("Door", n) => State::Door(n.unwrap_or(0)),
            ("Check", None) => State::Check,
            ("Home", None) => State::Home,
            ("Sleep", None) => State::Sleep,
            _ => return Err(DecodeError::malformed("status", format!("unknown state {s:?}"), line)),
        })
    }
}

/// A realtime status report.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// Machine state.
    pub state: State,
    /// Machine position per axis, degrees (3 or 4 values, X first).
    pub mpos: Vec<f64>,
    /// Current feed rate (`FS:` first value), if reported.
    pub feed: Option<f64>,
    /// Triggered input pins (`Pn:XP`), e.g. `X` for the X limit switch; empty if none.
    pub pins: String,
}

/// What the controller sends.
#[derive(Debug, Clone, PartialEq)]
pub enum Response {
    /// `ok`.
    Ok,
    /// `error:N` (see [`error_kind`]).
    Error(u16),
    /// `ALARM:N` (see [`alarm_kind`]); the controller is locked until `$H` or `$X`.
    Alarm(u16),
    /// `<...>` status report.
    Status(Status),
    /// `Grbl 1.1h ['$' for help]` after power-up or reset.
    Welcome {
        /// Version, e.g. `1.1h`.
        version: String,
    },
    /// `[MSG:...]` and other `[...]` feedback.
    Message(String),
    /// `$N=V` (reply to `$$`).
    Setting {
        /// Setting number.
        id: u16,
        /// Value.
        value: f64,
    },
}

impl Response {
    /// The line on the wire, with `\r\n` as GRBL sends it.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let text = match self {
            Response::Ok => "ok".to_string(),
            Response::Error(n) => format!("error:{n}"),
            Response::Alarm(n) => format!("ALARM:{n}"),
            Response::Welcome { version } => {
                check_text("version", version, |c| c.is_ascii_alphanumeric() || c == '.')?;
                format!("Grbl {version} ['$' for help]")
            }
            Response::Message(m) => {
                check_text("message", m, |c| (' '..='~').contains(&c) && c != ']' && c != '[')?;
                format!("[{m}]")
            }
            Response::Setting { id, value } => format!("${id}={}", format_decimal("setting value", *value, MAX_VALUE)?),
            Response::Status(s) => {
                if s.mpos.is_empty() || s.mpos.len() > Axis::ALL.len() {
                    return Err(EncodeError::Value {
                        field: "mpos",
                        value: format!("{} axes", s.mpos.len()),
                        allowed: "1 to 4 axes",
                    });
                }
                check_text("pins", &s.pins, |c| "XYZAPDHRS".contains(c))?;
                let pos: Result<Vec<String>, _> =
                    s.mpos.iter().map(|v| format_decimal("mpos", *v, MAX_VALUE)).collect();
                let mut t = format!("<{}|MPos:{}", s.state.encode(), pos?.join(","));
                if let Some(f) = s.feed {
                    t += &format!("|FS:{},0", format_decimal("feed", f, MAX_VALUE)?);
                }
                if !s.pins.is_empty() {
                    t += &format!("|Pn:{}", s.pins);
                }
                t + ">"
            }
        };
        let mut bytes = finish_line(text)?;
        bytes.insert(bytes.len() - 1, b'\r');
        Ok(bytes)
    }
}

fn check_text(field: &'static str, value: &str, ok: impl Fn(char) -> bool) -> Result<(), EncodeError> {
    if value.chars().all(ok) {
        Ok(())
    } else {
        Err(EncodeError::Text {
            field,
            value: value.to_string(),
            allowed: "printable ASCII without the framing characters",
        })
    }
}

/// Parses one controller line.
pub fn parse_response(line: &[u8]) -> Result<Response, DecodeError> {
    let text = ascii("response", line)?.trim();
    if text == "ok" {
        return Ok(Response::Ok);
    }
    let number = |s: &str, what| s.parse::<u16>().map_err(|_| DecodeError::malformed(what, "bad code", line));
    if let Some(n) = text.strip_prefix("error:") {
        return Ok(Response::Error(number(n, "error")?));
    }
    if let Some(n) = text.strip_prefix("ALARM:") {
        return Ok(Response::Alarm(number(n, "alarm")?));
    }
    if let Some(rest) = text.strip_prefix("Grbl ") {
        let version = rest.split(' ').next().unwrap_or("");
        if version.is_empty() || !version.chars().all(|c| c.is_ascii_alphanumeric() || c == '.') {
            return Err(DecodeError::malformed("welcome", "bad version", line));
        }
        return Ok(Response::Welcome { version: version.to_string() });
    }
    if let Some(m) = text.strip_prefix('[').and_then(|t| t.strip_suffix(']')) {
        return Ok(Response::Message(m.to_string()));
    }
    if let Some(rest) = text.strip_prefix('$') {
        let (id, value) =
            rest.split_once('=').ok_or_else(|| DecodeError::malformed("setting", "expected $N=V", line))?;
        return Ok(Response::Setting { id: number(id, "setting")?, value: decimal("setting value", value)? });
    }
    if let Some(body) = text.strip_prefix('<').and_then(|t| t.strip_suffix('>')) {
        let mut fields = body.split('|');
        let state = State::parse(fields.next().unwrap_or(""), line)?;
        let (mut mpos, mut feed, mut pins) = (None, None, String::new());
        for f in fields {
            if let Some(p) = f.strip_prefix("MPos:") {
                let v: Result<Vec<f64>, _> = p.split(',').map(|t| decimal("MPos", t)).collect();
                let v = v?;
                if v.len() > Axis::ALL.len() {
                    return Err(DecodeError::malformed("status", "more than 4 axes", line));
                }
                mpos = Some(v);
            } else if let Some(fs) = f.strip_prefix("FS:").or_else(|| f.strip_prefix("F:")) {
                feed = Some(decimal("FS", fs.split(',').next().unwrap_or(""))?);
            } else if let Some(p) = f.strip_prefix("Pn:") {
                pins = p.to_string();
            }
            // Other fields (Bf, Ln, WCO, Ov, A) are valid GRBL and ignored.
        }
        let mpos = mpos.ok_or_else(|| DecodeError::malformed("status", "no MPos field", line))?;
        return Ok(Response::Status(Status { state, mpos, feed, pins }));
    }
    Err(DecodeError::malformed("response", "unknown response", line))
}

/// Host-side decoder of controller lines.
pub type ResponseDecoder = LineDecoder<Response>;

impl ResponseDecoder {
    /// A decoder with the [`MAX_LINE`] limit.
    pub fn new() -> Self {
        LineDecoder::with_parser(MAX_LINE, parse_response)
    }
}

impl Default for ResponseDecoder {
    fn default() -> Self {
        Self::new()
    }
}

/// GRBL 1.1 `error:N` meaning.
pub fn error_text(code: u16) -> &'static str {
    match code {
        1 => "G-code words consist of a letter and a value; letter was not found",
        2 => "numeric value format is not valid or missing an expected value",
        3 => "'$' system command was not recognised or supported",
        4 => "negative value received for an expected positive value",
        5 => "homing cycle is not enabled via settings",
        6 => "minimum step pulse time must be greater than 3 us",
        7 => "EEPROM read failed; reset and restored to default values",
        8 => "'$' command cannot be used unless Grbl is idle",
        9 => "G-code locked out during alarm or jog state",
        10 => "soft limits cannot be enabled without homing also enabled",
        11 => "max characters per line exceeded; line was not processed",
        12 => "'$' setting value exceeds the maximum step rate supported",
        13 => "safety door detected as opened and door state initiated",
        14 => "build info or startup line exceeded EEPROM line length limit",
        15 => "jog target exceeds machine travel",
        16 => "jog command with no '=' or contains prohibited g-code",
        17 => "laser mode requires PWM output",
        20 => "unsupported or invalid g-code command found in block",
        21 => "more than one g-code command from same modal group found in block",
        22 => "feed rate has not yet been set or is undefined",
        23 => "g-code command in block requires an integer value",
        24 => "two g-code commands that both require the use of the XYZ axis words",
        25 => "a g-code word was repeated in the block",
        26 => "a g-code command implicitly or explicitly requires XYZ axis words in the block, but none were detected",
        27 => "N line number value is not within the valid range of 1 - 9,999,999",
        28 => "a g-code command was sent, but is missing some required P or L value words",
        29 => "Grbl supports six work coordinate systems G54-G59; G59.1, G59.2, and G59.3 are not supported",
        30 => "the G53 g-code command requires either a G0 seek or G1 feed motion mode to be active",
        31 => "there are unused axis words in the block and G80 motion mode cancel is active",
        32 => "a G2 or G3 arc was commanded but there are no XYZ axis words in the selected plane",
        33 => "the motion command has an invalid target",
        34 => "a G2 or G3 arc, traced with the radius definition, had a mathematical error",
        35 => "a G2 or G3 arc, traced with the offset definition, is missing the IJK offset word",
        36 => "there are unused, leftover g-code words that aren't used by any command in the block",
        37 => "the G43.1 dynamic tool length offset command cannot apply an offset to an axis other than its configured axis",
        38 => "tool number greater than max supported value",
        _ => "unknown error code",
    }
}

/// How the host should treat `error:N`.
///
/// A line damaged on the wire reads to GRBL as a bad word or number (1, 2) or an overlong
/// line (11); our encoder never produces those (the round-trip fuzz test), so they mean
/// transmission damage and are retryable ([`ErrorKind::CorruptData`]). 9 is the alarm lock
/// after power-up or an alarm: home first. 8 means a motion is still running.
pub fn error_kind(code: u16) -> ErrorKind {
    match code {
        1 | 2 | 11 => ErrorKind::CorruptData,
        8 => ErrorKind::Busy,
        9 => ErrorKind::NotHomed,
        15 | 33 => ErrorKind::OutOfRange,
        5 | 10 | 17 => ErrorKind::Unsupported,
        _ => ErrorKind::Other,
    }
}

/// GRBL 1.1 `ALARM:N` meaning.
pub fn alarm_text(code: u16) -> &'static str {
    match code {
        1 => "hard limit triggered; machine position is likely lost, re-homing is highly recommended",
        2 => "soft limit alarm: G-code motion target exceeds machine travel; machine position retained",
        3 => "reset while in motion; position is likely lost, re-homing is highly recommended",
        4 => "probe fail: the probe is not in the expected initial state",
        5 => "probe fail: the probe did not contact the workpiece",
        6 => "homing fail: reset during active homing cycle",
        7 => "homing fail: safety door was opened during active homing cycle",
        8 => "homing fail: cycle failed to clear limit switch when pulling off",
        9 => "homing fail: could not find limit switch within search distance",
        _ => "unknown alarm code",
    }
}

/// How the host should treat `ALARM:N`. No alarm is retryable as is: a soft limit means
/// the request was wrong; a reset in motion lost the position (home again); a hard limit
/// or a failed homing cycle needs a person.
pub fn alarm_kind(code: u16) -> ErrorKind {
    match code {
        2 => ErrorKind::OutOfRange,
        3 | 6 => ErrorKind::NotHomed,
        _ => ErrorKind::Other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> Vec<Result<Response, DecodeError>> {
        let mut d = ResponseDecoder::new();
        d.push(bytes);
        std::iter::from_fn(|| d.next()).collect()
    }

    #[test]
    fn command_byte_vectors() {
        let cases: [(Command, &[u8]); 10] = [
            (Command::Move { rapid: true, axis: Axis::X, target: 12.5, feed: None }, b"G0 X12.5\n"),
            (Command::Move { rapid: false, axis: Axis::A, target: -90.0, feed: Some(300.0) }, b"G1 A-90 F300\n"),
            (Command::Home, b"$H\n"),
            (Command::Unlock, b"$X\n"),
            (Command::ListSettings, b"$$\n"),
            (Command::Setting { id: 130, value: 180.0 }, b"$130=180\n"),
            (Command::StatusQuery, b"?"),
            (Command::FeedHold, b"!"),
            (Command::Resume, b"~"),
            (Command::SoftReset, b"\x18"),
        ];
        for (cmd, bytes) in cases {
            assert_eq!(cmd.encode().unwrap(), bytes, "{cmd:?}");
            let mut d = CommandDecoder::new();
            d.push(bytes);
            assert_eq!(d.next().unwrap().unwrap(), cmd);
            assert!(d.next().is_none());
        }
    }

    #[test]
    fn commands_in_grbl_spellings() {
        assert_eq!(
            parse_command(b"g1x10.5f300").unwrap(),
            Command::Move { rapid: false, axis: Axis::X, target: 10.5, feed: Some(300.0) }
        );
        assert_eq!(
            parse_command(b"G0 X.5").unwrap(),
            Command::Move { rapid: true, axis: Axis::X, target: 0.5, feed: None }
        );
        for bad in [
            &b"G2 X1"[..],
            b"G0",
            b"X10",
            b"G0 X1 X2",
            b"G0 Q1",
            b"G0 Xabc",
            b"$130",
            b"$a=1",
            b"G0 X1e3",
            b"\xffG0 X1",
        ] {
            assert!(parse_command(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
    }

    #[test]
    fn realtime_bytes_cut_out_of_a_line() {
        // `?` arrives in the middle of a line being typed: GRBL answers it at once and
        // the line stays whole.
        let mut d = CommandDecoder::new();
        d.push(b"G0 X1?0\n!");
        assert_eq!(d.next().unwrap().unwrap(), Command::StatusQuery);
        assert_eq!(d.next().unwrap().unwrap(), Command::FeedHold);
        assert_eq!(d.next().unwrap().unwrap(), Command::Move { rapid: true, axis: Axis::X, target: 10.0, feed: None });
        assert!(d.next().is_none());
    }

    #[test]
    fn response_byte_vectors() {
        let cases: Vec<(Response, &[u8])> = vec![
            (Response::Ok, b"ok\r\n"),
            (Response::Error(9), b"error:9\r\n"),
            (Response::Alarm(2), b"ALARM:2\r\n"),
            (Response::Welcome { version: "1.1h".into() }, b"Grbl 1.1h ['$' for help]\r\n"),
            (Response::Message("MSG:'$H'|'$X' to unlock".into()), b"[MSG:'$H'|'$X' to unlock]\r\n"),
            (Response::Setting { id: 130, value: 180.0 }, b"$130=180\r\n"),
            (
                Response::Status(Status {
                    state: State::Idle,
                    mpos: vec![12.5, 0.0, 0.0],
                    feed: Some(0.0),
                    pins: String::new(),
                }),
                b"<Idle|MPos:12.5,0,0|FS:0,0>\r\n",
            ),
            (
                Response::Status(Status {
                    state: State::Hold(1),
                    mpos: vec![-3.25, 0.0, 0.0],
                    feed: None,
                    pins: "X".into(),
                }),
                b"<Hold:1|MPos:-3.25,0,0|Pn:X>\r\n",
            ),
        ];
        for (r, bytes) in cases {
            assert_eq!(r.encode().unwrap(), bytes, "{r:?}");
            assert_eq!(decode_all(bytes), vec![Ok(r)]);
        }
    }

    #[test]
    fn real_grbl_status_with_extra_fields() {
        let r = parse_response(b"<Run|MPos:1.000,2.000,3.000|Bf:15,128|FS:500,0|WCO:0.000,0.000,0.000>").unwrap();
        assert_eq!(
            r,
            Response::Status(Status {
                state: State::Run,
                mpos: vec![1.0, 2.0, 3.0],
                feed: Some(500.0),
                pins: String::new()
            })
        );
    }

    #[test]
    fn malformed_truncated_and_oversized_responses() {
        for bad in [
            &b"error:"[..],
            b"error:x",
            b"ALARM:-1",
            b"<Idle>",
            b"<Bogus|MPos:1>",
            b"<Idle|MPos:1,,2>",
            b"okay",
            b"Grbl ",
            b"$130",
        ] {
            assert!(parse_response(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
        // Truncated: no line end yet, so nothing; the rest completes it.
        let mut d = ResponseDecoder::new();
        d.push(b"<Idle|MPos:1");
        assert!(d.next().is_none());
        d.push(b",0,0>\r\n");
        assert!(matches!(d.next(), Some(Ok(Response::Status(_)))));
        // Oversized then valid.
        let mut long = vec![b'a'; MAX_LINE + 1];
        long.extend_from_slice(b"\nok\n");
        assert_eq!(
            decode_all(&long),
            vec![Err(DecodeError::Oversized { what: "line", limit: MAX_LINE }), Ok(Response::Ok)]
        );
    }

    #[test]
    fn garbage_then_valid_split_at_every_offset() {
        let stream = b"\x00\x13\xfe}{noise\r\nok\r\n<Idle|MPos:5,0,0>\r\nerror:2\r\n";
        for cut in 0..=stream.len() {
            let mut d = ResponseDecoder::new();
            let mut got = Vec::new();
            d.push(&stream[..cut]);
            got.extend(std::iter::from_fn(|| d.next()));
            d.push(&stream[cut..]);
            got.extend(std::iter::from_fn(|| d.next()));
            assert_eq!(got.len(), 4, "cut {cut}");
            assert!(got[0].is_err());
            assert_eq!(got[1], Ok(Response::Ok));
            assert_eq!(got[3], Ok(Response::Error(2)));
        }
    }

    #[test]
    fn encoder_refuses_what_it_cannot_send() {
        assert!(Command::Move { rapid: true, axis: Axis::X, target: f64::NAN, feed: None }.encode().is_err());
        assert!(Command::Move { rapid: false, axis: Axis::X, target: 1.0, feed: Some(0.0) }.encode().is_err());
        assert!(Response::Message("a]b".into()).encode().is_err());
        assert!(Response::Status(Status { state: State::Idle, mpos: vec![], feed: None, pins: String::new() })
            .encode()
            .is_err());
    }

    #[test]
    fn error_and_alarm_kinds() {
        assert!(error_kind(2).is_retryable());
        assert!(error_kind(8).is_retryable());
        assert_eq!(error_kind(9), ErrorKind::NotHomed);
        assert_eq!(error_kind(33), ErrorKind::OutOfRange);
        assert!(!error_kind(20).is_retryable());
        assert_eq!(alarm_kind(2), ErrorKind::OutOfRange);
        assert_eq!(alarm_kind(1), ErrorKind::Other);
        for n in 0..=40 {
            assert!(!error_text(n).is_empty());
            assert!(!alarm_kind(n).is_retryable(), "alarm {n}");
        }
    }
}
