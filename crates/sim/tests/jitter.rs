//! Positioning error: landing = target + offset + jitter * N(0, 1), seeded.

mod common;

use btfrig_hw::MoveOptions;
use btfrig_sim::FaultScenario;
use common::*;

const OPTS: MoveOptions = MoveOptions::with_timeout_s(60.0);

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

#[tokio::test(start_paused = true)]
async fn landing_error_statistics_match_config() {
    let cfg = devices(
        "[robot]\nkind = \"sim\"\nhomed_at_start = true\noffset_deg = [0.2, -0.1, 0.0]\njitter_deg = [0.05, 0.1, 0.3]\n\
         [rail]\nkind = \"sim\"\nhomed_at_start = true\noffset_deg = -0.4\njitter_deg = 0.2\n",
    );
    let mut rig = rig(&cfg, 99, &FaultScenario::none());
    let n = 2000;
    let mut robot_err: [Vec<f64>; 3] = Default::default();
    let mut rail_err = Vec::new();
    for i in 0..n {
        // Distinct targets: the jitter is keyed by the target (a pose-dependent repeatability
        // error), so statistics need many targets.
        let a = if i % 2 == 0 { 0.3 } else { -0.2 } + 1e-6 * i as f64;
        let reported = rig.robot.move_to_rad([a, -a, 2.0 * a], OPTS).await.unwrap();
        let rail_reported = rig.rail.move_to_rad(1.0 + a, OPTS).await.unwrap();
        let truth = rig.world.truth().joints;
        let commanded = rig.world.commanded();
        // The devices report the commanded position; only the world knows the truth.
        assert_eq!(reported, commanded.robot);
        assert_eq!(rail_reported, commanded.rail);
        for (j, err) in robot_err.iter_mut().enumerate() {
            err.push((truth.robot[j] - commanded.robot[j]).to_degrees());
        }
        rail_err.push((truth.rail - commanded.rail).to_degrees());
    }
    let check = |err: &[f64], offset: f64, sigma: f64, what: &str| {
        let (m, s) = mean_std(err);
        // Mean within 4 standard errors; std within 8 % (its standard error is ~1.6 %).
        assert!((m - offset).abs() < 4.0 * sigma / (n as f64).sqrt(), "{what}: mean {m} vs {offset}");
        assert!((s / sigma - 1.0).abs() < 0.08, "{what}: std {s} vs {sigma}");
    };
    check(&robot_err[0], 0.2, 0.05, "joint 0");
    check(&robot_err[1], -0.1, 0.1, "joint 1");
    check(&robot_err[2], 0.0, 0.3, "joint 2");
    check(&rail_err, -0.4, 0.2, "rail");
    // Joints draw independent errors.
    let corr = {
        let (m0, s0) = mean_std(&robot_err[1]);
        let (m1, s1) = mean_std(&robot_err[2]);
        robot_err[1].iter().zip(&robot_err[2]).map(|(a, b)| (a - m0) * (b - m1)).sum::<f64>()
            / ((n - 1) as f64 * s0 * s1)
    };
    assert!(corr.abs() < 0.1, "correlation {corr}");
}

#[tokio::test(start_paused = true)]
async fn zero_jitter_lands_exactly_at_target_plus_offset() {
    let cfg = devices(
        "[robot]\nkind = \"sim\"\nhomed_at_start = true\noffset_deg = [1.0, 0.0, -1.0]\njitter_deg = [0.0, 0.0, 0.0]\n",
    );
    let mut rig = rig(&cfg, 3, &FaultScenario::none());
    rig.robot.move_to_rad([0.5, 0.25, 0.0], OPTS).await.unwrap();
    let t = rig.world.truth().joints.robot;
    let expect = [0.5 + 1f64.to_radians(), 0.25, -(1f64.to_radians())];
    for j in 0..3 {
        assert!((t[j] - expect[j]).abs() < 1e-12, "{t:?}");
    }
}
