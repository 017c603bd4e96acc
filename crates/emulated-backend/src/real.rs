//! Real serial controllers (`kind = "serial"` without `link.emulated`): their backends opened
//! on the port `link.port` names, for a run ([`open_real`]) and for the questions preflight
//! and `btfrig hw probe --rig` ask without moving anything ([`check_real`]).
//!
//! A rig with a real controller runs on the wall clock (`RigTime::for_rig`); its other
//! devices may still be simulated (a bench rig: a real stage and a simulated camera). The
//! simulated backend then opens the whole rig with a simulated stand-in of the same options in
//! each real controller's place ([`with_stand_ins`]): the stand-in lends the real backend its
//! configured limits and is dropped. The simulated camera renders the simulated world, in
//! which the stand-ins never move: such a rig measures timing and the device paths, not the
//! real sample.

use std::sync::Arc;

use btfrig_core::config::devices::{DeviceEntry, DevicesConfig};
use btfrig_hw::{AxisLimits, Device, DeviceError, DeviceInfo, ErrorKind, Health, SharedClock};
use btfrig_measurement::preflight::DeviceCheck;
use btfrig_protocols::grbl::Axis;
use btfrig_serial::grbl::{GrblAxis, GrblAxisConfig};
use btfrig_serial::lamp::{SerialLamp, SerialLampConfig};
use btfrig_serial::led::{SerialLedArray, SerialLedConfig};
use btfrig_serial::robot::{SerialRobot, SerialRobotConfig};
use btfrig_serial::transport::{LinkStats, SerialConnector};

use crate::firmware::{is_real_serial, link_options, GRBL_BAUD, LAMP_BAUD, LED_BAUD, ROBOT_BAUD};

/// The roles of `devices` that are real serial controllers.
pub fn real_roles(devices: &DevicesConfig) -> Vec<&'static str> {
    devices.entries().into_iter().filter(|(r, e)| is_real_serial(r, e)).map(|(r, _)| r).collect()
}

/// `devices` with each real serial controller replaced by a simulated stand-in of the same
/// options (`kind = "sim"`, no `link`).
pub fn with_stand_ins(devices: &DevicesConfig) -> DevicesConfig {
    let mut out = devices.clone();
    let stand_in = |e: &mut DeviceEntry| {
        e.options.remove("link");
        e.kind = "sim".into();
    };
    for role in real_roles(devices) {
        match role {
            "robot" => stand_in(&mut out.robot),
            "rail" => stand_in(&mut out.rail),
            "lamp" => stand_in(&mut out.lamp),
            "turntable" => out.turntable.iter_mut().for_each(stand_in),
            "led_array" => out.led_array.iter_mut().for_each(stand_in),
            _ => {}
        }
    }
    out
}

/// The limits a real controller's backend is configured with (from the rig config, through
/// the stand-in built from the same options); `None` where preflight asks only questions
/// that do not depend on them.
#[derive(Debug, Clone, Copy, Default)]
pub struct ConfiguredLimits {
    /// The robot's joints.
    pub robot: Option<[AxisLimits; 3]>,
    /// The rail.
    pub rail: Option<AxisLimits>,
    /// The turntable.
    pub turntable: Option<AxisLimits>,
}

/// Limits for a backend that only answers questions: no move is made with them.
const UNUSED_LIMITS: AxisLimits = AxisLimits { min_rad: -1e3, max_rad: 1e3, max_speed_rad_per_s: 1.0 };

/// A real controller's backend, opened.
pub enum RealDevice {
    /// The robot controller.
    Robot(SerialRobot),
    /// A GRBL axis: the rail or the turntable.
    Axis(GrblAxis),
    /// The lamp controller.
    Lamp(SerialLamp),
    /// The LED controller.
    Leds(SerialLedArray),
}

/// A real controller opened on its port, with what its link costs and how messages name it.
pub struct OpenedReal {
    /// The backend.
    pub device: RealDevice,
    /// Its link's counters.
    pub stats: Arc<LinkStats>,
    /// `PORT at BAUD baud`.
    pub target: String,
    /// The baud rate.
    pub baud: u32,
}

fn default_baud(role: &str) -> u32 {
    match role {
        "lamp" => LAMP_BAUD,
        "led_array" => LED_BAUD,
        "robot" => ROBOT_BAUD,
        _ => GRBL_BAUD,
    }
}

