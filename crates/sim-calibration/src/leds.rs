//! The simulated side of the LED (or flash) calibration (`btfrig_calibrate::leds`): a white
//! reference tile on the simulated dome's turntable, photographed lit by one light at a time
//! (the true LED powers and colours, the true lens, seeded sensor noise), the frames handed to
//! `btfrig_calibrate::leds::fit_leds`. The simulator's true powers and colours are read here
//! only to report how far the fitted file is from them.

use std::path::Path;

use btfrig_calibrate::leds::{fit_leds, LedCalibError, LedCalibrationFile, LedFitOptions, LedShot};
use btfrig_core::config::RigConfig;
use btfrig_render::dome_scene::DomeScene;
use btfrig_render::material::{AlbedoSpec, MaterialSpec, Pattern};
use btfrig_render::renderer::RenderOptions;

/// A simulated LED calibration and the truth it estimates.
#[derive(Debug, Clone)]
pub struct SimLedCalibration {
    /// The fitted file.
    pub file: LedCalibrationFile,
    /// Per light, its true power relative to the true mean (the file's `power` estimates it).
    pub true_power: Vec<f64>,
    /// Per light, its true camera-RGB colour on a white reflector, green = 1 (the file's
    /// `colour` estimates it).
    pub true_colour: Vec<[f64; 3]>,
    /// The true reference rate (the file's `reference_rate` estimates it), e-/s per photosite
    /// (e- per flash).
    pub true_reference_rate: f64,
    /// Exposure of the calibration frames, s.
    pub exposure_s: f64,
}

/// What the simulated procedure does.
#[derive(Debug, Clone)]
pub struct SimLedOptions {
    /// Noise seed (each frame's is derived from it and the frame index).
    pub seed: u64,
    /// Frames per light.
    pub repeats: usize,
    /// The white tile's brightest light reaches this fraction of full well (an LED's exposure
    /// is metered to it; a flash's exposure is its pulse, whatever it reaches).
    pub exposure_fraction: f64,
    /// Fit options (albedo, points, method, date).
    pub fit: LedFitOptions,
}

impl SimLedOptions {
    /// The defaults for `seed`: 2 frames per LED, 64 per flash (a flash is dim: 0.3 % power error), metered to
    /// half of full well.
    pub fn new(cfg: &RigConfig, seed: u64) -> SimLedOptions {
        let flash = cfg.dome.as_ref().is_some_and(|d| d.is_flash());
        SimLedOptions {
            seed,
            repeats: if flash { 64 } else { 2 },
            exposure_fraction: 0.5,
            fit: LedFitOptions { seed: Some(seed), ..LedFitOptions::default() },
        }
    }
}

/// The white reference tile as a material: flat, Lambertian, spectrally flat reflectance.
fn white_tile(albedo: f64) -> MaterialSpec {
    MaterialSpec {
        name: "white-reference".into(),
        description: "flat Lambertian white reference tile".into(),
        texels: 16,
        seed: 0,
        basis: vec![format!("flat:{albedo}")],
        height: Vec::new(),
        albedo: AlbedoSpec { pattern: Pattern::Constant { value: 1.0 }, stops: vec![vec![1.0], vec![1.0]] },
        specular: None,
    }
}

/// Per light its true power and colour, and the true reference rate.
pub type LedTruth = (Vec<f64>, Vec<[f64; 3]>, f64);

/// The simulator's truth of an LED calibration on dome `cfg`: per light its power relative to
/// the mean and its colour (green = 1), and the reference rate. For error figures only.
pub fn led_truth(cfg: &RigConfig) -> Result<LedTruth, LedCalibError> {
    let scene = DomeScene::new(cfg, &white_tile(1.0)).map_err(|e| LedCalibError::Rig(e.to_string()))?;
    let n = scene.dome().led_count();
    let white = scene.colour().camera_white();
    let rate = |j: usize, c: usize| {
        scene.nominal_irradiance() * scene.led_power()[j] * scene.led_colour()[j][c] * white[c] / white[1]
    };
    let reference = (0..n).map(|j| rate(j, 1)).sum::<f64>() / n as f64;
    Ok((
        (0..n).map(|j| rate(j, 1) / reference).collect(),
        (0..n).map(|j| [rate(j, 0) / rate(j, 1), 1.0, rate(j, 2) / rate(j, 1)]).collect(),
        reference,
    ))
}

/// Runs the LED calibration on the simulated dome `cfg` (the rig file at `rig_path`, for its
/// camera calibration): a dome's LEDs are photographed by camera 0, a camera array's flash `j`
/// by its own camera `j`, the turntable at 0.
pub fn calibrate_leds_simulated(
    cfg: &RigConfig,
    rig_path: Option<&Path>,
    opts: &SimLedOptions,
) -> Result<SimLedCalibration, LedCalibError> {
    let rig = |e: &dyn std::fmt::Display| LedCalibError::Rig(e.to_string());
    let scene = DomeScene::new(cfg, &white_tile(opts.fit.reference_albedo)).map_err(|e| rig(&e))?;
    let camera = btfrig_calibrate::processing_camera(cfg, rig_path).map_err(|e| rig(&e))?;
    let dome = scene.dome().clone();
    let n = dome.led_count();
    let flash = dome.is_flash();
    let sensor = scene.sensor();
    let max_power = scene.led_power().iter().cloned().fold(0.0, f64::max);
    let exposure_s = match &dome.flash {
        Some(f) => f.duration_s,
        // Metered as a lab meters on the tile; the colour factors stay within 20 %.
        None => (opts.exposure_fraction * cfg.sensor.full_well_e / (scene.nominal_irradiance() * max_power * 1.2))
            .clamp(1e-4, 30.0),
    };
    let jobs: Vec<(usize, usize)> = (0..n).flat_map(|j| (0..opts.repeats.max(1)).map(move |r| (j, r))).collect();
    let shots: Vec<LedShot> = jobs
        .iter()
        .enumerate()
        .map(|(k, &(j, _))| {
            let c = if flash { j } else { 0 };
            let (mut img, _) = scene.single_led_radiance(c, 0.0, j, &RenderOptions::default());
            if flash {
                // A flash's image is its signal per flash: spread over the exposure as a rate
                // (as the simulated camera array's frame source does).
                let k = (dome.light_units(exposure_s) / exposure_s) as f32;
                img.data.iter_mut().for_each(|px| *px = px.map(|v| v * k));
            }
            let seed = opts.seed ^ (k as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let frame = sensor.capture(&img, exposure_s, 1.0, seed).map_err(|e| rig(&e))?;
            Ok(LedShot { light: j, camera: c, turntable_rad: 0.0, frame })
        })
        .collect::<Result<_, LedCalibError>>()?;
    let file = fit_leds(cfg, &camera, &shots, &opts.fit)?;
    // The truth: light j's white-reflector rate is the nominal (green) rate times its power,
    // its colour and the camera's white relative to green.
    let white = scene.colour().camera_white();
    let rate = |j: usize, c: usize| {
        scene.nominal_irradiance() * scene.led_power()[j] * scene.led_colour()[j][c] * white[c] / white[1]
    };
    let true_reference_rate = (0..n).map(|j| rate(j, 1)).sum::<f64>() / n as f64;
    Ok(SimLedCalibration {
        true_power: (0..n).map(|j| rate(j, 1) / true_reference_rate).collect(),
        true_colour: (0..n).map(|j| [rate(j, 0) / rate(j, 1), 1.0, rate(j, 2) / rate(j, 1)]).collect(),
        true_reference_rate,
        exposure_s,
        file,
    })
}
