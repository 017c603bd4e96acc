//! `cargo run --release -p btfrig-camcal --example rig_probe [PLAN] [SEED]`: runs a calibration
//! plan on the default simulated rig and prints the errors against the truth (for tuning plans).
use btfrig_camcal::rig::{calibrate_simulated, CalibrationPlan};
use btfrig_camcal::{distortion_difference, mapping_difference_up_to_rotation};
use btfrig_core::config::RigConfig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let plan = match args.get(1) {
        Some(p) if p != "-" => CalibrationPlan::from_toml(&std::fs::read_to_string(p).unwrap(), p).unwrap(),
        _ => CalibrationPlan::default_plan(),
    };
    let seed: u64 = args.get(2).map_or(1, |s| s.parse().unwrap());
    let text = include_str!("../../../rig-configs/bonn-gonio-sim.toml");
    let cfg = RigConfig::from_toml(text, "bonn-gonio-sim.toml").unwrap();
    let r = calibrate_simulated(&cfg, &plan, seed, |s| eprintln!("{s}")).unwrap();
    let (c, t) = (&r.calibration, &r.truth);
    let e = &c.camera;
    let u = &c.uncertainty;
    eprintln!(
        "fx {:+.4}% (sd {:.3} px) fy {:+.4}% (sd {:.3}) cx {:+.3} (sd {:.3}) cy {:+.3} (sd {:.3}) dist {:.4} px, up-to-rot {:.4} px, rms {:.4} sigma0 {:.3} outliers {} points {} render {:.1}s detect {:.1}s cal {:.2}s",
        (e.fx / t.fx - 1.0) * 100.0, u.fx_px, (e.fy / t.fy - 1.0) * 100.0, u.fy_px,
        e.cx - t.cx, u.cx_px, e.cy - t.cy, u.cy_px,
        distortion_difference(t, e, 81), mapping_difference_up_to_rotation(t, e, 81).0,
        c.rms_px, c.sigma0, c.outliers, c.points_used, r.render_s, r.detect_s, r.calibrate_s
    );
    for (i, cap) in r.captures.iter().enumerate() {
        eprintln!("view {i} {:?}: {} markers {:?}", cap.view.to_degrees(), cap.markers, cap.skipped);
    }
}
