//! Emulated firmware in front of simulated devices: each emulated device's firmware is served
//! on a pseudo-terminal (the camera: an in-process PTP responder) and its real serial or PTP
//! backend connects to it like to hardware (docs/serial.md). Also the `[devices.ROLE.link]`
//! options, the faults a test injects into a firmware, and what each link cost.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::devices::{DeviceEntry, DevicesConfig};
use btfrig_hw::{Camera, Lamp, LedArray, Rail, Robot, SharedClock, Turntable};
use btfrig_measurement::backend::{LinkReport, LinkUse};
use btfrig_protocols::grbl::Axis;
use btfrig_ptp::camera::{PtpCamera, PtpCameraConfig, PtpStats};
use btfrig_ptp::responder::{PtpResponder, ResponderConfig};
use btfrig_serial::firmware::grbl::{AxisDevice, GrblFirmware};
use btfrig_serial::firmware::lamp::{LampFirmware, LampFirmwareConfig};
use btfrig_serial::firmware::led::LedFirmware;
use btfrig_serial::firmware::robot::RobotFirmware;
use btfrig_serial::grbl::{AxisUnits, GrblAxis, GrblAxisConfig};
use btfrig_serial::lamp::{SerialLamp, SerialLampConfig};
use btfrig_serial::led::{SerialLedArray, SerialLedConfig};
use btfrig_serial::robot::{SerialRobot, SerialRobotConfig};
use btfrig_serial::transport::{LinkStats, SerialConnector};

/// The backend options of an emulated device (`[devices.<role>.link]`).
#[derive(Debug, Clone, PartialEq)]
pub struct LinkOptions {
    /// Status poll interval while the device works, rig seconds.
    pub poll_s: f64,
    /// How long a reply may take, wall clock.
    pub reply_timeout: Duration,
    /// GRBL axis unit (rail, turntable).
    pub units: AxisUnits,
    /// The port of a real controller (`/dev/serial/by-id/...`); `None` when emulated.
    pub port: Option<String>,
    /// Its baud rate (8N1); `None`: the controller's default (robot and GRBL 115200, lamp
    /// 9600, LED 460800).
    pub baud: Option<u32>,
}

/// Baud rates a real serial link may name.
const BAUD_RATES: [u32; 12] =
    [1200, 2400, 4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600, 1_000_000];

/// The link options of `entry` (`devices.<role>`), or a message naming the bad key.
pub fn link_options(role: &str, entry: &DeviceEntry) -> Result<LinkOptions, String> {
    let mut o = LinkOptions {
        poll_s: 0.01,
        reply_timeout: Duration::from_millis(2000),
        units: AxisUnits::Radians,
        port: None,
        baud: None,
    };
    let Some(t) = entry.options.get("link").and_then(|l| l.as_table()) else { return Ok(o) };
    let f = |k: &str, v: &toml::Value| {
        v.as_float()
            .or_else(|| v.as_integer().map(|i| i as f64))
            .ok_or_else(|| format!("devices.{role}.link.{k} must be a number"))
    };
    for (k, v) in t {
        match k.as_str() {
            "emulated" => {}
            "poll_s" => {
                o.poll_s = f(k, v)?;
                if !(o.poll_s > 0.0 && o.poll_s <= 10.0) {
                    return Err(format!(
                        "devices.{role}.link.poll_s = {} is out of range: allowed (0, 10] s",
                        o.poll_s
                    ));
                }
            }
            "reply_timeout_ms" => {
                let ms = f(k, v)?;
                if !(1.0..=60_000.0).contains(&ms) {
                    return Err(format!(
                        "devices.{role}.link.reply_timeout_ms = {ms} is out of range: allowed [1, 60000]"
                    ));
                }
                o.reply_timeout = Duration::from_secs_f64(ms / 1000.0);
            }
            "port" if role != "camera" => match v.as_str() {
                Some(p) if !p.trim().is_empty() => o.port = Some(p.to_string()),
                _ => {
                    return Err(format!(
                        "devices.{role}.link.port = {v} must be a device path such as \"/dev/ttyUSB0\""
                    ))
                }
            },
            "baud" if role != "camera" => match v.as_integer() {
                Some(b) if BAUD_RATES.iter().any(|&r| i64::from(r) == b) => o.baud = Some(b as u32),
                _ => {
                    return Err(format!(
                        "devices.{role}.link.baud = {v} is not a supported rate: allowed {}",
                        BAUD_RATES.map(|b| b.to_string()).join(", ")
                    ))
                }
            },
            "units" if role == "rail" || role == "turntable" => {
                o.units = match v.as_str() {
                    Some("rad") => AxisUnits::Radians,
                    Some("deg") => AxisUnits::Degrees,
                    _ => return Err(format!("devices.{role}.link.units = {v} is unknown: allowed \"rad\", \"deg\"")),
                }
            }
            other => {
                return Err(format!(
                    "devices.{role}.link.{other} is unknown: allowed emulated, poll_s, reply_timeout_ms{}{}",
                    if role == "camera" { "" } else { ", port, baud" },
                    if role == "rail" || role == "turntable" { ", units" } else { "" }
                ))
            }
        }
    }
    let emulated = t.get("emulated").and_then(toml::Value::as_bool) == Some(true);
    if emulated && (o.port.is_some() || o.baud.is_some()) {
        return Err(format!(
            "devices.{role}.link: emulated = true and a port/baud: an emulated controller is served on a pty of its own; drop one"
        ));
    }
    Ok(o)
}

