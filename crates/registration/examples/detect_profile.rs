//! Profiling aid (not a test): one rendered 12 MP frame, the predicted-window detection run
//! 20 times on its demosaiced green, then as many times on the raw mosaic as a run reads it (`DETECT_REPEAT` times if set: a few hundred so that the search, not the scene's
//! setup, fills the profile). `perf record target/release/examples/detect_profile`.
use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::Mosaic;
use btfrig_markers::GrayImage;
use btfrig_registration::{GreyFrame, PlateRegistrar, RegisterOptions};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

fn main() {
    let path = std::env::args().nth(1).unwrap_or_else(|| "rig-configs/bonn-gonio-sim-12mp.toml".into());
    let cfg = RigConfig::from_toml(&std::fs::read_to_string(&path).unwrap(), &path).unwrap();
    let scene = RigScene::new(&cfg, &MaterialSpec::builtin("lacquered-wood").unwrap()).unwrap();
    let cam = scene.camera().model().clone();
    let mut reg = PlateRegistrar::new(cam.clone(), &cfg.plate, RegisterOptions::default()).unwrap();
    reg.detect.threshold_window_px = ((51.0 * cam.width as f64 / 1600.0).round() as usize) | 1;
    let j = scene.gonio().ik(Direction::from_degrees(45.0, 0.0), Direction::from_degrees(45.0, 90.0)).unwrap();
    let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
    let (raw, _) = scene.capture(&j, 1.0, exposure, 1.0, 11, &RenderOptions::default()).unwrap();
    let green: Vec<f32> = demosaic_bilinear(&raw).data.iter().map(|p| p[1]).collect();
    let img = GrayImage::new(raw.width, raw.height, &green).unwrap();
    let nominal = scene.pose(&j);
    for vt in [0.0, 45.0, 75.0, 80.0] {
        let j = scene.gonio().ik(Direction::from_degrees(45.0, 0.0), Direction::from_degrees(vt, 90.0)).unwrap();
        println!("view {vt}: smallest module {:.2?} px", reg.smallest_module_px(&scene.pose(&j)));
    }
    let repeat: usize = std::env::var("DETECT_REPEAT").ok().and_then(|s| s.parse().ok()).unwrap_or(20);
    let t = std::time::Instant::now();
    for _ in 0..repeat {
        let (w, f) = reg.detect_predicted(&img, &nominal, (2.0, 0.01)).unwrap();
        assert!(f.detections.len() == 12 && !w.is_empty());
    }
    println!("detect_predicted: {:.1} ms per frame", t.elapsed().as_secs_f64() * 1e3 / repeat as f64);
    let mosaic = Mosaic::of_raw(&raw).unwrap();
    let t = std::time::Instant::now();
    for _ in 0..repeat {
        let r = reg.register_grey_within(GreyFrame::Mosaic(mosaic), &nominal, Some((2.0, 0.01))).unwrap();
        assert!(r.detected.len() == 12);
    }
    println!("register_grey_within, mosaic: {:.1} ms per frame", t.elapsed().as_secs_f64() * 1e3 / repeat as f64);
}
