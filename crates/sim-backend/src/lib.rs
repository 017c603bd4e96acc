//! The simulated rig as a device backend of the runner (`btfrig_measurement::backend`).
//!
//! For a rig config whose devices are all `kind = "sim"` it builds the scene (the plan's
//! material on the holder), the rendered frame source (with the fault scenario's hidden
//! markers), the simulated devices on virtual time, and hands the run the devices and the
//! scene's truth probe (`btfrig_sim::truth::SceneTruth`; a dome's: [`DomeSceneTruth`]), which
//! only the report's error figures read. It checks the simulator's options of rigs and plans
//! (device options, materials, fault scenarios) for the runner, which knows no simulator
//! type, mounts calibration targets in the sample's place (`calibration_targets`), and opens the stand-ins `btfrig hw probe` puts behind emulated
//! firmware ([`probe`]). Rigs of emulated firmware (`kind = "serial"` / `"ptp"` with
//! `[devices.ROLE.link] emulated = true`) are opened by `btfrig_emulated_backend`, in front of
//! this backend's devices; [`registry`] holds both and [`install`] registers them as the
//! process's backends.
#![warn(missing_docs)]

mod calibration_targets;

use std::path::Path;
use std::sync::Arc;

use btfrig_acquire::dome::DomeDevices;
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::pose::ScenePose;
use btfrig_emulated_backend::{Devices, EmulatedBackend, Probed};
use btfrig_hw::truth::DomeTruthProbe;
use btfrig_hw::{ScaledClock, SharedClock, TokioClock};
use btfrig_measurement::backend::{
    BackendRegistry, CalibrationOpenRequest, DomeOpenRequest, GonioOpenRequest, InProcess, OpenedDome, OpenedGonio,
    OpenedRig, RigBackend, RigTime, SceneOptions,
};
use btfrig_measurement::{plan, RunError};
use btfrig_render::dome_scene::DomeScene;
use btfrig_render::material::{MaterialSpec, BUILTIN_MATERIALS};
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::dome::{DomeFrameSource, DomeRig};
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::{FaultScenario, RenderedFrameSource, SimRig};

/// The simulated rigs.
#[derive(Debug, Clone, Copy, Default)]
pub struct SimBackend;

/// The device kinds [`SimBackend`] opens.
pub const KINDS: &[&str] = &["sim"];

/// A registry with [`SimBackend`] for simulated rigs and, for rigs of emulated firmware, an
/// [`EmulatedBackend`] in front of it (a rig of simulated devices only is the first's), and
/// [`btfrig_recorded::RecordedBackend`] for rigs of recorded frames (`kind = "recorded"`).
pub fn registry() -> BackendRegistry {
    BackendRegistry::new()
        .with(Arc::new(SimBackend))
        .with(Arc::new(EmulatedBackend::new(Arc::new(SimBackend))))
        .with(Arc::new(btfrig_recorded::RecordedBackend))
}

/// Installs [`registry`] as the process's device backends (`btfrig_measurement::backend::install`).
pub fn install() {
    btfrig_measurement::backend::install(registry());
}

/// The rig clock of a simulated session: tokio's paused time, slowed a thousandfold. Paused
/// timers fire on whole milliseconds, so at 1:1 every device wait would be rounded up to the
/// next millisecond: about 6 s over the 6480 captures of the Bonn plan, more than the
/// motion-optimised order gains over the naive one there. Slowed, the rounding is 1 us per wait.
pub(crate) fn sim_clock() -> SharedClock {
    Arc::new(ScaledClock::new(1e-3).expect("a positive, finite speed"))
}

/// The clock of simulated devices on `time`: [`sim_clock`] on virtual time; tokio's own
/// timer on the wall clock, where the devices then wait in real time (a rig with real
/// devices, `[run] clock = "wall"`).
pub(crate) fn clock_for(time: RigTime) -> SharedClock {
    match time {
        RigTime::Virtual => sim_clock(),
        RigTime::Wall => TokioClock::shared(),
    }
}

/// The material used when a plan names none: deep relief, so that shadowing and masking show.
pub const DEFAULT_MATERIAL: &str = "corduroy";

