//! Rigs whose camera is a GenICam camera (`[devices.camera] kind = "genicam"`) as a device
//! backend of the runner (`btfrig_measurement::backend`).
//!
//! [`GenicamBackend`] opens the rig's other devices through another registry (simulated or
//! emulated serial ones: `btfrig_sim_backend::registry()` in the `btfrig` binary) with the
//! camera entry replaced by its simulated twin, then opens the GenICam camera by address
//! (`btfrig_genicam`) and hands the run that camera instead. With `link = { emulated = true,
//! serial = ... }` the camera at the address is Aravis's GigE Vision fake camera served by this process
//! and fed with the simulated camera's frames ([`FedCamera`]): the simulated rig seen
//! through a real GenICam stream (rig-configs/bonn-gonio-genicam.toml). The camera's keys
//! are [`CameraConfig`]; docs/genicam.md has the rest.
#![warn(missing_docs)]

use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use btfrig_core::config::devices::DeviceEntry;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_genicam::{
    DeviceOptions, FedFakeCamera, Feed, FeedFrame, GainUnit, GenicamCamera, GenicamDevice, OpenOptions, PixelFormat,
};
use btfrig_hw::{Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, Health};
use btfrig_measurement::backend::{
    BackendRegistry, CalibrationOpenRequest, GonioOpenRequest, LinkReport, LinkUse, OpenedGonio, OpenedRig, RigBackend,
    SceneOptions,
};
use btfrig_measurement::preflight::{DeviceCheck, Role};
use btfrig_measurement::RunError;
use serde::Deserialize;

pub use btfrig_genicam::Target;

/// The device kinds [`GenicamBackend`] opens: a GenICam camera, the other devices as the
/// inner registry opens them.
pub const KINDS: &[&str] = &["genicam", "sim", "serial", "ptp"];

/// `[devices.camera] link = { ... }` of a `kind = "genicam"` camera: the GenICam backend's
/// keys, as a serial device's `link` holds its port (docs/serial.md). The entry's other keys
/// are the camera options every backend shares (exposure and gain ranges, initial settings),
/// and with `emulated = true` they are those of the simulated camera behind the fake camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// The camera's IP address (GigE Vision; no discovery broadcast).
    pub address: Option<String>,
    /// Or its device id as Aravis lists it; opening by id broadcasts a discovery, so only
    /// Aravis's in-process `Fake_*` ids are accepted in a rig config.
    pub id: Option<String>,
    /// The pixel format on the wire (PFNC name: `BayerRG12`, `Mono16`, ...).
    pub pixel_format: String,
    /// The unit of the camera's `Gain` feature: `"db"` (SFNC, default) or `"linear"`.
    #[serde(default = "CameraConfig::default_gain_unit")]
    pub gain_unit: String,
    /// Serve Aravis's GigE Vision fake camera at `address` (loopback) from this process, fed
    /// with the simulated camera's frames.
    #[serde(default)]
    pub emulated: bool,
    /// The fake camera's serial number (1..15 ASCII characters; with `emulated`); the client
    /// checks it, so that it never streams from another camera on the same address.
    pub serial: Option<String>,
}

impl CameraConfig {
    fn default_gain_unit() -> String {
        "db".into()
    }

    /// Splits a `kind = "genicam"` entry into its `link` keys and the simulated twin's entry
    /// (the other keys), checking every value.
    pub fn split(entry: &DeviceEntry) -> Result<(CameraConfig, DeviceEntry), String> {
        let mut sim = entry.options.clone();
        let link = sim
            .remove("link")
            .and_then(|l| l.as_table().cloned())
            .ok_or("devices.camera.link: a GenICam camera needs a link table, e.g. link = { address = \"192.168.1.20\", pixel_format = \"BayerRG12\" }")?;
        let cfg: CameraConfig =
            link.try_into().map_err(|e: toml::de::Error| format!("devices.camera.link: {}", e.message()))?;
        cfg.target()?;
        cfg.format()?;
        cfg.gain()?;
        if cfg.emulated {
            if !matches!(cfg.target()?, Target::Address(a) if a.is_loopback()) {
                return Err("devices.camera.link.emulated: the fed fake camera is served on a loopback address; allowed: address = \"127.0.0.1\"".into());
            }
            match &cfg.serial {
                Some(s) if !s.is_empty() && s.len() <= 15 && s.is_ascii() => {}
                other => {
                    return Err(format!(
                        "devices.camera.link.serial = {other:?}: an emulated camera needs 1 to 15 ASCII characters"
                    ))
                }
            }
        } else if cfg.serial.is_some() {
            return Err(
                "devices.camera.link.serial: only with emulated = true (the fake camera's serial number)".into()
            );
        }
        Ok((cfg, DeviceEntry { kind: "sim".into(), options: sim }))
    }

