//! `btfrig hw probe`: every device of a rig asked for its identity, health and homing state
//! through its real backend without moving it: emulated ones behind their firmware in front
//! of simulated stand-ins, real serial controllers on their ports (the questions preflight
//! asks: [`crate::real::check_real`]).

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_hw::{DeviceError, ErrorKind, Health, SharedClock};

use crate::firmware::{check_probe, connect, Devices};
use crate::real::{check_real, real_roles, with_stand_ins};

/// One device as `btfrig hw probe` reports it.
#[derive(Debug, Clone)]
pub struct Probed {
    /// Role (`robot`, `rail`, ...).
    pub role: &'static str,
    /// Backend kind in the rig config.
    pub kind: String,
    /// What the backend connects to (`<dir>/robot`, a PTP responder, a real port at its
    /// baud rate), for emulated and real ones.
    pub link: Option<String>,
    /// Identity the device reported.
    pub info: btfrig_hw::DeviceInfo,
    /// Its health, or the error asking for it.
    pub health: String,
    /// Whether it is homed (robot, rail, turntable); `None` for devices that do not home or
    /// could not say.
    pub homed: Option<bool>,
    /// Why it cannot be used (unreachable, a fault it reports); `None`: it passed.
    pub failure: Option<String>,
}

/// Opens the simulated devices of a rig config whose devices are all simulated, on a clock:
/// what [`probe`] puts behind emulated firmware (the simulated backend provides it,
/// `btfrig_sim_backend::probe`).
pub type OpenSimulated<'a> = &'a dyn Fn(&RigConfig, SharedClock) -> Result<Devices, String>;

/// The health and the failure it means.
fn judged(health: Result<Health, DeviceError>) -> (String, Option<String>) {
    match health {
        Ok(Health::Fault(why)) => (format!("Fault({why:?})"), Some(format!("the device reports a fault: {why}"))),
        Ok(h) => (format!("{h:?}"), None),
        Err(e) => (format!("error: {e}"), Some(format!("health: {e}"))),
    }
}

/// Whether an axis reports a position (`NotHomed`: no).
fn homed_from(position: Result<(), DeviceError>) -> Option<bool> {
    match position {
        Ok(()) => Some(true),
        Err(e) if e.kind() == ErrorKind::NotHomed => Some(false),
        Err(_) => None,
    }
}

/// Asks every device of `rig` for its identity, health and homing state through its real
/// backend, moving nothing: emulated devices behind their firmware on a pty (started here)
/// in front of the simulated devices `open` builds, real serial controllers on the ports
/// their `link.port` names (at `link.baud`, on the wall clock). Simulated devices answer as
/// themselves. A device that cannot be reached or reports a fault has a `failure`; the
/// others still answer. Builds its own runtime: call from a plain thread.
pub fn probe(rig: &RigConfig, open: OpenSimulated<'_>) -> Result<Vec<Probed>, String> {
    check_probe(&rig.devices)?;
    // Real controllers are probed on their ports; the simulated device built from the same
    // options stands in for them in the emulated rig.
    let real = real_roles(&rig.devices);
    let devices = with_stand_ins(&rig.devices);
    let mut sim_cfg = rig.clone();
    sim_cfg.devices = devices.simulated().ok_or("a device is neither simulated, emulated nor a serial controller")?;
    let rt = btfrig_measurement::virtual_time_runtime().map_err(|e| e.to_string())?;
    let mut out = rt.block_on(async {
        let clock: SharedClock = Arc::new(btfrig_hw::ScaledClock::new(1e-3).map_err(|e| e.to_string())?);
        let sim = open(&sim_cfg, clock.clone())?;
        let mut c = connect(&devices, sim, clock, 30.0).await?;
        let dir = c.firmware.dir().map(|d| d.display().to_string());
        let entry = |role: &str| rig.devices.entries().into_iter().find(|(r, _)| *r == role).map(|(_, e)| e.clone());
        let mut out = Vec::new();
        let mut add = |role: &'static str,
                       info: btfrig_hw::DeviceInfo,
                       health: Result<Health, DeviceError>,
                       homed: Option<bool>| {
            let e = entry(role);
            let emulated = e.as_ref().is_some_and(|e| e.is_emulated());
            let link = match (emulated, role, &dir) {
                (true, "camera", _) => Some("in-process PTP responder".to_string()),
                (true, r, Some(d)) => Some(format!("{d}/{}", if r == "led_array" { "leds" } else { r })),
                _ => None,
            };
            let (health, failure) = judged(health);
            out.push(Probed { role, kind: e.map(|e| e.kind).unwrap_or_default(), link, info, health, homed, failure });
        };
        let d = &mut c.devices;
        let h = d.robot.health().await;
        let homed = d.robot.is_homed().await.ok();
        add("robot", d.robot.info().clone(), h, homed);
        let h = d.rail.health().await;
        let homed = homed_from(d.rail.position_rad().await.map(|_| ()));
        add("rail", d.rail.info().clone(), h, homed);
        if let Some(t) = d.turntable.as_mut() {
            let h = t.health().await;
            let homed = homed_from(t.position_rad().await.map(|_| ()));
            add("turntable", t.info().clone(), h, homed);
        }
        let h = d.lamp.health().await;
        add("lamp", d.lamp.info().clone(), h, None);
        if let Some(l) = d.led_array.as_mut() {
            let h = l.health().await;
            add("led_array", l.info().clone(), h, None);
        }
        let h = d.camera.health().await;
        add("camera", d.camera.info().clone(), h, None);
        Ok::<_, String>(out)
    })?;
    drop(rt);
    // The real controllers replace their stand-ins, in the same order, asked on the wall clock.
    let wall = tokio::runtime::Builder::new_current_thread().enable_time().build().map_err(|e| e.to_string())?;
    for p in out.iter_mut().filter(|p| real.contains(&p.role)) {
        let e = rig.devices.entries().into_iter().find(|(r, _)| *r == p.role).map(|(_, e)| e.clone());
        let e = e.ok_or_else(|| format!("devices.{}: missing", p.role))?;
        let c = wall.block_on(check_real(p.role, &e));
        *p = Probed {
            role: p.role,
            kind: c.kind,
            link: c.port,
            info: c.identity.unwrap_or_else(|| btfrig_hw::DeviceInfo {
                name: p.role.into(),
                backend: "serial".into(),
                model: String::new(),
                serial: None,
                firmware: None,
            }),
            health: c.health.unwrap_or_else(|| if c.failure.is_some() { "unreachable" } else { "not asked" }.into()),
            homed: c.homed,
            failure: c.failure,
        };
    }
    Ok(out)
}