/// The embedded fault scenarios (`sim/faults/*.toml`), by the names plans and `--faults` use
/// (`btfrig_core::plan::BUILTIN_FAULT_SCENARIOS`).
pub const FAULT_FILES: &[(&str, &str)] = &[
    ("none", include_str!("../../../sim/faults/none.toml")),
    ("flaky", include_str!("../../../sim/faults/flaky.toml")),
    ("lamp-drift", include_str!("../../../sim/faults/lamp-drift.toml")),
    ("stuck-led", include_str!("../../../sim/faults/stuck-led.toml")),
    ("robot-fault", include_str!("../../../sim/faults/robot-fault.toml")),
    ("hidden-markers", include_str!("../../../sim/faults/hidden-markers.toml")),
];

/// Loads an embedded material by name, or a material file if `name` ends in `.toml`
/// (default: [`DEFAULT_MATERIAL`]).
pub fn load_material(name: Option<&str>) -> Result<MaterialSpec, RunError> {
    let name = name.unwrap_or(DEFAULT_MATERIAL);
    if name.ends_with(".toml") {
        let text = std::fs::read_to_string(name)
            .map_err(|source| RunError::Read { path: name.into(), source })
            .map_err(|e| RunError::Input {
                what: format!("rig.material {name:?}"),
                message: format!("{e}; allowed: an existing material file (relative to the plan) or an embedded name"),
            })?;
        return MaterialSpec::from_toml(&text, name)
            .map_err(|e| RunError::Input { what: format!("material {name}"), message: e.to_string() });
    }
    MaterialSpec::builtin(name).map_err(|e| {
        let names: Vec<&str> = BUILTIN_MATERIALS.iter().map(|(n, _)| *n).collect();
        RunError::Input {
            what: format!("material {name:?}"),
            message: format!("{e}; allowed: {} or a path ending in .toml", names.join(", ")),
        }
    })
}

/// A fault scenario by name: an embedded one ([`FAULT_FILES`]) or a TOML file, relative to
/// `base` (the plan's directory for the plan's own field, the working directory for an
/// override). `field` names the setting in errors.
pub fn fault_scenario(name: &str, base: &Path, field: &str) -> Result<FaultScenario, RunError> {
    let bad = |message: String| RunError::Input { what: format!("{field} {name:?}"), message };
    if let Some((_, text)) = FAULT_FILES.iter().find(|(n, _)| *n == name) {
        return FaultScenario::from_toml(text, &format!("<embedded sim/faults/{name}.toml>"))
            .map_err(|e| bad(e.to_string()));
    }
    let path = base.join(name);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        let names: Vec<&str> = FAULT_FILES.iter().map(|(n, _)| *n).collect();
        bad(format!("cannot read {}: {e}; allowed: {} or a scenario file", path.display(), names.join(", ")))
    })?;
    FaultScenario::from_toml(&text, &path.display().to_string()).map_err(|e| bad(e.to_string()))
}

/// The fault scenario of a request: the override, the plan's, or none.
fn faults(req: &GonioOpenRequest<'_>) -> Result<FaultScenario, RunError> {
    match (req.fault_override, &req.plan.run.fault_scenario) {
        (Some(name), _) => fault_scenario(name, Path::new("."), "--faults"),
        (None, Some(name)) => {
            fault_scenario(name, req.plan_file.parent().unwrap_or(Path::new(".")), "run.fault_scenario")
        }
        (None, None) => Ok(FaultScenario::none()),
    }
}

/// The simulated devices of `rig` (every device simulated), rendering nothing: the stand-ins
/// `btfrig hw probe` asks through emulated firmware ([`probe`]).
fn stand_ins(rig: &RigConfig, clock: SharedClock) -> Result<Devices, String> {
    let source = Arc::new(btfrig_sim::FlatFrameSource::new(8, 6, 100.0));
    let sim = SimRig::from_rig_config(rig, &FaultScenario::none(), clock, source).map_err(|e| e.to_string())?;
    let SimRig { robot, rail, turntable, lamp, led_array, camera, .. } = sim;
    Ok(Devices { robot, rail, turntable, lamp, led_array, camera })
}

