//! The simulated rig as a device backend of the runner (`btfrig_runner::backend`).
//!
//! For a rig config whose devices are all `kind = "sim"`, or simulated devices behind emulated
//! firmware (`kind = "serial"` / `"ptp"` with `[devices.ROLE.link] emulated = true`), it builds
//! the scene (the plan's material on the holder), the rendered frame source (with the fault
//! scenario's hidden markers), the simulated devices on virtual time, puts emulated firmware
//! in front where asked (`btfrig_runner::emulated`), and hands the run the devices and the
//! scene's truth probe (`btfrig_sim::truth::SceneTruth`), which only the report's error
//! figures read. [`install`] registers it as the process's backend.
#![warn(missing_docs)]

use std::path::Path;
use std::sync::Arc;

use btfrig_hw::{ScaledClock, SharedClock};
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_runner::backend::{BackendRegistry, GonioOpenRequest, OpenedGonio, RigBackend};
use btfrig_runner::{emulated, plan, RunError};
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::{FaultScenario, RenderedFrameSource, SimRig};

/// The simulated and emulated-firmware rigs.
#[derive(Debug, Clone, Copy, Default)]
pub struct SimBackend;

/// The device kinds [`SimBackend`] opens.
pub const KINDS: &[&str] = &["sim", "serial", "ptp"];

/// A registry with [`SimBackend`].
pub fn registry() -> BackendRegistry {
    BackendRegistry::new().with(Arc::new(SimBackend))
}

/// Installs [`registry`] as the process's device backends (`btfrig_runner::backend::install`).
pub fn install() {
    btfrig_runner::backend::install(registry());
}

/// The rig clock of a simulated session: tokio's paused time, slowed a thousandfold. Paused
/// timers fire on whole milliseconds, so at 1:1 every device wait would be rounded up to the
/// next millisecond: about 6 s over the 6480 captures of the Bonn plan, more than the
/// motion-optimised order gains over the naive one there. Slowed, the rounding is 1 us per wait.
fn sim_clock() -> SharedClock {
    Arc::new(ScaledClock::new(1e-3).expect("a positive, finite speed"))
}

/// The fault scenario of a request: the override, the plan's, or none.
fn faults(req: &GonioOpenRequest<'_>) -> Result<FaultScenario, RunError> {
    match (req.fault_override, &req.plan.run.fault_scenario) {
        (Some(name), _) => plan::fault_scenario(name, Path::new("."), "--faults"),
        (None, Some(name)) => {
            plan::fault_scenario(name, req.plan_file.parent().unwrap_or(Path::new(".")), "run.fault_scenario")
        }
        (None, None) => Ok(FaultScenario::none()),
    }
}

#[async_trait::async_trait]
impl RigBackend for SimBackend {
    fn name(&self) -> &'static str {
        "simulated rig (btfrig-sim-backend)"
    }

    fn kinds(&self) -> &'static [&'static str] {
        KINDS
    }

    async fn open_gonio(&self, req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        let rig = req.rig;
        let faults = faults(&req)?;
        let material = plan::material(req.plan, req.validated, req.plan_file)?;
        let scene = Arc::new(RigScene::new(rig, &material).map_err(|e| RunError::Rig(e.to_string()))?);
        let mut source: Arc<dyn btfrig_sim::FrameSource> =
            Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default()));
        if faults.hidden_markers.is_active() {
            let occluder = btfrig_sim::faults::MarkerOccluder::new(
                source,
                scene.clone(),
                &rig.plate,
                faults.hidden_markers.clone(),
                rig.rig.seed,
            )
            .map_err(|e| RunError::Input { what: "fault scenario [hidden_markers]".into(), message: e.to_string() })?;
            source = Arc::new(occluder);
        }
        // The truth of every frame the camera renders, for the report's error figures only.
        let truth = Arc::new(SceneTruth::new(scene, source));
        // An emulated device is the simulator's behind emulated firmware and its real backend.
        emulated::check(&rig.devices).map_err(RunError::Rig)?;
        let mut sim_cfg = rig.clone();
        sim_cfg.devices = rig.devices.simulated().ok_or_else(|| {
            RunError::Rig(
                "a device is real hardware: the simulated backend opens simulated and emulated devices".into(),
            )
        })?;
        let sim = SimRig::from_rig_config(&sim_cfg, &faults, sim_clock(), truth.clone())
            .map_err(|e| RunError::Rig(e.to_string()))?;
        let clock = sim.world.clock().clone();
        let SimRig { robot, rail, turntable, lamp, led_array, camera, .. } = sim;
        let parts = emulated::SimDevices { robot, rail, turntable, lamp, led_array, camera };
        let emulated::Connected { robot, rail, lamp, camera, firmware, .. } =
            emulated::connect(&rig.devices, parts, clock.clone(), req.read_timeout_s).await.map_err(RunError::Rig)?;
        for f in req.link_faults {
            firmware.inject(f).map_err(RunError::Rig)?;
        }
        Ok(OpenedGonio { robot, rail, lamp, camera, clock, truth: Some(truth), links: Box::new(firmware) })
    }
}
