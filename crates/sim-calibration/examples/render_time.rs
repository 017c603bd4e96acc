//! Times one board capture: radiance vs sensor vs demosaic vs detection.
use btfrig_calibrate::CalibrationPlan;
use btfrig_core::config::RigConfig;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use std::time::Instant;
fn main() {
    let plan = CalibrationPlan::default_plan();
    let cfg = RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "x").unwrap();
    let scene = RigScene::with_target(&cfg, &plan.target).unwrap();
    let view = plan.views()[14];
    let j = scene.gonio().ik(plan.light_for(view), view).unwrap();
    for ss in [1u32, 4, 8] {
        let opts = RenderOptions { marker_supersampling: ss, ..Default::default() };
        let t = Instant::now();
        let (img, st) = scene.radiance(&j, 1.0, &opts);
        let r = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let raw = scene.sensor().capture(&img, 0.1, 1.0, 1).unwrap();
        let s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let g = btfrig_calibrate::green(&raw);
        let d = t.elapsed().as_secs_f64();
        eprintln!(
            "ss {ss}: radiance {r:.3}s sensor {s:.3}s green {d:.3}s traced {} plate hits {}",
            st.pixels_traced, st.plate_hits
        );
        let _ = g;
    }
}
