//! Line framing shared by the text protocols: lines end in `\n` (a `\r` before it is
//! dropped), blank lines are skipped, a line longer than the limit is rejected once and
//! discarded up to its end, so the decoder resynchronises at the next line.

use crate::DecodeError;

/// Splits a byte stream into lines of at most `max_len` bytes (without the line end).
#[derive(Debug, Clone)]
pub struct LineFramer {
    buf: Vec<u8>,
    max_len: usize,
    /// Inside an oversized line already reported: drop bytes up to the next `\n`.
    discarding: bool,
}

impl LineFramer {
    /// A framer for lines of at most `max_len` bytes.
    pub fn new(max_len: usize) -> Self {
        LineFramer { buf: Vec::new(), max_len, discarding: false }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held that do not yet end in a line end.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Drops everything buffered (after a reconnect: half a line from before is garbage).
    pub fn clear(&mut self) {
        self.buf.clear();
        self.discarding = false;
    }

    /// The next complete line, an [`DecodeError::Oversized`] for a line over the limit, or
    /// `None` when more bytes are needed.
    pub fn next_line(&mut self) -> Option<Result<Vec<u8>, DecodeError>> {
        loop {
            match self.buf.iter().position(|&b| b == b'\n') {
                Some(end) => {
                    let mut line: Vec<u8> = self.buf.drain(..=end).collect();
                    line.pop();
                    if line.last() == Some(&b'\r') {
                        line.pop();
                    }
                    if std::mem::take(&mut self.discarding) {
                        continue;
                    }
                    if line.len() > self.max_len {
                        return Some(Err(DecodeError::Oversized { what: "line", limit: self.max_len }));
                    }
                    if line.is_empty() {
                        continue;
                    }
                    return Some(Ok(line));
                }
                None => {
                    if self.buf.len() > self.max_len + 1 {
                        // Keep memory bounded: report once, then drop until the line ends.
                        self.buf.clear();
                        if !std::mem::replace(&mut self.discarding, true) {
                            return Some(Err(DecodeError::Oversized { what: "line", limit: self.max_len }));
                        }
                    }
                    return None;
                }
            }
        }
    }
}

/// A framer plus a parser: the incremental decoder of one text protocol's messages.
#[derive(Debug, Clone)]
pub struct LineDecoder<T> {
    framer: LineFramer,
    parse: fn(&[u8]) -> Result<T, DecodeError>,
}

impl<T> LineDecoder<T> {
    /// A decoder for lines of at most `max_len` bytes, each parsed by `parse`.
    pub fn with_parser(max_len: usize, parse: fn(&[u8]) -> Result<T, DecodeError>) -> Self {
        LineDecoder { framer: LineFramer::new(max_len), parse }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.framer.push(bytes);
    }

    /// Drops everything buffered.
    pub fn clear(&mut self) {
        self.framer.clear();
    }

    /// Bytes buffered that do not yet form a line.
    pub fn pending(&self) -> usize {
        self.framer.pending()
    }

