//! Ground truth for registration tests: the default rig, true poses with positioning error,
//! marker corners projected through the true pose with pixel noise. No detector involved.
#![allow(dead_code)]

use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::pose::ScenePose;
use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use btfrig_imaging::Region;
use btfrig_registration::Correspondence;
use btfrig_render::plate::{MarkerPlacement, PlateLayout};
use btfrig_sim::options::{SimAxisOptions, SimRobotOptions};
use nalgebra::{Point2, Point3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Texture size of the acceptance.
pub const SIZE: usize = 256;

pub struct Rig {
    pub gonio: Gonio,
    pub camera: CameraModel,
    pub markers: Vec<MarkerPlacement>,
    pub region: Region,
    /// Robot joint offset and jitter (deg), rail offset and jitter (deg), from the rig file's
    /// sim devices (sim defaults where the file is silent).
    pub robot_offset: [f64; 3],
    pub robot_jitter: [f64; 3],
    pub rail_offset: f64,
    pub rail_jitter: f64,
}

fn arr3(t: &toml::Table, key: &str, default: [f64; 3]) -> [f64; 3] {
    match t.get(key).and_then(|v| v.as_array()) {
        Some(a) => [0, 1, 2].map(|k| a[k].as_float().expect("float")),
        None => default,
    }
}

fn num(t: &toml::Table, key: &str, default: f64) -> f64 {
    t.get(key).and_then(|v| v.as_float()).unwrap_or(default)
}

pub fn rig() -> Rig {
    let text = include_str!("../../../../rig-configs/bonn-gonio-sim.toml");
    let cfg = RigConfig::from_toml(text, "bonn-gonio-sim.toml").expect("default rig parses");
    let robot = SimRobotOptions::default();
    let rail = SimAxisOptions::rail();
    let ro = &cfg.devices.robot.options;
    let ra = &cfg.devices.rail.options;
    let plate = PlateLayout::new(&cfg.plate).expect("plate");
    Rig {
        gonio: Gonio::new(cfg.geometry.clone()).expect("geometry"),
        camera: cfg.camera.to_model().expect("camera"),
        markers: plate.markers(),
        region: Region::centred_square(plate.sample_side_m),
        robot_offset: arr3(ro, "offset_deg", robot.offset_deg),
        robot_jitter: arr3(ro, "jitter_deg", robot.jitter_deg),
        rail_offset: num(ra, "offset_deg", rail.offset_deg),
        rail_jitter: num(ra, "jitter_deg", rail.jitter_deg),
    }
}

/// A reachable (light, view) pair for `view`: the first Bonn light (from `start`, cyclic)
/// the kinematics can reach together with it.
pub fn joints_for(rig: &Rig, view: Direction, start: usize) -> JointState {
    let lights = Sampling::bonn81();
    let n = lights.len();
    (0..n)
        .find_map(|k| rig.gonio.ik(lights.directions()[(start + k) % n], view).ok())
        .expect("some Bonn light is reachable with this view")
}

/// True joints: commanded plus `scale` times (offset + jitter N(0, 1)), per axis.
pub fn true_joints(rig: &Rig, commanded: &JointState, scale: f64, rng: &mut ChaCha8Rng) -> JointState {
    let mut j = *commanded;
    for k in 0..3 {
        let n: f64 = rng.sample(StandardNormal);
        j.robot[k] += (scale * (rig.robot_offset[k] + rig.robot_jitter[k] * n)).to_radians();
    }
    let n: f64 = rng.sample(StandardNormal);
    j.rail += (scale * (rig.rail_offset + rig.rail_jitter * n)).to_radians();
    j
}

/// Observed corners of every marker fully inside the image under `truth`, with Gaussian
/// pixel noise `sigma` per axis (the stated sigma is the same).
pub fn observe(rig: &Rig, truth: &ScenePose, sigma: f64, rng: &mut ChaCha8Rng) -> Vec<Correspondence> {
    let t = truth.camera_to_world.inverse() * truth.sample_to_world;
    let mut out = Vec::new();
    for m in &rig.markers {
        let px: Vec<Option<Point2<f64>>> = m
            .corners_sample_m
            .iter()
            .map(|c| rig.camera.project(&(t * Point3::new(c.x, c.y, 0.0))).filter(|p| rig.camera.in_image(*p)))
            .collect();
        if px.iter().any(|p| p.is_none()) {
            continue; // a detector rejects partly hidden markers
        }
        for (c, p) in m.corners_sample_m.iter().zip(px) {
            let p = p.expect("checked");
            let nx: f64 = rng.sample(StandardNormal);
            let ny: f64 = rng.sample(StandardNormal);
            out.push(Correspondence {
                plane: *c,
                pixel: Point2::new(p.x + sigma * nx, p.y + sigma * ny),
                sigma_px: sigma,
                marker: m.id,
            });
        }
    }
    out
}

/// All 81 Bonn view directions.
pub fn bonn_views() -> Vec<Direction> {
    Sampling::bonn81().directions().to_vec()
}
