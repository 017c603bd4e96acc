//! `btfrig hw probe`: what is attached (serial ports, USB devices, GenICam cameras named or,
//! on request, discovered) and, for a rig config, each device's identity through its real
//! backend.

use std::net::Ipv4Addr;
use std::path::Path;

pub fn probe(rig: Option<&Path>, genicam: &[Ipv4Addr], discover: bool) -> anyhow::Result<()> {
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
    let Some(path) = rig else { return Ok(()) };
    let cfg = crate::rig::load(Some(path))?;
    println!("rig {} ({}):", cfg.rig.name, path.display());
    let (cfg, camera) = rig_genicam_camera(&cfg)?;
    let devices = btfrig_sim_backend::probe(&cfg).map_err(anyhow::Error::msg)?;
    for d in devices {
        if d.role == "camera" && camera.is_some() {
            // The simulated twin the probe opened in the GenICam camera's place.
            continue;
        }
        let link = d.link.map_or(String::new(), |l| format!(" on {l}"));
        println!(
            "  {:<9} kind {:<6} backend {:<12} model {:?} serial {:?} firmware {:?}{link}: {}",
            d.role, d.kind, d.info.backend, d.info.model, d.info.serial, d.info.firmware, d.health
        );
    }
    if let Some(line) = camera {
        println!("  camera    kind genicam {line}");
    }
    Ok(())
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
) -> anyhow::Result<(btfrig_core::config::RigConfig, Option<String>)> {
    let camera = btfrig_genicam_backend::probe_rig_camera(cfg).map_err(anyhow::Error::msg)?;
    let rest = btfrig_genicam_backend::without_genicam_camera(cfg).map_err(anyhow::Error::msg)?;
    Ok((rest, camera.as_ref().map(describe)))
}

#[cfg(not(feature = "genicam"))]
fn rig_genicam_camera(
    cfg: &btfrig_core::config::RigConfig,
) -> anyhow::Result<(btfrig_core::config::RigConfig, Option<String>)> {
    Ok((cfg.clone(), None))
}
