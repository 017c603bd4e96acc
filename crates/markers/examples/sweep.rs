//! Diagnostics (not a test): corner error statistics of detector variants on rendered views.
//! `sweep [ss]`: the renderer's marker supersampling (default 16).
use std::time::Instant;

use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_markers::{detect, DetectParams, Dictionary, GrayImage, GreenSites};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use nalgebra::Point3;

fn main() {
    let ss: u32 = std::env::args().nth(1).map(|v| v.parse().unwrap()).unwrap_or(16);
    let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "rig").unwrap();
    let scene = RigScene::new(&cfg, &MaterialSpec::builtin("lacquered-wood").unwrap()).unwrap();
    let opts = RenderOptions { marker_supersampling: ss, ..RenderOptions::default() };
    let cam = scene.camera().model().clone();
    let dict = Dictionary::dict_4x4_50();
    let base = DetectParams { camera: Some(cam.clone()), ..DetectParams::default() };
    let mut variants: Vec<(&str, DetectParams)> = vec![
        ("scanline", DetectParams { edge_model: false, ..base.clone() }),
        ("model all", DetectParams { green_sites: GreenSites::All, ..base.clone() }),
        ("model auto", base.clone()),
        ("auto fl.015", DetectParams { corner_sigma_floor_px: 0.015, ..base.clone() }),
    ];
    if std::env::var("SWEEP_BONN").is_ok() {
        variants.retain(|v| v.0 == "scanline" || v.0 == "model auto");
    }
    let all = [
        ((0.0, 0.0), 21),
        ((45.0, 90.0), 22),
        ((45.0, 200.0), 23),
        ((75.0, 90.0), 24),
        ((75.0, 330.0), 25),
        ((80.0, 90.0), 26),
    ];
    let pick: Vec<usize> = std::env::args().skip(2).map(|v| v.parse().unwrap()).collect();
    // SWEEP_BONN: all 81 Bonn view directions instead (seed 100 + index).
    let views: Vec<((f64, f64), u64)> = if std::env::var("SWEEP_BONN").is_ok() {
        btfrig_core::sampling::Sampling::bonn81()
            .directions()
            .iter()
            .enumerate()
            .map(|(i, d)| ((d.theta.to_degrees(), d.phi.to_degrees()), 100 + i as u64))
            .collect()
    } else if let Ok(v) = std::env::var("SWEEP_VIEW") {
        // One view "theta,phi" (seed 7).
        let t: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
        vec![((t[0], t[1]), 7)]
    } else {
        all.to_vec()
    };
    for (i, &(view, seed)) in views.iter().enumerate() {
        if !pick.is_empty() && !pick.contains(&i) {
            continue;
        }
        let Ok(j) = scene.gonio().ik(Direction::from_degrees(45.0, 0.0), Direction::from_degrees(view.0, view.1))
        else {
            println!("view {view:?}: not reachable");
            continue;
        };
        let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
        let (raw, _) = scene.capture(&j, 1.0, exposure, 1.0, seed, &opts).unwrap();
        let img: Vec<f32> = if let Ok(rel) = std::env::var("SWEEP_RADIANCE") {
            // Noise-free radiance (green), plus seeded white Gaussian noise of `rel` times its
            // 99th percentile: a monochrome sensor without mosaic.
            use rand::SeedableRng;
            use rand_distr::Distribution;
            let rel: f64 = rel.parse().unwrap();
            let g: Vec<f32> = scene.radiance(&j, 1.0, &opts).0.data.iter().map(|p| p[1]).collect();
            let mut v = g.clone();
            v.sort_by(f32::total_cmp);
            let top = f64::from(v[v.len() * 99 / 100]);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let nd = rand_distr::Normal::new(0.0, rel * top).unwrap();
            g.iter().map(|&x| x + nd.sample(&mut rng) as f32).collect()
        } else {
            demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect()
        };
        let g = GrayImage::new(cam.width, cam.height, &img).unwrap();
        let pose = scene.pose(&j);
        let cs = pose.camera_to_world.inverse() * pose.sample_to_world;
        let markers = scene.renderer().scene().layout.markers();
        for (name, p) in &variants {
            let mut ms = f64::MAX;
            let mut dets = Vec::new();
            let reps = std::env::var("SWEEP_REPS").map(|v| v.parse().unwrap()).unwrap_or(1);
            let c0 = cpu_ticks();
            for _ in 0..reps {
                let t0 = Instant::now();
                dets = detect(&g, &dict, p).unwrap();
                ms = ms.min(t0.elapsed().as_secs_f64() * 1e3);
            }
            let cpu_ms = (cpu_ticks() - c0) as f64 * 10.0 / reps as f64;
            let (mut sum, mut max, mut n, mut ssum, mut rsum) = (0.0, 0.0f64, 0.0, 0.0, 0.0);
            for d in &dets {
                let Some(m) = markers.iter().find(|m| m.id == d.id) else { continue };
                for k in 0..4 {
                    let c = m.corners_sample_m[k];
                    let t = cam.project(&(cs * Point3::new(c.x, c.y, 0.0))).unwrap();
                    let e = (d.corners[k] - t).norm();
                    if std::env::var("SWEEP_DEBUG").is_ok_and(|v| e > v.parse::<f64>().unwrap_or(0.25)) {
                        println!(
                            "  {name} id {} corner {k} err {:.3} sigma {:.3} flags {}",
                            d.id, e, d.corner_sigma_px[k], d.quality.flags
                        );
                    }
                    sum += e;
                    max = max.max(e);
                    n += 1.0;
                    ssum += d.corner_sigma_px[k];
                    rsum += e / d.corner_sigma_px[k];
                }
            }
            let visible = markers
                .iter()
                .filter(|m| {
                    m.corners_sample_m.iter().all(|c| {
                        cam.project(&(cs * Point3::new(c.x, c.y, 0.0))).is_some_and(|t| {
                            t.x > 3.0 && t.y > 3.0 && t.x < cam.width as f64 - 4.0 && t.y < cam.height as f64 - 4.0
                        })
                    })
                })
                .count();
            println!(
                "view {view:?} {name:>10}: {}/{visible} markers, mean {:.4} max {:.4} px, sigma {:.4}, err/sigma {:.2}, {ms:.1} ms (cpu {cpu_ms:.0} ms)",
                dets.len(),
                sum / n,
                max,
                ssum / n,
                rsum / n
            );
        }
    }
}

/// This thread's user + system CPU time in clock ticks (1/100 s), from /proc (Linux).
fn cpu_ticks() -> u64 {
    let s = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let rest = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    f.get(11).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0)
        + f.get(12).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0)
}
