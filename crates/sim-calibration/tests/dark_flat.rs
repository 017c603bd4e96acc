//! The dark and flat calibration on the simulated rig against the simulated sensor's truth,
//! and its files written and read back (moved from `btfrig-calibrate`'s unit tests).

use btfrig_calibrate::dark_flat::{read_calibration, write_calibration, RadiometricPlan};
use btfrig_core::config::RigConfig;
use btfrig_sim_calibration::dark_flat::{calibrate_simulated, compare_with_truth};

fn small_rig() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim-small.toml"), "small").unwrap()
}

#[test]
fn measured_dark_model_and_flat_match_the_simulator_truth_within_their_noise() {
    let cfg = small_rig();
    let plan = RadiometricPlan::default_plan();
    let res = calibrate_simulated(&cfg, &plan, 7, |_| {}).unwrap();
    let t = compare_with_truth(&cfg, &res.cal, plan.flat.centre_fraction).unwrap();
    let s = &res.stats;
    eprintln!("stats {s:?}\ntruth errors {t:?}");
    // Errors against the truth are as large as the stated standard errors say (z RMS ~ 1).
    assert!((0.8..1.25).contains(&t.bias_z_rms), "{t:?}");
    assert!((0.8..1.25).contains(&t.rate_z_rms), "{t:?}");
    // Bias within ~0.2 DN (read noise 1.2 DN / sqrt(16 x 6 frames)), dark current within
    // ~1 e-/s (its floor is read noise / (sqrt(frames) t_max)).
    assert!(t.bias_rms_dn < 0.25 && t.rate_rms_e_per_s < 1.0, "{t:?}");
    // Every hot photosite found, none invented.
    assert!(t.hot_true > 0 && t.hot_found == t.hot_true && t.false_defects == 0, "{t:?}");
    // Flat: vignetting x PRNU to its shot-noise floor, < 0.3% RMS, corners included.
    assert!(t.flat_rms_rel[0] < 0.003 && t.flat_corner_rms_rel[0] < 0.004, "{t:?}");
    assert!((t.flat_rms_rel[0] / s.flats[0].sigma_rms - 1.0).abs() < 0.2, "{t:?} vs {s:?}");
    assert!(s.flats[0].min < 0.85, "the small rig's corners are vignetted: {s:?}");
}

#[test]
fn written_calibration_reads_back_identically() {
    let cfg = small_rig();
    let mut plan = RadiometricPlan::default_plan();
    plan.dark.frames = 2;
    plan.flat.frames = 2;
    plan.flat.f_numbers = vec![8.0, 11.0];
    let res = calibrate_simulated(&cfg, &plan, 1, |_| {}).unwrap();
    let dir = std::env::temp_dir().join(format!("btfrig-dark-flat-{}", std::process::id()));
    let header = write_calibration(&dir, &res, "small", &plan, 1).unwrap();
    let (back_header, back) = read_calibration(&dir).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(header, back_header);
    assert_eq!(back, res.cal);
    assert!(back.flat_for(Some(11.0)).is_ok() && back.flat_for(None).is_err());
}
