//! The measurement behind `btfrig bench render`: frame render time with and without the
//! renderer's skips, side by side, with the difference between the two images (the skips
//! must not change the image).

use std::time::Instant;

use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

/// A timed pose: (name, light (theta, phi), view (theta, phi)), angles in degrees.
type Pose = (&'static str, (f64, f64), (f64, f64));

/// The poses every material is timed at.
pub const POSES: [Pose; 3] = [
    ("frontal", (45.0, 0.0), (0.0, 0.0)),
    ("oblique", (30.0, 120.0), (45.0, 0.0)),
    ("grazing", (75.0, 90.0), (75.0, 270.0)),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One material at one pose.
#[derive(Debug, Clone)]
pub struct RenderRow {
    /// The pose's name ([`POSES`]).
    pub pose: &'static str,
    /// Median render time with the skips, seconds.
    pub skips_s: f64,
    /// Median render time without them, seconds.
    pub none_s: f64,
    /// Largest |skips - none| over all pixels and channels, relative to the image's peak.
    pub max_diff: f32,
    /// Pixels traced, per cent of the frame (with the skips).
    pub traced_pct: f64,
    /// Shadow rays cast (with the skips).
    pub shadow_rays: u64,
    /// Shadow rays skipped.
    pub skipped_rays: u64,
    /// Time of the sensor model on the frame, seconds.
    pub sensor_s: f64,
}

/// Renders `material` on the rig `cfg` at every pose of [`POSES`], `repeat` timed times with
/// and without the skips (interleaved), after one untimed render of each.
pub fn bench_material(cfg: &RigConfig, material: &MaterialSpec, repeat: usize) -> anyhow::Result<Vec<RenderRow>> {
    let scene = RigScene::new(cfg, material)?;
    let mut rows = Vec::new();
    for (pose_name, (lt, lp), (vt, vp)) in POSES {
        let joints = scene
            .gonio()
            .ik(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp))
            .map_err(|r| anyhow::anyhow!("bench pose {pose_name} unreachable: {r}"))?;
        let on = RenderOptions::with_skips(true);
        let off = RenderOptions::with_skips(false);
        // One untimed render of each warms caches and gives the images to compare.
        let (img_on, st_on) = scene.radiance(&joints, 1.0, &on);
        let (img_off, _) = scene.radiance(&joints, 1.0, &off);
        let mut t_on = Vec::new();
        let mut t_off = Vec::new();
        for _ in 0..repeat {
            // Interleaved, so a load change on this noisy machine hits both alike.
            let t = Instant::now();
            std::hint::black_box(scene.radiance(&joints, 1.0, &on));
            t_on.push(t.elapsed().as_secs_f64());
            let t = Instant::now();
            std::hint::black_box(scene.radiance(&joints, 1.0, &off));
            t_off.push(t.elapsed().as_secs_f64());
        }
        let peak = img_off.max_value().max(f32::MIN_POSITIVE);
        let diff = img_on
            .data
            .iter()
            .zip(&img_off.data)
            .flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs()))
            .fold(0.0f32, f32::max)
            / peak;
        let exposure = scene.exposure_for_white(0.6, 1e-4, 30.0);
        let t = Instant::now();
        std::hint::black_box(scene.sensor().capture(&img_on, exposure, 1.0, 1)?);
        let sensor_s = t.elapsed().as_secs_f64();
        rows.push(RenderRow {
            pose: pose_name,
            skips_s: median(t_on),
            none_s: median(t_off),
            max_diff: diff,
            traced_pct: 100.0 * st_on.pixels_traced as f64 / st_on.pixels.max(1) as f64,
            shadow_rays: st_on.shadow_rays,
            skipped_rays: st_on.shadow_rays_skipped,
            sensor_s,
        });
    }
    Ok(rows)
}
