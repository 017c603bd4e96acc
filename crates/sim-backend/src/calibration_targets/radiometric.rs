//! The radiometric targets on the simulated rig: white tile, uniform field, lens cap.
//!
//! The devices are a run's (robot, rail, lamp and camera of a gonioreflectometer; turntable,
//! LED array and cameras of a dome or camera array), on the request's clock, with the rig's
//! sensor; only what the camera sees changes:
//! - a white tile: a flat Lambertian tile of the given albedo on the holder, rendered like a
//!   sample (gonio: lit by the lamp, with the scene's truth probe; dome: lit by its LEDs);
//! - a uniform field: a diffuser filling the view, imaged through the true lens (its
//!   vignetting) at a rate proportional to the light that reaches it: the lamp's output on a
//!   gonioreflectometer, the mean LED output on a dome; at full light its brightest channel
//!   fills the sensor in [`FIELD_FILL_S`];
//! - a lens cap: no light at all, whatever the lights do.
//!
//! Each target's noise is seeded from the request's seed and the target, so dark frames and
//! flats taken on two openings are independent.

use std::sync::Arc;

use btfrig_acquire::dome::DomeDevices;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_hw::CaptureSettings;
use btfrig_measurement::backend::{CalibrationOpenRequest, MountedTarget, OpenedDome, OpenedRig};
use btfrig_measurement::RunError;
use btfrig_render::colour::ColourSystem;
use btfrig_render::dome_scene::DomeScene;
use btfrig_render::flat_field::{flat_field_radiance, white_flat_level};
use btfrig_render::radiance::RadianceImage;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::{CachedCamera, RigScene};
use btfrig_render::sensor::SensorModel;
use btfrig_sim::dome::DomeRig;
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::{FaultScenario, FrameSource, RenderedFrameSource, SensorFormat, SimRig, TrueState};
use btfrig_sim_calibration::light::white_tile;

/// At full light the uniform field's brightest channel fills the sensor's full scale at gain 1
/// in this time, seconds: a bright diffuser, so that a photon-transfer series stays short.
pub const FIELD_FILL_S: f64 = 0.1;

/// White tile, uniform field, lens cap.
pub(super) async fn open_radiometric(req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
    // The scene is the rig's own (its LEDs' powers and colours come from the rig seed); the
    // devices' noise is seeded from the request, one stream per target, so dark frames and
    // flats from two openings are independent.
    let scene_cfg = req.rig;
    let mut cfg = req.rig.clone();
    let salt = match req.target {
        MountedTarget::WhiteTile { .. } => 1,
        MountedTarget::UniformField => 2,
        MountedTarget::Capped => 3,
        other => return Err(RunError::Rig(format!("not a radiometric target: {}", other.name()))),
    };
    cfg.rig.seed = btfrig_sim::faults::derive_seed(req.seed, "calibration-target", salt);
    let clock = crate::clock_for(req.time);
    let rig_err = |e: &dyn std::fmt::Display| RunError::Rig(e.to_string());
    let faults = FaultScenario::none();
    match (&cfg.dome, req.target) {
        (None, MountedTarget::WhiteTile { albedo }) => {
            let scene = Arc::new(RigScene::new(scene_cfg, &white_tile(*albedo)).map_err(|e| rig_err(&e))?);
            let source: Arc<dyn FrameSource> =
                Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default()));
            let truth = Arc::new(SceneTruth::new(scene, source));
            let sim = SimRig::from_rig_config(&cfg, &faults, clock, truth.clone()).map_err(|e| rig_err(&e))?;
            Ok(super::opened_gonio(sim, Some(truth)))
        }
        (None, target) => {
            let source = Arc::new(FieldSource::new(&cfg, matches!(target, MountedTarget::UniformField))?);
            let sim = SimRig::from_rig_config(&cfg, &faults, clock, source).map_err(|e| rig_err(&e))?;
            Ok(super::opened_gonio(sim, None))
        }
        (Some(_), MountedTarget::WhiteTile { albedo }) => {
            let scene = Arc::new(DomeScene::new(scene_cfg, &white_tile(*albedo)).map_err(|e| rig_err(&e))?);
            let dome = DomeRig::build(&cfg, &faults, clock.clone(), scene, req.cameras, RenderOptions::default())
                .map_err(|e| rig_err(&e))?;
            Ok(OpenedRig::Dome(OpenedDome {
                devices: DomeDevices { turntable: dome.turntable, leds: dome.led_array, cameras: dome.cameras, clock },
                truth: None,
                links: Box::new(btfrig_measurement::backend::InProcess),
            }))
        }
        (Some(_), target) => {
            if req.cameras.len() != 1 {
                return Err(RunError::Rig(format!(
                    "the simulated dome mounts a {} in front of one camera at a time; {} were asked for",
                    target.name(),
                    req.cameras.len()
                )));
            }
            let source = Arc::new(FieldSource::new(&cfg, matches!(target, MountedTarget::UniformField))?);
            let sim = SimRig::from_rig_config(&cfg, &faults, clock.clone(), source).map_err(|e| rig_err(&e))?;
            let leds = sim.led_array.ok_or_else(|| RunError::Rig("the dome rig has no LED array".into()))?;
            Ok(OpenedRig::Dome(OpenedDome {
                devices: DomeDevices { turntable: sim.turntable, leds, cameras: vec![sim.camera], clock },
                truth: None,
                links: Box::new(btfrig_measurement::backend::InProcess),
            }))
        }
    }
}