/// `btfrig hw probe`: every device of `rig` asked for its identity and health through its
/// real backend, emulated ones in front of the simulator's devices
/// (`btfrig_emulated_backend::probe`). Builds its own runtime: call from a plain thread.
pub fn probe(rig: &RigConfig) -> Result<Vec<Probed>, String> {
    btfrig_emulated_backend::probe(rig, &stand_ins)
}

/// The truth behind a simulated dome's frames: the scene's ground truth and the cameras'
/// own frame sources (whose single-light images are cached per view, so the truth costs no
/// second rendering), and the LEDs the fault scenario holds on.
pub struct DomeSceneTruth {
    scene: Arc<DomeScene>,
    sources: Vec<Arc<DomeFrameSource>>,
    stuck_on: Vec<usize>,
    /// The cameras' true lens.
    camera: CameraModel,
}

impl DomeSceneTruth {
    /// The truth of `scene` as the cameras of `sources` see it, under `faults`.
    pub fn new(
        scene: Arc<DomeScene>,
        sources: Vec<Arc<DomeFrameSource>>,
        faults: &FaultScenario,
        camera: CameraModel,
    ) -> Self {
        let stuck_on = faults
            .stuck_leds
            .iter()
            .filter(|s| s.state == btfrig_sim::faults::StuckState::On)
            .map(|s| s.index)
            .collect();
        DomeSceneTruth { scene, sources, stuck_on, camera }
    }
}

impl DomeTruthProbe for DomeSceneTruth {
    fn texture(&self, camera: usize, turntable_rad: f64, light: usize, size: usize) -> Vec<[f32; 3]> {
        self.scene.ground_truth(camera, turntable_rad, light, size).data
    }

    fn noise_free_dn(&self, camera: usize, turntable_rad: f64, lights: &[f64], exposure_s: f64, gain: f64) -> Vec<f32> {
        match self.sources.iter().find(|s| s.camera() == camera) {
            Some(s) => s.noise_free_dn(turntable_rad, lights, exposure_s, gain),
            // A camera the run did not open: rendered afresh.
            None => DomeFrameSource::new(self.scene.clone(), camera, RenderOptions::default()).noise_free_dn(
                turntable_rad,
                lights,
                exposure_s,
                gain,
            ),
        }
    }

    fn stuck_on(&self) -> Vec<usize> {
        self.stuck_on.clone()
    }

    fn true_turntable(&self, camera: usize, timestamp_s: f64) -> Option<f64> {
        self.sources.iter().filter(|s| s.camera() == camera).find_map(|s| s.true_turntable(timestamp_s))
    }

    fn pose(&self, camera: usize, turntable_rad: f64) -> ScenePose {
        // The pose does not depend on the light: LED 0 stands for any.
        self.scene.pose(camera, turntable_rad, 0)
    }

    fn camera(&self) -> &CameraModel {
        &self.camera
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
        let material = load_material(plan::material_name(req.plan, req.validated, req.plan_file).as_deref())?;
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
        let sim = SimRig::from_rig_config(rig, &faults, clock_for(req.time), truth.clone())
            .map_err(|e| RunError::Rig(e.to_string()))?;
        let clock = sim.world.clock().clone();
        let SimRig { robot, rail, lamp, camera, .. } = sim;
        Ok(OpenedGonio { robot, rail, lamp, camera, clock, truth: Some(truth), links: Box::new(InProcess) })
    }