    /// How the camera is reached.
    pub fn target(&self) -> Result<Target, String> {
        match (&self.address, &self.id) {
            (Some(a), None) => a.parse::<Ipv4Addr>().map(Target::Address).map_err(|_| {
                format!("devices.camera.link.address = {a:?} is not an IPv4 address; allowed: e.g. \"192.168.1.20\"")
            }),
            (None, Some(id)) if id.starts_with("Fake_") => Ok(Target::Id(id.clone())),
            (None, Some(id)) => Err(format!(
                "devices.camera.link.id = {id:?}: opening by id broadcasts a discovery on every network interface; \
                 allowed: address = \"IP\" (find it with `btfrig hw probe --discover`), or an Aravis Fake_ id"
            )),
            _ => Err("devices.camera.link: give exactly one of address (an IPv4 address) or id".into()),
        }
    }

    /// The pixel format.
    pub fn format(&self) -> Result<PixelFormat, String> {
        PixelFormat::from_name(&self.pixel_format).ok_or_else(|| {
            format!(
                "devices.camera.link.pixel_format = {:?} is not read by btfrig; allowed: {}",
                self.pixel_format,
                PixelFormat::names().join(", ")
            )
        })
    }

    fn gain(&self) -> Result<GainUnit, String> {
        match self.gain_unit.as_str() {
            "db" => Ok(GainUnit::Decibel),
            "linear" => Ok(GainUnit::Linear),
            other => Err(format!("devices.camera.link.gain_unit = {other:?}; allowed: \"db\", \"linear\"")),
        }
    }
}

/// The rig with its GenICam camera replaced by the simulated twin, and the camera's keys.
fn inner_rig(rig: &RigConfig) -> Result<(RigConfig, CameraConfig), String> {
    if rig.devices.camera.kind != "genicam" {
        return Err(format!(
            "devices.camera.kind = {:?}: the GenICam backend opens kind = \"genicam\"",
            rig.devices.camera.kind
        ));
    }
    let (cfg, sim) = CameraConfig::split(&rig.devices.camera)?;
    let mut inner = rig.clone();
    inner.devices.camera = sim;
    Ok((inner, cfg))
}

/// GenICam cameras in front of another registry's devices.
pub struct GenicamBackend {
    inner: BackendRegistry,
}

impl GenicamBackend {
    /// The backend; `inner` opens everything but the camera.
    pub fn new(inner: BackendRegistry) -> Self {
        GenicamBackend { inner }
    }
}

/// What the GenICam camera cost: frames, bytes, wall time in its calls, dropped buffers.
#[derive(Debug, Default)]
struct Costs {
    frames: AtomicU64,
    bytes: AtomicU64,
    wall_ns: AtomicU64,
    dropped: AtomicU64,
}

/// The camera's link with the inner backend's links.
struct Links {
    inner: Box<dyn LinkReport>,
    costs: Arc<Costs>,
    target: String,
    // Dropped last: the fake camera outlives the client that streams from it.
    _fake: Option<Arc<FedFakeCamera>>,
}

impl LinkReport for Links {
    fn link_use(&self) -> Vec<LinkUse> {
        let mut v = self.inner.link_use();
        let c = &self.costs;
        v.push(LinkUse {
            role: "camera",
            target: self.target.clone(),
            exchanges: c.frames.load(Ordering::Relaxed),
            bytes_out: 0,
            bytes_in: c.bytes.load(Ordering::Relaxed),
            wall_s: c.wall_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            wire_s: None,
            dropped_buffers: Some(c.dropped.load(Ordering::Relaxed)),
        });
        v
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        self.inner.skipped_lines()
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        Some(self.costs.wall_ns.load(Ordering::Relaxed) as f64 * 1e-9)
    }

