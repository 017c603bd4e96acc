//! Where the simulated camera gets its pixels from.
//!
//! The camera device knows *when* a frame is taken and with which settings; a
//! [`FrameSource`] knows *what* the sensor sees given the rig's true state. The physically
//! based renderer implements this trait; [`FlatFrameSource`] is a trivial one for tests.

use btfrig_core::frame::{BayerPattern, FrameMeta, RawFrame};
use btfrig_hw::CaptureSettings;

use crate::TrueState;

/// Layout of the frames a source produces (the simulated sensor).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorFormat {
    /// Width, photosites.
    pub width: usize,
    /// Height, photosites.
    pub height: usize,
    /// Bits per sample.
    pub bit_depth: u8,
    /// Colour filter array, `None` for monochrome.
    pub bayer: Option<BayerPattern>,
    /// Black level, digital numbers.
    pub black_level: u16,
    /// Saturation level, digital numbers.
    pub white_level: u16,
}

/// Renders what the camera sees.
pub trait FrameSource: Send + Sync {
    /// The layout of every frame [`FrameSource::render`] returns.
    fn format(&self) -> SensorFormat;

    /// The raw frame for the rig's true state at the start of the exposure, taken with
    /// `settings`. `seed` drives all randomness (sensor noise): the same inputs and seed
    /// must give the same frame. The camera overwrites the metadata it owns (sequence,
    /// timestamp, settings, levels), so a source need not fill those exactly. Called on
    /// the camera's task: expensive sources may do their work on a rayon pool inside.
    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame;
}

/// A flat frame whose value encodes the exposure: every photosite reads
/// `black_level + round(dn_per_s * exposure_s * gain * light)`, clamped to the white level,
/// where `light` is the lamp intensity factor plus the sum of the LED intensities.
#[derive(Debug, Clone)]
pub struct FlatFrameSource {
    /// Frame layout.
    pub format: SensorFormat,
    /// Digital numbers per second of exposure at gain 1 and unit light.
    pub dn_per_s: f64,
}

impl FlatFrameSource {
    /// A small 12-bit RGGB frame of `width` x `height`, black level 64.
    pub fn new(width: usize, height: usize, dn_per_s: f64) -> Self {
        FlatFrameSource {
            format: SensorFormat {
                width,
                height,
                bit_depth: 12,
                bayer: Some(BayerPattern::Rggb),
                black_level: 64,
                white_level: 4095,
            },
            dn_per_s,
        }
    }

    /// The value every photosite of a frame taken under `truth` with `settings` reads.
    pub fn expected_value(&self, truth: &TrueState, settings: &CaptureSettings) -> u16 {
        let light = truth.lamp_intensity + truth.leds.iter().sum::<f64>();
        let v =
            f64::from(self.format.black_level) + (self.dn_per_s * settings.exposure_s * settings.gain * light).round();
        v.clamp(0.0, f64::from(self.format.white_level)) as u16
    }
}

impl FrameSource for FlatFrameSource {
    fn format(&self) -> SensorFormat {
        self.format
    }

    fn render(&self, truth: &TrueState, settings: &CaptureSettings, _seed: u64) -> RawFrame {
        let f = self.format;
        RawFrame {
            width: f.width,
            height: f.height,
            data: vec![self.expected_value(truth, settings); f.width * f.height],
            meta: FrameMeta {
                sequence: 0,
                exposure_s: settings.exposure_s,
                gain: settings.gain,
                f_number: settings.f_number,
                black_level: f.black_level,
                white_level: f.white_level,
                bit_depth: f.bit_depth,
                bayer: f.bayer,
                timestamp_s: truth.time_s,
                temperature_c: None,
            },
        }
    }
}
