//! A whole simulated rig's physics assembled from a rig config: kinematics, lens, colour,
//! scene, sensor. This is what the simulated camera calls for every frame and what the
//! tools call for ground truth.
//!
//! Units: frames are in the sensor's digital numbers. Ground truth is the *radiance factor*
//! in linear sRGB (D65): reflected radiance times `pi` over the irradiance the lamp gives a
//! surface facing it at the nominal sample centre. A white Lambertian reflector lit along
//! its normal from the nominal lamp distance is `(1, 1, 1)`; the lamp's true intensity
//! factor (warm-up, drift) multiplies it, because it multiplies the true radiance.

use std::sync::OnceLock;

use btfrig_core::camera::{CameraError, CameraModel};
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::pose::ScenePose;
use btfrig_core::ConfigError;
use nalgebra::{Point2, Point3, Vector3};
use rayon::prelude::*;

use crate::chart::ColorChart;
use crate::colour::ColourSystem;
use crate::ground_truth::GroundTruth;
use crate::material::{MaterialError, MaterialSpec};
use crate::radiance::RadianceImage;
use crate::renderer::{subpixel_rays, PixelRays, RenderOptions, RenderStats, Renderer};
use crate::scene::{Scene, SceneError};
use crate::sensor::{electrons_per_second_scale, SensorError, SensorModel};
use crate::spectral::{self, Spectrum};
use btfrig_core::config::target::TargetBoard;
use btfrig_imaging::demosaic::{demosaic_bilinear, preview_srgb8};

