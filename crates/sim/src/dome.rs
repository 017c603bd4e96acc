//! A simulated dome rig: the turntable (an LED dome's; a camera array has none), the LED
//! array (on a camera array: the flash triggers, one channel per camera) and one simulated
//! camera per view position, all acting on one [`SimWorld`], with frames rendered from a
//! [`btfrig_render::dome_scene::DomeScene`].
//!
//! Each camera has its own [`DomeFrameSource`] (which arc position it sees) and its own noise
//! seed. A frame is, by linearity, the true LED intensities (stuck LEDs included) times the
//! single-LED radiance images of the current view, summed, then the sensor model adds noise
//! once. The single-LED images are rendered on first use and cached for the current turntable
//! angle only (a view's 198 images of 320 x 240 are 182 MB), so memory stays bounded by one
//! view per camera.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::ConfigError;
use btfrig_hw::{Camera, CaptureSettings, LedArray, SharedClock, Turntable};
use btfrig_render::dome_scene::DomeScene;
use btfrig_render::radiance::RadianceImage;
use btfrig_render::renderer::RenderOptions;

use crate::faults::derive_seed;
use crate::rig::{factory_for, BuildContext};
use crate::{FaultScenario, FrameSource, SensorFormat, SimRig, SimWorld, TrueState};

type ViewCache = Option<(u64, Vec<Option<Arc<RadianceImage>>>)>;

/// The pixels of one dome camera.
pub struct DomeFrameSource {
    scene: Arc<DomeScene>,
    camera: usize,
    options: RenderOptions,
    cache: Mutex<ViewCache>,
    /// The true turntable angle behind each frame rendered, by the frame's time stamp (the
    /// simulated camera stamps a frame with its true state's time): for the truth figures.
    turntable_log: Mutex<HashMap<u64, f64>>,
}

impl DomeFrameSource {
    /// The source of camera `camera` of the arc.
    pub fn new(scene: Arc<DomeScene>, camera: usize, options: RenderOptions) -> Self {
        DomeFrameSource { scene, camera, options, cache: Mutex::new(None), turntable_log: Mutex::new(HashMap::new()) }
    }

    /// The true turntable angle, radians, at the exposure of the frame stamped `timestamp_s`
    /// (`None` if this source never rendered it).
    pub fn true_turntable(&self, timestamp_s: f64) -> Option<f64> {
        self.turntable_log.lock().unwrap_or_else(|e| e.into_inner()).get(&timestamp_s.to_bits()).copied()
    }

    /// Which camera of the arc this is.
    pub fn camera(&self) -> usize {
        self.camera
    }

    /// The scene.
    pub fn scene(&self) -> &DomeScene {
        &self.scene
    }

    /// The single-LED image of `led` at `turntable_rad` (rendered once per view).
    pub fn single(&self, turntable_rad: f64, led: usize) -> Arc<RadianceImage> {
        let key = turntable_rad.to_bits();
        {
            let cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((k, imgs)) = cache.as_ref() {
                if *k == key {
                    if let Some(img) = &imgs[led] {
                        return img.clone();
                    }
                }
            }
        }
        let img = Arc::new(self.scene.single_led_radiance(self.camera, turntable_rad, led, &self.options).0);
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        let n = self.scene.dome().led_count();
        if cache.as_ref().is_none_or(|(k, _)| *k != key) {
            *cache = Some((key, vec![None; n]));
        }
        if let Some((_, imgs)) = cache.as_mut() {
            imgs[led] = Some(img.clone());
        }
        img
    }

    /// The signal rate (e-/s per photosite, camera RGB; for flashes e- per flash) of LED
    /// intensities `leds` at `turntable_rad`: the weighted sum of single-LED images.
    pub fn radiance(&self, turntable_rad: f64, leds: &[f64]) -> RadianceImage {
        let cam = self.scene.camera().model();
        let mut out = RadianceImage::black(cam.width, cam.height);
        for (j, &l) in leds.iter().enumerate().filter(|(_, l)| **l > 0.0) {
            let img = self.single(turntable_rad, j);
            let k = l as f32;
            for (o, v) in out.data.iter_mut().zip(&img.data) {
                for c in 0..3 {
                    o[c] += k * v[c];
                }
            }
        }
        out
    }

