//! Synthetic views of a planar target through a known camera (shared by the tests and the
//! `calibrate_sim` example).
#![allow(dead_code)]

use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_intrinsics::{Correspondence, View};
use nalgebra::{Point2, Point3, Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

pub fn rig() -> RigConfig {
    RigConfig::from_toml(
        include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../rig-configs/bonn-gonio-sim.toml")),
        "bonn-gonio-sim.toml",
    )
    .unwrap()
}

pub fn truth() -> CameraModel {
    rig().camera.to_model().unwrap()
}

/// The default rig's sensor behind a moderately wide lens (fx = 1600 px, 53 degrees across)
/// with a decentred principal point and a stronger distortion.
pub fn wide() -> CameraModel {
    let d = btfrig_core::camera::Distortion { k1: -0.12, k2: 0.05, k3: -0.01, p1: 4e-4, p2: -3e-4 };
    CameraModel::new(1600, 1200, 1600.0, 1598.0, 812.4, 590.7, d, btfrig_core::camera::Vignetting::default()).unwrap()
}

/// Target points: a 12 x 12 grid, 16 mm pitch (the corners of 6 x 6 markers of 16 mm with
/// 16 mm gaps on a 0.2 m plate look much the same to the calibration).
pub fn target() -> Vec<Point2<f64>> {
    (0..12)
        .flat_map(|i| (0..12).map(move |j| Point2::new((i as f64 - 5.5) * 0.016, (j as f64 - 5.5) * 0.016)))
        .collect()
}

pub struct Scene {
    pub views: Vec<View>,
    /// Index of the points displaced as gross outliers, per view.
    pub outliers: Vec<Vec<bool>>,
}

/// `n` views tilted `tilt_deg.0..tilt_deg.1` about random in-plane axes, at 1.1-1.3 m, with the
/// target centre anywhere in the middle 70% of the image; only points inside the image are kept.
pub fn scene(cam: &CameraModel, seed: u64, n: usize, tilt_deg: (f64, f64), sigma: f64, outlier_frac: f64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma).unwrap();
    let pts = target();
    let mut views = Vec::new();
    let mut outliers = Vec::new();
    while views.len() < n {
        let tilt = rng.gen_range(tilt_deg.0..=tilt_deg.1).to_radians();
        let az: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let spin: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let axis = Unit::new_normalize(Vector3::new(az.cos(), az.sin(), 0.0));
        let r = Rotation3::from_axis_angle(&axis, tilt) * Rotation3::from_axis_angle(&Vector3::z_axis(), spin);
        // Same image coverage whatever the lens: 1.1-1.3 m behind a 4800 px focal length.
        let z = rng.gen_range(1.1..1.3) * cam.fx / 4800.0;
        let u0 = rng.gen_range(0.15..0.85) * cam.width as f64;
        let v0 = rng.gen_range(0.15..0.85) * cam.height as f64;
        let t = Vector3::new((u0 - cam.cx) / cam.fx * z, (v0 - cam.cy) / cam.fy * z, z);
        let mut v = View::default();
        let mut out = Vec::new();
        for p in &pts {
            let pc = r * Point3::new(p.x, p.y, 0.0) + t;
            let Some(px) = cam.project(&pc) else { continue };
            if !cam.in_image(px) {
                continue;
            }
            let mut obs = px + nalgebra::Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
            let gross = rng.gen_bool(outlier_frac);
            if gross {
                let mag = rng.gen_range(3.0..30.0);
                let dir: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                obs += nalgebra::Vector2::new(dir.cos(), dir.sin()) * mag;
            }
            v.points.push(Correspondence { target: *p, pixel: obs, sigma_px: None });
            out.push(gross);
        }
        if v.points.len() >= 30 {
            views.push(v);
            outliers.push(out);
        }
    }
    Scene { views, outliers }
}
