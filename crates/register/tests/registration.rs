//! Registration against ground truth on the default rig (no detector: marker corners are
//! projected through the true pose and perturbed). Run with
//! `cargo test --release -p btfrig-register -- --nocapture` to see the figures.

mod common;

use std::time::Instant;

use btfrig_core::Direction;
use btfrig_register::{register, texel_position_error, Correspondence, RegisterError, RegisterOptions, Registration};
use common::{joints_for, observe, rig, true_joints, Rig, SIZE};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// One registered view: errors of the estimate and of the nominal pose, time, prediction.
struct Case {
    est_mean: f64,
    est_max: f64,
    nom_mean: f64,
    nom_max: f64,
    seconds: f64,
    predicted: f64,
    reg: Registration,
}

/// Registers one view whose observations come from `corrupt(observations)`.
fn run_view(
    rig: &Rig,
    view: Direction,
    light_start: usize,
    error_scale: f64,
    sigma: f64,
    seed: u64,
    corrupt: &dyn Fn(&mut Vec<Correspondence>, &mut ChaCha8Rng),
) -> Result<Case, RegisterError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cmd = joints_for(rig, view, light_start);
    let nominal = rig.gonio.scene_pose(&cmd);
    let truth = rig.gonio.scene_pose(&true_joints(rig, &cmd, error_scale, &mut rng));
    let mut obs = observe(rig, &truth, sigma, &mut rng);
    corrupt(&mut obs, &mut rng);
    let t0 = Instant::now();
    let reg = register(&obs, &rig.camera, &nominal, &RegisterOptions::default())?;
    let seconds = t0.elapsed().as_secs_f64();
    let (est_mean, est_max) = texel_position_error(&truth, &reg.pose, &rig.camera, rig.region, SIZE);
    let (nom_mean, nom_max) = texel_position_error(&truth, &nominal, &rig.camera, rig.region, SIZE);
    let predicted = reg.texel_sigma(&rig.camera, rig.region, SIZE);
    Ok(Case { est_mean, est_max, nom_mean, nom_max, seconds, predicted, reg })
}

fn none(_: &mut Vec<Correspondence>, _: &mut ChaCha8Rng) {}

struct Summary {
    mean: f64,
    max: f64,
    nom_mean: f64,
    nom_max: f64,
}

fn summarise(label: &str, cases: &[Case]) -> Summary {
    let n = cases.len() as f64;
    let mean = cases.iter().map(|c| c.est_mean).sum::<f64>() / n;
    let max = cases.iter().map(|c| c.est_max).fold(0.0, f64::max);
    let worst_mean = cases.iter().map(|c| c.est_mean).fold(0.0, f64::max);
    let nom_mean = cases.iter().map(|c| c.nom_mean).sum::<f64>() / n;
    let nom_max = cases.iter().map(|c| c.nom_max).fold(0.0, f64::max);
    let t_mean = cases.iter().map(|c| c.seconds).sum::<f64>() / n;
    let t_max = cases.iter().map(|c| c.seconds).fold(0.0, f64::max);
    let rms = cases.iter().map(|c| c.reg.rms_px).sum::<f64>() / n;
    let pred = cases.iter().map(|c| c.predicted).sum::<f64>() / n;
    println!(
        "{label}: {} views; texel error registered mean {mean:.4} (worst view mean {worst_mean:.4}) max {max:.4}; \
         nominal mean {nom_mean:.4} max {nom_max:.4}; predicted sigma {pred:.4}; reprojection rms {rms:.3} px; \
         time mean {:.3} ms max {:.3} ms",
        cases.len(),
        t_mean * 1e3,
        t_max * 1e3
    );
    Summary { mean, max, nom_mean, nom_max }
}

#[test]
fn all_81_bonn_views_default_jitter_meet_the_acceptance() {
    let rig = rig();
    for sigma in [0.05, 0.1, 0.2] {
        let cases: Vec<Case> = common::bonn_views()
            .into_iter()
            .enumerate()
            .map(|(k, v)| run_view(&rig, v, 7 * k, 1.0, sigma, 1000 + k as u64, &none).expect("registers"))
            .collect();
        let s = summarise(&format!("bonn81 sigma {sigma} px"), &cases);
        let worst = cases.iter().enumerate().max_by(|a, b| a.1.est_mean.total_cmp(&b.1.est_mean)).unwrap();
        let v = common::bonn_views()[worst.0];
        println!(
            "  worst view {} (theta {:.0} phi {:.0}): mean {:.4} max {:.4} predicted {:.4}",
            worst.0,
            v.theta.to_degrees(),
            v.phi.to_degrees(),
            worst.1.est_mean,
            worst.1.est_max,
            worst.1.predicted
        );
        for (k, c) in cases.iter().enumerate() {
            assert!(c.reg.rejected_markers.is_empty(), "view {k}: clean markers rejected {:?}", c.reg.rejected_markers);
            // The covariance is not optimistic: the realised error stays within a few
            // predicted sigmas.
            assert!(c.est_mean < 3.0 * c.predicted, "view {k}: error {} vs predicted {}", c.est_mean, c.predicted);
        }
        // Acceptance: mean under 0.05 texel and max under 0.2 texel at 256x256, at detector
        // noise up to 0.1 px; twice that at 0.2 px (the error scales with the noise).
        let scale = if sigma <= 0.1 { 1.0 } else { 2.0 };
        assert!(s.mean < 0.05 * scale, "mean texel error {}", s.mean);
        assert!(s.max < 0.2 * scale, "max texel error {}", s.max);
        // The nominal pose is clearly worse under jitter.
        assert!(s.nom_mean > 3.0 * s.mean, "nominal {} vs registered {}", s.nom_mean, s.mean);
        assert!(s.nom_max > s.max);
    }
}
