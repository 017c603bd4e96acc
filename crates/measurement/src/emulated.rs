//! Emulated rigs: the real serial and PTP backends driving the simulator's devices through
//! emulated firmware (`kind = "serial"` / `"ptp"` with `[devices.<role>.link] emulated =
//! true`, docs/serial.md). Each emulated device's firmware is served on a pseudo-terminal
//! (the camera: an in-process PTP responder) and the backend opens it like real hardware.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::devices::{DeviceEntry, DevicesConfig};
use btfrig_hw::{Camera, Device, Lamp, LedArray, Rail, Robot, SharedClock, Turntable};
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

/// Checks every emulated device's kind and link options; the kinds are `"serial"` for
/// robot, rail, turntable, lamp and LED array, `"ptp"` for the camera. Real devices are
/// refused: runs drive simulated and emulated rigs ([`check_probe`] accepts real ports).
pub fn check(devices: &DevicesConfig) -> Result<(), String> {
    check_kinds(devices, false)
}

/// As [`check`], but real serial devices are allowed too, with a `link.port` each (what
/// `btfrig hw probe --rig` talks to).
pub fn check_probe(devices: &DevicesConfig) -> Result<(), String> {
    check_kinds(devices, true)
}

/// Whether `entry` is a real serial controller (not simulated, not emulated).
fn is_real_serial(role: &str, e: &DeviceEntry) -> bool {
    e.kind == "serial" && role != "camera" && !e.is_emulated()
}

fn check_kinds(devices: &DevicesConfig, allow_real: bool) -> Result<(), String> {
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
            let Some(port) = &o.port else {
                return Err(format!(
                    "devices.{role}.link.port is missing: a real {want} controller names its port (e.g. \"/dev/serial/by-id/...\"), or set emulated = true"
                ));
            };
            if !allow_real {
                return Err(format!(
                    "devices.{role}: real hardware on {port}: plans run on simulated and emulated rigs only so far (the pipeline needs the simulator's scene); `btfrig hw probe --rig FILE` talks to it"
                ));
            }
        }
    }
    Ok(())
}

/// The devices of a rig, some through emulated firmware, and what keeps that firmware
/// running (drop it after the devices).
pub struct Connected {
    /// The robot.
    pub robot: Box<dyn Robot>,
    /// The rail.
    pub rail: Box<dyn Rail>,
    /// The turntable, if any.
    pub turntable: Option<Box<dyn Turntable>>,
    /// The lamp.
    pub lamp: Box<dyn Lamp>,
    /// The LED array, if any.
    pub led_array: Option<Box<dyn LedArray>>,
    /// The camera.
    pub camera: Box<dyn Camera>,
    /// The firmware emulators and their pty directory.
    pub firmware: Firmware,
}

/// A fault for one emulated device's firmware (tests: [`crate::RunRequest::link_faults`]).
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

/// What talking to one emulated device cost this session (the run report's `links`): the
/// time the serial and PTP paths add over calling the simulated device in-process.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkUse {
    /// Role (`robot`, `rail`, ..., `camera`).
    pub role: &'static str,
    /// What the backend talks to (pty path at a nominal baud rate, or the PTP responder).
    pub target: String,
    /// Exchanges (serial) or transactions (PTP).
    pub exchanges: u64,
    /// Bytes sent to the device.
    pub bytes_out: u64,
    /// Bytes received from it.
    pub bytes_in: u64,
    /// Wall seconds spent on this link: serial exchanges as the caller waited for them, PTP
    /// coding on the host (see `LinkTotals::exchange_wall_s`, `PtpTotals::codec_wall_s`).
    /// Links overlap each other and the camera's work, so these do not add up to what the
    /// run lost: that is the report's `link_added_wall_s`.
    pub wall_s: f64,
    /// Rig seconds the same bytes would take on a real line at the nominal baud rate
    /// (serial only; a pty has no baud rate, so the emulated run's rig time does not have it).
    pub wire_s: Option<f64>,
}

impl LinkUse {
    /// As a JSON object (the report's `links` entries).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "role": self.role,
            "target": self.target,
            "exchanges": self.exchanges,
            "bytes_out": self.bytes_out,
            "bytes_in": self.bytes_in,
            "wall_s": self.wall_s,
            "wire_s": self.wire_s,
        })
    }
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
                    target: format!("{} at {} baud (nominal)", m.target, m.baud),
                    exchanges: t.exchanges,
                    bytes_out: t.bytes_out,
                    bytes_in: t.bytes_in,
                    wall_s: t.exchange_wall_s,
                    wire_s: Some(t.wire_s(m.baud)),
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

/// The simulated devices, as built from [`DevicesConfig::simulated`].
pub struct SimDevices {
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
const ROBOT_BAUD: u32 = 115_200;
const GRBL_BAUD: u32 = 115_200;
const LAMP_BAUD: u32 = 9_600;
const LED_BAUD: u32 = 460_800;

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
    sim: SimDevices,
    clock: SharedClock,
    read_timeout_s: f64,
) -> Result<Connected, String> {
    check(devices)?;
    let mut fw = Firmware::for_devices(devices)?;
    let dir = fw.dir.clone().unwrap_or_default();

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
    Ok(Connected { robot, rail, turntable, lamp, led_array, camera, firmware: fw })
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
    let turntable = turntable.map(|t| emulate_turntable(&mut fw, devices, t, &clock)).transpose()?;
    let leds = emulate_leds(&mut fw, devices, leds, &clock).await?;
    Ok((turntable, leds, fw))
}

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
pub type OpenSimulated<'a> = &'a dyn Fn(&btfrig_core::config::RigConfig, SharedClock) -> Result<SimDevices, String>;

/// Asks every device of `rig` for its identity and health through its real backend:
/// emulated devices behind their firmware on a pty (started here) in front of the simulated
/// devices `open` builds, real serial controllers on the ports their `link.port` names (at
/// `link.baud`). Simulated devices answer as themselves. Builds its own runtime: call from a
/// plain thread.
pub fn probe(rig: &btfrig_core::config::RigConfig, open: OpenSimulated<'_>) -> Result<Vec<Probed>, String> {
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
    let rt = crate::virtual_time_runtime().map_err(|e| e.to_string())?;
    rt.block_on(async {
        let clock: SharedClock = Arc::new(btfrig_hw::ScaledClock::new(1e-3).map_err(|e| e.to_string())?);
        let SimDevices { robot, rail, turntable, lamp, led_array, camera } = open(&sim_cfg, clock.clone())?;
        let limits = ConfiguredLimits {
            robot: robot.joint_limits(),
            rail: rail.limits(),
            turntable: turntable.as_ref().map(|t| t.limits()),
        };
        let mut c =
            connect(&devices, SimDevices { robot, rail, turntable, lamp, led_array, camera }, clock, 30.0).await?;
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
        let h = c.robot.health().await;
        add("robot", c.robot.info().clone(), h);
        let h = c.rail.health().await;
        add("rail", c.rail.info().clone(), h);
        if let Some(t) = c.turntable.as_mut() {
            let h = t.health().await;
            add("turntable", t.info().clone(), h);
        }
        let h = c.lamp.health().await;
        add("lamp", c.lamp.info().clone(), h);
        if let Some(l) = c.led_array.as_mut() {
            let h = l.health().await;
            add("led_array", l.info().clone(), h);
        }
        let h = c.camera.health().await;
        add("camera", c.camera.info().clone(), h);
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

impl crate::backend::LinkReport for Firmware {
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
