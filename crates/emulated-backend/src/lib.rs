//! Emulated-firmware rigs as a device backend of the runner (`btfrig_measurement::backend`).
//!
//! A rig config whose devices are `kind = "serial"` / `"ptp"` with `[devices.ROLE.link]
//! emulated = true` (docs/serial.md), or real serial controllers on the ports their
//! `link.port` names ([`real`]), is opened by [`EmulatedBackend`]: it asks another backend
//! (the simulated one, `btfrig_sim_backend`, which composes the two in its registry) for the
//! simulated devices of the same rig, serves each emulated device's firmware on a
//! pseudo-terminal (the camera: an in-process PTP responder) and connects the real serial and
//! PTP backends to it, as to hardware. The run gets the real backends' devices, the inner
//! backend's truth probe and what each link cost. [`probe`] is `btfrig hw probe`. This crate
//! knows no simulator type: the simulated devices come from the inner backend, or (probe)
//! from the caller.
#![warn(missing_docs)]

// The files, one job each:
// - lib:      EmulatedBackend, the registry entry (open, check, link faults)
// - firmware: firmware emulators in front of devices, link options, link faults and costs
// - real:     real serial controllers on their ports: opened for a run, asked by preflight
// - probe:    `btfrig hw probe` through the real backends, emulated and real ports

use std::sync::Arc;

use btfrig_acquire::dome::DomeDevices;
use btfrig_core::config::RigConfig;
use btfrig_measurement::backend::{
    CalibrationOpenRequest, DomeOpenRequest, GonioOpenRequest, LinkReport, LinkUse, OpenedDome, OpenedGonio, OpenedRig,
    RigBackend, RigTime, SceneOptions,
};
use btfrig_measurement::preflight::{DeviceCheck, Role};
use btfrig_measurement::RunError;

pub mod firmware;
pub mod probe;
pub mod real;

pub use firmware::{check, check_probe, connect, connect_dome, link_options, Connected, Devices, Firmware, LinkFault};
pub use probe::{probe, OpenSimulated, Probed};

/// The device kinds [`EmulatedBackend`] opens: emulated serial controllers and PTP cameras,
/// and simulated devices beside them.
pub const KINDS: &[&str] = &["sim", "serial", "ptp"];

/// Emulated firmware in front of the simulated devices another backend opens.
pub struct EmulatedBackend {
    inner: Arc<dyn RigBackend>,
    link_faults: Vec<LinkFault>,
}

impl EmulatedBackend {
    /// Emulated firmware in front of the devices `inner` opens for the rig with every
    /// emulated device simulated ([`btfrig_core::config::devices::DevicesConfig::simulated`]).
    pub fn new(inner: Arc<dyn RigBackend>) -> Self {
        EmulatedBackend { inner, link_faults: Vec::new() }
    }

    /// The same backend injecting `faults` into the firmware of every gonioreflectometer it
    /// opens, right after its backends connect, before the rig is prepared (fault tests,
    /// `crates/measurement/tests/serial_faults.rs`). A fault for a device that is not
    /// emulated is an error.
    pub fn with_link_faults(mut self, faults: Vec<LinkFault>) -> Self {
        self.link_faults = faults;
        self
    }
}

/// The rig config the inner backend opens: emulated devices as the simulated ones behind the
/// firmware, real serial controllers as simulated stand-ins of the same options
/// ([`real::with_stand_ins`]). Real devices need the wall clock: on virtual time they are
/// refused, naming them.
fn simulated(rig: &RigConfig, time: RigTime) -> Result<RigConfig, RunError> {
    let real = real::real_roles(&rig.devices);
    if !real.is_empty() && time == RigTime::Virtual {
        return Err(RunError::Rig(format!(
            "{} real hardware: it runs on the wall clock, not on virtual time (RigTime::for_rig)",
            real.iter().map(|r| format!("devices.{r}")).collect::<Vec<_>>().join(", ")
        )));
    }
    let mut sim_cfg = rig.clone();
    sim_cfg.devices = real::with_stand_ins(&rig.devices).simulated().ok_or_else(|| {
        RunError::Rig(
            "a device is neither simulated, emulated nor a serial controller: the emulated-firmware backend opens those"
                .into(),
        )
    })?;
    Ok(sim_cfg)
}

