//! `btfrig hw probe`: every device of a rig asked for its identity and health through its
//! real backend, emulated ones behind their firmware in front of simulated stand-ins, real
//! serial controllers on their ports.

use std::sync::Arc;

use btfrig_core::config::devices::DeviceEntry;
use btfrig_core::config::RigConfig;
use btfrig_hw::{Device, SharedClock};
use btfrig_protocols::grbl::Axis;
use btfrig_serial::grbl::{GrblAxis, GrblAxisConfig};
use btfrig_serial::lamp::{SerialLamp, SerialLampConfig};
use btfrig_serial::led::{SerialLedArray, SerialLedConfig};
use btfrig_serial::robot::{SerialRobot, SerialRobotConfig};
use btfrig_serial::transport::SerialConnector;

use crate::firmware::{
    check_probe, connect, is_real_serial, link_options, Devices, GRBL_BAUD, LAMP_BAUD, LED_BAUD, ROBOT_BAUD,
};

/// One device as `btfrig hw probe` reports it.
#[derive(Debug, Clone)]
pub struct Probed {
    /// Role (`robot`, `rail`, ...).
    pub role: &'static str,
    /// Backend kind in the rig config.
    pub kind: String,
    /// What the backend connects to (`<dir>/robot`, a PTP responder, ...), for emulated ones.
    pub link: Option<String>,
    /// Identity the device reported.
    pub info: btfrig_hw::DeviceInfo,
    /// Its health, or the error asking for it.
    pub health: String,
}

/// Opens the simulated devices of a rig config whose devices are all simulated, on a clock:
/// what [`probe`] puts behind emulated firmware (the simulated backend provides it,
/// `btfrig_sim_backend::probe`).
pub type OpenSimulated<'a> = &'a dyn Fn(&RigConfig, SharedClock) -> Result<Devices, String>;

/// Asks every device of `rig` for its identity and health through its real backend:
/// emulated devices behind their firmware on a pty (started here) in front of the simulated
/// devices `open` builds, real serial controllers on the ports their `link.port` names (at
/// `link.baud`). Simulated devices answer as themselves. Builds its own runtime: call from a
/// plain thread.
pub fn probe(rig: &RigConfig, open: OpenSimulated<'_>) -> Result<Vec<Probed>, String> {
    check_probe(&rig.devices)?;
    // Real controllers are probed on their ports; the simulated device built from the same
    // options stands in for them in the emulated rig and lends its configured limits.
    let real: Vec<&'static str> =
        rig.devices.entries().into_iter().filter(|(r, e)| is_real_serial(r, e)).map(|(r, _)| r).collect();
    let mut devices = rig.devices.clone();
    let stand_in = |e: &mut DeviceEntry| {
        e.options.remove("link");
        e.kind = "sim".into();
    };
    for role in &real {
        match *role {
            "robot" => stand_in(&mut devices.robot),
            "rail" => stand_in(&mut devices.rail),
            "lamp" => stand_in(&mut devices.lamp),
            "turntable" => devices.turntable.iter_mut().for_each(stand_in),
            "led_array" => devices.led_array.iter_mut().for_each(stand_in),
            _ => {}
        }
    }
    let mut sim_cfg = rig.clone();
    sim_cfg.devices = devices.simulated().ok_or("a device is neither simulated, emulated nor a serial controller")?;
    let rt = btfrig_measurement::virtual_time_runtime().map_err(|e| e.to_string())?;
    rt.block_on(async {
        let clock: SharedClock = Arc::new(btfrig_hw::ScaledClock::new(1e-3).map_err(|e| e.to_string())?);
        let Devices { robot, rail, turntable, lamp, led_array, camera } = open(&sim_cfg, clock.clone())?;
        let limits = ConfiguredLimits {
            robot: robot.joint_limits(),
            rail: rail.limits(),
            turntable: turntable.as_ref().map(|t| t.limits()),
        };
        let mut c = connect(&devices, Devices { robot, rail, turntable, lamp, led_array, camera }, clock, 30.0).await?;
        let dir = c.firmware.dir().map(|d| d.display().to_string());
        let entry = |role: &str| rig.devices.entries().into_iter().find(|(r, _)| *r == role).map(|(_, e)| e.clone());
        let mut out = Vec::new();
        let mut add = |role: &'static str,
                       info: btfrig_hw::DeviceInfo,
                       health: Result<btfrig_hw::Health, btfrig_hw::DeviceError>| {
            let e = entry(role);
            let emulated = e.as_ref().is_some_and(|e| e.is_emulated());
            let link = match (emulated, role, &dir) {
                (true, "camera", _) => Some("in-process PTP responder".to_string()),
                (true, r, Some(d)) => Some(format!("{d}/{}", if r == "led_array" { "leds" } else { r })),
                _ => None,
            };
            let health = match health {
                Ok(h) => format!("{h:?}"),
                Err(e) => format!("error: {e}"),
            };
            out.push(Probed { role, kind: e.map(|e| e.kind).unwrap_or_default(), link, info, health });
        };
        let h = c.devices.robot.health().await;
        add("robot", c.devices.robot.info().clone(), h);
        let h = c.devices.rail.health().await;
        add("rail", c.devices.rail.info().clone(), h);
        if let Some(t) = c.devices.turntable.as_mut() {
            let h = t.health().await;
            add("turntable", t.info().clone(), h);
        }
        let h = c.devices.lamp.health().await;
        add("lamp", c.devices.lamp.info().clone(), h);
        if let Some(l) = c.devices.led_array.as_mut() {
            let h = l.health().await;
            add("led_array", l.info().clone(), h);
        }
        let h = c.devices.camera.health().await;
        add("camera", c.devices.camera.info().clone(), h);
        // The real controllers replace their stand-ins, in the same order.
        for p in out.iter_mut().filter(|p| real.contains(&p.role)) {
            let e = entry(p.role).ok_or_else(|| format!("devices.{}: missing", p.role))?;
            *p = probe_real(p.role, &e, &limits).await?;
        }
        Ok(out)
    })
}

