//! Ground truth for registration on RENDERED frames (detector included): the default rig and a
//! material, true joints drawn like the sim draws them (offset + jitter · N(0, 1), seeded; the
//! helper in `tests/common`), a frame captured at the true joints through the renderer and the
//! sensor model, bilinear demosaic, green channel, `PlateRegistrar::register_image` with the
//! nominal (commanded) pose; the texel position error of the registered and of the nominal pose
//! against the true one.
#![allow(dead_code)]

use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::JointState;
use btfrig_core::pose::ScenePose;
use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::Region;
use btfrig_markers::GrayImage;
use btfrig_registration::frame::{FrameError, FrameRegistration, PlateRegistrar};
use btfrig_registration::{texel_position_error, RegisterOptions};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use nalgebra::{Point2, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::common::{self, Rig, SIZE};

/// Fraction of the sensor's full scale a white Lambertian reflector facing the lamp reaches
/// under the default exposure (as the other rendered-frame tests in the workspace).
pub const WHITE_FRACTION: f64 = 0.5;

/// One rig with one material on its holder.
pub struct Bench {
    pub cfg: RigConfig,
    pub rig: Rig,
    pub scene: RigScene,
    pub registrar: PlateRegistrar,
    pub material: String,
    pub opts: RenderOptions,
}

/// A captured frame's green channel.
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub grey: Vec<f32>,
    /// Seconds to render and capture the frame.
    pub render_s: f64,
}

/// Commanded and true joints and the poses of one view.
#[derive(Clone)]
pub struct Shot {
    pub view: Direction,
    pub light: Direction,
    pub commanded: JointState,
    pub truth: JointState,
    pub nominal_pose: ScenePose,
    pub true_pose: ScenePose,
}

/// A registered frame measured against the truth.
#[derive(Clone)]
pub struct Measured {
    pub reg: FrameRegistration,
    /// Texel position error of the registered pose (mean, max) in texels.
    pub est: (f64, f64),
    /// The same for the nominal pose.
    pub nom: (f64, f64),
    /// Predicted texel sigma from the registration's covariance.
    pub predicted: f64,
}

/// The outcome of one view.
pub struct Outcome {
    pub shot: Shot,
    pub result: Result<Measured, FrameError>,
    pub render_s: f64,
    /// Per-marker corner errors ([`corner_errors`]) when asked for.
    pub corners: Vec<(u32, f64, f64, f64)>,
}

impl Bench {
    /// The default rig with `material` (a builtin name) on its holder.
    pub fn new(material: &str) -> Bench {
        let text = include_str!("../../../../rig-configs/bonn-gonio-sim.toml");
        let cfg = RigConfig::from_toml(text, "bonn-gonio-sim.toml").expect("default rig parses");
        let scene = RigScene::new(&cfg, &MaterialSpec::builtin(material).expect("builtin material")).expect("scene");
        let registrar = PlateRegistrar::new(scene.camera().model().clone(), &cfg.plate, RegisterOptions::default())
            .expect("registrar");
        Bench {
            rig: common::rig(),
            cfg,
            scene,
            registrar,
            material: material.to_string(),
            opts: RenderOptions::default(),
        }
    }

    /// The camera model of the rig.
    pub fn camera(&self) -> &CameraModel {
        self.scene.camera().model()
    }

    /// The sample region rectified (the whole sample).
    pub fn region(&self) -> Region {
        self.rig.region
    }

    /// The default exposure (white at [`WHITE_FRACTION`] of full scale, gain 1).
    pub fn default_exposure(&self) -> f64 {
        self.scene.exposure_for_white(WHITE_FRACTION, 1e-4, 30.0)
    }

    /// A light for `view`: the reachable Bonn light nearest the pole that is at least 25 degrees
    /// from the view's mirror direction (so a glossy sample does not saturate into a large
    /// highlight, and the plate is well lit).
    pub fn light_for(&self, view: Direction) -> Direction {
        let mirror = Direction::new(view.theta, view.phi + std::f64::consts::PI);
        let mut lights = Sampling::bonn81().directions().to_vec();
        lights.sort_by(|a, b| a.theta.total_cmp(&b.theta).then(a.phi.total_cmp(&b.phi)));
        lights
            .into_iter()
            .filter(|l| l.angle_to(mirror) > 25f64.to_radians())
            .find(|l| self.rig.gonio.ik(*l, view).is_ok())
            .expect("some Bonn light is reachable with this view")
    }

