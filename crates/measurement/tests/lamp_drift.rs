//! Lamp drift on the simulated rig: a run whose lamp warms up and drifts by about 5 % is
//! corrected by the lamp factor measured on the holder plate in every frame, against the light
//! calibration (white tile) made before; the brightness of every texture is compared with the
//! ground truth at the NOMINAL (calibrated) lamp.

use std::path::{Path, PathBuf};

use btfrig_calibrate::light::{LightPlan, LAMP};
use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest};
use btfrig_process::light::{LampReference, LampTotals, LightCorrection};
use btfrig_sim_calibration::light::calibrate_light_simulated;

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("lamp-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// 12 captures up to theta 30 deg, 32-texel textures (the runner tests' tiny plan).
const PLAN: &str = r#"
name = "lamp-drift"
[rig]
config = "builtin:bonn-gonio-sim"
material = "lacquered-wood"
seed = 5
[sampling]
light = { preset = "bonn81", theta_max_deg = 30 }
view = { preset = "bonn81", theta_max_deg = 30 }
[texture]
size = 32
region = { u = [0.25, 0.75], v = [0.25, 0.75] }
[exposure]
mode = "auto"
[skip]
max_captures = 12
"#;

/// An HMI lamp whose warm-up is not quite over when the run starts (the rig waits its nominal
/// 180 s; this lamp's time constant is 60 s: 0.5 % missing at the start) and that then loses 2.6
/// per hour (4.3 % per minute): about 5 % over the run's 70 s of rig time.
const DRIFT: &str = r#"
description = "HMI lamp: warm-up not quite finished, then a fast drift"
[lamp_drift]
start_fraction = 0.9
warm_up_tau_s = 60.0
drift_per_hour = -2.6
drift_delay_s = 180.0
"#;

fn run_one(name: &str, faults: Option<&str>, light: Option<LightCorrection>) -> (f64, LampTotals) {
    let dir = scratch(name);
    let faults = faults.map(|text| {
        let f = dir.join("faults.toml");
        std::fs::write(&f, text).unwrap();
        f.display().to_string()
    });
    let req = RunRequest::from_text(PLAN, &dir.join("plan.toml"), &dir.join("dataset"))
        .with_faults(faults.or(Some("none".into())))
        .with_light(light);
    let s = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(s.outcome, RunOutcome::Finished);
    assert_eq!(s.captures, 12);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dataset/report.json")).unwrap()).unwrap();
    // Per-step factors in the report with a light calibration; the brightness figure always.
    let steps = if req.light.is_some() { 12 } else { 0 };
    assert!(report["lamp"]["steps"].as_array().is_some_and(|a| a.len() == steps), "{}", report["lamp"]);
    assert!(report["lamp"]["brightness_err_abs_max"].as_f64().is_some(), "{}", report["lamp"]);
    // The manifest records the calibrations the frames were processed with.
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dataset/manifest.json")).unwrap()).unwrap();
    let cal = &manifest["calibration"];
    assert_eq!(cal["geometry"], "builtin:bonn-gonio-sim-geometry", "{cal}");
    assert_eq!(cal["color"]["reference"], "builtin:bonn-gonio-sim-color", "{cal}");
    assert!(cal["color"]["held_out_delta_e00_mean"].as_f64().is_some_and(|d| d > 0.0 && d < 1.5), "{cal}");
    match &req.light {
        Some(l) => {
            assert_eq!(cal["light"]["light"], l.reference.light.as_str(), "{cal}");
            assert_eq!(cal["light"]["drift_corrected"], l.correct_drift, "{cal}");
        }
        None => assert!(cal["light"].is_null(), "{cal}"),
    }
    (s.hardware_s, s.lamp.expect("a simulated run measures brightness"))
}

/// Per (light, view): the lamp factor (if measured) and the brightness error.
type Steps = std::collections::BTreeMap<(u32, u32), (Option<[f64; 3]>, f64)>;

fn by_step(t: &LampTotals) -> Steps {
    t.steps
        .iter()
        .map(|s| ((s.step.light, s.step.view), (s.factor.map(|f| f.factor), s.brightness_err.unwrap())))
        .collect()
}

#[test]
fn a_drifting_lamp_is_corrected_to_under_half_a_percent() {
    btfrig_sim_backend::install();
    let (_, cfg_text) = BUILTIN_RIGS.iter().find(|(n, _)| *n == btfrig_core::plan::BUILTIN_RIG).unwrap();
    let cfg = RigConfig::from_toml(cfg_text, "builtin rig").unwrap();
    let cal = calibrate_light_simulated(&cfg, &LightPlan::default_plan(), 3).unwrap();
    let e = cal.file.light(LAMP).unwrap();
    let light = LightCorrection::new(LampReference {
        light: LAMP.into(),
        white_rate: e.white_rate_e_per_s,
        plate_albedo: e.plate_albedo,
    });

    // Same seed: the same poses and noise draws; only the lamp differs between the runs.
    let (_, steady) = run_one("steady", None, Some(light.clone()));
    let (hw_s, raw) = run_one("raw", Some(DRIFT), None);
    let (_, fixed) = run_one("fixed", Some(DRIFT), Some(light.clone()));
    let (steady, raw_s, fixed_s) = (by_step(&steady), by_step(&raw), by_step(&fixed));

    let mut worst = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (k, (f0, b0)) in &steady {
        let (_, b_raw) = raw_s[k];
        let (f, b_fix) = fixed_s[k];
        let (f0, f) = (f0.unwrap(), f.unwrap());
        println!(
            "step {k:?}: steady factor {:.5} err {:+.4} %; drifting: uncorrected err {:+.4} %, factor {:.5}, corrected err {:+.4} %",
            f0[1],
            100.0 * b0,
            100.0 * b_raw,
            f[1],
            100.0 * b_fix
        );
        worst.0 = worst.0.max(f0.iter().map(|v| (v - 1.0).abs()).fold(0.0, f64::max));
        worst.1 = worst.1.max((b_raw - b0).abs());
        worst.2 = worst.2.max((b_fix - b0).abs());
        worst.3 = worst.3.max(b_fix.abs());
    }
    println!(
        "run {hw_s:.0} s of rig time; steady lamp: max |factor - 1| {:.4} %; drifting: max brightness change {:.3} % \
         uncorrected, {:.4} % corrected (absolute corrected error {:.4} %); uncorrected range {:?}, factor range {:?}",
        100.0 * worst.0,
        100.0 * worst.1,
        100.0 * worst.2,
        100.0 * worst.3,
        (raw.brightness_err_min, raw.brightness_err_max),
        fixed.factor_range()
    );
    // A constant lamp is not "corrected": factors 1 within noise.
    assert!(worst.0 < 2e-3, "steady lamp factor off by {}", worst.0);
    // The drift shows without correction (about 5 % between first and last frame)...
    assert!(raw.brightness_err_max - raw.brightness_err_min > 0.03, "{raw:?}");
    assert!(worst.1 > 0.03, "{worst:?}");
    // ...and is gone with it: under 0.5 % per frame (the issue's acceptance). The residual is
    // measured against the same capture under a constant lamp: what is left of the texture's
    // brightness error against the nominal-lamp truth then is the pipeline's error without any
    // drift (2.4 to 3.3 % here: the colour matrix fitted on the ColorChecker and this
    // material's spectra, issue 5's colour part), the same in both runs.
    assert!(worst.2 < 5e-3, "residual {}", worst.2);
    assert!(worst.3 < worst.2 + 0.04, "absolute {}", worst.3);
}
