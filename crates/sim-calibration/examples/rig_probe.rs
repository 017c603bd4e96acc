//! `cargo run --release -p btfrig-sim-calibration --example rig_probe [PLAN|-] [SEED]`: runs a
//! calibration plan on the default simulated rig and prints the errors against the truth, for
//! the plan as given and with k3 held at 0, with one and two detection passes (tuning plans).
use btfrig_calibrate::{calibrate_captures, CalibrationPlan, RigCalibration};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_intrinsics::{distortion_difference, mapping_difference_up_to_rotation};
use btfrig_sim_calibration::capture_simulated;
use rand::SeedableRng;

fn show(label: &str, r: &RigCalibration, t: &CameraModel) {
    let c = &r.calibration;
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
    let r = calibrate_captures(&cfg, &plan, &shots, |_| {}).unwrap();
    let scene = btfrig_render::rig_scene::RigScene::with_target(&cfg, &plan.target).unwrap();
    let truth = scene.camera().model().clone();
    show(&format!("plan as given (k3 {} passes {})", plan.estimate_k3, plan.passes), &r, &truth);
    // Diagnostic: detected corners against their true projections (true lens, true joints),
    // and the same calibration on the true projections plus Gaussian noise of the detector's
    // stated sigma (geometry alone, without the capture chain).
    let used: Vec<_> = r.captures.iter().filter(|c| c.skipped.is_none()).collect();
    let (mut sx, mut sy, mut s2, mut n) = (0.0, 0.0, 0.0, 0usize);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    // Detected - true binned by radius from the image centre (radial and tangential parts).
    let mut bins = [(0.0f64, 0.0f64, 0usize); 5];
    let mut synth = Vec::new();
    for (cap, view) in used.iter().zip(&r.views) {
        let pose = scene.pose(&cap.joints);
        let s2c = pose.camera_to_world.inverse() * pose.sample_to_world;
        let mut pts = Vec::new();
        for c in &view.points {
            let p = truth.project(&(s2c * nalgebra::Point3::new(c.target.x, c.target.y, 0.0))).unwrap();
            let d = c.pixel - p;
            let rv = nalgebra::Vector2::new(p.x - 799.5, p.y - 599.5);
            let rn = rv.norm();
            let b = ((rn / 1000.0 * 5.0) as usize).min(4);
            let u = rv / rn.max(1e-9);
            bins[b].0 += d.dot(&u);
            bins[b].1 += d.x * -u.y + d.y * u.x;
            bins[b].2 += 1;
            sx += d.x;
            sy += d.y;
            s2 += d.norm_squared();
            n += 1;
            let sd = c.sigma_px.unwrap_or(0.05);
            let noise = nalgebra::Vector2::new(
                rand_distr::Distribution::sample(&rand_distr::Normal::new(0.0, sd).unwrap(), &mut rng),
                rand_distr::Distribution::sample(&rand_distr::Normal::new(0.0, sd).unwrap(), &mut rng),
            );
            pts.push(btfrig_intrinsics::Correspondence { pixel: p + noise, ..*c });
        }
        synth.push(btfrig_intrinsics::View { points: pts });
    }
    eprintln!(
        "detected - true: mean ({:+.4}, {:+.4}) px, rms {:.4} px over {n} corners",
        sx / n as f64,
        sy / n as f64,
        (s2 / n as f64).sqrt()
    );
    for (k, b) in bins.iter().enumerate() {
        let m = b.2.max(1) as f64;
        eprintln!(
            "radius {}-{} px: mean radial {:+.4} tangential {:+.4} px ({} corners)",
            k * 200,
            k * 200 + 200,
            b.0 / m,
            b.1 / m,
            b.2
        );
    }
    let unweighted: Vec<btfrig_intrinsics::View> = r
        .views
        .iter()
        .map(|v| btfrig_intrinsics::View {
            points: v.points.iter().map(|c| btfrig_intrinsics::Correspondence { sigma_px: None, ..*c }).collect(),
        })
        .collect();
    let mut o = btfrig_intrinsics::Options::new(truth.width, truth.height);
    o.estimate_k3 = plan.estimate_k3;
    let mut ru = r.clone();
    ru.calibration = btfrig_intrinsics::calibrate(&unweighted, &o).unwrap();
    show("detected corners, equal weights", &ru, &truth);
    o.estimate_k3 = plan.estimate_k3;
    let c = btfrig_intrinsics::calibrate(&synth, &o).unwrap();
    let mut rs = r.clone();
    rs.calibration = c;
    show("true corners + stated noise", &rs, &truth);
}