    async fn open_dome(&self, req: DomeOpenRequest<'_>) -> Result<OpenedDome, RunError> {
        let rig = req.rig;
        let base = req.plan_file.parent().unwrap_or(Path::new("."));
        let faults = fault_scenario(req.fault_scenario, base, "fault_scenario")?;
        let material =
            load_material(plan::dome_material_name(req.plan.plan.rig.material.as_deref(), req.plan_file).as_deref())?;
        let scene = Arc::new(
            DomeScene::new(rig, &material)
                .map_err(|e| RunError::Input { what: "dome scene".into(), message: e.to_string() })?,
        );
        let clock = TokioClock::shared();
        let dome =
            DomeRig::build(rig, &faults, clock.clone(), scene.clone(), &req.plan.cameras, RenderOptions::default())
                .map_err(|e| RunError::Rig(e.to_string()))?;
        let camera = rig
            .camera
            .to_model()
            .map_err(|e| RunError::Input { what: "rig.config [camera]".into(), message: e.to_string() })?;
        let truth = Arc::new(DomeSceneTruth::new(scene, dome.sources.clone(), &faults, camera));
        Ok(OpenedDome {
            devices: DomeDevices { turntable: dome.turntable, leds: dome.led_array, cameras: dome.cameras, clock },
            truth: Some(truth),
            links: Box::new(InProcess),
        })
    }

    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        calibration_targets::open(req).await
    }

    fn check_rig(&self, rig: &RigConfig) -> Result<(), String> {
        btfrig_sim::check_sim_options(&rig.devices).map_err(|e| e.to_string())
    }

    fn check_scene(&self, options: &SceneOptions<'_>) -> Result<(), RunError> {
        if let Some(m) = options.material {
            load_material(Some(m))?;
        }
        if let Some((name, base, field)) = options.faults {
            fault_scenario(name, base, field)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::plan::BUILTIN_RIGS;

    /// The dome rigs' `[dome] nominal_signal_e_per_s` (the planner's brightness when a rig
    /// names no LED calibration) is the simulated scene's own: a datasheet figure that
    /// disagrees with the simulated lights would plan the wrong mode or exposure.
    #[test]
    fn the_dome_rigs_nominal_signal_is_the_scenes() {
        let material = load_material(None).unwrap();
        let mut checked = 0;
        for (name, text) in BUILTIN_RIGS {
            let rig = RigConfig::from_toml(text, name).unwrap();
            let Some(dome) = rig.dome.as_ref() else { continue };
            let scene = DomeScene::new(&rig, &material).unwrap();
            let truth = scene.nominal_irradiance();
            let nominal = dome.nominal_signal_e_per_s.unwrap_or_else(|| {
                panic!("{name} sets no [dome] nominal_signal_e_per_s; the scene's is {truth:.4} e-/s")
            });
            let err = (nominal / truth - 1.0).abs();
            eprintln!("{name}: nominal {nominal} e-/s, scene {truth:.6} e-/s ({:.3} %)", 100.0 * err);
            assert!(err < 0.01, "{name}: [dome] nominal_signal_e_per_s = {nominal}, the scene's is {truth:.6}");
            checked += 1;
        }
        assert_eq!(checked, 3, "bonn-dome-sim, bonn-dome-serial and bonn-camera-array-sim");
    }

    #[test]
    fn embedded_fault_files_are_the_names_plans_may_use_and_all_parse() {
        let mut ours: Vec<&str> = FAULT_FILES.iter().map(|(n, _)| *n).collect();
        let mut core: Vec<&str> = btfrig_core::plan::BUILTIN_FAULT_SCENARIOS.to_vec();
        ours.sort_unstable();
        core.sort_unstable();
        assert_eq!(ours, core);
        for (name, _) in FAULT_FILES {
            fault_scenario(name, Path::new("/nonexistent"), "--faults").unwrap();
        }
    }

    /// A missing or bad scenario file is an error naming the setting, the file and (for a bad
    /// one) the field, and listing the embedded names for a missing one.
    #[test]
    fn a_missing_or_bad_fault_file_is_named() {
        let e = fault_scenario("nosuch", Path::new("/nonexistent"), "--faults").unwrap_err().to_string();
        assert!(
            e.contains("--faults \"nosuch\"") && e.contains("robot-fault") && e.contains("/nonexistent/nosuch"),
            "{e}"
        );
        let dir = std::env::temp_dir().join(format!("btfrig-sim-backend-faults-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("typo.toml"), "description = \"x\"\n[[stuck_led]]\nindex = 3\nstate = \"on\"\n")
            .unwrap();
        let e = fault_scenario("typo.toml", &dir, "run.fault_scenario").unwrap_err().to_string();
        assert!(
            e.contains("run.fault_scenario \"typo.toml\"") && e.contains("typo.toml") && e.contains("stuck_led"),
            "{e}"
        );
        std::fs::write(dir.join("range.toml"), "[[stuck_leds]]\nindex = 3\nstate = \"sideways\"\n").unwrap();
        let e = fault_scenario("range.toml", &dir, "run.fault_scenario").unwrap_err().to_string();
        assert!(e.contains("run.fault_scenario \"range.toml\"") && e.contains("sideways"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