    fn count(&self) -> usize {
        self.inner.count() + 1
    }
}

/// A camera whose every call is timed and whose dropped buffers are counted.
struct Metered<C> {
    camera: C,
    costs: Arc<Costs>,
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
    sim: Box<dyn Camera>,
    genicam: Metered<GenicamDevice>,
    feed: Arc<Feed>,
    fake: Arc<FedFakeCamera>,
    format: PixelFormat,
    pending: Option<RawFrame>,
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

/// Runs a blocking GenICam call off the async threads.
async fn blocking<R: Send + 'static>(f: impl FnOnce() -> Result<R, String> + Send + 'static) -> Result<R, RunError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| RunError::Rig(format!("devices.camera: {e}")))?
        .map_err(RunError::Rig)
}

#[async_trait]
impl RigBackend for GenicamBackend {
    fn name(&self) -> &'static str {
        "GenICam camera (btfrig-genicam-backend)"
    }

    fn kinds(&self) -> &'static [&'static str] {
        KINDS
    }

    async fn open_gonio(&self, req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        let (inner_cfg, cfg) = inner_rig(req.rig).map_err(RunError::Rig)?;
        let inner = self.inner.for_rig(&inner_cfg)?;
        let opened = inner.open_gonio(GonioOpenRequest { rig: &inner_cfg, ..req }).await?;
        with_genicam_camera(&cfg, opened).await
    }

    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        let (inner_cfg, cfg) = inner_rig(req.rig).map_err(RunError::Rig)?;
        let inner = self.inner.for_rig(&inner_cfg)?;
        match inner.open_calibration(CalibrationOpenRequest { rig: &inner_cfg, ..req }).await? {
            OpenedRig::Gonio(opened) => Ok(OpenedRig::Gonio(with_genicam_camera(&cfg, opened).await?)),
            OpenedRig::Dome(_) => Err(RunError::Rig(
                "devices.camera.kind = \"genicam\": GenICam cameras are opened on gonioreflectometers only so far \
                 (a dome's cameras are kind = \"sim\" or \"ptp\")"
                    .into(),
            )),
        }
    }

    fn preflight(&self, rig: &RigConfig, roles: &[Role]) -> Vec<DeviceCheck> {
        let (inner_cfg, cfg) = match inner_rig(rig) {
            Ok(v) => v,
            Err(e) => {
                let mut c = DeviceCheck::unasked("camera", &rig.devices.camera.kind, "");
                (c.note, c.failure) = (None, Some(e));
                return vec![c];
            }
        };
        let mut checks = match self.inner.for_rig(&inner_cfg) {
            Ok(inner) => inner.preflight(&inner_cfg, roles),
            Err(e) => {
                let mut c = DeviceCheck::unasked("camera", "genicam", "");
                (c.note, c.failure) = (None, Some(e.to_string()));
                return vec![c];
            }
        };
        if let Some(c) = checks.iter_mut().find(|c| c.role == "camera") {
            *c = preflight_camera(&cfg);
        }
        checks
    }

    fn check_rig(&self, rig: &RigConfig) -> Result<(), String> {
        let (inner_cfg, _) = inner_rig(rig)?;
        let inner = self.inner.for_rig(&inner_cfg).map_err(|e| e.to_string())?;
        inner.check_rig(&inner_cfg)
    }

    fn check_scene(&self, options: &SceneOptions<'_>) -> Result<(), RunError> {
        // The scene is the inner (simulated) backend's; a rig of real devices has none and
        // its backend refuses it when the run opens.
        let _ = options;
        Ok(())
    }
}

