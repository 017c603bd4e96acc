//! ArUco-style marker dictionaries: the data bits of every marker id.
//!
//! The shipped dictionary is read from `calibration/markers/DICT_4X4_50.txt` (dumped from
//! OpenCV; its header gives the bit order). The renderer (`btfrig-render`) keeps its own copy
//! of the parser for drawing the plate; a test of this crate checks that both agree.

/// Why a dictionary text cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DictionaryError {
    /// A line is not `<id> <bits>` with consecutive ids and `size * size` bits of `0`/`1`.
    #[error("dictionary {name}: line {line}: {why}: {text:?}")]
    BadLine {
        /// Dictionary name.
        name: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        why: &'static str,
        /// The line's text.
        text: String,
    },
    /// The size is outside 2..=8 (codes are packed into a `u64`).
    #[error("dictionary {name}: data size {size} not in 2..=8")]
    BadSize {
        /// Dictionary name.
        name: String,
        /// Requested size.
        size: usize,
    },
    /// No marker in the text.
    #[error("dictionary {name}: no markers")]
    Empty {
        /// Dictionary name.
        name: String,
    },
}

/// A marker dictionary: `codes[id]` holds the `size x size` data bits of marker `id`,
/// row-major from the marker's top-left data module (row 0 = top row of the marker image,
/// as OpenCV draws it), bit `i` of the `u64` is data module `i`, `1` = white.
#[derive(Debug, Clone, PartialEq)]
pub struct Dictionary {
    /// OpenCV name, e.g. `DICT_4X4_50`.
    pub name: String,
    /// Data modules per side (4 for a 4x4 dictionary); a marker has `size + 2` modules
    /// per side with its one-module black border.
    pub size: usize,
    /// Data bits of each id.
    pub codes: Vec<u64>,
}

const DICT_4X4_50: &str = include_str!("../../../calibration/markers/DICT_4X4_50.txt");

impl Dictionary {
    /// OpenCV's `DICT_4X4_50`, embedded.
    pub fn dict_4x4_50() -> Dictionary {
        Self::parse("DICT_4X4_50", 4, DICT_4X4_50).expect("embedded DICT_4X4_50 parses")
    }

    /// The shipped dictionary called `name`, or `None`.
    pub fn by_name(name: &str) -> Option<Dictionary> {
        (name == "DICT_4X4_50").then(Self::dict_4x4_50)
    }

    /// Parses the text format of `calibration/markers/*.txt`: `#` comment lines, then one
    /// line `<id> <size*size bits>` per marker with ids `0, 1, 2, ...`.
    pub fn parse(name: &str, size: usize, text: &str) -> Result<Dictionary, DictionaryError> {
        if !(2..=8).contains(&size) {
            return Err(DictionaryError::BadSize { name: name.into(), size });
        }
        let mut codes = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let t = line.trim();
            if t.is_empty() || t.starts_with('#') {
                continue;
            }
            let bad = |why| DictionaryError::BadLine { name: name.into(), line: n + 1, why, text: line.into() };
            let mut parts = t.split_whitespace();
            let id: usize = parts.next().and_then(|s| s.parse().ok()).ok_or_else(|| bad("no integer id"))?;
            if id != codes.len() {
                return Err(bad("ids must be consecutive from 0"));
            }
            let bits = parts.next().ok_or_else(|| bad("no bits"))?;
            if bits.len() != size * size || parts.next().is_some() {
                return Err(bad("wrong number of bits"));
            }
            let mut code = 0u64;
            for (i, c) in bits.bytes().enumerate() {
                match c {
                    b'1' => code |= 1 << i,
                    b'0' => {}
                    _ => return Err(bad("bits must be 0 or 1")),
                }
            }
            codes.push(code);
        }
        if codes.is_empty() {
            return Err(DictionaryError::Empty { name: name.into() });
        }
        Ok(Dictionary { name: name.into(), size, codes })
    }

    /// Whether data module (`row`, `col`) (`0..size`) of marker `id` is white.
    pub fn is_white(&self, id: usize, row: usize, col: usize) -> bool {
        self.codes[id] >> (row * self.size + col) & 1 == 1
    }

    /// `code` as seen after turning the marker a quarter turn: the data module at
    /// (`row`, `col`) of the result is module (`col`, `size - 1 - row`) of `code`, i.e. the
    /// grid read starting from the marker's corner 1 instead of corner 0.
    pub fn rotate(&self, code: u64) -> u64 {
        let n = self.size;
        let mut out = 0u64;
        for r in 0..n {
            for c in 0..n {
                if code >> (c * n + (n - 1 - r)) & 1 == 1 {
                    out |= 1 << (r * n + c);
                }
            }
        }
        out
    }

    /// Smallest Hamming distance between two different codes over all rotations (and
    /// between a code and its own non-trivial rotations): the dictionary's error margin.
    pub fn min_distance(&self) -> u32 {
        let mut best = u32::MAX;
        for (a, &ca) in self.codes.iter().enumerate() {
            let mut r = ca;
            for k in 0..4 {
                for (b, &cb) in self.codes.iter().enumerate() {
                    if a == b && k == 0 {
                        continue;
                    }
                    best = best.min((r ^ cb).count_ones());
                }
                r = self.rotate(r);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dict_4x4_50_parses_and_separates_codes() {
        let d = Dictionary::dict_4x4_50();
        assert_eq!(d.codes.len(), 50);
        // Marker 0, first data row as OpenCV draws it: 1011.
        assert!(d.is_white(0, 0, 0) && !d.is_white(0, 0, 1) && d.is_white(0, 0, 2) && d.is_white(0, 0, 3));
        // Four quarter turns are the identity.
        for &c in &d.codes {
            assert_eq!(d.rotate(d.rotate(d.rotate(d.rotate(c)))), c);
        }
        // One corrected bit (OpenCV's maxCorrectionBits = 1) needs a distance of at least 3.
        assert!(d.min_distance() >= 3, "min distance {}", d.min_distance());
    }

    #[test]
    fn bad_text_is_rejected_with_the_line() {
        let e = Dictionary::parse("X", 2, "0 0101\n2 1111\n").unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        assert!(Dictionary::parse("X", 2, "0 01x1\n").is_err());
        assert!(Dictionary::parse("X", 2, "# nothing\n").is_err());
        assert!(Dictionary::parse("X", 9, "").is_err());
    }
}