    /// Commanded joints for (light, view) and true joints off by `error_scale` times the rig's
    /// positioning error (offset + jitter · N(0, 1), seeded by `seed`).
    pub fn shot(&self, view: Direction, error_scale: f64, seed: u64) -> Shot {
        let light = self.light_for(view);
        let commanded = self.rig.gonio.ik(light, view).expect("reachable");
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = common::true_joints(&self.rig, &commanded, error_scale, &mut rng);
        Shot {
            view,
            light,
            nominal_pose: self.scene.pose(&commanded),
            true_pose: self.scene.pose(&truth),
            commanded,
            truth,
        }
    }

    /// Captures the frame the camera takes at the shot's true joints (sensor noise from
    /// `seed`) and returns its green channel.
    pub fn capture(&self, shot: &Shot, exposure_s: f64, gain: f64, seed: u64) -> Frame {
        let t = std::time::Instant::now();
        let (raw, _) = self.scene.capture(&shot.truth, 1.0, exposure_s, gain, seed, &self.opts).expect("capture");
        let grey: Vec<f32> = demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect();
        Frame { width: raw.width, height: raw.height, grey, render_s: t.elapsed().as_secs_f64() }
    }

    /// Renders the shot once and captures it at each (exposure, gain) with noise from `seed`:
    /// the green channels, in order.
    pub fn capture_levels(&self, shot: &Shot, levels: &[(f64, f64)], seed: u64) -> Vec<Frame> {
        let t = std::time::Instant::now();
        let (radiance, _) = self.scene.radiance(&shot.truth, 1.0, &self.opts);
        let render_s = t.elapsed().as_secs_f64();
        levels
            .iter()
            .map(|&(exposure_s, gain)| {
                let raw = self.scene.sensor().capture(&radiance, exposure_s, gain, seed).expect("capture");
                let grey: Vec<f32> = demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect();
                Frame { width: raw.width, height: raw.height, grey, render_s }
            })
            .collect()
    }

    /// A registrar for the window of the frame starting at column `x0` (a sensor cropped on
    /// the left): the camera model with the width and principal point shifted.
    pub fn cropped_registrar(&self, x0: usize) -> PlateRegistrar {
        let mut cam = self.cfg.camera.clone();
        cam.width_px -= x0;
        cam.cx_px -= x0 as f64;
        PlateRegistrar::new(cam.to_model().expect("cropped camera"), &self.cfg.plate, RegisterOptions::default())
            .expect("registrar")
    }

    /// Registers `frame` with `registrar` (its camera must match the frame) and measures it.
    pub fn measure(&self, registrar: &PlateRegistrar, shot: &Shot, frame: &Frame) -> Result<Measured, FrameError> {
        let img = GrayImage::new(frame.width, frame.height, &frame.grey).expect("image");
        let reg = registrar.register_image(&img, &shot.nominal_pose)?;
        let cam = registrar.camera();
        let est = texel_position_error(&shot.true_pose, &reg.registration.pose, cam, self.region(), SIZE);
        let nom = texel_position_error(&shot.true_pose, &shot.nominal_pose, cam, self.region(), SIZE);
        let predicted = reg.registration.texel_sigma(cam, self.region(), SIZE);
        Ok(Measured { reg, est, nom, predicted })
    }

    /// One view end to end with the default exposure, `edit` applied to the grey frame.
    pub fn run(&self, view: Direction, error_scale: f64, seed: u64, edit: &dyn Fn(&Shot, &mut Frame)) -> Outcome {
        self.run_with(view, error_scale, seed, edit, false)
    }

    /// [`Bench::run`], with the detector's corner errors when `diagnose`.
    pub fn run_with(
        &self,
        view: Direction,
        error_scale: f64,
        seed: u64,
        edit: &dyn Fn(&Shot, &mut Frame),
        diagnose: bool,
    ) -> Outcome {
        let shot = self.shot(view, error_scale, seed);
        let mut frame = self.capture(&shot, self.default_exposure(), 1.0, seed ^ 0x5eed);
        edit(&shot, &mut frame);
        let result = self.measure(&self.registrar, &shot, &frame);
        let corners = if diagnose { corner_errors(self, &self.registrar, &shot, &frame) } else { Vec::new() };
        Outcome { shot, result, render_s: frame.render_s, corners }
    }

