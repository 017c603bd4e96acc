//! `btfrig hw probe`: what is attached (serial ports, USB devices, GenICam cameras named or,
//! on request, discovered) and, for a rig config, each device's identity, health and homing
//! state through its real backend, moving nothing; recorded-camera directories (`--recorded
//! DIR`, or a recorded rig's `[devices.camera] recording`). Exit status 1 when a device of
//! the rig or a recording fails, naming it.

use std::net::Ipv4Addr;
use std::path::Path;
use std::process::ExitCode;

pub fn probe(
    rig: Option<&Path>,
    recorded: &[std::path::PathBuf],
    genicam: &[Ipv4Addr],
    discover: bool,
) -> anyhow::Result<ExitCode> {
    if !recorded.is_empty() || rig.is_some_and(is_recorded_rig) {
        return probe_recorded(rig, recorded);
    }
    match serialport::available_ports() {
        Ok(ports) if ports.is_empty() => println!("serial ports: none"),
        Ok(ports) => {
            println!("serial ports:");
            for p in ports {
                let what = match p.port_type {
                    serialport::SerialPortType::UsbPort(u) => format!(
                        "USB {:04x}:{:04x} {} {}",
                        u.vid,
                        u.pid,
                        u.manufacturer.unwrap_or_default(),
                        u.product.unwrap_or_default()
                    ),
                    serialport::SerialPortType::PciPort => "PCI".into(),
                    serialport::SerialPortType::BluetoothPort => "Bluetooth".into(),
                    serialport::SerialPortType::Unknown => "unknown".into(),
                };
                println!("  {}  {what}", p.port_name);
            }
        }
        Err(e) => println!("serial ports: cannot list: {e}"),
    }
    match btfrig_ptp::usb::list_devices() {
        Ok(devs) if devs.is_empty() => println!("USB devices: none"),
        Ok(devs) => {
            println!("USB devices:");
            for d in devs {
                let ptp = d.ptp_interface.map_or(String::new(), |i| format!("  [PTP camera, interface {i}]"));
                println!(
                    "  bus {:03} address {:03}  {:04x}:{:04x}  {} {}{}{ptp}",
                    d.bus,
                    d.address,
                    d.vendor_id,
                    d.product_id,
                    d.manufacturer.unwrap_or_default(),
                    d.product.unwrap_or_default(),
                    d.serial.map_or(String::new(), |s| format!(" (serial {s})"))
                );
            }
        }
        Err(e) => println!("USB devices: cannot list: {e}"),
    }
    genicam_cameras(genicam, discover)?;
    let Some(path) = rig else { return Ok(ExitCode::SUCCESS) };
    let cfg = crate::rig::load(Some(path))?;
    println!("rig {} ({}):", cfg.rig.name, path.display());
    let (cfg, camera) = rig_genicam_camera(&cfg)?;
    let devices = btfrig_sim_backend::probe(&cfg).map_err(anyhow::Error::msg)?;
    let mut failed = Vec::new();
    for d in &devices {
        if d.role == "camera" && !camera.is_empty() {
            // The simulated twin the probe opened in the GenICam camera's place.
            continue;
        }
        let link = d.link.as_ref().map_or(String::new(), |l| format!(" on {l}"));
        let homed = match d.homed {
            Some(true) => ", homed",
            Some(false) => ", not homed",
            None => "",
        };
        println!(
            "  {:<9} kind {:<6} backend {:<12} model {:?} serial {:?} firmware {:?}{link}: {}{homed}",
            d.role, d.kind, d.info.backend, d.info.model, d.info.serial, d.info.firmware, d.health
        );
        if let Some(f) = &d.failure {
            failed.push(format!("devices.{}{link}: {f}", d.role));
        }
    }
    for (line, failure) in camera {
        println!("  camera    kind genicam {line}");
        failed.extend(failure);
    }
    if failed.is_empty() {
        return Ok(ExitCode::SUCCESS);
    }
    eprintln!("btfrig: hw probe: {} device(s) of rig {} failed:", failed.len(), cfg.rig.name);
    for f in &failed {
        eprintln!("  {f}");
    }
    Ok(ExitCode::FAILURE)
}