/// Checks every emulated and real device's kind and link options; the kinds are `"serial"`
/// for robot, rail, turntable, lamp and LED array, `"ptp"` for the camera (emulated only so
/// far). A real serial controller names its port (`link.port`).
pub fn check(devices: &DevicesConfig) -> Result<(), String> {
    check_kinds(devices)
}

/// What `btfrig hw probe --rig` accepts: the same as [`check`].
pub fn check_probe(devices: &DevicesConfig) -> Result<(), String> {
    check_kinds(devices)
}

/// Whether `entry` is a real serial controller (not simulated, not emulated).
pub(crate) fn is_real_serial(role: &str, e: &DeviceEntry) -> bool {
    e.kind == "serial" && role != "camera" && !e.is_emulated()
}

fn check_kinds(devices: &DevicesConfig) -> Result<(), String> {
    for (role, e) in devices.entries() {
        if e.kind == "sim" {
            continue;
        }
        let want = if role == "camera" { "ptp" } else { "serial" };
        if e.kind != want {
            return Err(format!("devices.{role}.kind = {:?} is unknown: allowed \"sim\", {want:?}", e.kind));
        }
        let o = link_options(role, e)?;
        if !e.is_emulated() {
            if role == "camera" {
                return Err(
                    "devices.camera: a PTP camera over USB is not selectable in a rig config yet; set [devices.camera.link] emulated = true, or kind = \"sim\" (attached cameras: `btfrig hw probe`)"
                        .into(),
                );
            }
            if o.port.is_none() {
                return Err(format!(
                    "devices.{role}.link.port is missing: a real {want} controller names its port (e.g. \"/dev/serial/by-id/...\"), or set emulated = true"
                ));
            }
        }
    }
    Ok(())
}

/// The devices of a rig, some through emulated firmware, and what keeps that firmware
/// running (drop it after the devices).
pub struct Connected {
    /// The devices, those configured as emulated behind their firmware.
    pub devices: Devices,
    /// The firmware emulators and their pty directory.
    pub firmware: Firmware,
}

/// A fault for one emulated device's firmware (tests: [`crate::EmulatedBackend::with_link_faults`]).
/// Faults apply when injected; wrap one in `OnNextMove` to fire it right after the next
/// move is accepted, and nest `OnNextMove` n times for the n-th move (homing is not a move).
#[derive(Debug, Clone)]
pub enum LinkFault {
    /// To the rail's GRBL controller.
    Rail(btfrig_serial::firmware::grbl::Fault),
    /// To the turntable's GRBL controller.
    Turntable(btfrig_serial::firmware::grbl::Fault),
    /// To the robot controller.
    Robot(btfrig_serial::firmware::robot::Fault),
    /// To the camera's PTP responder.
    Camera(btfrig_ptp::responder::Fault),
}

impl LinkFault {
    /// The fault `f` on the `n`-th move from now (n >= 1).
    pub fn on_move_grbl(n: usize, f: btfrig_serial::firmware::grbl::Fault) -> btfrig_serial::firmware::grbl::Fault {
        use btfrig_serial::firmware::grbl::Fault;
        (0..n).fold(f, |f, _| Fault::OnNextMove(Box::new(f)))
    }

    /// The fault `f` on the robot's `n`-th move from now (n >= 1).
    pub fn on_move_robot(n: usize, f: btfrig_serial::firmware::robot::Fault) -> btfrig_serial::firmware::robot::Fault {
        use btfrig_serial::firmware::robot::Fault;
        (0..n).fold(f, |f, _| Fault::OnNextMove(Box::new(f)))
    }
}

