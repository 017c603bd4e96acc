//! Fiducial marker dictionaries, embedded as data.
//!
//! `calibration/markers/DICT_4X4_50.txt` holds the bit patterns of OpenCV's ArUco dictionary
//! `DICT_4X4_50`, dumped from OpenCV itself (the file's header says how and in which bit
//! order), so the rendered markers are exactly the ones an independent ArUco detector reads.

/// One marker dictionary: `bits[id]` is the `size x size` data grid, row-major from the
/// marker's top-left data module; `true` = white.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerDictionary {
    /// OpenCV name, e.g. `DICT_4X4_50`.
    pub name: String,
    /// Data modules per side (4 for a 4x4 dictionary).
    pub size: usize,
    /// Data bits of each marker id.
    pub bits: Vec<Vec<bool>>,
}

const DICT_4X4_50: &str = include_str!("../../../calibration/markers/DICT_4X4_50.txt");

impl MarkerDictionary {
    /// The dictionary called `name`, or `None` if it is not shipped.
    pub fn by_name(name: &str) -> Option<MarkerDictionary> {
        match name {
            "DICT_4X4_50" => Some(Self::parse(name, 4, DICT_4X4_50)),
            _ => None,
        }
    }

    fn parse(name: &str, size: usize, text: &str) -> MarkerDictionary {
        let mut bits = Vec::new();
        for line in text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()) {
            let mut parts = line.split_whitespace();
            let id: usize = parts.next().and_then(|s| s.parse().ok()).expect("embedded dictionary: id");
            let b = parts.next().expect("embedded dictionary: bits");
            assert_eq!(id, bits.len(), "embedded dictionary ids are consecutive");
            assert_eq!(b.len(), size * size, "embedded dictionary: bit count");
            bits.push(b.bytes().map(|c| c == b'1').collect());
        }
        MarkerDictionary { name: name.into(), size, bits }
    }

    /// Modules across a whole marker: the data grid plus one black border module each side.
    pub fn modules(&self) -> usize {
        self.size + 2
    }

    /// Whether module (`row`, `col`) of marker `id` is white; rows and columns count over the
    /// whole marker including its black border (`0..modules()`), row 0 at the marker's top.
    pub fn is_white(&self, id: usize, row: usize, col: usize) -> bool {
        let m = self.modules();
        if row == 0 || col == 0 || row + 1 >= m || col + 1 >= m {
            return false;
        }
        self.bits[id][(row - 1) * self.size + (col - 1)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dictionary_has_fifty_distinct_markers() {
        let d = MarkerDictionary::by_name("DICT_4X4_50").unwrap();
        assert_eq!(d.bits.len(), 50);
        for a in 0..50 {
            for b in 0..a {
                assert_ne!(d.bits[a], d.bits[b], "markers {a} and {b} are equal");
            }
        }
        // Marker 0 as OpenCV draws it (first data row 1011).
        assert_eq!(&d.bits[0][..4], &[true, false, true, true]);
        assert!(!d.is_white(0, 0, 3) && !d.is_white(0, 5, 2));
        assert!(MarkerDictionary::by_name("DICT_9X9_1").is_none());
    }
}
