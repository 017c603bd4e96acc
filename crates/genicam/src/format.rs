//! The pixel formats btfrig reads from GenICam cameras: monochrome and Bayer, 8, 12 and 16
//! bits, unpacked (12-bit samples in the low bits of 16-bit little-endian words, as GenICam's
//! PFNC defines `Mono12` / `BayerRG12`). Packed formats (`Mono12p`) are not offered: a camera
//! that has only those is refused at open with the list it has.

use btfrig_core::frame::BayerPattern;

/// A pixel format by its PFNC code (the value of the `PixelFormat` feature).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// Monochrome, `bits` per sample (8, 12 or 16).
    Mono {
        /// Bits per sample.
        bits: u8,
    },
    /// A Bayer mosaic, `bits` per sample (8, 12 or 16).
    Bayer {
        /// The colour filter array, from the top-left photosite.
        pattern: BayerPattern,
        /// Bits per sample.
        bits: u8,
    },
}

/// Every format of [`PixelFormat`] with its PFNC name and code.
pub const FORMATS: &[(&str, u32, PixelFormat)] = &[
    ("Mono8", 0x0108_0001, PixelFormat::Mono { bits: 8 }),
    ("Mono12", 0x0110_0005, PixelFormat::Mono { bits: 12 }),
    ("Mono16", 0x0110_0007, PixelFormat::Mono { bits: 16 }),
    ("BayerGR8", 0x0108_0008, PixelFormat::Bayer { pattern: BayerPattern::Grbg, bits: 8 }),
    ("BayerRG8", 0x0108_0009, PixelFormat::Bayer { pattern: BayerPattern::Rggb, bits: 8 }),
    ("BayerGB8", 0x0108_000a, PixelFormat::Bayer { pattern: BayerPattern::Gbrg, bits: 8 }),
    ("BayerBG8", 0x0108_000b, PixelFormat::Bayer { pattern: BayerPattern::Bggr, bits: 8 }),
    ("BayerGR12", 0x0110_0010, PixelFormat::Bayer { pattern: BayerPattern::Grbg, bits: 12 }),
    ("BayerRG12", 0x0110_0011, PixelFormat::Bayer { pattern: BayerPattern::Rggb, bits: 12 }),
    ("BayerGB12", 0x0110_0012, PixelFormat::Bayer { pattern: BayerPattern::Gbrg, bits: 12 }),
    ("BayerBG12", 0x0110_0013, PixelFormat::Bayer { pattern: BayerPattern::Bggr, bits: 12 }),
    ("BayerGR16", 0x0110_002e, PixelFormat::Bayer { pattern: BayerPattern::Grbg, bits: 16 }),
    ("BayerRG16", 0x0110_002f, PixelFormat::Bayer { pattern: BayerPattern::Rggb, bits: 16 }),
    ("BayerGB16", 0x0110_0030, PixelFormat::Bayer { pattern: BayerPattern::Gbrg, bits: 16 }),
    ("BayerBG16", 0x0110_0031, PixelFormat::Bayer { pattern: BayerPattern::Bggr, bits: 16 }),
];

impl PixelFormat {
    /// The format of a PFNC code, if btfrig reads it.
    pub fn from_code(code: u32) -> Option<PixelFormat> {
        FORMATS.iter().find(|(_, c, _)| *c == code).map(|(_, _, f)| *f)
    }

    /// The format of a PFNC name (`BayerRG12`), if btfrig reads it.
    pub fn from_name(name: &str) -> Option<PixelFormat> {
        FORMATS.iter().find(|(n, _, _)| *n == name).map(|(_, _, f)| *f)
    }