/// Running emulators; dropping stops them and removes the pty links.
#[derive(Default)]
pub struct Firmware {
    robot: Option<RobotFirmware>,
    rail: Option<GrblFirmware>,
    turntable: Option<GrblFirmware>,
    lamp: Option<LampFirmware>,
    leds: Option<LedFirmware>,
    camera: Option<PtpResponder>,
    dir: Option<PathBuf>,
    serial_links: Vec<SerialMeter>,
    camera_link: Option<Arc<PtpStats>>,
}

/// A serial backend's counters, with what it is connected to.
struct SerialMeter {
    role: &'static str,
    target: String,
    baud: u32,
    stats: Arc<LinkStats>,
}

impl Firmware {
    /// The directory of the pty links (`robot`, `rail`, ...), if any device is emulated.
    pub fn dir(&self) -> Option<&std::path::Path> {
        self.dir.as_deref()
    }

    /// Injects `fault` into its device's emulator, or says that device is not emulated.
    pub fn inject(&self, fault: &LinkFault) -> Result<(), String> {
        let missing = |role: &str| format!("link fault {fault:?}: the {role} is not emulated in this rig");
        match fault {
            LinkFault::Rail(f) => self.rail.as_ref().ok_or_else(|| missing("rail"))?.inject(f.clone()),
            LinkFault::Turntable(f) => self.turntable.as_ref().ok_or_else(|| missing("turntable"))?.inject(f.clone()),
            LinkFault::Robot(f) => self.robot.as_ref().ok_or_else(|| missing("robot"))?.inject(f.clone()),
            LinkFault::Camera(f) => self.camera.as_ref().ok_or_else(|| missing("camera"))?.inject(f.clone()),
        }
        Ok(())
    }

    /// Undecodable lines or frames each serial backend skipped so far (garbage on the line),
    /// for the devices that skipped any; the runner turns them into warnings.
    pub fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        self.serial_links.iter().map(|m| (m.role, m.stats.totals().skipped)).filter(|(_, n)| *n > 0).collect()
    }

    /// Wall seconds the camera's PTP coding took so far (on the engine's own path, so it
    /// adds to the run's wall time); `None` without an emulated camera.
    pub fn camera_coding_wall_s(&self) -> Option<f64> {
        self.camera_link.as_ref().map(|c| c.totals().codec_wall_s)
    }

    /// What each emulated link cost so far, serial links first, then the camera.
    pub fn link_use(&self) -> Vec<LinkUse> {
        let mut out: Vec<LinkUse> = self
            .serial_links
            .iter()
            .map(|m| {
                let t = m.stats.totals();
                LinkUse {
                    role: m.role,
                    // A real controller's target names its port at its own baud rate.
                    target: if m.target.ends_with(" baud") {
                        m.target.clone()
                    } else {
                        format!("{} at {} baud (nominal)", m.target, m.baud)
                    },
                    exchanges: t.exchanges,
                    bytes_out: t.bytes_out,
                    bytes_in: t.bytes_in,
                    wall_s: t.exchange_wall_s,
                    wire_s: Some(t.wire_s(m.baud)),
                    dropped_buffers: None,
                }
            })
            .collect();
        if let Some(c) = &self.camera_link {
            let t = c.totals();
            out.push(LinkUse {
                role: "camera",
                target: "in-process PTP responder".into(),
                exchanges: t.transactions,
                bytes_out: t.bytes_out,
                bytes_in: t.bytes_in,
                wall_s: t.codec_wall_s,
                wire_s: None,
                dropped_buffers: None,
            });
        }
        out
    }

    /// How many emulators run.
    pub fn count(&self) -> usize {
        usize::from(self.robot.is_some())
            + usize::from(self.rail.is_some())
            + usize::from(self.turntable.is_some())
            + usize::from(self.lamp.is_some())
            + usize::from(self.leds.is_some())
            + usize::from(self.camera.is_some())
    }
}