/// The port and baud rate of the real controller `role`.
fn port_of(role: &str, e: &DeviceEntry) -> Result<(String, u32), String> {
    let o = link_options(role, e)?;
    let port = o.port.clone().ok_or_else(|| {
        format!("devices.{role}.link.port is missing: a real serial controller names its port (e.g. \"/dev/serial/by-id/...\")")
    })?;
    Ok((port, o.baud.unwrap_or_else(|| default_baud(role))))
}

/// Opens the backend of the real serial controller `role` (entry `e`) on its port, on
/// `clock`, and asks it who it is where its protocol says (robot, lamp, LED controller; a
/// GRBL axis is asked for its status). The error names the device and the port.
pub async fn open_real(
    role: &'static str,
    e: &DeviceEntry,
    limits: &ConfiguredLimits,
    clock: SharedClock,
) -> Result<OpenedReal, String> {
    let o = link_options(role, e)?;
    let (port, baud) = port_of(role, e)?;
    let target = format!("{port} at {baud} baud");
    let fail = |what: &str, err: DeviceError| format!("devices.{role} on {target}: {what}: {err}");
    let connector = Arc::new(SerialConnector { path: port.clone(), baud });
    let (device, stats) = match role {
        "robot" => {
            let cfg = SerialRobotConfig {
                name: role.into(),
                joint_limits: limits.robot.unwrap_or([UNUSED_LIMITS; 3]),
                poll_s: o.poll_s,
                reply_timeout: o.reply_timeout,
            };
            let mut r = SerialRobot::new(cfg, connector, clock);
            r.identify().await.map_err(|err| fail("identity", err))?;
            let stats = r.link_stats();
            (RealDevice::Robot(r), stats)
        }
        "rail" | "turntable" => {
            let axis_limits = if role == "rail" { limits.rail } else { limits.turntable };
            let cfg = GrblAxisConfig {
                name: role.into(),
                model: format!("GRBL {role}"),
                axis: Axis::X,
                limits: axis_limits.unwrap_or(UNUSED_LIMITS),
                poll_s: o.poll_s,
                reply_timeout: o.reply_timeout,
                units: o.units,
            };
            let mut a = GrblAxis::new(cfg, connector, clock);
            // GRBL has no identity query: a status report is its sign of life.
            a.health().await.map_err(|err| fail("status", err))?;
            let stats = a.link_stats();
            (RealDevice::Axis(a), stats)
        }
        "lamp" => {
            let cfg = SerialLampConfig { name: role.into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
            let l = SerialLamp::open(cfg, connector, clock).await.map_err(|err| fail("identity", err))?;
            let stats = l.link_stats();
            (RealDevice::Lamp(l), stats)
        }
        "led_array" => {
            let cfg = SerialLedConfig { name: role.into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
            let l = SerialLedArray::open(cfg, connector, clock).await.map_err(|err| fail("identity", err))?;
            let stats = l.link_stats();
            (RealDevice::Leds(l), stats)
        }
        other => return Err(format!("devices.{other}: not a serial controller")),
    };
    Ok(OpenedReal { device, stats, target, baud })
}

/// Asks the real serial controller `role` for its identity, health and homing state, without
/// moving it, on a wall clock (call inside a runtime on real time). Whatever fails is the
/// check's `failure`, naming what: an unopenable port, no answer, a fault the controller
/// reports. A GRBL controller in alarm state that reports no position is taken as waiting
/// for homing (its state after power-up with homing enabled): not homed, not a failure; the
/// run homes it, and homing fails with the controller's alarm if that was something else.
pub async fn check_real(role: &'static str, e: &DeviceEntry) -> DeviceCheck {
    let mut check = DeviceCheck {
        role,
        kind: e.kind.clone(),
        port: None,
        identity: None,
        health: None,
        homed: None,
        failure: None,
        note: None,
    };
    let (port, baud) = match port_of(role, e) {
        Ok(p) => p,
        Err(err) => {
            check.failure = Some(err);
            return check;
        }
    };
    check.port = Some(format!("{port} at {baud} baud"));
    let clock: SharedClock = btfrig_hw::TokioClock::shared();
    let opened = match open_real(role, e, &ConfiguredLimits::default(), clock).await {
        Ok(o) => o,
        Err(err) => {
            // `open_real` names the device and port; the check's label does that already.
            let prefix = format!("devices.{role} on {port} at {baud} baud: ");
            check.failure = Some(err.strip_prefix(&prefix).map(str::to_string).unwrap_or(err));
            return check;
        }
    };
    let (info, health, homed): (DeviceInfo, _, _) = match opened.device {
        RealDevice::Robot(mut r) => {
            let h = r.health().await;
            let homed = btfrig_hw::Robot::is_homed(&mut r).await;
            (r.info().clone(), h, homed.map(Some))
        }
        RealDevice::Axis(mut a) => {
            let h = a.health().await;
            let homed = match btfrig_hw::Rail::position_rad(&mut a).await {
                Ok(_) => Ok(Some(true)),
                Err(err) if err.kind() == ErrorKind::NotHomed => Ok(Some(false)),
                Err(err) => Err(err),
            };
            // An alarm that only locks the axis until homing is not a fault here.
            let h = match (h, &homed) {
                (Ok(Health::Fault(_)), Ok(Some(false))) => Ok(Health::Warning("locked until homed".into())),
                (h, _) => h,
            };
            (a.info().clone(), h, homed)
        }
        RealDevice::Lamp(mut l) => {
            let h = l.health().await;
            (l.info().clone(), h, Ok(None))
        }
        RealDevice::Leds(mut l) => {
            let h = l.health().await;
            (l.info().clone(), h, Ok(None))
        }
    };
    check.identity = Some(info);
    match health {
        Ok(Health::Fault(why)) => {
            check.health = Some(format!("Fault({why:?})"));
            check.failure = Some(format!("the controller reports a fault: {why}"));
        }
        Ok(h) => check.health = Some(format!("{h:?}")),
        Err(err) => {
            check.health = Some(format!("error: {err}"));
            check.failure = Some(format!("health: {err}"));
        }
    }
    match homed {
        Ok(h) => check.homed = h,
        Err(err) => {
            if check.failure.is_none() {
                check.failure = Some(format!("homing state: {err}"));
            }
        }
    }
    if check.homed == Some(false) {
        check.note = Some("not homed: the run homes it first".into());
    }
    check
}

/// [`check_real`] for each real controller of `roles` in `devices`, on a runtime of its own
/// on a thread of its own (wall clock), and the others as needing no questions: simulated
/// devices answer for themselves, emulated firmware exists only once the rig is opened.
pub fn preflight(devices: &DevicesConfig, roles: &[&str]) -> Vec<DeviceCheck> {
    let entries: Vec<(&'static str, DeviceEntry)> =
        devices.entries().into_iter().filter(|(r, _)| roles.contains(r)).map(|(r, e)| (r, e.clone())).collect();
    let asked = std::thread::scope(|s| {
        s.spawn(|| {
            let rt = match tokio::runtime::Builder::new_current_thread().enable_time().build() {
                Ok(rt) => rt,
                Err(err) => return Err(format!("preflight runtime: {err}")),
            };
            Ok(rt.block_on(async {
                let mut out = Vec::new();
                for (role, e) in &entries {
                    out.push(if is_real_serial(role, e) {
                        check_real(role, e).await
                    } else if e.is_emulated() {
                        DeviceCheck::unasked(role, &e.kind, "emulated firmware: asked when the rig is opened")
                    } else if e.kind == "sim" {
                        DeviceCheck::unasked(role, &e.kind, "simulated: no questions")
                    } else {
                        let mut c = DeviceCheck::unasked(role, &e.kind, "");
                        c.note = None;
                        c.failure = Some(format!("kind {:?} is not a serial controller this backend opens", e.kind));
                        c
                    });
                }
                out
            }))
        })
        .join()
    });
    match asked {
        Ok(Ok(v)) => v,
        Ok(Err(err)) => entries
            .iter()
            .map(|(r, e)| {
                let mut c = DeviceCheck::unasked(r, &e.kind, "");
                c.failure = Some(err.clone());
                c
            })
            .collect(),
        Err(_) => entries
            .iter()
            .map(|(r, e)| {
                let mut c = DeviceCheck::unasked(r, &e.kind, "");
                c.failure = Some("the preflight thread panicked".into());
                c
            })
            .collect(),
    }
}