/// Whether `path` is a rig config of recorded devices.
fn is_recorded_rig(path: &Path) -> bool {
    crate::rig::load(Some(path))
        .is_ok_and(|cfg| cfg.devices.entries().iter().any(|(_, e)| e.kind == btfrig_recorded::KIND))
}

/// Each recording: what it holds, or every problem found in it; fails if any is unusable.
fn probe_recorded(rig: Option<&Path>, recorded: &[std::path::PathBuf]) -> anyhow::Result<ExitCode> {
    let mut dirs = recorded.to_vec();
    if let Some(path) = rig {
        let cfg = crate::rig::load(Some(path))?;
        let options = btfrig_recorded::RecordedOptions::of(&cfg)
            .map_err(|m| anyhow::anyhow!("rig config {}: {m}", path.display()))?;
        println!(
            "rig {} ({}): recorded devices, camera recording {:?}",
            cfg.rig.name,
            path.display(),
            options.recording
        );
        dirs.push(options.dir(Some(path)));
    }
    let mut unusable = 0;
    for dir in &dirs {
        let (usable, lines) = btfrig_recorded::probe::describe(dir);
        for l in lines {
            println!("{l}");
        }
        unusable += usize::from(!usable);
    }
    if unusable == 0 {
        return Ok(ExitCode::SUCCESS);
    }
    eprintln!("btfrig: hw probe: {unusable} of {} recording(s) are not usable (problems listed above)", dirs.len());
    Ok(ExitCode::FAILURE)
}

#[cfg(feature = "genicam")]
fn describe(c: &btfrig_genicam_backend::ProbedCamera) -> String {
    match &c.info {
        Ok(i) => format!(
            "{}: id {:?} model {:?} {:?} serial {:?} pixel formats {} temperature {}",
            c.target,
            i.id,
            i.vendor,
            i.model,
            i.serial,
            i.pixel_formats.join(","),
            c.temperature_c.map_or("not reported".to_string(), |t| format!("{t:.1} C"))
        ),
        Err(e) => format!("{}: cannot open: {e}", c.target),
    }
}

/// GenICam cameras by address and, with `discover`, by discovery.
#[cfg(feature = "genicam")]
fn genicam_cameras(addresses: &[Ipv4Addr], discover: bool) -> anyhow::Result<()> {
    if addresses.is_empty() && !discover {
        println!("GenICam cameras: none asked for (--genicam ADDR, or --discover, which broadcasts)");
        return Ok(());
    }
    let targets: Vec<_> = addresses.iter().map(|a| btfrig_genicam_backend::Target::Address(*a)).collect();
    let found = btfrig_genicam_backend::probe_cameras(&targets, discover);
    println!("GenICam cameras:");
    for c in &found {
        println!("  {}", describe(c));
    }
    Ok(())
}

#[cfg(not(feature = "genicam"))]
fn genicam_cameras(addresses: &[Ipv4Addr], discover: bool) -> anyhow::Result<()> {
    anyhow::ensure!(addresses.is_empty() && !discover, "{}", crate::backends::WITHOUT_GENICAM);
    Ok(())
}

/// The rig with a GenICam camera replaced by its simulated twin for the other devices' probe,
/// and the camera's probe line.
#[cfg(feature = "genicam")]
fn rig_genicam_camera(
    cfg: &btfrig_core::config::RigConfig,
) -> anyhow::Result<(btfrig_core::config::RigConfig, RigCamera)> {
    let cameras = btfrig_genicam_backend::probe_rig_camera(cfg).map_err(anyhow::Error::msg)?;
    let rest = btfrig_genicam_backend::without_genicam_camera(cfg).map_err(anyhow::Error::msg)?;
    Ok((
        rest,
        cameras
            .iter()
            .map(|c| {
                (describe(c), c.info.as_ref().err().map(|e| format!("devices.camera on GenICam {}: {e}", c.target)))
            })
            .collect(),
    ))
}

#[cfg(not(feature = "genicam"))]
fn rig_genicam_camera(
    cfg: &btfrig_core::config::RigConfig,
) -> anyhow::Result<(btfrig_core::config::RigConfig, RigCamera)> {
    Ok((cfg.clone(), Vec::new()))
}

/// A rig's GenICam camera as `hw probe` saw it: its line, and why it failed.
type RigCamera = Vec<(String, Option<String>)>;