    /// The names btfrig reads, for messages.
    pub fn names() -> Vec<&'static str> {
        FORMATS.iter().map(|(n, _, _)| *n).collect()
    }

    fn entry(self) -> &'static (&'static str, u32, PixelFormat) {
        FORMATS.iter().find(|(_, _, f)| *f == self).expect("every PixelFormat value is in FORMATS")
    }

    /// The PFNC name.
    pub fn name(self) -> &'static str {
        self.entry().0
    }

    /// The PFNC code.
    pub fn code(self) -> u32 {
        self.entry().1
    }

    /// Significant bits per sample.
    pub fn bits(self) -> u8 {
        match self {
            PixelFormat::Mono { bits } | PixelFormat::Bayer { bits, .. } => bits,
        }
    }

    /// Bytes per sample on the wire: 1 for 8-bit formats, 2 (little-endian) otherwise.
    pub fn bytes_per_sample(self) -> usize {
        if self.bits() == 8 {
            1
        } else {
            2
        }
    }

    /// The colour filter array, `None` for monochrome.
    pub fn bayer(self) -> Option<BayerPattern> {
        match self {
            PixelFormat::Mono { .. } => None,
            PixelFormat::Bayer { pattern, .. } => Some(pattern),
        }
    }

    /// The 16-bit format of the same layout (`BayerRG16` for `BayerRG12`).
    pub fn widened(self) -> PixelFormat {
        match self {
            PixelFormat::Mono { .. } => PixelFormat::Mono { bits: 16 },
            PixelFormat::Bayer { pattern, .. } => PixelFormat::Bayer { pattern, bits: 16 },
        }
    }

    /// Bytes of a `width` x `height` image.
    pub fn image_bytes(self, width: usize, height: usize) -> usize {
        width * height * self.bytes_per_sample()
    }

    /// The samples of an image as it arrived, one `u16` each; `None` if `bytes` is not
    /// `width` x `height` samples long. A sample beyond the format's bits is kept as it is (the
    /// caller checks the range: [`btfrig_hw::verify_frame`]).
    pub fn unpack(self, bytes: &[u8], width: usize, height: usize) -> Option<Vec<u16>> {
        if bytes.len() != self.image_bytes(width, height) {
            return None;
        }
        Some(match self.bytes_per_sample() {
            1 => bytes.iter().map(|&b| u16::from(b)).collect(),
            _ => bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect(),
        })
    }

    /// Samples as bytes on the wire (the inverse of [`PixelFormat::unpack`]); `None` if a
    /// sample does not fit the format's bits.
    pub fn pack(self, samples: &[u16]) -> Option<Vec<u8>> {
        let max = if self.bits() >= 16 { u16::MAX } else { (1u16 << self.bits()) - 1 };
        if samples.iter().any(|&s| s > max) {
            return None;
        }
        Some(match self.bytes_per_sample() {
            1 => samples.iter().map(|&s| s as u8).collect(),
            _ => samples.iter().flat_map(|s| s.to_le_bytes()).collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_codes_round_trip() {
        for (name, code, f) in FORMATS {
            assert_eq!(PixelFormat::from_code(*code), Some(*f));
            assert_eq!(PixelFormat::from_name(name), Some(*f));
            assert_eq!((f.name(), f.code()), (*name, *code));
            // PFNC: bits 16..24 of the code are the bits a sample occupies.
            assert_eq!(((code >> 16) & 0xff) as usize, 8 * f.bytes_per_sample(), "{name}");
        }
        assert_eq!(PixelFormat::from_code(0x010c_0006), None, "Mono12Packed is not read");
    }

    #[test]
    fn pack_and_unpack_are_inverse_and_check_ranges() {
        let f = PixelFormat::from_name("BayerRG12").unwrap();
        let samples = [0u16, 1, 4095, 0x0abc];
        let bytes = f.pack(&samples).unwrap();
        assert_eq!(bytes, [0, 0, 1, 0, 0xff, 0x0f, 0xbc, 0x0a]);
        assert_eq!(f.unpack(&bytes, 2, 2).unwrap(), samples);
        assert_eq!(f.pack(&[4096]), None);
        assert_eq!(f.unpack(&bytes[1..], 2, 2), None);
        let m8 = PixelFormat::Mono { bits: 8 };
        assert_eq!(m8.unpack(&m8.pack(&[0, 255]).unwrap(), 2, 1).unwrap(), [0, 255]);
        assert_eq!(m8.pack(&[256]), None);
        assert_eq!(f.widened().name(), "BayerRG16");
    }
}
