//! Asking GenICam cameras who they are without streaming: preflight and `btfrig hw probe`.

use std::net::Ipv4Addr;

use btfrig_core::config::RigConfig;
use btfrig_genicam::{FedFakeCamera, GenicamCamera, OpenOptions};
use btfrig_hw::DeviceInfo;
use btfrig_measurement::preflight::DeviceCheck;

use crate::config::{inner_rig, rig_sites, CameraConfig, CameraSite};
use crate::Target;

/// Preflight of the rig's GenICam cameras (one, or one per camera position of a dome or
/// camera array, asked in parallel so that absent cameras' timeouts do not add up).
pub(crate) fn preflight_cameras(rig: &RigConfig, cfg: &CameraConfig) -> Vec<DeviceCheck> {
    let sites = match rig_sites(rig, cfg) {
        Ok(s) => s,
        Err(e) => {
            let mut c = DeviceCheck::unasked("camera", "genicam", "");
            (c.note, c.failure) = (None, Some(e));
            return vec![c];
        }
    };
    let dome = rig.dome.is_some();
    std::thread::scope(|scope| {
        let jobs: Vec<_> = sites.iter().map(|site| scope.spawn(move || preflight_camera(cfg, site, dome))).collect();
        jobs.into_iter().map(|j| j.join().expect("a camera preflight panicked")).collect()
    })
}

/// Preflight of one GenICam camera: opened by its address (no streaming), who it says it is
/// and its temperature. A fed fake camera is served only when the rig is opened: not asked.
fn preflight_camera(cfg: &CameraConfig, site: &CameraSite, dome: bool) -> DeviceCheck {
    let mut c = DeviceCheck::unasked("camera", "genicam", "");
    c.note = None;
    let target = site.target.clone();
    c.port = Some(if dome {
        format!("GenICam {target}, camera position {}", site.position)
    } else {
        format!("GenICam {target}")
    });
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

/// `btfrig hw probe --rig`: the rig's GenICam cameras, if its camera is one (a dome's or
/// camera array's: one per camera position; fed fake cameras are served for the probe's
/// duration). Empty for a rig of another camera kind.
pub fn probe_rig_camera(rig: &RigConfig) -> Result<Vec<ProbedCamera>, String> {
    if rig.devices.camera.kind != "genicam" {
        return Ok(Vec::new());
    }
    let (_, cfg) = inner_rig(rig)?;
    let sites = rig_sites(rig, &cfg)?;
    let mut fakes = Vec::new();
    for site in &sites {
        if let (Some(serial), Target::Address(a), true) = (&site.serial, &site.target, cfg.emulated) {
            fakes.push(
                FedFakeCamera::start(*a, serial).map_err(|e| format!("devices.camera (emulated GenICam {a}): {e}"))?,
            );
        }
    }
    let probed = std::thread::scope(|scope| {
        let jobs: Vec<_> = sites.iter().map(|s| scope.spawn(|| probe_one(s.target.clone(), false))).collect();
        jobs.into_iter().map(|j| j.join().expect("a camera probe panicked")).collect()
    });
    drop(fakes);
    Ok(probed)
}

/// The rig with its GenICam camera as the simulated twin the other devices' probe opens
/// (the camera itself is probed by [`probe_rig_camera`]).
pub fn without_genicam_camera(rig: &RigConfig) -> Result<RigConfig, String> {
    if rig.devices.camera.kind != "genicam" {
        return Ok(rig.clone());
    }
    inner_rig(rig).map(|(r, _)| r)
}
