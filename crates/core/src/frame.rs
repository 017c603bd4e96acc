//! Raw sensor frames as a camera delivers them, with the metadata needed to process them.

use serde::{Deserialize, Serialize};

/// Colour filter array layout of the top-left 2x2 block of the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum BayerPattern {
    /// R G / G B
    Rggb,
    /// B G / G R
    Bggr,
    /// G R / B G
    Grbg,
    /// G B / R G
    Gbrg,
}

impl BayerPattern {
    /// Colour channel (0 = R, 1 = G, 2 = B) of the photosite at column `x`, row `y`.
    pub fn channel_at(self, x: usize, y: usize) -> usize {
        let i = (y & 1) * 2 + (x & 1);
        let layout: [usize; 4] = match self {
            BayerPattern::Rggb => [0, 1, 1, 2],
            BayerPattern::Bggr => [2, 1, 1, 0],
            BayerPattern::Grbg => [1, 0, 2, 1],
            BayerPattern::Gbrg => [1, 2, 0, 1],
        };
        layout[i]
    }
}

/// Everything known about how a frame was taken. The simulator fills in the same fields a
/// real camera backend does; ground truth is never stored here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    /// Running number of the frame from this camera, starting at 0.
    pub sequence: u64,
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Analogue gain (ISO-like multiplier, 1 = base).
    pub gain: f64,
    /// Aperture f-number, if the camera reports it.
    pub f_number: Option<f64>,
    /// Black (dark) level in digital numbers.
    pub black_level: u16,
    /// Largest value a photosite can report (saturation), digital numbers.
    pub white_level: u16,
    /// Bits per sample.
    pub bit_depth: u8,
    /// Colour filter array, or `None` for a monochrome sensor.
    pub bayer: Option<BayerPattern>,
    /// Capture time on the rig's clock, seconds since the rig started.
    pub timestamp_s: f64,
    /// Sensor temperature in degrees Celsius, where the camera reports it (dark current
    /// doubles every few kelvin, so calibrations and reports want it).
    #[serde(default)]
    pub temperature_c: Option<f64>,
}

/// A raw frame: one `u16` per photosite, row-major, `width * height` values.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFrame {
    /// Width in photosites.
    pub width: usize,
    /// Height in photosites.
    pub height: usize,
    /// Row-major photosite values in digital numbers.
    pub data: Vec<u16>,
    /// How the frame was taken.
    pub meta: FrameMeta,
}

impl RawFrame {
    /// The value at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> u16 {
        self.data[y * self.width + x]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pattern_has_two_greens_per_block() {
        for p in [BayerPattern::Rggb, BayerPattern::Bggr, BayerPattern::Grbg, BayerPattern::Gbrg] {
            let mut count = [0; 3];
            for y in 0..2 {
                for x in 0..2 {
                    count[p.channel_at(x, y)] += 1;
                }
            }
            assert_eq!(count, [1, 2, 1], "{p:?}");
        }
        assert_eq!(BayerPattern::Rggb.channel_at(0, 0), 0);
        assert_eq!(BayerPattern::Rggb.channel_at(3, 3), 2);
    }
}