    /// Pixel positions of a marker's corners (scaled by `grow` about its centre on the plate)
    /// under the true pose.
    pub fn marker_quad(&self, shot: &Shot, id: u32, grow: f64) -> Vec<Point2<f64>> {
        let t = shot.true_pose.camera_to_world.inverse() * shot.true_pose.sample_to_world;
        let m = self.registrar.markers().iter().find(|m| m.id == id).expect("plate marker");
        let c = m.corners_sample_m.iter().fold(Point2::origin(), |a, p| a + p.coords / 4.0);
        m.corners_sample_m
            .iter()
            .map(|p| {
                let q = c + (p - c) * grow;
                self.camera().project(&(t * Point3::new(q.x, q.y, 0.0))).expect("projects")
            })
            .collect()
    }

    /// Paints markers `ids` over with an occluder of the plate's own grey (the median of the
    /// frame along a ring 1.6 marker sizes wide around each), covering 1.4 marker sizes: to
    /// the detector the marker is simply not there.
    pub fn hide_markers(&self, shot: &Shot, frame: &mut Frame, ids: &[u32]) {
        for &id in ids {
            let inner = self.marker_quad(shot, id, 1.4);
            let ring = self.marker_quad(shot, id, 1.6);
            let mut samples: Vec<f32> = Vec::new();
            for k in 0..4 {
                let (a, b) = (ring[k], ring[(k + 1) % 4]);
                for s in 0..50 {
                    let p = a + (b - a) * (s as f64 / 50.0);
                    let (x, y) = (p.x.round() as isize, p.y.round() as isize);
                    if x >= 0 && y >= 0 && (x as usize) < frame.width && (y as usize) < frame.height {
                        samples.push(frame.grey[y as usize * frame.width + x as usize]);
                    }
                }
            }
            samples.sort_by(f32::total_cmp);
            let level = samples[samples.len() / 2];
            fill_quad(frame, &inner, level);
        }
    }
}

/// The frame's columns from `x0` on.
pub fn crop_left(frame: &Frame, x0: usize) -> Frame {
    let width = frame.width - x0;
    let grey = frame.grey.chunks(frame.width).flat_map(|row| row[x0..].iter().copied()).collect();
    Frame { width, height: frame.height, grey, render_s: frame.render_s }
}

/// Fills the convex quad `q` (pixel coordinates, integer = pixel centre) with `value`.
pub fn fill_quad(frame: &mut Frame, q: &[Point2<f64>], value: f32) {
    let (x0, x1) = q.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.x), b.max(p.x)));
    let (y0, y1) = q.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.y), b.max(p.y)));
    // Inside a convex polygon: the same side of every edge.
    let side = |p: Point2<f64>, k: usize| {
        let (a, b) = (q[k], q[(k + 1) % q.len()]);
        (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
    };
    for y in (y0.floor().max(0.0) as usize)..=(y1.ceil().min(frame.height as f64 - 1.0) as usize) {
        for x in (x0.floor().max(0.0) as usize)..=(x1.ceil().min(frame.width as f64 - 1.0) as usize) {
            let p = Point2::new(x as f64, y as f64);
            let s: Vec<f64> = (0..q.len()).map(|k| side(p, k)).collect();
            if s.iter().all(|v| *v >= 0.0) || s.iter().all(|v| *v <= 0.0) {
                frame.grey[y * frame.width + x] = value;
            }
        }
    }
}

/// Summary of several outcomes that registered.
pub struct Summary {
    pub views: usize,
    pub mean: f64,
    pub max: f64,
    pub worst_mean: f64,
    pub nom_mean: f64,
    pub nom_max: f64,
    pub predicted: f64,
    pub detect_ms: (f64, f64),
    pub register_ms: (f64, f64),
    pub render_s: f64,
}

