//! A perfect calibration of the simulated gonioreflectometer: the processing model whose
//! calibrations are the simulator's own constants (true lens, sensor constants, nominal
//! irradiance, manufacturer-style colour matrix). For tests and benchmarks that measure the
//! pipeline itself against the ground truth, without calibration error; runs load their models
//! from calibration files (`btfrig_measurement::model`).

use btfrig_color::{ColorModel, ModelKind};
use btfrig_core::config::RigConfig;
use btfrig_process::color::ColorCorrection;
use btfrig_process::light::{LampReference, LightCorrection};
use btfrig_process::{ProcessingModel, SensorConstants};
use btfrig_render::rig_scene::RigScene;

/// The model a perfect calibration of `scene` would give: its true lens, sensor constants,
/// nominal irradiance (as a light calibration without drift correction) and manufacturer-style
/// colour matrix (as a linear colour calibration).
pub fn truth_model(cfg: &RigConfig, scene: &RigScene) -> ProcessingModel {
    let s = scene.sensor();
    let sensor = SensorConstants {
        electrons_per_dn: s.electrons_per_dn,
        read_noise_e: s.read_noise_e,
        dark_current_e_per_s: s.dark_current_e_per_s,
        full_scale_e: f64::from(s.white_level(1.0) - s.black_level_dn) * s.electrons_per_dn,
    };
    let fit = scene.colour().colorchecker_matrix();
    let nominal = scene.white_signal_dn(1.0, 1.0) / s.dn_per_electron(1.0);
    let wb = fit.white_balance;
    let mut light = LightCorrection::new(LampReference {
        light: "lamp".into(),
        white_rate: std::array::from_fn(|c| nominal * wb[1] / wb[c]),
        plate_albedo: [0.8; 3],
    });
    light.correct_drift = false;
    // ColorModel rows are terms: coefficient[j][c] multiplies input channel j into output c.
    let m = fit.matrix;
    let rows = (0..3).map(|j| [m[0][j], m[1][j], m[2][j]]).collect();
    let color = ColorCorrection {
        name: "the simulator's matrix".into(),
        white_balance: wb,
        model: ColorModel::from_coefficients(ModelKind::Linear, rows).unwrap(),
    };
    ProcessingModel::uncalibrated(
        cfg.rig.name.clone(),
        scene.gonio().clone(),
        scene.camera().model().clone(),
        sensor,
        cfg.plate.clone(),
    )
    .with_light(Some(light))
    .with_color(Some(color))
}