/// `opened` (the inner backend's gonioreflectometer) with each emulated device behind its
/// firmware and each real controller on its port, `faults` injected into the firmware.
async fn front_gonio(
    rig: &RigConfig,
    opened: OpenedGonio,
    read_timeout_s: f64,
    faults: &[LinkFault],
) -> Result<OpenedGonio, RunError> {
    let OpenedGonio { robot, rail, lamp, camera, clock, truth, links } = opened;
    let parts = Devices { robot, rail, turntable: None, lamp, led_array: None, camera };
    let Connected { devices: Devices { robot, rail, lamp, camera, .. }, firmware } =
        connect(&rig.devices, parts, clock.clone(), read_timeout_s).await.map_err(RunError::Rig)?;
    for f in faults {
        firmware.inject(f).map_err(RunError::Rig)?;
    }
    Ok(OpenedGonio { robot, rail, lamp, camera, clock, truth, links: Box::new(Links { firmware, _inner: links }) })
}

/// `opened` (the inner backend's dome) with its turntable and LED controller behind their
/// firmware or on their ports; the cameras stay the inner backend's.
async fn front_dome(rig: &RigConfig, opened: OpenedDome) -> Result<OpenedDome, RunError> {
    let OpenedDome { devices, truth, links } = opened;
    let DomeDevices { turntable, leds, cameras, clock } = devices;
    let (turntable, leds, firmware) =
        connect_dome(&rig.devices, turntable, leds, clock.clone()).await.map_err(RunError::Rig)?;
    Ok(OpenedDome {
        devices: DomeDevices { turntable, leds, cameras, clock },
        truth,
        // Dropped in order: the firmware first, then what the inner backend keeps.
        links: Box::new(Links { firmware, _inner: links }),
    })
}

/// The engine's read-out timeout a calibration's devices get (the emulated camera gives up
/// on a read-out after it too).
const CALIBRATION_READ_TIMEOUT_S: f64 = 60.0;

/// The firmware's links, with the inner backend's (kept alive until the firmware stops).
struct Links {
    firmware: Firmware,
    _inner: Box<dyn LinkReport>,
}

impl LinkReport for Links {
    fn link_use(&self) -> Vec<LinkUse> {
        self.firmware.link_use()
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        self.firmware.skipped_lines()
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        self.firmware.camera_coding_wall_s()
    }

    fn count(&self) -> usize {
        self.firmware.count()
    }
}

#[async_trait::async_trait]
impl RigBackend for EmulatedBackend {
    fn name(&self) -> &'static str {
        "emulated-firmware rig (btfrig-emulated-backend)"
    }

    fn kinds(&self) -> &'static [&'static str] {
        KINDS
    }

    async fn open_gonio(&self, req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        let rig = req.rig;
        let read_timeout_s = req.read_timeout_s;
        check(&rig.devices).map_err(RunError::Rig)?;
        let sim_cfg = simulated(rig, req.time)?;
        let opened = self.inner.open_gonio(GonioOpenRequest { rig: &sim_cfg, ..req }).await?;
        front_gonio(rig, opened, read_timeout_s, &self.link_faults).await
    }

    async fn open_dome(&self, req: DomeOpenRequest<'_>) -> Result<OpenedDome, RunError> {
        let rig = req.rig;
        check(&rig.devices).map_err(RunError::Rig)?;
        let sim_cfg = simulated(rig, req.time)?;
        let opened = self.inner.open_dome(DomeOpenRequest { rig: &sim_cfg, ..req }).await?;
        front_dome(rig, opened).await
    }

    // The inner backend opens the simulated halves with the target mounted; the devices
    // configured as emulated or real are then put behind their firmware or ports, as for a run.
    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        let rig = req.rig;
        check(&rig.devices).map_err(RunError::Rig)?;
        let sim_cfg = simulated(rig, req.time)?;
        match self.inner.open_calibration(CalibrationOpenRequest { rig: &sim_cfg, ..req }).await? {
            OpenedRig::Gonio(g) => {
                Ok(OpenedRig::Gonio(front_gonio(rig, g, CALIBRATION_READ_TIMEOUT_S, &self.link_faults).await?))
            }
            OpenedRig::Dome(d) => Ok(OpenedRig::Dome(front_dome(rig, d).await?)),
        }
    }

    fn preflight(&self, rig: &RigConfig, roles: &[Role]) -> Vec<DeviceCheck> {
        let names: Vec<&str> = roles.iter().map(|r| r.name()).collect();
        real::preflight(&rig.devices, &names)
    }

    // The inner backend checks and calibrates with the rig as given: it knows emulated
    // entries stand for its simulated devices (`DevicesConfig::simulated`); real controllers
    // are checked as the stand-ins that lend them their limits.
    fn check_rig(&self, rig: &RigConfig) -> Result<(), String> {
        check(&rig.devices)?;
        let mut stand_ins = rig.clone();
        stand_ins.devices = real::with_stand_ins(&rig.devices);
        self.inner.check_rig(&stand_ins)
    }

    fn check_scene(&self, options: &SceneOptions<'_>) -> Result<(), RunError> {
        self.inner.check_scene(options)
    }
}
