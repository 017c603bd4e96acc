//! The GenICam camera as the runner sees it: metered (wall time, dropped buffers) and, for the
//! simulated rig, fed with the simulated camera's frames.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use async_trait::async_trait;
use btfrig_core::frame::RawFrame;
use btfrig_genicam::{FedFakeCamera, Feed, FeedFrame, GenicamDevice, PixelFormat};
use btfrig_hw::{Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, Health};
use btfrig_measurement::backend::{LinkReport, LinkUse};

/// What the GenICam camera cost: frames, bytes, wall time in its calls, dropped buffers.
#[derive(Debug, Default)]
pub(crate) struct Costs {
    pub(crate) frames: AtomicU64,
    pub(crate) bytes: AtomicU64,
    pub(crate) wall_ns: AtomicU64,
    pub(crate) dropped: AtomicU64,
}

/// The camera's link with the inner backend's links.
pub(crate) struct Links {
    pub(crate) inner: Box<dyn LinkReport>,
    pub(crate) costs: Arc<Costs>,
    pub(crate) target: String,
    // Dropped last: the fake camera outlives the client that streams from it.
    pub(crate) _fake: Option<Arc<FedFakeCamera>>,
}

impl Costs {
    /// The camera's link as the report shows it.
    pub(crate) fn link_use(&self, role: &'static str, target: String) -> LinkUse {
        LinkUse {
            role,
            target,
            exchanges: self.frames.load(Ordering::Relaxed),
            bytes_out: 0,
            bytes_in: self.bytes.load(Ordering::Relaxed),
            wall_s: self.wall_s(),
            wire_s: None,
            dropped_buffers: Some(self.dropped.load(Ordering::Relaxed)),
        }
    }

    /// Wall time spent in the camera's calls, s.
    pub(crate) fn wall_s(&self) -> f64 {
        self.wall_ns.load(Ordering::Relaxed) as f64 * 1e-9
    }
}

impl LinkReport for Links {
    fn link_use(&self) -> Vec<LinkUse> {
        let mut v = self.inner.link_use();
        v.push(self.costs.link_use("camera", self.target.clone()));
        v
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        self.inner.skipped_lines()
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        Some(self.costs.wall_s())
    }

    fn count(&self) -> usize {
        self.inner.count() + 1
    }
}

/// A camera whose every call is timed and whose dropped buffers are counted.
pub(crate) struct Metered<C> {
    pub(crate) camera: C,
    pub(crate) costs: Arc<Costs>,
}

impl<C> Metered<C> {
    fn account<R>(&self, t0: Instant, r: &Result<R, DeviceError>) {
        self.costs.wall_ns.fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        if let Err(e) = r {
            if matches!(e.kind(), ErrorKind::Timeout | ErrorKind::CorruptData | ErrorKind::Disconnected) {
                self.costs.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// The simulated camera seen through the GenICam stream: each capture renders the simulated
/// frame (on the rig's clock), hands its pixels to the fed fake camera, triggers the GenICam
/// camera and returns what arrived over GigE Vision. Exposure and gain go to the GenICam
/// camera, and the simulated sensor takes what the camera confirmed; the lens (f-number)
/// and the frame's time stamp on the rig's clock (which the truth probe keys on) are the
/// simulated camera's, since GenICam carries neither.
pub struct FedCamera {
    pub(crate) sim: Box<dyn Camera>,
    pub(crate) genicam: Metered<GenicamDevice>,
    pub(crate) feed: Arc<Feed>,
    pub(crate) fake: Arc<FedFakeCamera>,
    pub(crate) format: PixelFormat,
    pub(crate) pending: Option<RawFrame>,
}

#[async_trait]
impl Device for FedCamera {
    fn info(&self) -> &DeviceInfo {
        self.genicam.info()
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        self.genicam.health().await
    }

    async fn temperature_c(&mut self) -> Result<Option<f64>, DeviceError> {
        self.genicam.temperature_c().await
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.pending = None;
        self.genicam.reconnect().await
    }
}

#[async_trait]
impl Camera for FedCamera {
    fn capabilities(&self) -> CameraCapabilities {
        self.genicam.capabilities()
    }

    fn settings(&self) -> CaptureSettings {
        CaptureSettings { f_number: self.sim.settings().f_number, ..self.genicam.settings() }
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        self.genicam.set_exposure_s(exposure_s).await?;
        self.sim.set_exposure_s(self.genicam.settings().exposure_s).await
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        self.genicam.set_gain(gain).await?;
        self.sim.set_gain(self.genicam.settings().gain).await
    }

    async fn set_f_number(&mut self, f_number: f64) -> Result<(), DeviceError> {
        self.sim.set_f_number(f_number).await
    }

    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError> {
        self.pending = None;
        self.sim.trigger(timeout_s).await?;
        let frame = self.sim.read_frame(timeout_s).await?;
        let bytes = self.format.pack(&frame.data).ok_or_else(|| {
            DeviceError::new(
                self.genicam.name(),
                ErrorKind::Other,
                format!("a simulated sample exceeds {}", self.format.name()),
            )
        })?;
        if let Some(t) = frame.meta.temperature_c {
            self.fake.set_temperature_c(t);
        }
        self.feed.set_next(FeedFrame {
            width: frame.width as u32,
            height: frame.height as u32,
            pixel_format: self.format.code(),
            bytes,
        });
        let seq = self.genicam.trigger(timeout_s).await?;
        self.pending = Some(frame);
        Ok(seq)
    }

    async fn read_frame(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError> {
        let sim = self.pending.take();
        let mut frame = self.genicam.read_frame(timeout_s).await?;
        if let Some(sim) = sim {
            frame.meta.timestamp_s = sim.meta.timestamp_s;
            frame.meta.f_number = sim.meta.f_number;
            frame.meta.black_level = sim.meta.black_level;
            frame.meta.white_level = sim.meta.white_level;
        }
        Ok(frame)
    }
}

#[async_trait]
impl<C: Camera> Device for Metered<C> {
    fn info(&self) -> &DeviceInfo {
        self.camera.info()
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        self.camera.health().await
    }

    async fn temperature_c(&mut self) -> Result<Option<f64>, DeviceError> {
        self.camera.temperature_c().await
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.camera.reconnect().await
    }
}

#[async_trait]
impl<C: Camera> Camera for Metered<C> {
    fn capabilities(&self) -> CameraCapabilities {
        self.camera.capabilities()
    }

    fn settings(&self) -> CaptureSettings {
        self.camera.settings()
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        self.camera.set_exposure_s(exposure_s).await
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        self.camera.set_gain(gain).await
    }

    async fn set_f_number(&mut self, f_number: f64) -> Result<(), DeviceError> {
        self.camera.set_f_number(f_number).await
    }

    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError> {
        let t0 = Instant::now();
        let r = self.camera.trigger(timeout_s).await;
        self.account(t0, &r);
        r
    }

    async fn read_frame(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError> {
        let t0 = Instant::now();
        let r = self.camera.read_frame(timeout_s).await;
        self.account(t0, &r);
        if let Ok(f) = &r {
            self.costs.frames.fetch_add(1, Ordering::Relaxed);
            self.costs.bytes.fetch_add(2 * f.data.len() as u64, Ordering::Relaxed);
        }
        r
    }
}
