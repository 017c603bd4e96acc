//! The detector on frames of the simulated rig (renderer + sensor noise + bilinear demosaic)
//! against the true corners: the plate's marker corners projected with the true pose and the
//! camera model including its lens distortion.

use std::time::Instant;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::JointState;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_markers::{detect, DetectParams, Detection, Dictionary, GrayImage};
use btfrig_render::demosaic::demosaic_bilinear;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use nalgebra::{Point2, Point3};

struct Setup {
    scene: RigScene,
    opts: RenderOptions,
}

impl Setup {
    fn new(material: &str) -> Setup {
        let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
        let ss = std::env::var("MARKERS_SS").ok().and_then(|v| v.parse().ok()).unwrap_or(16);
        let opts = RenderOptions { marker_supersampling: ss, ..RenderOptions::default() };
        Setup { scene: RigScene::new(&cfg, &MaterialSpec::builtin(material).unwrap()).unwrap(), opts }
    }

    fn joints(&self, light: (f64, f64), view: (f64, f64)) -> JointState {
        self.scene
            .gonio()
            .ik(Direction::from_degrees(light.0, light.1), Direction::from_degrees(view.0, view.1))
            .unwrap()
    }

    fn cam(&self) -> &CameraModel {
        self.scene.camera().model()
    }

    /// A captured frame (seeded sensor noise), demosaiced, as grey = R + G + B.
    fn shoot(&self, joints: &JointState, seed: u64) -> Vec<f32> {
        let exposure = self.scene.exposure_for_white(0.5, 1e-4, 30.0);
        let (raw, _) = self.scene.capture(joints, 1.0, exposure, 1.0, seed, &self.opts).unwrap();
        demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect()
    }

    /// The noise-free radiance image (no sensor, no demosaic), grey = R + G + B.
    fn clean(&self, joints: &JointState) -> Vec<f32> {
        let (img, _) = self.scene.radiance(joints, 1.0, &self.opts);
        img.data.iter().map(|p| p[0] + p[1] + p[2]).collect()
    }

    /// True corners (OpenCV order) of every marker, projected with distortion.
    fn truth(&self, joints: &JointState) -> Vec<(u32, [Point2<f64>; 4])> {
        let pose = self.scene.pose(joints);
        let cam_from_sample = pose.camera_to_world.inverse() * pose.sample_to_world;
        self.scene
            .renderer()
            .scene()
            .layout
            .markers()
            .iter()
            .map(|m| {
                let c = m.corners_sample_m.map(|c| {
                    let p = cam_from_sample * Point3::new(c.x, c.y, 0.0);
                    self.cam().project(&p).unwrap()
                });
                (m.id, c)
            })
            .collect()
    }
}

struct Errors {
    mean: f64,
    max: f64,
    mean_sigma: f64,
    /// Errors over predicted sigmas (per axis, so ~ sqrt(2) if calibrated).
    mean_ratio: f64,
}

/// Matches detections with the truth: every visible marker found with its id, nothing else.
fn compare(label: &str, dets: &[Detection], truth: &[(u32, [Point2<f64>; 4])], cam: &CameraModel) -> Errors {
    let inside = |c: &[Point2<f64>; 4]| {
        c.iter().all(|p| p.x > 3.0 && p.y > 3.0 && p.x < cam.width as f64 - 4.0 && p.y < cam.height as f64 - 4.0)
    };
    let visible: Vec<_> = truth.iter().filter(|(_, c)| inside(c)).collect();
    for (id, _) in &visible {
        assert!(dets.iter().any(|d| d.id == *id), "{label}: marker {id} not found; found {:?}", ids(dets));
    }
    for d in dets {
        assert!(visible.iter().any(|(id, _)| *id == d.id), "{label}: false or partly visible detection {}", d.id);
    }
    let (mut sum, mut max, mut n, mut ssum, mut rsum) = (0.0, 0.0f64, 0.0, 0.0, 0.0);
    for d in dets {
        let (_, tc) = visible.iter().find(|(id, _)| *id == d.id).unwrap();
        for k in 0..4 {
            let e = (d.corners[k] - tc[k]).norm();
            if std::env::var("MARKERS_DEBUG").is_ok() {
                let ctr = (tc[0].coords + tc[1].coords + tc[2].coords + tc[3].coords) / 4.0;
                let out = (tc[k].coords - ctr).normalize();
                let dv = d.corners[k] - tc[k];
                eprintln!("{label} id {} k {k}: d ({:.3},{:.3}) radial {:.3}", d.id, dv.x, dv.y, dv.dot(&out));
            }
            sum += e;
            max = max.max(e);
            n += 1.0;
            ssum += d.corner_sigma_px[k];
            rsum += e / d.corner_sigma_px[k];
            assert!(d.corner_sigma_px[k].is_finite() && d.corner_sigma_px[k] > 0.0);
        }
    }
    Errors { mean: sum / n, max, mean_sigma: ssum / n, mean_ratio: rsum / n }
}

fn ids(d: &[Detection]) -> Vec<u32> {
    d.iter().map(|d| d.id).collect()
}

const LIGHT: (f64, f64) = (45.0, 0.0);

#[test]
fn rendered_views_frontal_45_75_all_markers_at_the_true_corners() {
    let s = Setup::new("lacquered-wood");
    let dict = Dictionary::dict_4x4_50();
    let cam = s.cam().clone();
    let with_cam = DetectParams { camera: Some(cam.clone()), ..DetectParams::default() };
    let plain = DetectParams::default();
    // (view, bound on mean error, bound on max error), with the camera model.
    for (view, seed, mean_bound, max_bound) in [
        ((0.0, 0.0), 21, 0.1, 0.3),
        ((45.0, 90.0), 22, 0.1, 0.3),
        ((45.0, 200.0), 23, 0.1, 0.3),
        ((75.0, 90.0), 24, 0.2, 0.6),
        ((75.0, 330.0), 25, 0.2, 0.6),
    ] {
        let joints = s.joints(LIGHT, view);
        let img = if std::env::var("MARKERS_CLEAN").is_ok() { s.clean(&joints) } else { s.shoot(&joints, seed) };
        let g = GrayImage::new(cam.width, cam.height, &img).unwrap();
        let truth = s.truth(&joints);
        let t0 = Instant::now();
        let dets = detect(&g, &dict, &with_cam).unwrap();
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let e = compare(&format!("{view:?}"), &dets, &truth, &cam);
        let p = compare(&format!("{view:?} no camera"), &detect(&g, &dict, &plain).unwrap(), &truth, &cam);
        println!(
            "view {view:?}: {} markers, corner error mean {:.4} max {:.4} px (without camera model: mean {:.4} max \
             {:.4}); mean sigma {:.4} px, mean error/sigma {:.2}; {ms:.1} ms",
            dets.len(),
            e.mean,
            e.max,
            p.mean,
            p.max,
            e.mean_sigma,
            e.mean_ratio
        );
        assert!(e.mean < mean_bound && e.max < max_bound, "view {view:?}: mean {} max {}", e.mean, e.max);
    }
}
