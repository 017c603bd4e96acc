//! [`GenicamDevice`]: a GenICam camera behind `btfrig_hw::Camera`.
//!
//! Every call runs on a blocking thread (`spawn_blocking`), which also keeps a paused tokio
//! clock from jumping ahead while the camera works in real time. Errors keep their kinds:
//! a dropped buffer is [`ErrorKind::Timeout`], an incomplete one
//! [`ErrorKind::CorruptData`], a camera that stopped answering
//! [`ErrorKind::Disconnected`] (the engine calls `reconnect` and retries); all three are
//! retryable.

use std::time::Duration;

use async_trait::async_trait;
use btfrig_core::frame::{FrameMeta, RawFrame};
use btfrig_hw::{
    Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, Health, SharedClock,
};

use crate::camera::{Frame, GenicamCamera, ImageFormat, Trigger};
use crate::error::Error;
use crate::format::PixelFormat;

/// The unit of the camera's gain feature, to and from the `Camera` trait's linear gain
/// (1 = base).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GainUnit {
    /// Decibels (SFNC `Gain`): linear = 10^(dB / 20).
    #[default]
    Decibel,
    /// The feature is the linear factor itself.
    Linear,
}

impl GainUnit {
    fn to_camera(self, linear: f64) -> f64 {
        match self {
            GainUnit::Decibel => 20.0 * linear.log10(),
            GainUnit::Linear => linear,
        }
    }

    fn to_linear(self, camera: f64) -> f64 {
        match self {
            GainUnit::Decibel => 10f64.powf(camera / 20.0),
            GainUnit::Linear => camera,
        }
    }
}

/// What the `Camera` trait needs that GenICam does not say: the sensor's levels, its
/// significant bits and the setting ranges a rig allows.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceOptions {
    /// The device's name in the rig config (`camera`).
    pub name: String,
    /// Width and height read out, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The pixel format on the wire.
    pub pixel_format: PixelFormat,
    /// Significant bits of a sample (a 14-bit sensor in a 16-bit format: 14).
    pub bit_depth: u8,
    /// Black level, DN.
    pub black_level: u16,
    /// Saturation level, DN.
    pub white_level: u16,
    /// Exposure range the rig allows, seconds (within the camera's).
    pub exposure_range_s: (f64, f64),
    /// Gain range the rig allows, linear.
    pub gain_range: (f64, f64),
    /// The gain feature's unit.
    pub gain_unit: GainUnit,
    /// Exposure and gain set at open.
    pub initial: (f64, f64),
}

/// A GenICam camera as a `btfrig_hw::Camera` (software-triggered).
pub struct GenicamDevice {
    info: DeviceInfo,
    camera: GenicamCamera,
    options: DeviceOptions,
    settings: CaptureSettings,
    clock: SharedClock,
    pending: Option<(Frame, f64)>,
}

/// Runs a camera call on a blocking thread; maps the error to the device's.
async fn blocking<R: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> Result<R, Error> + Send + 'static,
) -> Result<R, DeviceError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| DeviceError::new(name, ErrorKind::Other, format!("the camera call panicked: {e}")))?
        .map_err(|e| e.into_device_error(name))
}

impl GenicamDevice {
    /// Configures `camera` for `options` (format, software trigger, initial exposure and
    /// gain) and starts its stream. `clock` stamps the frames (`FrameMeta.timestamp_s` is on
    /// the rig's clock; the camera's own stamps are in [`Frame`]).
    pub async fn open(camera: GenicamCamera, options: DeviceOptions, clock: SharedClock) -> Result<Self, DeviceError> {
        let info = camera.info();
        let name = options.name.clone();
        let format = ImageFormat { width: options.width, height: options.height, pixel_format: options.pixel_format };
        let cam = camera.clone();
        blocking(&name, move || {
            cam.set_image_format(format)?;
            cam.set_trigger(Trigger::Software)
        })
        .await?;
        let mut dev = GenicamDevice {
            info: DeviceInfo {
                name: name.clone(),
                backend: "genicam".into(),
                model: format!("{} {}", info.vendor, info.model),
                serial: Some(info.serial.clone()),
                firmware: info.version.clone(),
            },
            camera,
            settings: CaptureSettings { exposure_s: options.initial.0, gain: options.initial.1, f_number: None },
            options,
            clock,
            pending: None,
        };
        let (exposure, gain) = dev.options.initial;
        dev.set_exposure_s(exposure).await?;
        dev.set_gain(gain).await?;
        let cam = dev.camera.clone();
        blocking(&name, move || cam.start()).await?;
        Ok(dev)
    }

    /// The camera underneath (its statistics, its info).
    pub fn camera(&self) -> &GenicamCamera {
        &self.camera
    }

