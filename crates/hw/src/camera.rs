//! The camera: settings, trigger, and read-out of raw frames with full metadata.
//!
//! A capture has two halves so that the run engine can overlap motion with image transfer:
//! [`Camera::trigger`] returns once the exposure is over and the sensor has been read into
//! the camera's buffer (the scene may change from then on), and [`Camera::read_frame`]
//! transfers that frame to the host. [`Camera::capture`] does both.

use async_trait::async_trait;
use btfrig_core::frame::{BayerPattern, RawFrame};

use crate::{Device, DeviceError, ErrorKind};

/// What the camera can do: sensor layout and the ranges of its settings.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraCapabilities {
    /// Sensor width, photosites.
    pub width: usize,
    /// Sensor height, photosites.
    pub height: usize,
    /// Bits per sample of the raw data.
    pub bit_depth: u8,
    /// Colour filter array, `None` for a monochrome sensor.
    pub bayer: Option<BayerPattern>,
    /// Black level, digital numbers.
    pub black_level: u16,
    /// Saturation level, digital numbers.
    pub white_level: u16,
    /// Shortest and longest exposure, seconds.
    pub exposure_range_s: (f64, f64),
    /// Lowest and highest analogue gain (1 = base).
    pub gain_range: (f64, f64),
    /// Widest and narrowest f-number, or `None` for a fixed or unreported aperture.
    pub f_number_range: Option<(f64, f64)>,
}

/// The settings a frame is taken with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureSettings {
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Analogue gain (1 = base).
    pub gain: f64,
    /// Aperture f-number, if the camera has a controllable aperture.
    pub f_number: Option<f64>,
}

/// A camera that delivers raw frames.
#[async_trait]
pub trait Camera: Device {
    /// Sensor layout and setting ranges.
    fn capabilities(&self) -> CameraCapabilities;

    /// The settings the next capture will use (as last confirmed by the camera).
    fn settings(&self) -> CaptureSettings;

    /// Sets the exposure time, seconds; outside the range fails with
    /// [`ErrorKind::OutOfRange`].
    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError>;

    /// Sets the analogue gain; outside the range fails with [`ErrorKind::OutOfRange`].
    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError>;

    /// Sets the aperture. Default: [`ErrorKind::Unsupported`].
    async fn set_f_number(&mut self, f_number: f64) -> Result<(), DeviceError> {
        let _ = f_number;
        Err(DeviceError::unsupported(self.name(), "aperture control"))
    }

    /// Exposes one frame and returns its sequence number once the exposure has ended and the
    /// sensor has been read into the camera's buffer. A frame still waiting unread in the
    /// buffer is discarded (its sequence number is skipped), so that retrying a capture
    /// whose read-out failed always starts afresh.
    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError>;

    /// Transfers the buffered frame to the host, with its metadata. Fails with
    /// [`ErrorKind::Timeout`] when no frame arrives in time (a dropped frame) and
    /// [`ErrorKind::CorruptData`] when it arrives damaged (see [`verify_frame`]); in both
    /// cases the buffer is empty afterwards and the capture must be repeated.
    async fn read_frame(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError>;

    /// Trigger and read-out in one call; `timeout_s` applies to each half.
    async fn capture(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError> {
        self.trigger(timeout_s).await?;
        self.read_frame(timeout_s).await
    }
}

/// Checksum a camera sends along with a frame's pixel data: 64-bit FNV-1a over the samples
/// in little-endian byte order. The host recomputes it on what arrived.
pub fn frame_checksum(data: &[u16]) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h = OFFSET;
    for v in data {
        for b in v.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(PRIME);
        }
    }
    h
}

/// Host-side check of a frame that arrived from `device`: the sample count matches
/// width x height, no sample exceeds the bit depth, and the checksum the camera sent
/// matches the data. Any mismatch is [`ErrorKind::CorruptData`].
pub fn verify_frame(device: &str, frame: &RawFrame, sent_checksum: u64) -> Result<(), DeviceError> {
    let expected = frame.width * frame.height;
    if frame.data.len() != expected {
        return Err(DeviceError::new(
            device,
            ErrorKind::CorruptData,
            format!(
                "frame {} has {} samples, expected {}x{} = {expected}",
                frame.meta.sequence,
                frame.data.len(),
                frame.width,
                frame.height
            ),
        ));
    }
    let max = if frame.meta.bit_depth >= 16 { u16::MAX } else { (1u16 << frame.meta.bit_depth) - 1 };
    if let Some(i) = frame.data.iter().position(|&v| v > max) {
        return Err(DeviceError::new(
            device,
            ErrorKind::CorruptData,
            format!(
                "frame {} sample {i} = {} exceeds the {}-bit range",
                frame.meta.sequence, frame.data[i], frame.meta.bit_depth
            ),
        ));
    }
    let got = frame_checksum(&frame.data);
    if got != sent_checksum {
        return Err(DeviceError::new(
            device,
            ErrorKind::CorruptData,
            format!("frame {} checksum {got:016x} does not match the sent {sent_checksum:016x}", frame.meta.sequence),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::frame::FrameMeta;

    fn frame(data: Vec<u16>) -> RawFrame {
        RawFrame {
            width: 2,
            height: 2,
            data,
            meta: FrameMeta {
                sequence: 7,
                exposure_s: 0.1,
                gain: 1.0,
                f_number: None,
                black_level: 0,
                white_level: 4095,
                bit_depth: 12,
                bayer: None,
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn checksum_matches_published_fnv1a_vector() {
        // FNV-1a 64 of the empty input is the offset basis; of "foobar" it is the published
        // test vector 85944171f73967e8. "foobar" as little-endian u16 pairs: "fo", "ob", "ar".
        assert_eq!(frame_checksum(&[]), 0xcbf2_9ce4_8422_2325);
        assert_eq!(frame_checksum(&[0x6f66, 0x626f, 0x7261]), 0x8594_4171_f739_67e8);
        assert_ne!(frame_checksum(&[0x0102]), frame_checksum(&[0x0201]));
    }

    #[test]
    fn verify_catches_each_corruption() {
        let good = frame(vec![1, 2, 3, 4]);
        let sum = frame_checksum(&good.data);
        verify_frame("camera", &good, sum).unwrap();

        let mut flipped = good.clone();
        flipped.data[2] ^= 0x10;
        let e = verify_frame("camera", &flipped, sum).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::CorruptData);
        assert!(e.is_retryable());
        assert!(e.to_string().contains("checksum"), "{e}");

        let mut short = good.clone();
        short.data.pop();
        assert!(verify_frame("camera", &short, sum).unwrap_err().to_string().contains("3 samples"));

        let over = frame(vec![1, 2, 4096, 4]);
        let e = verify_frame("camera", &over, frame_checksum(&over.data)).unwrap_err();
        assert!(e.to_string().contains("12-bit"), "{e}");
    }
}