/// Why a rig scene could not be built.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RigSceneError {
    /// A section of the rig config is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The `[camera]` section does not describe a usable lens.
    #[error("[camera]: {0}")]
    Camera(#[from] CameraError),
    /// The `[sensor]` section is invalid.
    #[error("[sensor]: {0}")]
    Sensor(#[from] SensorError),
    /// The lamp spectrum or camera sensitivity is unknown.
    #[error("[lamp]/[sensor]: {0}")]
    Spectral(#[from] spectral::SpectralError),
    /// The material file is invalid.
    #[error(transparent)]
    Material(#[from] MaterialError),
    /// The plate or a material colour is invalid.
    #[error(transparent)]
    Scene(#[from] SceneError),
}

/// One pixel's subsample rays, computed on first use.
type SubsampleRays = OnceLock<Vec<Vector3<f64>>>;

/// A camera model with its pixel rays and vignetting cached for integer pixel centres:
/// undistortion is an iteration per pixel, too slow to repeat for every frame.
#[derive(Debug, Clone)]
pub struct CachedCamera {
    model: CameraModel,
    rays: Vec<[f64; 3]>,
    vignetting: Vec<f32>,
    interpolate: bool,
    /// Per pixel, its subsample rays once computed, for one supersampling factor
    /// ([`CachedCamera::caching_subsamples`]).
    subsamples: Option<(usize, Vec<SubsampleRays>)>,
}

impl CachedCamera {
    /// Precomputes the ray and vignetting of every pixel centre.
    pub fn new(model: CameraModel) -> Self {
        let (w, h) = (model.width, model.height);
        let mut rays = vec![[0.0; 3]; w * h];
        let mut vignetting = vec![0.0f32; w * h];
        rays.par_chunks_mut(w).zip(vignetting.par_chunks_mut(w)).enumerate().for_each(|(y, (r, v))| {
            for x in 0..w {
                let px = Point2::new(x as f64, y as f64);
                let d = model.pixel_ray(px);
                r[x] = [d.x, d.y, d.z];
                v[x] = model.vignetting(px) as f32;
            }
        });
        CachedCamera { model, rays, vignetting, interpolate: false, subsamples: None }
    }

    /// Rays between pixel centres (the renderer's marker-edge supersamples) interpolated
    /// bilinearly from the cached ones instead of undistorted exactly: the ray field is so
    /// smooth that the difference is about 1e-5 px for the default lens, and it saves one
    /// Newton undistortion per subsample (most of a board frame's render time).
    pub fn interpolating(mut self, on: bool) -> Self {
        self.interpolate = on;
        self
    }

    /// Keeps each pixel's `ss x ss` subsample rays once computed (the renderer's marker-edge
    /// supersampling at `marker_supersampling = ss`), for a camera that renders many frames
    /// of one view: a dome renders every LED's image from the same camera, and without the
    /// cache each frame undistorts every marker-edge pixel's subsamples again (more than a
    /// third of a dome run's time). Exactly the uncached rays; at most `ss² · w · h` rays
    /// (30 MB for the domes' 320 x 240 at ss = 4).
    pub fn caching_subsamples(mut self, ss: usize) -> Self {
        let n = self.model.width * self.model.height;
        self.subsamples = (ss > 1).then(|| (ss, (0..n).map(|_| OnceLock::new()).collect()));
        self
    }

    /// The lens model.
    pub fn model(&self) -> &CameraModel {
        &self.model
    }

    fn index(&self, x: f64, y: f64) -> Option<usize> {
        let (xi, yi) = (x as usize, y as usize);
        (x >= 0.0 && y >= 0.0 && x == xi as f64 && y == yi as f64 && xi < self.model.width && yi < self.model.height)
            .then(|| yi * self.model.width + xi)
    }
}

impl PixelRays for CachedCamera {
    fn width(&self) -> usize {
        self.model.width
    }
    fn height(&self) -> usize {
        self.model.height
    }
    fn ray(&self, x: f64, y: f64) -> Vector3<f64> {
        if let Some(i) = self.index(x, y) {
            return Vector3::from(self.rays[i]);
        }
        let (w, h) = (self.model.width, self.model.height);
        if self.interpolate && x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64 && w > 1 && h > 1 {
            let (x0, y0) = ((x.floor() as usize).min(w - 2), (y.floor() as usize).min(h - 2));
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let r = |i: usize, j: usize| Vector3::from(self.rays[j * w + i]);
            let v = r(x0, y0) * ((1.0 - fx) * (1.0 - fy))
                + r(x0 + 1, y0) * (fx * (1.0 - fy))
                + r(x0, y0 + 1) * ((1.0 - fx) * fy)
                + r(x0 + 1, y0 + 1) * (fx * fy);
            return v.normalize();
        }
        self.model.pixel_ray(Point2::new(x, y))
    }
    fn vignetting(&self, x: f64, y: f64) -> f64 {
        match self.index(x, y) {
            Some(i) => f64::from(self.vignetting[i]),
            None => self.model.vignetting(Point2::new(x, y)),
        }
    }
    fn project(&self, p: &Vector3<f64>) -> Option<[f64; 2]> {
        self.model.project(&Point3::from(*p)).map(|q| [q.x, q.y])
    }
    fn subpixel_rays(&self, x: usize, y: usize, ss: usize, out: &mut Vec<Vector3<f64>>) {
        match &self.subsamples {
            Some((n, cells)) if *n == ss && x < self.model.width && y < self.model.height => {
                let cached = cells[y * self.model.width + x].get_or_init(|| {
                    let mut v = Vec::with_capacity(ss * ss);
                    subpixel_rays(self, x, y, ss, &mut v);
                    v
                });
                out.extend_from_slice(cached);
            }
            _ => subpixel_rays(self, x, y, ss, out),
        }
    }
}

/// Resolves a material's spectrum name to `(camera RGB, output RGB)` in `colour`:
/// `flat:R` (a grey of reflectance R in [0, 1]) or `colorchecker:NAME` (a ColorChecker
/// Classic patch, e.g. `colorchecker:dark skin`, from its measured spectrum).
pub fn resolve_spectrum(colour: &ColourSystem, name: &str) -> Result<([f64; 3], [f64; 3]), String> {
    let spectrum = if let Some(v) = name.strip_prefix("flat:") {
        let r: f64 = v.trim().parse().map_err(|_| format!("{name:?}: expected flat:R with R a number in [0, 1]"))?;
        if !(0.0..=1.0).contains(&r) {
            return Err(format!("{name:?}: reflectance {r} out of range, allowed [0, 1]"));
        }
        Spectrum::constant(r)
    } else if let Some(patch) = name.strip_prefix("colorchecker:") {
        let refs = spectral::colorchecker24_reference();
        let i = refs.iter().position(|p| p.name.eq_ignore_ascii_case(patch.trim())).ok_or_else(|| {
            let names: Vec<&str> = refs.iter().map(|p| p.name.as_str()).collect();
            format!("{name:?}: unknown ColorChecker patch, allowed: {}", names.join(", "))
        })?;
        spectral::colorchecker24()[i]
    } else {
        return Err(format!("{name:?}: unknown spectrum, allowed flat:R or colorchecker:NAME"));
    };
    Ok((colour.camera_rgb(&spectrum), colour.output_rgb(&spectrum)))
}

/// The physics of one simulated gonioreflectometer with one material on its holder.
pub struct RigScene {
    gonio: Gonio,
    camera: CachedCamera,
    sensor: SensorModel,
    colour: ColourSystem,
    renderer: Renderer,
    /// Irradiance the lamp gives a surface facing it at the nominal sample centre, in the
    /// renderer's units (`lamp_scale / d^2`).
    nominal_irradiance: f64,
    preview_matrix: [[f64; 3]; 3],
}

impl RigScene {
    /// Builds everything from the rig config and a material. Every section is validated.
    pub fn new(cfg: &RigConfig, material: &MaterialSpec) -> Result<RigScene, RigSceneError> {
        Self::build(cfg, |lamp_scale, resolve| Renderer::new(&cfg.plate, material, lamp_scale, resolve))
    }

    /// The rig with a calibration board ([`TargetBoard`]) on the holder in place of the
    /// plate and sample: same kinematics, true lens, sensor and lamp. For geometric camera
    /// calibration captures.
    pub fn with_target(cfg: &RigConfig, board: &TargetBoard) -> Result<RigScene, RigSceneError> {
        Self::build(cfg, |lamp_scale, resolve| {
            Ok(Renderer::from_scene(Scene::build_target(board, resolve)?, lamp_scale))
        })
    }

    /// The rig with a colour chart ([`ColorChart`]) in the sample region of its holder plate
    /// (markers as usual): same kinematics, true lens, sensor and lamp. For colour
    /// calibration captures; the ground truth is the patches' output colours.
    pub fn with_chart(cfg: &RigConfig, chart: &ColorChart) -> Result<RigScene, RigSceneError> {
        let colour = ColourSystem::from_config(&cfg.lamp, &cfg.sensor)?;
        let colours: Vec<([f64; 3], [f64; 3])> =
            chart.patches.iter().map(|p| (colour.camera_rgb(&p.spectrum), colour.output_rgb(&p.spectrum))).collect();
        let black = Spectrum::constant(crate::chart::GAP_REFLECTANCE);
        let gap = (colour.camera_rgb(&black), colour.output_rgb(&black));
        Self::build(cfg, |lamp_scale, resolve| {
            Ok(Renderer::from_scene(crate::chart::chart_scene(&cfg.plate, chart, &colours, gap, resolve)?, lamp_scale))
        })
    }

    fn build(
        cfg: &RigConfig,
        make: impl FnOnce(f64, &crate::scene::Resolver) -> Result<Renderer, SceneError>,
    ) -> Result<RigScene, RigSceneError> {
        cfg.validate()?;
        // The scene is posed by the gonioreflectometer's kinematics; a dome has DomeScene.
        cfg.require_gonio("a gonioreflectometer scene (RigScene; a dome uses DomeScene)")?;
        let gonio = Gonio::new(cfg.geometry.clone())?;
        // Marker-edge subsample rays interpolated from the cached pixel rays: about 1e-5 px
        // from the exact ones, and it saves a Newton undistortion per subsample (measured
        // 18-22 % of a 1600 x 1200 gonio run's time).
        let camera = CachedCamera::new(cfg.camera.to_model()?).interpolating(true);
        let sensor = SensorModel::from_config(&cfg.sensor)?;
        let colour = ColourSystem::from_config(&cfg.lamp, &cfg.sensor)?;
        // The renderer's radiance is `lamp_scale * pi * f * cos / r^2`, and the sensor's rate
        // is `K * f * cos / r^2` (see `electrons_per_second_scale`), so lamp_scale = K / pi.
        let k = electrons_per_second_scale(&cfg.camera, &cfg.sensor, &cfg.lamp, &colour);
        let lamp_scale = k / std::f64::consts::PI;
        let resolve = |name: &str| resolve_spectrum(&colour, name);
        let renderer = make(lamp_scale, &resolve)?;
        let d = cfg.geometry.lamp_distance_m;
        let preview_matrix = colour.colorchecker_matrix().matrix;
        Ok(RigScene {
            gonio,
            camera,
            sensor,
            colour,
            renderer,
            nominal_irradiance: lamp_scale / (d * d),
            preview_matrix,
        })
    }

    /// The kinematics of the rig.
    pub fn gonio(&self) -> &Gonio {
        &self.gonio
    }
    /// The cached camera.
    pub fn camera(&self) -> &CachedCamera {
        &self.camera
    }
    /// The sensor model.
    pub fn sensor(&self) -> &SensorModel {
        &self.sensor
    }
    /// The colour system of lamp and camera.
    pub fn colour(&self) -> &ColourSystem {
        &self.colour
    }
    /// The renderer.
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// The world poses of sample, camera and lamp for true joint values.
    pub fn pose(&self, joints: &JointState) -> ScenePose {
        self.gonio.scene_pose(joints)
    }

    /// The camera-RGB signal rate (e-/s per photosite) for true joints and lamp intensity.
    pub fn radiance(
        &self,
        joints: &JointState,
        lamp_intensity: f64,
        opts: &RenderOptions,
    ) -> (RadianceImage, RenderStats) {
        let (mut img, stats) = self.renderer.render_with_stats(&self.pose(joints), &self.camera, opts);
        if lamp_intensity != 1.0 {
            let k = lamp_intensity as f32;
            img.data.par_iter_mut().for_each(|p| *p = p.map(|c| c * k));
        }
        (img, stats)
    }

    /// A raw frame: the radiance through the sensor with noise from `seed`.
    pub fn capture(
        &self,
        joints: &JointState,
        lamp_intensity: f64,
        exposure_s: f64,
        gain: f64,
        seed: u64,
        opts: &RenderOptions,
    ) -> Result<(RawFrame, RenderStats), SensorError> {
        let (img, stats) = self.radiance(joints, lamp_intensity, opts);
        Ok((self.sensor.capture(&img, exposure_s, gain, seed)?, stats))
    }

    /// The ground-truth texture (`size x size` texels over the sample) for true joints and
    /// lamp intensity, as a radiance factor (see the module documentation).
    pub fn ground_truth(&self, joints: &JointState, lamp_intensity: f64, size: usize) -> GroundTruth {
        let mut gt = self.renderer.ground_truth(&self.pose(joints), size, size, None);
        let k = (lamp_intensity / self.nominal_irradiance) as f32;
        gt.data.par_iter_mut().for_each(|p| *p = p.map(|c| c * k));
        gt
    }

    /// The exposure time that puts a white Lambertian reflector lit along its normal from the
    /// nominal lamp distance at `fraction` of the sensor's full scale at gain 1, clamped to
    /// `[min_s, max_s]`. Glossy highlights may still saturate: that is what HDR is for.
    pub fn exposure_for_white(&self, fraction: f64, min_s: f64, max_s: f64) -> f64 {
        let full_scale_e =
            f64::from(self.sensor.white_level(1.0) - self.sensor.black_level_dn) / self.sensor.dn_per_electron(1.0);
        (fraction * full_scale_e / self.nominal_irradiance).clamp(min_s, max_s)
    }

    /// Signal (DN above black) of a white Lambertian reflector facing the lamp at the
    /// nominal sample centre, for an exposure and gain: the natural white point of previews.
    pub fn white_signal_dn(&self, exposure_s: f64, gain: f64) -> f64 {
        self.nominal_irradiance * exposure_s * self.sensor.dn_per_electron(gain)
    }

    /// An 8-bit sRGB preview of a raw frame (bilinear demosaic, white balance for the lamp,
    /// the camera-to-sRGB matrix fitted on the ColorChecker), scaled so that a signal of
    /// `white_dn` above black maps to white.
    pub fn preview(&self, raw: &RawFrame, white_dn: f64) -> Vec<u8> {
        // The demosaic maps [black, white level] to [0, 1]; rescale so `white_dn` maps to 1.
        let img = demosaic_bilinear(raw);
        let range = f64::from(raw.meta.white_level) - f64::from(raw.meta.black_level);
        preview_srgb8(&img, self.colour.white_balance(), &self.preview_matrix, range / white_dn.max(1.0))
    }
}
