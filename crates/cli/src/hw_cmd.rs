//! `btfrig hw probe`: what is attached (serial ports, USB devices) and, for a rig config,
//! each device's identity through its real backend; recorded-camera directories
//! (`--recorded DIR`, or a recorded rig's `[devices.camera] recording`).

use std::path::Path;

pub fn probe(rig: Option<&Path>, recorded: &[std::path::PathBuf]) -> anyhow::Result<()> {
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
    let Some(path) = rig else { return Ok(()) };
    let cfg = crate::rig::load(Some(path))?;
    println!("rig {} ({}):", cfg.rig.name, path.display());
    let devices = btfrig_sim_backend::probe(&cfg).map_err(anyhow::Error::msg)?;
    for d in devices {
        let link = d.link.map_or(String::new(), |l| format!(" on {l}"));
        println!(
            "  {:<9} kind {:<6} backend {:<12} model {:?} serial {:?} firmware {:?}{link}: {}",
            d.role, d.kind, d.info.backend, d.info.model, d.info.serial, d.info.firmware, d.health
        );
    }
    Ok(())
}

/// Whether `path` is a rig config of recorded devices.
fn is_recorded_rig(path: &Path) -> bool {
    crate::rig::load(Some(path))
        .is_ok_and(|cfg| cfg.devices.entries().iter().any(|(_, e)| e.kind == btfrig_recorded::KIND))
}

/// Each recording: what it holds, or every problem found in it; fails if any is unusable.
fn probe_recorded(rig: Option<&Path>, recorded: &[std::path::PathBuf]) -> anyhow::Result<()> {
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
    anyhow::ensure!(unusable == 0, "{unusable} of {} recording(s) are not usable (problems listed above)", dirs.len());
    Ok(())
}
