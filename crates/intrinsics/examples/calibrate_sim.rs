//! `cargo run --release -p btfrig-intrinsics --example calibrate_sim [SEED] [VIEWS] [NOISE_PX]`:
//! calibrates the default rig's camera from synthetic views (tilted 20-60 degrees, Gaussian
//! noise), prints the time and errors against the truth, and the calibration file on stdout.
//! Environment switches for experiments: `WIDE=1` (53-degree lens of the tests instead of the
//! rig's), `FIX_PP=1` (hold the principal point at the image centre), `NO_TANG=1`, `NO_K3=1`
//! (hold p1, p2 or k3 at 0), `TILT_MIN`, `TILT_MAX` (degrees), `CAMCAL_CORR=1` (print the
//! correlation matrix of the camera parameters).

#[path = "../tests/support/mod.rs"]
mod support;

use std::time::Instant;

use btfrig_intrinsics::{
    calibrate, distortion_difference, mapping_difference, mapping_difference_up_to_rotation, CalibrationFile, Options,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).map_or(2026, |s| s.parse().expect("SEED is an integer"));
    let views: usize = args.get(2).map_or(15, |s| s.parse().expect("VIEWS is an integer"));
    let noise: f64 = args.get(3).map_or(0.2, |s| s.parse().expect("NOISE_PX is a number"));
    let truth = if std::env::var_os("WIDE").is_some() { support::wide() } else { support::truth() };
    let tmin: f64 = std::env::var("TILT_MIN").map_or(20.0, |s| s.parse().unwrap());
    let tmax: f64 = std::env::var("TILT_MAX").map_or(60.0, |s| s.parse().unwrap());
    let scene = support::scene(&truth, seed, views, (tmin, tmax), noise, 0.0);
    let mut opts = Options::new(truth.width, truth.height);
    opts.estimate_tangential = std::env::var_os("NO_TANG").is_none();
    opts.estimate_k3 = std::env::var_os("NO_K3").is_none();
    if std::env::var_os("FIX_PP").is_some() {
        opts.fixed_principal_point = Some(nalgebra::Point2::new(799.5, 599.5));
    }
    let reps = 10;
    let t0 = Instant::now();
    let mut cal = None;
    for _ in 0..reps {
        cal = Some(calibrate(&scene.views, &opts).expect("calibration succeeds"));
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let c = cal.unwrap();
    let e = &c.camera;
    let rot = mapping_difference_up_to_rotation(&truth, e, 81);
    eprintln!(
        "{views} views, {} points, noise {noise} px: {ms:.2} ms per calibration ({} LM iterations)\n\
         fx err {:+.4}% (sd {:.3} px), fy err {:+.4}% (sd {:.3} px), principal point err {:.3} px (sd {:.3}, {:.3})\n\
         distortion effect max diff {:.4} px, whole mapping max diff {:.3} px ({:.4} px up to a rotation of {:.1e} rad), \
         rms {:.4} px, sigma0 {:.4}",
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
        rot.0,
        rot.1,
        c.rms_px,
        c.sigma0,
    );
    if std::env::var_os("CAMCAL_CORR").is_some() {
        correlations(&c);
    }
    let source = format!(
        "simulated: rig-configs/bonn-gonio-sim.toml camera, {views} synthetic views tilted 20-60 deg, \
         Gaussian noise {noise} px, seed {seed} (crates/intrinsics/examples/calibrate_sim.rs)"
    );
    print!("{}", CalibrationFile::from_calibration(&c, &source).to_toml());
}

#[allow(dead_code)]
fn correlations(c: &btfrig_intrinsics::Calibration) {
    let cv = &c.covariance;
    for r in 0..9 {
        let row: Vec<String> =
            (0..9).map(|k| format!("{:+.3}", cv[r][k] / (cv[r][r] * cv[k][k]).sqrt().max(1e-300))).collect();
        eprintln!("{:>3} {}", btfrig_intrinsics::CAM_NAMES[r], row.join(" "));
    }
}
