//! The physics of a simulated dome rig (an LED dome, `kind = "led_dome"`, or a camera array
//! whose lights are its cameras' flashes, `kind = "camera_array"`): the same renderer, lens,
//! sensor and colour model as [`crate::rig_scene::RigScene`], posed by the dome's geometry.
//!
//! A view is a camera of the arc plus a turntable angle of the sample; a light is one LED, a
//! point source at its position ([`btfrig_core::config::dome::DomeConfig::scene_pose`]). The
//! renderer is built with the LED's scale (`lamp_scale · E_led / E_lamp`, the `[lamp]`
//! spectrum), so one render is the camera-RGB signal rate of LED `j` at nominal power; LED
//! `j`'s true output multiplies it by its power factor and colour factors. By linearity the
//! image of a pattern is the intensity-weighted sum of single-LED images; the sensor adds
//! noise once (the frame source in `btfrig-sim` caches the single-LED images per view).
//!
//! A flash is a point light at its camera's flash position (`[dome.flash] offset_m`), and a
//! short pulse: its scale is the flash's radiant exposure (`energy_at_1m_j_m2`) in place of
//! the LED's irradiance, so one render is the camera-RGB signal of one whole flash
//! (electrons per flash, not per second) and a frame collects
//! `DomeConfig::light_units(exposure)` flashes' worth (1 for an exposure at least as long as
//! the pulse).

use btfrig_core::config::dome::DomeConfig;
use btfrig_core::config::RigConfig;
use btfrig_core::pose::ScenePose;
use rayon::prelude::*;

use crate::colour::ColourSystem;
use crate::ground_truth::GroundTruth;
use crate::material::MaterialSpec;
use crate::radiance::RadianceImage;
use crate::renderer::{RenderOptions, RenderStats, Renderer};
use crate::rig_scene::{resolve_spectrum, CachedCamera, RigSceneError};
use crate::sensor::{electrons_per_second_scale, SensorModel};

/// One simulated LED dome with one material on its turntable.
pub struct DomeScene {
    dome: DomeConfig,
    camera: CachedCamera,
    sensor: SensorModel,
    colour: ColourSystem,
    renderer: Renderer,
    led_power: Vec<f64>,
    led_colour: Vec<[f64; 3]>,
    /// Camera-RGB rate of a white Lambertian reflector facing an LED of nominal power at the
    /// dome radius (`led_scale / R²`).
    nominal_irradiance: f64,
    preview_matrix: [[f64; 3]; 3],
}

impl DomeScene {
    /// Builds everything from an LED dome's rig config and a material (a gonioreflectometer
    /// config is refused naming `rig.kind`).
    pub fn new(cfg: &RigConfig, material: &MaterialSpec) -> Result<DomeScene, RigSceneError> {
        cfg.validate()?;
        let dome = cfg.require_dome("a dome scene")?.clone();
        // Every LED's image of a view comes from the same camera: its marker-edge subsample
        // rays are worth keeping.
        let ss = RenderOptions::default().marker_supersampling as usize;
        let camera = CachedCamera::new(cfg.camera.to_model()?).caching_subsamples(ss);
        let sensor = SensorModel::from_config(&cfg.sensor)?;
        let colour = ColourSystem::from_config(&cfg.lamp, &cfg.sensor)?;
        let k = electrons_per_second_scale(&cfg.camera, &cfg.sensor, &cfg.lamp, &colour);
        // An LED (or a flash) emits the lamp's spectrum at its own irradiance (or radiant
        // exposure, per flash; see the module docs).
        let led_scale = k / std::f64::consts::PI * dome.light_at_1m() / cfg.lamp.irradiance_at_1m_w_m2;
        let resolve = |name: &str| resolve_spectrum(&colour, name);
        let renderer = Renderer::new(&cfg.plate, material, led_scale, &resolve)?;
        let r = dome.light_distance_m();
        Ok(DomeScene {
            led_power: dome.led_power(cfg.rig.seed),
            led_colour: dome.led_colour(cfg.rig.seed),
            preview_matrix: colour.colorchecker_matrix().matrix,
            nominal_irradiance: led_scale / (r * r),
            dome,
            camera,
            sensor,
            colour,
            renderer,
        })
    }

    /// The `[dome]` section.
    pub fn dome(&self) -> &DomeConfig {
        &self.dome
    }
    /// The cached camera (every camera of the arc has the same lens).
    pub fn camera(&self) -> &CachedCamera {
        &self.camera
    }
    /// The sensor model.
    pub fn sensor(&self) -> &SensorModel {
        &self.sensor
    }
    /// The colour system of LEDs and camera.
    pub fn colour(&self) -> &ColourSystem {
        &self.colour
    }
    /// The renderer.
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }
    /// The true power factor of every LED (what a real dome's LED calibration measures).
    pub fn led_power(&self) -> &[f64] {
        &self.led_power
    }
    /// The true camera-RGB colour factor of every LED (green = 1).
    pub fn led_colour(&self) -> &[[f64; 3]] {
        &self.led_colour
    }
    /// Camera-RGB rate (e-/s per photosite, green; for flashes e- per flash) of a white
    /// Lambertian reflector facing a light of nominal power at the nominal distance
    /// (`DomeConfig::light_distance_m`), on the optical axis.
    pub fn nominal_irradiance(&self) -> f64 {
        self.nominal_irradiance
    }
    /// The camera-to-sRGB matrix fitted on the ColorChecker.
    pub fn color_matrix(&self) -> [[f64; 3]; 3] {
        self.preview_matrix
    }

    /// The world poses of camera `c`, the sample turned by `turntable_rad`, and LED `led`.
    pub fn pose(&self, c: usize, turntable_rad: f64, led: usize) -> ScenePose {
        self.dome.scene_pose(c, turntable_rad, led)
    }

    /// The camera-RGB signal rate (e-/s per photosite) of LED `led` alone at full output,
    /// seen by camera `c` with the sample at `turntable_rad`: its power and colour included.
    pub fn single_led_radiance(
        &self,
        c: usize,
        turntable_rad: f64,
        led: usize,
        opts: &RenderOptions,
    ) -> (RadianceImage, RenderStats) {
        let (mut img, stats) = self.renderer.render_with_stats(&self.pose(c, turntable_rad, led), &self.camera, opts);
        let p = self.led_power[led];
        let k = self.led_colour[led].map(|v| (v * p) as f32);
        img.data.par_iter_mut().for_each(|px| *px = [px[0] * k[0], px[1] * k[1], px[2] * k[2]]);
        (img, stats)
    }

    /// The ground-truth texture (`size x size` texels over the sample region) of camera `c`,
    /// the sample at `turntable_rad` and LED `led`, as a radiance factor: radiance over the
    /// irradiance the LED gives at the dome radius (its calibrated power and colour divided
    /// out, as the pipeline does).
    pub fn ground_truth(&self, c: usize, turntable_rad: f64, led: usize, size: usize) -> GroundTruth {
        let mut gt = self.renderer.ground_truth(&self.pose(c, turntable_rad, led), size, size, None);
        let k = (1.0 / self.nominal_irradiance) as f32;
        gt.data.par_iter_mut().for_each(|p| *p = p.map(|v| v * k));
        gt
    }
}