    /// The noise-free signal of every photosite (DN above black and dark level, before
    /// rounding) for LED intensities `leds`: the simulator's truth against which measured
    /// noise is computed.
    pub fn noise_free_dn(&self, turntable_rad: f64, leds: &[f64], exposure_s: f64, gain: f64) -> Vec<f32> {
        let img = self.radiance(turntable_rad, leds);
        let s = self.scene.sensor();
        let k = s.dn_per_electron(gain) * self.scene.dome().light_units(exposure_s);
        let w = img.width;
        img.data
            .iter()
            .enumerate()
            .map(|(i, px)| {
                let (x, y) = (i % w, i / w);
                (f64::from(px[s.channel_at(x, y)]) * s.prnu_gain(x, y) * k) as f32
            })
            .collect()
    }
}

impl FrameSource for DomeFrameSource {
    fn format(&self) -> SensorFormat {
        crate::rendered::sensor_format(self.scene.camera().model(), self.scene.sensor())
    }

    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame {
        let sensor = self.scene.sensor();
        let (exposure_s, gain) = crate::rendered::sensor_settings(sensor, settings);
        self.turntable_log
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(truth.time_s.to_bits(), truth.joints.turntable);
        let mut img = self.radiance(truth.joints.turntable, &truth.leds);
        if self.scene.dome().is_flash() {
            // A flash's image is its signal per flash: spread it over the exposure as a rate,
            // so the sensor collects `light_units` flashes and its dark current the exposure.
            let k = (self.scene.dome().light_units(exposure_s) / exposure_s) as f32;
            img.data.iter_mut().for_each(|px| *px = px.map(|v| v * k));
        }
        sensor.capture(&img, exposure_s, gain, seed).expect("exposure and gain were clamped into the sensor's ranges")
    }
}

/// The devices of a simulated LED dome and the world they act on.
pub struct DomeRig {
    /// The shared world (true turntable angle, true LED intensities, fault log).
    pub world: SimWorld,
    /// The turntable under the sample (`None` on a camera array).
    pub turntable: Option<Box<dyn Turntable>>,
    /// The LED array (a camera array's flash triggers).
    pub led_array: Box<dyn LedArray>,
    /// One camera per requested arc position, in the order asked for.
    pub cameras: Vec<Box<dyn Camera>>,
    /// The frame source of each camera (same order), for ground truth and noise-free images.
    pub sources: Vec<Arc<DomeFrameSource>>,
}

impl DomeRig {
    /// Builds a dome rig's devices from its rig config: `[devices.turntable]` (LED dome only),
    /// `[devices.led_array]` (with `faults.stuck_leds`), and one camera from
    /// `[devices.camera]` for each of `cameras` (camera indices), each with its own noise seed.
    pub fn build(
        cfg: &RigConfig,
        faults: &FaultScenario,
        clock: SharedClock,
        scene: Arc<DomeScene>,
        cameras: &[usize],
        options: RenderOptions,
    ) -> Result<DomeRig, ConfigError> {
        let dome = cfg.require_dome("a simulated dome rig")?;
        if let Some(&c) = cameras.iter().find(|&&c| c >= dome.camera_count()) {
            return Err(ConfigError::out_of_range(
                "cameras",
                c,
                &format!("0..{} (the arc's cameras)", dome.camera_count()),
            ));
        }
        let sources: Vec<Arc<DomeFrameSource>> =
            cameras.iter().map(|&c| Arc::new(DomeFrameSource::new(scene.clone(), c, options))).collect();
        let first: Arc<dyn FrameSource> = match sources.first() {
            Some(s) => s.clone(),
            None => return Err(ConfigError::out_of_range("cameras", "[]", "at least one camera")),
        };
        let rig = SimRig::from_rig_config(cfg, faults, clock, first)?;
        // An LED dome has a turntable (validated); a camera array has none.
        let turntable = rig.turntable;
        let led_array = rig.led_array.expect("a dome config has an LED array (validated)");
        let factory = factory_for(&cfg.devices.camera, "devices.camera.kind")?;
        let mut devs = Vec::new();
        for s in &sources {
            let frames: Arc<dyn FrameSource> = s.clone();
            let cx = BuildContext {
                world: &rig.world,
                timing: &cfg.timing,
                faults,
                seed: derive_seed(cfg.rig.seed, "dome-camera", s.camera() as u64),
                frames: &frames,
            };
            devs.push((factory.camera)(&cx, &cfg.devices.camera.options)?);
        }
        Ok(DomeRig { world: rig.world, turntable, led_array, cameras: devs, sources })
    }
}
