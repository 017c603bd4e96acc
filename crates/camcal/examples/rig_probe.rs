//! `cargo run --release -p btfrig-camcal --example rig_probe [PLAN|-] [SEED]`: runs a
//! calibration plan on the default simulated rig and prints the errors against the truth, for
//! the plan as given and with k3 held at 0, with one and two detection passes (tuning plans).
use btfrig_camcal::rig::{calibrate_captures, capture_simulated, CalibrationPlan, RigCalibration};
use btfrig_camcal::{distortion_difference, mapping_difference_up_to_rotation};
use btfrig_core::config::RigConfig;

fn show(label: &str, r: &RigCalibration) {
    let (c, t) = (&r.calibration, &r.truth);
    let e = &c.camera;
    let u = &c.uncertainty;
    eprintln!(
        "{label}: fx {:+.4}% (sd {:.3} px) fy {:+.4}% (sd {:.3}) cx {:+.3} (sd {:.3}) cy {:+.3} (sd {:.3}) \
         dist {:.4} px, up-to-rot {:.4} px, rms {:.4} sigma0 {:.3} outliers {} points {} detect {:.1}s cal {:.2}s",
        (e.fx / t.fx - 1.0) * 100.0,
        u.fx_px,
        (e.fy / t.fy - 1.0) * 100.0,
        u.fy_px,
        e.cx - t.cx,
        u.cx_px,
        e.cy - t.cy,
        u.cy_px,
        distortion_difference(t, e, 81),
        mapping_difference_up_to_rotation(t, e, 81).0,
        c.rms_px,
        c.sigma0,
        c.outliers,
        c.points_used,
        r.detect_s,
        r.calibrate_s
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let plan = match args.get(1) {
        Some(p) if p != "-" => CalibrationPlan::from_toml(&std::fs::read_to_string(p).unwrap(), p).unwrap(),
        _ => CalibrationPlan::default_plan(),
    };
    let seed: u64 = args.get(2).map_or(1, |s| s.parse().unwrap());
    let text = include_str!("../../../rig-configs/bonn-gonio-sim.toml");
    let cfg = RigConfig::from_toml(text, "bonn-gonio-sim.toml").unwrap();
    let shots = capture_simulated(&cfg, &plan, seed).unwrap();
    eprintln!("{} views rendered in {:.1} s", shots.frames.len(), shots.render_s);
    for (k3, passes) in [(plan.estimate_k3, plan.passes), (false, plan.passes), (plan.estimate_k3, 1), (false, 1)] {
        let p = CalibrationPlan { estimate_k3: k3, passes, ..plan.clone() };
        let r = calibrate_captures(&cfg, &p, &shots, |_| {}).unwrap();
        show(&format!("k3 {k3} passes {passes}"), &r);
    }
}