impl Drop for Firmware {
    fn drop(&mut self) {
        self.robot = None;
        self.rail = None;
        self.turntable = None;
        self.lamp = None;
        self.leds = None;
        self.camera = None;
        if let Some(d) = &self.dir {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// A rig's devices (turntable and LED array where it has them): as another backend opened
/// them (the simulated ones of [`DevicesConfig::simulated`]), or with some behind emulated
/// firmware ([`Connected`]).
pub struct Devices {
    /// The robot.
    pub robot: Box<dyn Robot>,
    /// The rail.
    pub rail: Box<dyn Rail>,
    /// The turntable.
    pub turntable: Option<Box<dyn Turntable>>,
    /// The lamp.
    pub lamp: Box<dyn Lamp>,
    /// The LED array.
    pub led_array: Option<Box<dyn LedArray>>,
    /// The camera.
    pub camera: Box<dyn Camera>,
}

/// Nominal baud rates of the emulated links: what the controllers' real counterparts use
/// (docs/serial.md); a pty ignores them, the report's `wire_s` uses them.
pub(crate) const ROBOT_BAUD: u32 = 115_200;
pub(crate) const GRBL_BAUD: u32 = 115_200;
pub(crate) const LAMP_BAUD: u32 = 9_600;
pub(crate) const LED_BAUD: u32 = 460_800;

impl Firmware {
    fn meter(&mut self, role: &'static str, link: &std::path::Path, baud: u32, stats: Arc<LinkStats>) {
        self.serial_links.push(SerialMeter { role, target: link.display().to_string(), baud, stats });
    }
}

fn serial(path: &std::path::Path, baud: u32) -> Arc<SerialConnector> {
    Arc::new(SerialConnector { path: path.to_string_lossy().into_owned(), baud })
}

/// Puts emulated firmware in front of each simulated device whose entry in `devices` is
/// emulated and connects the real backend to it; other devices pass through. Call inside
/// the tokio runtime the devices run on; `read_timeout_s` is the engine's read-out timeout
/// (the emulated camera gives up on a read-out after it too).
pub async fn connect(
    devices: &DevicesConfig,
    sim: Devices,
    clock: SharedClock,
    read_timeout_s: f64,
) -> Result<Connected, String> {
    check(devices)?;
    let mut fw = Firmware::for_devices(devices)?;
    let dir = fw.dir.clone().unwrap_or_default();
    let sim = connect_real(&mut fw, devices, sim, &clock).await?;

    let robot: Box<dyn Robot> = if devices.robot.is_emulated() {
        let o = link_options("robot", &devices.robot)?;
        let link = dir.join("robot");
        let joint_limits = sim.robot.joint_limits();
        fw.robot = Some(RobotFirmware::spawn(sim.robot, &link).map_err(|e| firmware_io("robot", e))?);
        let cfg =
            SerialRobotConfig { name: "robot".into(), joint_limits, poll_s: o.poll_s, reply_timeout: o.reply_timeout };
        let mut r = SerialRobot::new(cfg, serial(&link, ROBOT_BAUD), clock.clone());
        fw.meter("robot", &link, ROBOT_BAUD, r.link_stats());
        r.identify().await.map_err(|e| backend_error("robot", e))?;
        Box::new(r)
    } else {
        sim.robot
    };
    let rail: Box<dyn Rail> = if devices.rail.is_emulated() {
        let o = link_options("rail", &devices.rail)?;
        let limits = sim.rail.limits();
        Box::new(emulate_axis(&mut fw, "rail", AxisDevice::Rail(sim.rail), limits, &o, &clock)?)
    } else {
        sim.rail
    };
    let turntable = match sim.turntable {
        Some(t) => Some(emulate_turntable(&mut fw, devices, t, &clock)?),
        None => None,
    };
    let lamp: Box<dyn Lamp> = if devices.lamp.is_emulated() {
        let o = link_options("lamp", &devices.lamp)?;
        let link = dir.join("lamp");
        fw.lamp = Some(
            LampFirmware::spawn(sim.lamp, LampFirmwareConfig::default(), clock.clone(), &link)
                .map_err(|e| firmware_io("lamp", e))?,
        );
        let cfg = SerialLampConfig { name: "lamp".into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
        let l = SerialLamp::open(cfg, serial(&link, LAMP_BAUD), clock.clone())
            .await
            .map_err(|e| backend_error("lamp", e))?;
        fw.meter("lamp", &link, LAMP_BAUD, l.link_stats());
        Box::new(l)
    } else {
        sim.lamp
    };
    let led_array = match sim.led_array {
        Some(l) => Some(emulate_leds(&mut fw, devices, l, &clock).await?),
        None => None,
    };
    let camera: Box<dyn Camera> = if devices.camera.is_emulated() {
        let capabilities = sim.camera.capabilities();
        let rcfg = ResponderConfig { read_timeout_s, ..ResponderConfig::default() };
        let (responder, transport) = PtpResponder::spawn(sim.camera, rcfg);
        fw.camera = Some(responder);
        let cfg = PtpCameraConfig { name: "camera".into(), capabilities, op_timeout_s: 10.0, read_margin_s: 1.0 };
        let c =
            PtpCamera::open(cfg, Box::new(transport), clock.clone()).await.map_err(|e| backend_error("camera", e))?;
        fw.camera_link = Some(c.stats());
        Box::new(c)
    } else {
        sim.camera
    };
    Ok(Connected { devices: Devices { robot, rail, turntable, lamp, led_array, camera }, firmware: fw })
}

/// Replaces the simulated stand-in of each real serial controller in `devices`
/// ([`crate::real::with_stand_ins`]) with the controller's backend on its port, configured
/// with the stand-in's limits.
async fn connect_real(
    fw: &mut Firmware,
    devices: &DevicesConfig,
    mut sim: Devices,
    clock: &SharedClock,
) -> Result<Devices, String> {
    use crate::real::{open_real, ConfiguredLimits, RealDevice};
    let limits = ConfiguredLimits {
        robot: Some(sim.robot.joint_limits()),
        rail: Some(sim.rail.limits()),
        turntable: sim.turntable.as_ref().map(|t| t.limits()),
    };
    for role in crate::real::real_roles(devices) {
        let entry = devices.entries().into_iter().find(|(r, _)| *r == role).map(|(_, e)| e.clone());
        let entry = entry.ok_or_else(|| format!("devices.{role}: missing"))?;
        let opened = open_real(role, &entry, &limits, clock.clone()).await?;
        fw.serial_links.push(SerialMeter {
            role,
            target: opened.target.clone(),
            baud: opened.baud,
            stats: opened.stats,
        });
        let wrong = || format!("devices.{role}: the backend opened does not fit the role");
        match (role, opened.device) {
            ("robot", RealDevice::Robot(r)) => sim.robot = Box::new(r),
            ("rail", RealDevice::Axis(a)) => sim.rail = Box::new(a),
            ("turntable", RealDevice::Axis(a)) => sim.turntable = Some(Box::new(a)),
            ("lamp", RealDevice::Lamp(l)) => sim.lamp = Box::new(l),
            ("led_array", RealDevice::Leds(l)) => sim.led_array = Some(Box::new(l)),
            _ => return Err(wrong()),
        }
    }
    Ok(sim)
}

fn firmware_io(what: &str, e: std::io::Error) -> String {
    format!("emulated {what} firmware: {e}")
}

fn backend_error(what: &str, e: btfrig_hw::DeviceError) -> String {
    format!("connecting the {what} backend to its emulated firmware: {e}")
}

impl Firmware {
    /// No emulators yet, and a new pty directory if any device of `devices` is emulated.
    fn for_devices(devices: &DevicesConfig) -> Result<Firmware, String> {
        let mut fw = Firmware::default();
        if devices.any_emulated() {
            static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
            let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let dir = std::env::temp_dir().join(format!("btfrig-emulated-{}-{n}", std::process::id()));
            std::fs::create_dir_all(&dir).map_err(|e| format!("pty directory {}: {e}", dir.display()))?;
            fw.dir = Some(dir);
        }
        Ok(fw)
    }

    fn link(&self, name: &str) -> PathBuf {
        self.dir.clone().unwrap_or_default().join(name)
    }
}

/// The turntable `t`, behind emulated GRBL firmware if `devices.turntable` is emulated.
fn emulate_turntable(
    fw: &mut Firmware,
    devices: &DevicesConfig,
    t: Box<dyn Turntable>,
    clock: &SharedClock,
) -> Result<Box<dyn Turntable>, String> {
    let Some(e) = devices.turntable.as_ref().filter(|e| e.is_emulated()) else { return Ok(t) };
    let o = link_options("turntable", e)?;
    let limits = t.limits();
    Ok(Box::new(emulate_axis(fw, "turntable", AxisDevice::Turntable(t), limits, &o, clock)?))
}

/// `device` (rail or turntable, as `role`) behind emulated GRBL firmware, and the GRBL
/// backend connected to it.
fn emulate_axis(
    fw: &mut Firmware,
    role: &'static str,
    device: AxisDevice,
    limits: btfrig_hw::AxisLimits,
    o: &LinkOptions,
    clock: &SharedClock,
) -> Result<GrblAxis, String> {
    let link = fw.link(role);
    let firmware = GrblFirmware::spawn_with_units(device, &link, o.units).map_err(|e| firmware_io(role, e))?;
    match role {
        "rail" => fw.rail = Some(firmware),
        _ => fw.turntable = Some(firmware),
    }
    let cfg = GrblAxisConfig {
        name: role.into(),
        model: format!("GRBL {role} (emulated)"),
        axis: Axis::X,
        limits,
        poll_s: o.poll_s,
        reply_timeout: o.reply_timeout,
        units: o.units,
    };
    let a = GrblAxis::new(cfg, serial(&link, GRBL_BAUD), clock.clone());
    fw.meter(role, &link, GRBL_BAUD, a.link_stats());
    Ok(a)
}

/// The LED array `l`, behind the emulated LED controller if `devices.led_array` is emulated.
async fn emulate_leds(
    fw: &mut Firmware,
    devices: &DevicesConfig,
    l: Box<dyn LedArray>,
    clock: &SharedClock,
) -> Result<Box<dyn LedArray>, String> {
    let Some(e) = devices.led_array.as_ref().filter(|e| e.is_emulated()) else { return Ok(l) };
    let o = link_options("led_array", e)?;
    let link = fw.link("leds");
    fw.leds = Some(LedFirmware::spawn(l, &link).map_err(|e| firmware_io("LED", e))?);
    let cfg = SerialLedConfig { name: "led_array".into(), poll_s: o.poll_s, reply_timeout: o.reply_timeout };
    let l = SerialLedArray::open(cfg, serial(&link, LED_BAUD), clock.clone())
        .await
        .map_err(|e| backend_error("LED array", e))?;
    fw.meter("led_array", &link, LED_BAUD, l.link_stats());
    Ok(Box::new(l))
}

/// A dome's turntable and LED array, each behind emulated firmware where its entry in
/// `devices` is emulated (the cameras stay the simulator's). Call inside the tokio runtime
/// the devices run on; keep the returned firmware until the devices are dropped.
pub async fn connect_dome(
    devices: &DevicesConfig,
    turntable: Option<Box<dyn Turntable>>,
    leds: Box<dyn LedArray>,
    clock: SharedClock,
) -> Result<(Option<Box<dyn Turntable>>, Box<dyn LedArray>, Firmware), String> {
    check(devices)?;
    let mut fw = Firmware::for_devices(devices)?;
    let (turntable, leds) = connect_real_dome(&mut fw, devices, turntable, leds, &clock).await?;
    let turntable = turntable.map(|t| emulate_turntable(&mut fw, devices, t, &clock)).transpose()?;
    let leds = emulate_leds(&mut fw, devices, leds, &clock).await?;
    Ok((turntable, leds, fw))
}

/// A dome's turntable and LED array with each real controller's stand-in replaced by its
/// backend on its port.
async fn connect_real_dome(
    fw: &mut Firmware,
    devices: &DevicesConfig,
    mut turntable: Option<Box<dyn Turntable>>,
    mut leds: Box<dyn LedArray>,
    clock: &SharedClock,
) -> Result<(Option<Box<dyn Turntable>>, Box<dyn LedArray>), String> {
    use crate::real::{open_real, ConfiguredLimits, RealDevice};
    let limits = ConfiguredLimits { robot: None, rail: None, turntable: turntable.as_ref().map(|t| t.limits()) };
    for role in crate::real::real_roles(devices).into_iter().filter(|r| *r == "turntable" || *r == "led_array") {
        let entry = devices.entries().into_iter().find(|(r, _)| *r == role).map(|(_, e)| e.clone());
        let entry = entry.ok_or_else(|| format!("devices.{role}: missing"))?;
        let opened = open_real(role, &entry, &limits, clock.clone()).await?;
        fw.serial_links.push(SerialMeter {
            role,
            target: opened.target.clone(),
            baud: opened.baud,
            stats: opened.stats,
        });
        match opened.device {
            RealDevice::Axis(a) => turntable = Some(Box::new(a)),
            RealDevice::Leds(l) => leds = Box::new(l),
            _ => return Err(format!("devices.{role}: the backend opened does not fit the role")),
        }
    }
    Ok((turntable, leds))
}

impl LinkReport for Firmware {
    fn link_use(&self) -> Vec<LinkUse> {
        Firmware::link_use(self)
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        Firmware::skipped_lines(self)
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        Firmware::camera_coding_wall_s(self)
    }

    fn count(&self) -> usize {
        Firmware::count(self)
    }
}