/// `opened` (the inner backend's devices, its camera the simulated twin) with the GenICam
/// camera of `cfg` in the twin's place: a fed fake camera serving the twin's frames when
/// `cfg.emulated`, else the camera at the address, the twin dropped.
async fn with_genicam_camera(cfg: &CameraConfig, opened: OpenedGonio) -> Result<OpenedGonio, RunError> {
    let OpenedGonio { robot, rail, lamp, camera: twin, clock, truth, links } = opened;
    let target = cfg.target().map_err(RunError::Rig)?;
    let format = cfg.format().map_err(RunError::Rig)?;
    let gain_unit = cfg.gain().map_err(RunError::Rig)?;
    // The fed fake camera first, so that the client finds it at the address.
    let fake = match (&cfg.serial, &target) {
        (Some(serial), Target::Address(address)) if cfg.emulated => {
            let (address, serial) = (*address, serial.clone());
            let fake = blocking(move || {
                FedFakeCamera::start(address, &serial).map_err(|e| format!("devices.camera (emulated GenICam): {e}"))
            })
            .await?;
            Some(Arc::new(fake))
        }
        _ => None,
    };
    let t = target.clone();
    let camera = blocking(move || {
        GenicamCamera::open(OpenOptions { control_timeout: Duration::from_secs(5), ..OpenOptions::new(t.clone()) })
            .map_err(|e| format!("devices.camera (GenICam {t}): {e}"))
    })
    .await?;
    let info = camera.info();
    if let (true, Some(serial)) = (cfg.emulated, &cfg.serial) {
        if &info.serial != serial {
            return Err(RunError::Rig(format!(
                "devices.camera: the camera at {target} has serial {:?}, not the fake camera's {serial:?}: another camera holds the address",
                info.serial
            )));
        }
    }
    // The sensor as the rig config describes it (the simulated twin reads the same
    // [camera] and [sensor] sections).
    let caps = twin.capabilities();
    let settings = twin.settings();
    if format.bits() < caps.bit_depth || format.bayer() != caps.bayer {
        return Err(RunError::Rig(format!(
            "devices.camera.link.pixel_format = {:?} does not carry the sensor's {}-bit {} samples; allowed: a {}-bit or wider {} format",
            format.name(),
            caps.bit_depth,
            caps.bayer.map_or("monochrome".to_string(), |b| format!("{b:?} Bayer")),
            caps.bit_depth,
            if caps.bayer.is_some() { "Bayer" } else { "Mono" }
        )));
    }
    let options = DeviceOptions {
        name: "camera".into(),
        width: caps.width as u32,
        height: caps.height as u32,
        pixel_format: format,
        bit_depth: caps.bit_depth,
        black_level: caps.black_level,
        white_level: caps.white_level,
        exposure_range_s: caps.exposure_range_s,
        gain_range: caps.gain_range,
        gain_unit,
        initial: (settings.exposure_s, settings.gain),
    };
    let device = GenicamDevice::open(camera, options, clock.clone()).await.map_err(|e| RunError::Rig(e.to_string()))?;
    let costs = Arc::new(Costs::default());
    let (camera, label): (Box<dyn Camera>, String) = match &fake {
        Some(f) => {
            let feed = f.feed();
            // Only the GenICam calls are metered: the simulated frame's rendering is not the
            // GenICam path's cost.
            let genicam = Metered { camera: device, costs: costs.clone() };
            let mut fed = FedCamera { sim: twin, genicam, feed, fake: f.clone(), format, pending: None };
            // The simulated sensor starts where the GenICam camera was set.
            fed.sim
                .set_exposure_s(fed.genicam.settings().exposure_s)
                .await
                .map_err(|e| RunError::Rig(e.to_string()))?;
            fed.sim.set_gain(fed.genicam.settings().gain).await.map_err(|e| RunError::Rig(e.to_string()))?;
            (
                Box::new(fed),
                format!(
                    "GenICam {target} ({} {}, serial {}): Aravis GigE fake camera fed by the simulator",
                    info.vendor, info.model, info.serial
                ),
            )
        }
        None => {
            drop(twin);
            (
                Box::new(Metered { camera: device, costs: costs.clone() }),
                format!("GenICam {target} ({} {}, serial {})", info.vendor, info.model, info.serial),
            )
        }
    };
    Ok(OpenedGonio {
        robot,
        rail,
        lamp,
        camera,
        clock,
        truth,
        links: Box::new(Links { inner: links, costs, target: label, _fake: fake }),
    })
}