/// What the camera sees of a uniform field (lit) or through a lens cap (dark): the field
/// through the true lens, scaled by the light reaching it, through the rig's sensor model.
struct FieldSource {
    sensor: SensorModel,
    format: SensorFormat,
    /// The field at full light; `None`: capped.
    field: Option<RadianceImage>,
    width: usize,
    height: usize,
}

impl FieldSource {
    fn new(cfg: &RigConfig, lit: bool) -> Result<FieldSource, RunError> {
        let rig_err = |e: &dyn std::fmt::Display| RunError::Rig(e.to_string());
        let sensor = SensorModel::from_config(&cfg.sensor).map_err(|e| rig_err(&e))?;
        let model = cfg.camera.to_model().map_err(|e| rig_err(&e))?;
        let (width, height) = (model.width, model.height);
        let format = SensorFormat {
            width,
            height,
            bit_depth: sensor.bit_depth,
            bayer: sensor.bayer,
            black_level: sensor.black_level_dn,
            white_level: sensor.white_level(1.0),
        };
        let field = if lit {
            let colour = ColourSystem::from_config(&cfg.lamp, &cfg.sensor).map_err(|e| rig_err(&e))?;
            let full_scale_e = f64::from(sensor.white_level(1.0) - sensor.black_level_dn) / sensor.dn_per_electron(1.0);
            let level = white_flat_level(colour.camera_white(), 1.0, full_scale_e, FIELD_FILL_S);
            Some(flat_field_radiance(&CachedCamera::new(model), level))
        } else {
            None
        };
        Ok(FieldSource { sensor, format, field, width, height })
    }
}

impl FrameSource for FieldSource {
    fn format(&self) -> SensorFormat {
        self.format
    }

    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame {
        // The light on the field: the lamp's output (gonio) or the LEDs' mean (dome).
        let light = if truth.leds.is_empty() {
            truth.lamp_intensity
        } else {
            truth.leds.iter().sum::<f64>() / truth.leds.len() as f64
        } as f32;
        let image = match &self.field {
            Some(f) if light > 0.0 => {
                let mut img = f.clone();
                img.data.iter_mut().for_each(|p| *p = p.map(|v| v * light));
                img
            }
            _ => RadianceImage::filled(self.width, self.height, [0.0; 3]),
        };
        let exposure = settings.exposure_s.clamp(0.0, 3600.0);
        let gain = settings.gain.clamp(1.0, self.sensor.max_analogue_gain);
        self.sensor.capture(&image, exposure, gain, seed).expect("exposure and gain clamped into the sensor's ranges")
    }
}
