//! `cargo run --release -p btfrig-camcal --example calibrate_sim [SEED] [VIEWS] [NOISE_PX]`:
//! calibrates the default rig's camera from synthetic views (tilted 20-60 degrees, Gaussian
//! noise), prints the time and errors against the truth, and the calibration file on stdout.

#[path = "../tests/support/mod.rs"]
mod support;

use std::time::Instant;

use btfrig_camcal::{calibrate, distortion_difference, mapping_difference, CalibrationFile, Options};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).map_or(2026, |s| s.parse().expect("SEED is an integer"));
    let views: usize = args.get(2).map_or(15, |s| s.parse().expect("VIEWS is an integer"));
    let noise: f64 = args.get(3).map_or(0.2, |s| s.parse().expect("NOISE_PX is a number"));
    let truth = support::truth();
    let scene = support::scene(&truth, seed, views, (20.0, 60.0), noise, 0.0);
    let opts = Options::new(truth.width, truth.height);
    let reps = 10;
    let t0 = Instant::now();
    let mut cal = None;
    for _ in 0..reps {
        cal = Some(calibrate(&scene.views, &opts).expect("calibration succeeds"));
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let c = cal.unwrap();
    let e = &c.camera;
    eprintln!(
        "{views} views, {} points, noise {noise} px: {ms:.2} ms per calibration ({} LM iterations)\n\
         fx err {:+.4}% (sd {:.3} px), fy err {:+.4}% (sd {:.3} px), principal point err {:.3} px (sd {:.3}, {:.3})\n\
         distortion effect max diff {:.4} px, whole mapping max diff {:.3} px, rms {:.4} px, sigma0 {:.4}",
        c.points_used,
        c.iterations,
        (e.fx / truth.fx - 1.0) * 100.0,
        c.uncertainty.fx_px,
        (e.fy / truth.fy - 1.0) * 100.0,
        c.uncertainty.fy_px,
        (e.cx - truth.cx).hypot(e.cy - truth.cy),
        c.uncertainty.cx_px,
        c.uncertainty.cy_px,
        distortion_difference(&truth, e, 81),
        mapping_difference(&truth, e, 81),
        c.rms_px,
        c.sigma0,
    );
    let source = format!(
        "simulated: rig-configs/bonn-gonio-sim.toml camera, {views} synthetic views tilted 20-60 deg, \
         Gaussian noise {noise} px, seed {seed} (crates/camcal/examples/calibrate_sim.rs)"
    );
    print!("{}", CalibrationFile::from_calibration(&c, &source).to_toml());
}
