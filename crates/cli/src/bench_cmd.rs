//! `btfrig bench render`: frame render time with and without the renderer's skips, side by
//! side, with the difference between the two images (the skips must not change the image).

use std::time::Instant;

use btfrig_core::Direction;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

/// (name, light, view) in degrees: the poses every material is timed at.
const POSES: [(&str, (f64, f64), (f64, f64)); 3] = [
    ("frontal", (45.0, 0.0), (0.0, 0.0)),
    ("oblique", (30.0, 120.0), (45.0, 0.0)),
    ("grazing", (75.0, 90.0), (75.0, 270.0)),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs the benchmark and prints one row per (material, pose).
pub fn render(rig: Option<&std::path::Path>, materials: &[String], texels: usize, repeat: usize) -> anyhow::Result<()> {
    anyhow::ensure!((2..=4096).contains(&texels), "--texels {texels}: allowed 2..=4096");
    anyhow::ensure!((1..=100).contains(&repeat), "--repeat {repeat}: allowed 1..=100");
    let cfg = crate::rig::load(rig)?;
    let names: Vec<String> = if materials.is_empty() {
        crate::material::names().iter().map(|s| s.to_string()).collect()
    } else {
        materials.to_vec()
    };
    println!(
        "render benchmark: {}x{} frame, {texels}x{texels}-texel sample, {} rayon threads, median of {repeat}",
        cfg.camera.width_px,
        cfg.camera.height_px,
        rayon::current_num_threads()
    );
    println!(
        "{:<16} {:<8} {:>10} {:>10} {:>6} {:>10} {:>10} {:>12} {:>12} {:>10}",
        "material",
        "pose",
        "skips (s)",
        "none (s)",
        "ratio",
        "max diff",
        "traced %",
        "shadow rays",
        "skipped rays",
        "sensor (s)"
    );
    for name in &names {
        let material = crate::material::load(Some(name))?.with_texels(texels);
        let scene = RigScene::new(&cfg, &material)?;
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
            let (m_on, m_off) = (median(t_on), median(t_off));
            println!(
                "{:<16} {:<8} {:>10.3} {:>10.3} {:>6.2} {:>10.1e} {:>10.1} {:>12} {:>12} {:>10.3}",
                name,
                pose_name,
                m_on,
                m_off,
                m_off / m_on,
                diff,
                100.0 * st_on.pixels_traced as f64 / st_on.pixels.max(1) as f64,
                st_on.shadow_rays,
                st_on.shadow_rays_skipped,
                sensor_s
            );
        }
    }
    println!("max diff: largest |skips - none| over all pixels and channels, relative to the image's peak");
    Ok(())
}