    fn to_raw(&self, frame: Frame, timestamp_s: f64) -> Result<RawFrame, DeviceError> {
        let o = &self.options;
        let corrupt = |m: String| DeviceError::new(&o.name, ErrorKind::CorruptData, m);
        if frame.width != o.width || frame.height != o.height || frame.pixel_format != o.pixel_format {
            return Err(corrupt(format!(
                "frame {} is {} x {} {}, configured {} x {} {}",
                frame.sequence,
                frame.width,
                frame.height,
                frame.pixel_format.name(),
                o.width,
                o.height,
                o.pixel_format.name()
            )));
        }
        let data = frame
            .pixel_format
            .unpack(&frame.data, frame.width as usize, frame.height as usize)
            .ok_or_else(|| corrupt(format!("frame {} has {} bytes", frame.sequence, frame.data.len())))?;
        let max = if o.bit_depth >= 16 { u16::MAX } else { (1u16 << o.bit_depth) - 1 };
        if let Some(i) = data.iter().position(|&v| v > max) {
            return Err(corrupt(format!(
                "frame {} sample {i} = {} exceeds the sensor's {} bits",
                frame.sequence, data[i], o.bit_depth
            )));
        }
        Ok(RawFrame {
            width: frame.width as usize,
            height: frame.height as usize,
            data,
            meta: FrameMeta {
                sequence: frame.sequence,
                exposure_s: self.settings.exposure_s,
                gain: self.settings.gain,
                f_number: None,
                black_level: o.black_level,
                white_level: o.white_level,
                bit_depth: o.bit_depth,
                bayer: frame.pixel_format.bayer(),
                timestamp_s,
                temperature_c: frame.temperature_c,
            },
        })
    }
}

#[async_trait]
impl Device for GenicamDevice {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        let cam = self.camera.clone();
        let stats = blocking(&self.options.name, move || cam.stats()).await?;
        Ok(if stats.failures + stats.timeouts > 0 {
            Health::Warning(format!(
                "{} dropped and {} incomplete buffers of {}",
                stats.timeouts,
                stats.failures,
                stats.completed + stats.failures + stats.timeouts
            ))
        } else {
            Health::Ok
        })
    }

    async fn temperature_c(&mut self) -> Result<Option<f64>, DeviceError> {
        let cam = self.camera.clone();
        blocking(&self.options.name, move || cam.temperature_c()).await
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.pending = None;
        let cam = self.camera.clone();
        blocking(&self.options.name, move || cam.reconnect().map(|_| ())).await
    }
}

#[async_trait]
impl Camera for GenicamDevice {
    fn capabilities(&self) -> CameraCapabilities {
        let o = &self.options;
        CameraCapabilities {
            width: o.width as usize,
            height: o.height as usize,
            bit_depth: o.bit_depth,
            bayer: o.pixel_format.bayer(),
            black_level: o.black_level,
            white_level: o.white_level,
            exposure_range_s: o.exposure_range_s,
            gain_range: o.gain_range,
            f_number_range: None,
        }
    }

    fn settings(&self) -> CaptureSettings {
        self.settings
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        let (lo, hi) = self.options.exposure_range_s;
        if !(exposure_s >= lo && exposure_s <= hi) {
            return Err(DeviceError::out_of_range(
                &self.options.name,
                "exposure_s",
                exposure_s,
                format!("[{lo}, {hi}] s"),
            ));
        }
        let us = exposure_s * 1e6;
        let cam = self.camera.clone();
        let got = blocking(&self.options.name, move || cam.set_exposure_us(us)).await?;
        // A camera that took exactly the microseconds sent applied the exposure asked for; one
        // that rounded it (its own resolution) applied what it reports.
        self.settings.exposure_s = if got == us { exposure_s } else { got / 1e6 };
        Ok(())
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        let (lo, hi) = self.options.gain_range;
        if !(gain >= lo && gain <= hi) {
            return Err(DeviceError::out_of_range(&self.options.name, "gain", gain, format!("[{lo}, {hi}]")));
        }
        let unit = self.options.gain_unit;
        let value = unit.to_camera(gain);
        let cam = self.camera.clone();
        let got = blocking(&self.options.name, move || cam.set_gain(value)).await?;
        self.settings.gain = if got == value { gain } else { unit.to_linear(got) };
        Ok(())
    }

    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError> {
        self.pending = None;
        let cam = self.camera.clone();
        let timeout = Duration::from_secs_f64(timeout_s.max(0.001));
        let frame = blocking(&self.options.name, move || cam.trigger_software(timeout)).await?;
        let sequence = frame.sequence;
        self.pending = Some((frame, self.clock.now_s()));
        Ok(sequence)
    }

    async fn read_frame(&mut self, _timeout_s: f64) -> Result<RawFrame, DeviceError> {
        // The buffer arrived whole during `trigger` (GigE Vision sends the frame as it is read
        // out); here it is only converted.
        let (frame, t) = self.pending.take().ok_or_else(|| {
            DeviceError::new(&self.options.name, ErrorKind::Timeout, "no frame is waiting: trigger first")
        })?;
        self.to_raw(frame, t)
    }
}