    /// The next message, a decode error (the offending line is already skipped), or `None`
    /// when more bytes are needed.
    #[allow(clippy::should_implement_trait)] // not an Iterator: `None` means "need more bytes", not "done"
    pub fn next(&mut self) -> Option<Result<T, DecodeError>> {
        self.framer.next_line().map(|r| r.and_then(|line| (self.parse)(&line)))
    }
}

/// The line as ASCII text, or a [`DecodeError::Malformed`] naming the first byte that is
/// not printable ASCII (tab allowed).
pub fn ascii<'a>(what: &'static str, line: &'a [u8]) -> Result<&'a str, DecodeError> {
    if let Some(i) = line.iter().position(|&b| !(b == b'\t' || (0x20..0x7f).contains(&b))) {
        return Err(DecodeError::malformed(what, format!("byte {:#04x} at {i} is not printable ASCII", line[i]), line));
    }
    // All bytes are ASCII, so this cannot fail; map anyway rather than unwrap.
    std::str::from_utf8(line).map_err(|_| DecodeError::malformed(what, "not UTF-8", line))
}

/// Parses a plain decimal number (`-12.5`, `.5`, `3`): digits, one point, a leading sign.
/// Rejects what `f64::from_str` would also take (`inf`, `NaN`, `1e5`) so a damaged line
/// never yields a surprising value.
pub fn decimal(what: &'static str, token: &str) -> Result<f64, DecodeError> {
    let digits = token.strip_prefix(['-', '+']).unwrap_or(token);
    let ok = !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && digits.bytes().filter(|&b| b == b'.').count() <= 1
        && digits.bytes().any(|b| b.is_ascii_digit());
    if !ok {
        return Err(DecodeError::malformed(what, "not a decimal number", token.as_bytes()));
    }
    token.parse().map_err(|_| DecodeError::malformed(what, "not a decimal number", token.as_bytes()))
}

/// Formats `v` as the shortest decimal that parses back to exactly `v` (Rust's `Display`
/// for `f64`), rejecting non-finite values and magnitudes of `max_abs` or more.
pub fn format_decimal(field: &'static str, v: f64, max_abs: f64) -> Result<String, crate::EncodeError> {
    if !v.is_finite() || v.abs() >= max_abs {
        return Err(crate::EncodeError::Value {
            field,
            value: v.to_string(),
            allowed: "a finite number of moderate magnitude",
        });
    }
    // Display never uses an exponent, but prints tiny values with many zeros; round
    // magnitudes below 1e-30 to zero (at most ~50 characters per number). Not 1e-12: the
    // planner's inverse kinematics yields joint targets such as 4.2e-17 rad (cos(pi/2)
    // residues), and a host and an emulated controller must agree on them bit for bit.
    let v = if v.abs() < 1e-30 { 0.0 } else { v };
    Ok(format!("{v}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(f: &mut LineFramer) -> Vec<Result<Vec<u8>, DecodeError>> {
        std::iter::from_fn(|| f.next_line()).collect()
    }

    #[test]
    fn splits_crlf_and_lf_and_skips_blank() {
        let mut f = LineFramer::new(16);
        f.push(b"ab\r\n\n\r\ncd\nef");
        assert_eq!(lines(&mut f), vec![Ok(b"ab".to_vec()), Ok(b"cd".to_vec())]);
        assert_eq!(f.pending(), 2);
        f.push(b"\n");
        assert_eq!(lines(&mut f), vec![Ok(b"ef".to_vec())]);
    }

    #[test]
    fn oversized_reported_once_then_resynchronised() {
        let mut f = LineFramer::new(4);
        f.push(b"0123456789");
        assert_eq!(lines(&mut f), vec![Err(DecodeError::Oversized { what: "line", limit: 4 })]);
        f.push(b"more garbage without end");
        assert_eq!(lines(&mut f), vec![]);
        f.push(b"x\nok\n");
        assert_eq!(lines(&mut f), vec![Ok(b"ok".to_vec())]);
        // A complete long line in one push is reported too.
        f.push(b"12345\nok\n");
        assert_eq!(lines(&mut f), vec![Err(DecodeError::Oversized { what: "line", limit: 4 }), Ok(b"ok".to_vec())]);
        // Exactly the limit passes.
        f.push(b"1234\r\n");
        assert_eq!(lines(&mut f), vec![Ok(b"1234".to_vec())]);
    }

    #[test]
    fn decimal_accepts_plain_numbers_only() {
        assert_eq!(decimal("x", "-12.5").unwrap(), -12.5);
        assert_eq!(decimal("x", ".5").unwrap(), 0.5);
        assert_eq!(decimal("x", "+3").unwrap(), 3.0);
        for bad in ["", "-", ".", "1.2.3", "inf", "NaN", "1e5", "0x10", "--1"] {
            assert!(decimal("x", bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn format_decimal_round_trips_exactly() {
        for v in [
            0.1,
            -1.0 / 3.0,
            123.456_789_012_345_67,
            1e-9,
            179.999_999_999_999_97,
            -4.163_336_342_344_337_6e-17,
            1.110_223_024_625_156_8e-16,
        ] {
            let s = format_decimal("v", v, 1e9).unwrap();
            assert_eq!(decimal("v", &s).unwrap(), v, "{s}");
        }
        assert!(format_decimal("v", f64::NAN, 1e9).is_err());
        assert!(format_decimal("v", 1e9, 1e9).is_err());
    }
}