/// Preflight of the GenICam camera: opened by its address (no streaming), who it says it is
/// and its temperature. A fed fake camera is served only when the rig is opened: not asked.
fn preflight_camera(cfg: &CameraConfig) -> DeviceCheck {
    let mut c = DeviceCheck::unasked("camera", "genicam", "");
    c.note = None;
    let target = match cfg.target() {
        Ok(t) => t,
        Err(e) => {
            c.failure = Some(e);
            return c;
        }
    };
    c.port = Some(format!("GenICam {target}"));
    if cfg.emulated {
        c.note = Some("emulated: the fed fake camera is served when the rig is opened".into());
        return c;
    }
    let probed = probe_one(target, false);
    match probed.info {
        Ok(info) => {
            c.identity = Some(DeviceInfo {
                name: "camera".into(),
                backend: "genicam".into(),
                model: format!("{} {}", info.vendor, info.model),
                serial: Some(info.serial.clone()),
                firmware: info.version.clone(),
            });
            c.health = Some("Ok".into());
            match cfg.format() {
                Ok(f) if !info.pixel_formats.iter().any(|p| p == f.name()) => {
                    c.failure = Some(format!(
                        "the camera does not offer devices.camera.link.pixel_format = {:?}; it offers {}",
                        f.name(),
                        info.pixel_formats.join(", ")
                    ))
                }
                Ok(_) => {}
                Err(e) => c.failure = Some(e),
            }
            if let Some(t) = probed.temperature_c {
                c.note = Some(format!("temperature {t:.1} °C"));
            }
        }
        Err(e) => c.failure = Some(e),
    }
    c
}

/// What `btfrig hw probe` learned of one GenICam camera.
#[derive(Debug, Clone)]
pub struct ProbedCamera {
    /// How it was reached (address or id).
    pub target: String,
    /// Who it is and what it offers, or why it could not be opened.
    pub info: Result<btfrig_genicam::CameraInfo, String>,
    /// `DeviceTemperature`, °C, where it has one.
    pub temperature_c: Option<f64>,
}

fn probe_one(target: Target, allow_discovery: bool) -> ProbedCamera {
    let name = target.to_string();
    let opened = GenicamCamera::open(OpenOptions { allow_discovery, ..OpenOptions::new(target) });
    match opened {
        Ok(cam) => {
            let temperature_c = cam.temperature_c().ok().flatten();
            ProbedCamera { target: name, info: Ok(cam.info()), temperature_c }
        }
        Err(e) => ProbedCamera { target: name, info: Err(e.to_string()), temperature_c: None },
    }
}

/// Opens each camera of `targets` and reads who it is. With `discover`, first lists every
/// camera Aravis finds, which BROADCASTS a discovery on every network interface: only on the
/// user's request (`--discover`).
pub fn probe_cameras(targets: &[Target], discover: bool) -> Vec<ProbedCamera> {
    let mut out: Vec<ProbedCamera> = targets.iter().map(|t| probe_one(t.clone(), false)).collect();
    if discover {
        for d in btfrig_genicam::discover() {
            let target = match d.address.parse::<Ipv4Addr>() {
                Ok(a) if d.protocol == "GigEVision" => Target::Address(a),
                _ => Target::Id(d.id.clone()),
            };
            if !targets.contains(&target) {
                out.push(probe_one(target, true));
            }
        }
    }
    out
}

/// `btfrig hw probe --rig`: the rig's GenICam camera, if its camera is one (a fed fake camera
/// is served for the probe's duration). `Ok(None)` for a rig of another camera kind.
pub fn probe_rig_camera(rig: &RigConfig) -> Result<Option<ProbedCamera>, String> {
    if rig.devices.camera.kind != "genicam" {
        return Ok(None);
    }
    let (cfg, _) = CameraConfig::split(&rig.devices.camera)?;
    let target = cfg.target()?;
    let _fake = match (&cfg.serial, &target) {
        (Some(serial), Target::Address(a)) if cfg.emulated => {
            Some(FedFakeCamera::start(*a, serial).map_err(|e| format!("devices.camera (emulated GenICam): {e}"))?)
        }
        _ => None,
    };
    Ok(Some(probe_one(target, false)))
}

/// The rig with its GenICam camera as the simulated twin the other devices' probe opens
/// (the camera itself is probed by [`probe_rig_camera`]).
pub fn without_genicam_camera(rig: &RigConfig) -> Result<RigConfig, String> {
    if rig.devices.camera.kind != "genicam" {
        return Ok(rig.clone());
    }
    inner_rig(rig).map(|(r, _)| r)
}
