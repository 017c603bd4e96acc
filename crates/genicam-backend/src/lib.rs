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

mod cameras;
mod config;
mod probe;

use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use btfrig_acquire::dome::DomeDevices;
use btfrig_core::config::RigConfig;
use btfrig_genicam::{DeviceOptions, FedFakeCamera, GenicamCamera, GenicamDevice, OpenOptions};
use btfrig_hw::{Camera, SharedClock};
use btfrig_measurement::backend::{
    BackendRegistry, CalibrationOpenRequest, DomeOpenRequest, GonioOpenRequest, LinkReport, LinkUse, OpenedDome,
    OpenedGonio, OpenedRig, RigBackend, SceneOptions,
};
use btfrig_measurement::preflight::{DeviceCheck, Role};
use btfrig_measurement::RunError;

pub use cameras::FedCamera;
use cameras::{Costs, Links, Metered};
use config::{inner_rig, rig_sites};
pub use config::{CameraConfig, CameraSite};
use probe::preflight_cameras;
pub use probe::{probe_cameras, probe_rig_camera, without_genicam_camera, ProbedCamera};

pub use btfrig_genicam::Target;

/// The device kinds [`GenicamBackend`] opens: a GenICam camera, the other devices as the
/// inner registry opens them.
pub const KINDS: &[&str] = &["genicam", "sim", "serial", "ptp"];

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
        with_genicam_camera(req.rig, &cfg, opened).await
    }

    async fn open_dome(&self, req: DomeOpenRequest<'_>) -> Result<OpenedDome, RunError> {
        let (inner_cfg, cfg) = inner_rig(req.rig).map_err(RunError::Rig)?;
        let inner = self.inner.for_rig(&inner_cfg)?;
        let rig = req.rig;
        let positions = req.plan.cameras.clone();
        let opened = inner.open_dome(DomeOpenRequest { rig: &inner_cfg, ..req }).await?;
        with_genicam_cameras(rig, &cfg, &positions, opened).await
    }

    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        let (inner_cfg, cfg) = inner_rig(req.rig).map_err(RunError::Rig)?;
        let inner = self.inner.for_rig(&inner_cfg)?;
        match inner.open_calibration(CalibrationOpenRequest { rig: &inner_cfg, ..req }).await? {
            OpenedRig::Gonio(opened) => Ok(OpenedRig::Gonio(with_genicam_camera(req.rig, &cfg, opened).await?)),
            OpenedRig::Dome(opened) => {
                Ok(OpenedRig::Dome(with_genicam_cameras(req.rig, &cfg, req.cameras, opened).await?))
            }
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
        if let Some(at) = checks.iter().position(|c| c.role == "camera") {
            checks.retain(|c| c.role != "camera");
            let cameras = preflight_cameras(rig, &cfg);
            checks.splice(at..at, cameras);
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
/// camera of `cfg` in the twin's place.
async fn with_genicam_camera(
    rig: &RigConfig,
    cfg: &CameraConfig,
    opened: OpenedGonio,
) -> Result<OpenedGonio, RunError> {
    let OpenedGonio { robot, rail, lamp, camera: twin, clock, truth, links } = opened;
    let site = rig_sites(rig, cfg).map_err(RunError::Rig)?.remove(0);
    let placed = place_genicam_camera(cfg, &site, "camera".into(), twin, clock.clone()).await?;
    Ok(OpenedGonio {
        robot,
        rail,
        lamp,
        camera: placed.camera,
        clock,
        truth,
        links: Box::new(Links { inner: links, costs: placed.costs, target: placed.label, _fake: placed.fake }),
    })
}

/// A dome's or camera array's devices with a GenICam camera in each simulated twin's place:
/// the camera at `positions[i]`'s address replaces the twin `i`. The cameras open in turn
/// (each open is a few control exchanges; a dome's handful of cameras takes well under a
/// second).
async fn with_genicam_cameras(
    rig: &RigConfig,
    cfg: &CameraConfig,
    positions: &[usize],
    opened: OpenedDome,
) -> Result<OpenedDome, RunError> {
    let OpenedDome { devices, truth, links } = opened;
    let sites = rig_sites(rig, cfg).map_err(RunError::Rig)?;
    if devices.cameras.len() != positions.len() {
        return Err(RunError::Rig(format!(
            "the inner backend opened {} cameras for camera positions {positions:?}",
            devices.cameras.len()
        )));
    }
    let mut cameras = Vec::with_capacity(positions.len());
    let mut fakes = Vec::new();
    let mut meters = Vec::new();
    for (twin, &position) in devices.cameras.into_iter().zip(positions) {
        let site = sites.get(position).ok_or_else(|| {
            RunError::Rig(format!("camera position {position}: the rig has {} camera positions", sites.len()))
        })?;
        let placed = place_genicam_camera(cfg, site, format!("camera {position}"), twin, devices.clock.clone()).await?;
        cameras.push(placed.camera);
        meters.push((format!("camera {position}"), placed.label, placed.costs));
        fakes.extend(placed.fake);
    }
    Ok(OpenedDome {
        devices: DomeDevices { cameras, ..devices },
        truth,
        links: Box::new(DomeLinks { inner: links, cameras: meters, _fakes: fakes }),
    })
}

/// A dome's links: the inner backend's and one per GenICam camera (its position, label and
/// costs). Dropped in field order: the fed fake cameras last, since they outlive the clients
/// that stream from them.
struct DomeLinks {
    inner: Box<dyn LinkReport>,
    cameras: Vec<(String, String, Arc<Costs>)>,
    _fakes: Vec<Arc<FedFakeCamera>>,
}

impl LinkReport for DomeLinks {
    fn link_use(&self) -> Vec<LinkUse> {
        let mut v = self.inner.link_use();
        v.extend(self.cameras.iter().map(|(_, target, costs)| costs.link_use("camera", target.clone())));
        v
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        self.inner.skipped_lines()
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        Some(self.cameras.iter().map(|(_, _, c)| c.wall_s()).sum())
    }

    fn count(&self) -> usize {
        self.inner.count() + self.cameras.len()
    }
}

/// One GenICam camera in its simulated twin's place.
struct Placed {
    camera: Box<dyn Camera>,
    label: String,
    costs: Arc<Costs>,
    fake: Option<Arc<FedFakeCamera>>,
}

/// The GenICam camera of `site` in place of `twin`: a fed fake camera serving the twin's frames
/// when `cfg.emulated`, else the camera at the address, the twin dropped. `name` is the
/// device's name in messages.
async fn place_genicam_camera(
    cfg: &CameraConfig,
    site: &CameraSite,
    name: String,
    twin: Box<dyn Camera>,
    clock: SharedClock,
) -> Result<Placed, RunError> {
    let target = site.target.clone();
    let format = cfg.format().map_err(RunError::Rig)?;
    let gain_unit = cfg.gain().map_err(RunError::Rig)?;
    let key = if site.position == 0 && cfg.addresses.is_none() {
        "devices.camera".to_string()
    } else {
        format!("devices.camera (position {})", site.position)
    };
    // The fed fake camera first, so that the client finds it at the address.
    let fake = match (&site.serial, &target) {
        (Some(serial), Target::Address(address)) if cfg.emulated => {
            let (address, serial, k) = (*address, serial.clone(), key.clone());
            let fake = blocking(move || {
                FedFakeCamera::start(address, &serial).map_err(|e| format!("{k} (emulated GenICam): {e}"))
            })
            .await?;
            Some(Arc::new(fake))
        }
        _ => None,
    };
    let (t, k) = (target.clone(), key.clone());
    let camera = blocking(move || {
        GenicamCamera::open(OpenOptions { control_timeout: Duration::from_secs(5), ..OpenOptions::new(t.clone()) })
            .map_err(|e| format!("{k} (GenICam {t}): {e}"))
    })
    .await?;
    let info = camera.info();
    if let (true, Some(serial)) = (cfg.emulated, &site.serial) {
        if &info.serial != serial {
            return Err(RunError::Rig(format!(
                "{key}: the camera at {target} has serial {:?}, not the fake camera's {serial:?}: another camera holds the address",
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
        name,
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
    let device = GenicamDevice::open(camera, options, clock).await.map_err(|e| RunError::Rig(e.to_string()))?;
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
    Ok(Placed { camera, label, costs, fake })
}