/// Summarises the registered outcomes (errors are skipped; count them separately) and prints
/// one line under `label`.
pub fn summarise(label: &str, outcomes: &[Outcome]) -> Summary {
    let ok: Vec<(&Outcome, &Measured)> =
        outcomes.iter().filter_map(|o| o.result.as_ref().ok().map(|m| (o, m))).collect();
    if ok.is_empty() {
        println!("{label}: 0/{} views registered", outcomes.len());
    }
    let n = ok.len().max(1) as f64;
    let avg = |f: &dyn Fn(&Measured) -> f64| ok.iter().map(|(_, m)| f(m)).sum::<f64>() / n;
    let top = |f: &dyn Fn(&Measured) -> f64| ok.iter().map(|(_, m)| f(m)).fold(0.0, f64::max);
    let s = Summary {
        views: ok.len(),
        mean: avg(&|m| m.est.0),
        max: top(&|m| m.est.1),
        worst_mean: top(&|m| m.est.0),
        nom_mean: avg(&|m| m.nom.0),
        nom_max: top(&|m| m.nom.1),
        predicted: avg(&|m| m.predicted),
        detect_ms: (avg(&|m| m.reg.detect_s * 1e3), top(&|m| m.reg.detect_s * 1e3)),
        register_ms: (avg(&|m| m.reg.register_s * 1e3), top(&|m| m.reg.register_s * 1e3)),
        render_s: outcomes.iter().map(|o| o.render_s).sum::<f64>() / outcomes.len().max(1) as f64,
    };
    if ok.is_empty() {
        return s;
    }
    println!(
        "{label}: {}/{} views registered; texel error registered mean {:.4} (worst view mean {:.4}) max {:.4}; \
         nominal mean {:.4} max {:.4}; predicted sigma {:.4}; detect {:.1} / {:.1} ms, register {:.2} / {:.2} ms \
         (mean / max); render {:.2} s per frame",
        s.views,
        outcomes.len(),
        s.mean,
        s.worst_mean,
        s.max,
        s.nom_mean,
        s.nom_max,
        s.predicted,
        s.detect_ms.0,
        s.detect_ms.1,
        s.register_ms.0,
        s.register_ms.1,
        s.render_s
    );
    s
}

/// One line per view.
pub fn print_view(label: &str, o: &Outcome) {
    let (t, p) = o.shot.view.to_degrees();
    let (lt, lp) = o.shot.light.to_degrees();
    match &o.result {
        Ok(m) => println!(
            "  {label} view ({t:.0}, {p:.0}) light ({lt:.0}, {lp:.0}): markers {:?} rejected {:?}; registered \
             {:.4} / {:.4}, nominal {:.4} / {:.4} texel, predicted {:.4}, rms {:.3} px; detect {:.1} ms, register \
             {:.2} ms",
            m.reg.detected,
            m.reg.registration.rejected_markers,
            m.est.0,
            m.est.1,
            m.nom.0,
            m.nom.1,
            m.predicted,
            m.reg.registration.rms_px,
            m.reg.detect_s * 1e3,
            m.reg.register_s * 1e3
        ),
        Err(e) => println!("  {label} view ({t:.0}, {p:.0}) light ({lt:.0}, {lp:.0}): refused: {e}"),
    }
    if !o.corners.is_empty() {
        let line: Vec<String> =
            o.corners.iter().map(|(id, mean, max, sigma)| format!("{id}: {mean:.2}/{max:.2} ({sigma:.2})")).collect();
        println!("    corner error mean/max px (stated sigma): {}", line.join(", "));
    }
}

/// Per detected plate marker: id, mean and max corner error (px) against the corners projected
/// with the true pose, and the detector's mean stated sigma. For diagnosis of bad views.
pub fn corner_errors(
    bench: &Bench,
    registrar: &PlateRegistrar,
    shot: &Shot,
    frame: &Frame,
) -> Vec<(u32, f64, f64, f64)> {
    let img = GrayImage::new(frame.width, frame.height, &frame.grey).expect("image");
    let dict = btfrig_markers::Dictionary::by_name(&bench.cfg.plate.marker_dictionary).expect("dictionary");
    let found = btfrig_markers::detect(&img, &dict, &registrar.detect).expect("detect");
    let t = shot.true_pose.camera_to_world.inverse() * shot.true_pose.sample_to_world;
    let mut out = Vec::new();
    for d in &found {
        let Some(m) = registrar.markers().iter().find(|m| m.id == d.id) else { continue };
        let errs: Vec<f64> = (0..4)
            .map(|k| {
                let c = m.corners_sample_m[k];
                let p = registrar.camera().project(&(t * Point3::new(c.x, c.y, 0.0))).expect("projects");
                (d.corners[k] - p).norm()
            })
            .collect();
        let sigma = d.corner_sigma_px.iter().sum::<f64>() / 4.0;
        out.push((d.id, errs.iter().sum::<f64>() / 4.0, errs.iter().cloned().fold(0.0, f64::max), sigma));
    }
    out
}
