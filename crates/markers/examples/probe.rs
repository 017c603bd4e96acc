//! Diagnostics for one rendered view (not a test): per-marker edge residuals and corner errors.
use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_markers::{detect, DetectParams, Dictionary, GrayImage};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use nalgebra::Point3;

fn main() {
    let a: Vec<f64> = std::env::args().skip(1).map(|v| v.parse().unwrap()).collect();
    let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "rig").unwrap();
    let scene = RigScene::new(&cfg, &MaterialSpec::builtin("lacquered-wood").unwrap()).unwrap();
    let opts = RenderOptions { marker_supersampling: 16, ..RenderOptions::default() };
    let j = scene.gonio().ik(Direction::from_degrees(45.0, 0.0), Direction::from_degrees(a[0], a[1])).unwrap();
    let img: Vec<f32> = if a[2] > 1.0 {
        // Mode 2: noise-free radiance, green, plus white Gaussian noise of a[3] relative to
        // the 99th percentile (no demosaic).
        let g: Vec<f32> = scene.radiance(&j, 1.0, &opts).0.data.iter().map(|p| p[1]).collect();
        let mut v = g.clone();
        v.sort_by(f32::total_cmp);
        let top = v[v.len() * 99 / 100];
        let mut state = 12345u64;
        g.iter()
            .map(|&x| {
                // Irwin-Hall approximation of a normal deviate from an LCG: diagnostics only.
                let mut s = 0.0;
                for _ in 0..12 {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    s += (state >> 11) as f64 / (1u64 << 53) as f64;
                }
                x + ((s - 6.0) * a[3] * top as f64) as f32
            })
            .collect()
    } else if a[2] > 0.0 {
        let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
        let (raw, _) = scene.capture(&j, 1.0, exposure, 1.0, 24, &opts).unwrap();
        demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect()
    } else {
        scene.radiance(&j, 1.0, &opts).0.data.iter().map(|p| p[1]).collect()
    };
    let cam = scene.camera().model();
    let g = GrayImage::new(cam.width, cam.height, &img).unwrap();
    let pose = scene.pose(&j);
    let cs = pose.camera_to_world.inverse() * pose.sample_to_world;
    let markers = scene.renderer().scene().layout.markers();
    let dets = detect(&g, &Dictionary::dict_4x4_50(), &DetectParams::default()).unwrap();
    for m in &markers {
        if !dets.iter().any(|d| d.id == m.id) {
            let c = m.corners_sample_m[0];
            let t = cam.project(&(cs * Point3::new(c.x, c.y, 0.0))).unwrap();
            println!("missed id {} (top-left corner at {:.1}, {:.1})", m.id, t.x, t.y);
        }
    }
    for d in detect(&g, &Dictionary::dict_4x4_50(), &DetectParams::default()).unwrap() {
        let m = markers.iter().find(|m| m.id == d.id).unwrap();
        let errs: Vec<String> = (0..4)
            .map(|k| {
                let c = m.corners_sample_m[k];
                let t = cam.project(&(cs * Point3::new(c.x, c.y, 0.0))).unwrap();
                let e = d.corners[k] - t;
                format!("({:+.3},{:+.3})", e.x, e.y)
            })
            .collect();
        let side: Vec<String> =
            (0..4).map(|k| format!("{:.1}", (d.corners[(k + 1) % 4] - d.corners[k]).norm())).collect();
        println!("id {:2} rms {:.3?} sides {:?} err {}", d.id, d.quality.edge_rms_px, side, errs.join(" "));
    }
}