/// Limits a real controller's backend is configured with (from the rig config, through the
/// simulated device built from the same options).
struct ConfiguredLimits {
    robot: [btfrig_hw::AxisLimits; 3],
    rail: btfrig_hw::AxisLimits,
    turntable: Option<btfrig_hw::AxisLimits>,
}

/// Opens the backend of the real serial controller `role` on its port and asks it for its
/// identity and health (in wall-clock time: real hardware). A port that cannot be opened or
/// a controller that does not answer is a health error, not a failed probe.
async fn probe_real(role: &'static str, e: &DeviceEntry, limits: &ConfiguredLimits) -> Result<Probed, String> {
    let o = link_options(role, e)?;
    let port = o.port.clone().ok_or_else(|| format!("devices.{role}.link.port is missing"))?;
    let default_baud = match role {
        "lamp" => LAMP_BAUD,
        "led_array" => LED_BAUD,
        "robot" => ROBOT_BAUD,
        _ => GRBL_BAUD,
    };
    let baud = o.baud.unwrap_or(default_baud);
    let connector = Arc::new(SerialConnector { path: port.clone(), baud });
    let clock: SharedClock = Arc::new(btfrig_hw::ScaledClock::new(1.0).map_err(|e| e.to_string())?);
    let unnamed = |backend: &str| btfrig_hw::DeviceInfo {
        name: role.into(),
        backend: backend.into(),
        model: String::new(),
        serial: None,
        firmware: None,
    };
    let (info, health) = match role {
        "robot" => {
            let cfg = SerialRobotConfig {
                name: role.into(),
                joint_limits: limits.robot,
                poll_s: o.poll_s,
                reply_timeout: o.reply_timeout,
            };
            let mut r = SerialRobot::new(cfg, connector, clock);
            match r.identify().await {
                Ok(()) => {
                    let h = r.health().await;
                    (r.info().clone(), h)
                }
                Err(e) => (r.info().clone(), Err(e)),
            }
        }
        "rail" | "turntable" => {
            let axis_limits = if role == "rail" { Some(limits.rail) } else { limits.turntable };
            let cfg = GrblAxisConfig {
                name: role.into(),
                model: format!("GRBL {role}"),
                axis: Axis::X,
                limits: axis_limits.ok_or_else(|| format!("devices.{role}: no limits configured"))?,
                poll_s: o.poll_s,
                reply_timeout: o.reply_timeout,
                units: o.units,
            };
            let mut a = GrblAxis::new(cfg, connector, clock);
            let h = a.health().await;
            (a.info().clone(), h)
        }
        "lamp" => {
            let cfg = SerialLampConfig { name: role.into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
            match SerialLamp::open(cfg, connector, clock).await {
                Ok(mut l) => {
                    let h = l.health().await;
                    (l.info().clone(), h)
                }
                Err(e) => (unnamed("serial"), Err(e)),
            }
        }
        "led_array" => {
            let cfg = SerialLedConfig { name: role.into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
            match SerialLedArray::open(cfg, connector, clock).await {
                Ok(mut l) => {
                    let h = l.health().await;
                    (l.info().clone(), h)
                }
                Err(e) => (unnamed("serial"), Err(e)),
            }
        }
        other => return Err(format!("devices.{other}: not a serial controller")),
    };
    let health = match health {
        Ok(h) => format!("{h:?}"),
        Err(e) => format!("error: {e}"),
    };
    Ok(Probed { role, kind: e.kind.clone(), link: Some(format!("{port} at {baud} baud")), info, health })
}
