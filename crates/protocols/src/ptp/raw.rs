//! The btfrig raw-frame object format (PTP object format [`super::FORMAT_BTFRIG_RAW`]):
//! what `GetObject` downloads from the btfrig camera firmware.
//!
//! ```text
//! offset size field
//!      0    8 magic "BTFRAW01"
//!      8    4 width (u32)          12 4 height (u32)
//!     16    1 bit depth (1..=16)   17 1 Bayer: 0 none, 1 RGGB, 2 BGGR, 3 GRBG, 4 GBRG
//!     18    2 black level (u16)    20 2 white level (u16)
//!     22    8 sequence (u64)
//!     30    8 exposure s (f64)     38 8 gain (f64)
//!     46    8 f-number (f64; NaN: none)
//!     54    8 timestamp s (f64)
//!     62    8 FNV-1a 64 checksum of the samples (btfrig_hw::frame_checksum)
//!     70  2wh samples, u16 little-endian, row-major
//! ```
//! All integers little-endian. The decoder checks the size, the bit depth and every
//! sample against it, and the checksum, through [`btfrig_hw::verify_frame`]'s rules.

use btfrig_core::frame::{BayerPattern, FrameMeta, RawFrame};

use crate::{DecodeError, EncodeError};

/// The first 8 bytes.
pub const MAGIC: &[u8; 8] = b"BTFRAW01";
/// Header bytes before the samples.
pub const HEADER: usize = 70;
/// Largest frame accepted: 2^27 photosites (256 MiB of samples).
pub const MAX_PIXELS: usize = 1 << 27;

fn bayer_code(b: Option<BayerPattern>) -> u8 {
    match b {
        None => 0,
        Some(BayerPattern::Rggb) => 1,
        Some(BayerPattern::Bggr) => 2,
        Some(BayerPattern::Grbg) => 3,
        Some(BayerPattern::Gbrg) => 4,
    }
}

