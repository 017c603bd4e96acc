//! Shared by the integration tests and the benchmark example: a simulated rig frame, its
//! rectification, radiometric conversion and ground truth.
#![allow(dead_code)]

use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::JointState;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::{
    compare, rectify, to_radiance_factor, vignetting_map, Filter, LinearImage, Radiometry, Region, Texture,
    TextureError,
};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

/// A rig scene with one material, and what the tests need to know about it.
pub struct Setup {
    pub cfg: RigConfig,
    pub scene: RigScene,
}

impl Setup {
    pub fn new(material: &str) -> Setup {
        let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
        let scene = RigScene::new(&cfg, &MaterialSpec::builtin(material).unwrap()).unwrap();
        Setup { cfg, scene }
    }

    pub fn region(&self) -> Region {
        Region::centred_square(self.cfg.plate.sample_side_m)
    }

    /// Nominal joints for a light and view (degrees).
    pub fn joints(&self, light: (f64, f64), view: (f64, f64)) -> JointState {
        self.scene
            .gonio()
            .ik(Direction::from_degrees(light.0, light.1), Direction::from_degrees(view.0, view.1))
            .unwrap_or_else(|e| panic!("light {light:?} view {view:?} unreachable: {e}"))
    }
}

/// One captured, demosaiced frame and the parameters to convert it.
pub struct Shot {
    pub joints: JointState,
    pub image: LinearImage,
    pub radiometry: Radiometry,
}

/// The radiometric parameters of this rig for an exposure at gain 1. `RigScene`'s nominal
/// irradiance is private; it is recovered from the public `white_signal_dn` (which is
/// `nominal_irradiance * exposure * dn_per_electron`).
pub fn radiometry(s: &Setup, exposure_s: f64, dn_range: f64) -> Radiometry {
    let sensor = s.scene.sensor();
    let k = sensor.dn_per_electron(1.0);
    let fit = s.scene.colour().colorchecker_matrix();
    Radiometry {
        dn_range,
        exposure_s,
        dn_per_electron: k,
        dark_e_per_s: sensor.dark_current_e_per_s,
        nominal_irradiance: s.scene.white_signal_dn(1.0, 1.0) / k,
        white_balance: fit.white_balance,
        matrix: fit.matrix,
    }
}

/// Renders, captures (seeded) and demosaics a frame at `joints`.
pub fn shoot(s: &Setup, joints: JointState, seed: u64) -> Shot {
    let exposure = s.scene.exposure_for_white(0.5, 1e-4, 30.0);
    let (raw, _) = s.scene.capture(&joints, 1.0, exposure, 1.0, seed, &RenderOptions::default()).unwrap();
    let dm = demosaic_bilinear(&raw);
    let dn_range = f64::from(raw.meta.white_level) - f64::from(raw.meta.black_level);
    let image = LinearImage { width: dm.width, height: dm.height, data: dm.data };
    Shot { joints, image, radiometry: radiometry(s, exposure, dn_range) }
}

/// The noise-free camera-RGB rate image (e-/s) at `joints`, with the radiometry that
/// converts it (no sensor, no demosaic: isolates resampling and colour conversion).
pub fn noise_free(s: &Setup, joints: JointState) -> Shot {
    let (img, _) = s.scene.radiance(&joints, 1.0, &RenderOptions::default());
    let image = LinearImage { width: img.width, height: img.height, data: img.data };
    // Rates in e-/s: exposure 1 s, 1 DN per electron, range 1, no dark current.
    let mut r = radiometry(s, 1.0, 1.0);
    r.dn_per_electron = 1.0;
    r.dark_e_per_s = 0.0;
    Shot { joints, image, radiometry: r }
}

/// Rectifies `shot` with the pose of `pose_joints` and converts it to the radiance factor.
pub fn rectified(s: &Setup, shot: &Shot, pose_joints: &JointState, size: usize, filter: Filter) -> Texture {
    let pose = s.scene.pose(pose_joints);
    let cam = s.scene.camera().model();
    let t = rectify(&shot.image, cam, &pose, s.region(), size, filter).unwrap();
    let vig = vignetting_map(cam, &pose, s.region(), size).unwrap();
    to_radiance_factor(&t, &vig, &shot.radiometry).unwrap()
}

/// Point-sampled ground truth (the renderer's definition).
pub fn ground_truth(s: &Setup, joints: &JointState, size: usize) -> Vec<[f32; 3]> {
    s.scene.ground_truth(joints, 1.0, size).data
}

/// Area-averaged ground truth: `k x k` point samples per texel, averaged (what a texel holds
/// if it stands for its whole square).
pub fn ground_truth_box(s: &Setup, joints: &JointState, size: usize, k: usize) -> Vec<[f32; 3]> {
    s.scene.ground_truth(joints, 1.0, size * k).box_average(k).data
}

pub fn err(t: &Texture, gt: &[[f32; 3]]) -> TextureError {
    compare(&t.data, gt).unwrap()
}
