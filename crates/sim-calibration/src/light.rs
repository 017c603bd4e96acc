//! The light calibration on the simulated rig: the white reference tile rendered with the
//! true lens, the lamp at its settled output and seeded sensor noise
//! (`btfrig_calibrate::light::calibrate_light` measures it), and the simulator's truth
//! (the lamp model's white rate, the plate spectrum's albedo) next to the result.

use btfrig_calibrate::light::{calibrate_light, LightCalibError, LightCalibrationFile, LightPlan, TileCamera};
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_render::material::{AlbedoSpec, MaterialSpec, Pattern};
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::{resolve_spectrum, RigScene};

/// A light calibration with the simulator's truth next to it.
#[derive(Debug, Clone, PartialEq)]
pub struct SimLightCalibration {
    /// The calibration.
    pub file: LightCalibrationFile,
    /// The true `W_c` of the simulated lamp (model's nominal irradiance times the camera's
    /// white).
    pub true_white_rate: [f64; 3],
    /// The true plate albedo relative to a white reflector (camera RGB of the plate's
    /// spectrum over the camera's white).
    pub true_plate_albedo: [f64; 3],
    /// Per frame: `W_c` estimated from it (scatter shows the geometry model holds).
    pub per_frame_white_rate: Vec<[f64; 3]>,
}

/// The white reference tile as a material: flat, Lambertian, spectrally flat reflectance.
pub fn white_tile(albedo: f64) -> MaterialSpec {
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

/// The simulated rig with the white tile on the holder: a [`TileCamera`], frame `k`'s noise
/// seeded from the seed and `k`.
pub struct SimTileCamera {
    scene: RigScene,
    seed: u64,
}

impl SimTileCamera {
    /// The rig `cfg` with a tile of reflectance `albedo`.
    pub fn new(cfg: &RigConfig, albedo: f64, seed: u64) -> Result<SimTileCamera, LightCalibError> {
        let scene = RigScene::new(cfg, &white_tile(albedo)).map_err(|e| LightCalibError::Rig(e.to_string()))?;
        Ok(SimTileCamera { scene, seed })
    }
}

impl TileCamera for SimTileCamera {
    fn exposure_for_white(&self, fraction: f64) -> f64 {
        self.scene.exposure_for_white(fraction, 1e-4, 30.0)
    }

    fn capture(&self, frame: usize, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String> {
        let s = self.seed ^ (frame as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.scene
            .capture(joints, 1.0, exposure_s, 1.0, s, &RenderOptions::default())
            .map(|(raw, _)| raw)
            .map_err(|e| e.to_string())
    }
}

/// The simulator's truth of a light calibration on rig `cfg`: the lamp's true `W_c` (the
/// model's nominal irradiance times the camera's white) and the plate's true albedo relative
/// to a white reflector. For error figures only.
pub fn light_truth(cfg: &RigConfig) -> Result<([f64; 3], [f64; 3]), LightCalibError> {
    let scene = RigScene::new(cfg, &white_tile(1.0)).map_err(|e| LightCalibError::Rig(e.to_string()))?;
    let nominal = scene.white_signal_dn(1.0, 1.0) / scene.sensor().dn_per_electron(1.0);
    let white = scene.colour().camera_white();
    let (plate_cam, _) = resolve_spectrum(scene.colour(), &cfg.plate.albedo).map_err(LightCalibError::Rig)?;
    Ok((std::array::from_fn(|c| nominal * white[c]), std::array::from_fn(|c| plate_cam[c] / white[c])))
}

/// Runs `plan` on the simulated rig `cfg` (noise seeded from `seed` and the frame index) and
/// puts the simulator's truth next to the result.
pub fn calibrate_light_simulated(
    cfg: &RigConfig,
    plan: &LightPlan,
    seed: u64,
) -> Result<SimLightCalibration, LightCalibError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(LightCalibError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let rig = SimTileCamera::new(cfg, plan.reference_albedo, seed)?;
    let source = format!("plan {}, rig {}, seed {seed}, simulated", plan.name, cfg.rig.name);
    let cal = calibrate_light(cfg, plan, &rig, source)?;
    // The truth: the model's nominal irradiance (green rate of a white reflector) times the
    // camera's white, and the plate spectrum's camera RGB over the camera's white.
    let scene = &rig.scene;
    let nominal = scene.white_signal_dn(1.0, 1.0) / scene.sensor().dn_per_electron(1.0);
    let white = scene.colour().camera_white();
    let (plate_cam, _) = resolve_spectrum(scene.colour(), &cfg.plate.albedo).map_err(LightCalibError::Rig)?;
    Ok(SimLightCalibration {
        file: cal.file,
        true_white_rate: std::array::from_fn(|c| nominal * white[c]),
        true_plate_albedo: std::array::from_fn(|c| plate_cam[c] / white[c]),
        per_frame_white_rate: cal.per_frame_white_rate,
    })
}