/// The object bytes of `frame`.
pub fn encode(frame: &RawFrame) -> Result<Vec<u8>, EncodeError> {
    let n = frame.width.checked_mul(frame.height).filter(|&n| n <= MAX_PIXELS && n == frame.data.len());
    let Some(n) = n else {
        return Err(EncodeError::Value {
            field: "frame size",
            value: format!("{}x{} with {} samples", frame.width, frame.height, frame.data.len()),
            allowed: "width x height = sample count <= 2^27",
        });
    };
    let m = &frame.meta;
    let mut out = Vec::with_capacity(HEADER + 2 * n);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(frame.width as u32).to_le_bytes());
    out.extend_from_slice(&(frame.height as u32).to_le_bytes());
    out.push(m.bit_depth);
    out.push(bayer_code(m.bayer));
    out.extend_from_slice(&m.black_level.to_le_bytes());
    out.extend_from_slice(&m.white_level.to_le_bytes());
    out.extend_from_slice(&m.sequence.to_le_bytes());
    for v in [m.exposure_s, m.gain, m.f_number.unwrap_or(f64::NAN), m.timestamp_s] {
        out.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    out.extend_from_slice(&btfrig_hw::frame_checksum(&frame.data).to_le_bytes());
    for v in &frame.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// The frame in `bytes`, checked; a damaged one is an error naming what is wrong.
pub fn decode(bytes: &[u8]) -> Result<RawFrame, DecodeError> {
    let bad = |d: String| DecodeError::malformed("raw frame", d, &[]);
    if bytes.len() < HEADER {
        return Err(bad(format!("{} bytes, shorter than the {HEADER}-byte header", bytes.len())));
    }
    if &bytes[..8] != MAGIC {
        return Err(bad("bad magic (not a btfrig raw frame)".into()));
    }
    let width = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    let height = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]) as usize;
    let n = width.checked_mul(height).filter(|&n| n <= MAX_PIXELS);
    let Some(n) = n else {
        return Err(DecodeError::Oversized { what: "raw frame", limit: 2 * MAX_PIXELS });
    };
    if bytes.len() != HEADER + 2 * n {
        return Err(bad(format!("{} bytes, expected {} for {width}x{height}", bytes.len(), HEADER + 2 * n)));
    }
    let bit_depth = bytes[16];
    if !(1..=16).contains(&bit_depth) {
        return Err(bad(format!("bit depth {bit_depth} outside 1..=16")));
    }
    let bayer = match bytes[17] {
        0 => None,
        1 => Some(BayerPattern::Rggb),
        2 => Some(BayerPattern::Bggr),
        3 => Some(BayerPattern::Grbg),
        4 => Some(BayerPattern::Gbrg),
        b => return Err(bad(format!("Bayer code {b} unknown"))),
    };
    let f = |at| f64::from_bits(u64_at(bytes, at));
    let f_number = f(46);
    let meta = FrameMeta {
        sequence: u64_at(bytes, 22),
        exposure_s: f(30),
        gain: f(38),
        f_number: if f_number.is_nan() { None } else { Some(f_number) },
        black_level: u16::from_le_bytes([bytes[18], bytes[19]]),
        white_level: u16::from_le_bytes([bytes[20], bytes[21]]),
        bit_depth,
        bayer,
        timestamp_s: f(54),
        temperature_c: None,
    };
    let sent = u64_at(bytes, 62);
    let data: Vec<u16> = bytes[HEADER..].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    let frame = RawFrame { width, height, data, meta };
    btfrig_hw::verify_frame("camera", &frame, sent).map_err(|e| bad(e.message().to_string()))?;
    Ok(frame)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame() -> RawFrame {
        RawFrame {
            width: 3,
            height: 2,
            data: vec![0, 1, 2, 4095, 100, 7],
            meta: FrameMeta {
                sequence: 5,
                exposure_s: 0.2,
                gain: 1.0,
                f_number: Some(8.0),
                black_level: 64,
                white_level: 4095,
                bit_depth: 12,
                bayer: Some(BayerPattern::Rggb),
                timestamp_s: 12.5,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn round_trip_and_layout() {
        let bytes = encode(&frame()).unwrap();
        assert_eq!(bytes.len(), HEADER + 12);
        assert_eq!(&bytes[..8], b"BTFRAW01");
        assert_eq!(&bytes[8..18], &[3, 0, 0, 0, 2, 0, 0, 0, 12, 1]);
        assert_eq!(&bytes[HEADER + 6..HEADER + 8], &[0xFF, 0x0F]);
        assert_eq!(decode(&bytes).unwrap(), frame());
        let mut mono = frame();
        mono.meta.bayer = None;
        mono.meta.f_number = None;
        assert_eq!(decode(&encode(&mono).unwrap()).unwrap(), mono);
    }

    #[test]
    fn damage_is_named() {
        let bytes = encode(&frame()).unwrap();
        for cut in [0, 10, HEADER - 1, HEADER, bytes.len() - 1] {
            assert!(decode(&bytes[..cut]).is_err(), "cut {cut}");
        }
        let mut flipped = bytes.clone();
        flipped[HEADER + 2] ^= 1;
        assert!(decode(&flipped).unwrap_err().to_string().contains("checksum"));
        let mut over = frame();
        over.data[1] = 5000; // beyond 12 bits
        assert!(decode(&encode(&over).unwrap()).unwrap_err().to_string().contains("12-bit"));
        let mut huge = bytes.clone();
        huge[8..16].copy_from_slice(&[0xFF; 8]);
        assert!(matches!(decode(&huge), Err(DecodeError::Oversized { .. })));
        let mut magic = bytes.clone();
        magic[0] = b'X';
        assert!(decode(&magic).is_err());
        let mut depth = bytes;
        depth[16] = 0;
        assert!(decode(&depth).is_err());
    }
}
