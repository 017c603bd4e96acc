//! Whole camera-array runs on the simulated camera array (rig-configs/bonn-camera-array-sim.toml:
//! 151 cameras whose flashes are the lights) through the dome planner, engine, pipeline and
//! store, checked against the simulator's ground truth.

use std::path::{Path, PathBuf};

use btfrig_measurement::dome::{run, DomeRunRequest, DomeRunSummary};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("btfrig-camera-array-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// One camera (the first of the 37.5 degree ring) under all 151 flashes: 151 pattern frames
/// plus (by default) 4 single-flash reference frames.
fn plan(extra: &str) -> String {
    // The leather's mean brightness on the sample's photosites relative to white, measured
    // (docs/multiplexing.md): what the noise model's prediction is for.
    let brightness = if extra.contains("sample_brightness") { "" } else { "sample_brightness = 0.1\n" };
    format!(
        "name = \"camera-array-test\"\ntexture_size = 16\n[rig]\nconfig = \"builtin:bonn-camera-array-sim\"\nmaterial = \"leather\"\n\
         [dome]\ncameras = [31]\nexposure_s = 0.01\n{brightness}{extra}"
    )
}

fn go(text: String, out: &Path) -> DomeRunSummary {
    let req = DomeRunRequest {
        plan_text: text,
        plan_path: PathBuf::from("<test>"),
        out: out.to_path_buf(),
        faults: None,
        preview: false,
        compressed_model: None,
    };
    run(&req, &mut |line| eprintln!("{line}")).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn a_camera_array_run_multiplexes_all_151_flashes_and_beats_single_flash_frames() {
    btfrig_sim_backend::install();
    let out = tmp("whole");
    let s = go(plan(""), &out);
    eprintln!("{}", s.to_json());
    assert_eq!((s.rig_kind, s.light), ("camera_array", "flash"));
    // Paley 151: every flash is a column, no always-off slot.
    assert_eq!(s.mode, "s-matrix 151");
    assert!(s.multiplex_reason.starts_with("multiplexing with s-matrix 151"), "{}", s.multiplex_reason);
    assert_eq!((s.textures, s.frames, s.leds, s.views), (151, 155, 151, 1));
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    // Measured against noise-free renders, the gain agrees with the noise model.
    let (p, m) = (s.multiplex_gain_predicted, s.multiplex_gain_measured.unwrap());
    assert!(p > 1.5 && (m / p - 1.0).abs() < 0.15, "predicted {p}, measured {m}");
    // The reference flashes' textures: demultiplexed closer to the truth than single-flash frames.
    let (mux, single) = (s.reference_mux_texture_rel_rmse.unwrap(), s.reference_texture_rel_rmse.unwrap());
    assert!(mux < 0.8 * single, "demultiplexed {mux} vs single-flash {single}");
    // Single flashes would average G² frames each for the same SNR.
    assert!((s.time_saved_fraction - (1.0 - 1.0 / (p * p))).abs() < 1e-9, "{}", s.time_saved_fraction);
    // 155 frames at 10 ms: the exposure is a small part of the rig time (flash recycle, read-out).
    assert!((s.exposure_time_s - 1.55).abs() < 1e-9, "{}", s.exposure_time_s);
    let report = btfrig_store::verify(&out);
    assert!(report.is_ok(), "{report:?}");
    // Stored with light = flash index, view = camera index (one rotation).
    let info = btfrig_store::info(&out).unwrap();
    let sm = &info.manifest.samplings;
    assert_eq!((sm.light.len(), sm.view.len(), info.done), (151, 151, 151));
    let pairs = sm.pairs.as_ref().unwrap();
    assert!(pairs.iter().all(|p| p.view == 31) && pairs.iter().map(|p| p.light).eq(0..151));
    // Camera 31 sits at theta 37.5, phi 0; its own flash is 4 cm above it, a few degrees off.
    let (v, l) = (sm.view[31], sm.light[31]);
    assert!((v.theta_deg - 37.5).abs() < 1e-6, "{v:?}");
    assert!((l.theta_deg - v.theta_deg).abs() > 1.0 && (l.theta_deg - v.theta_deg).abs() < 4.0, "{l:?} vs {v:?}");
    let _ = std::fs::remove_dir_all(&out);
}

/// The shipped array with each flash `factor` times brighter, written to `dir` with its flash
/// calibration (the shipped one with `reference_rate` times `factor`: a flash's signal is
/// linear in its energy, and a lab that turns its flashes up calibrates them again, or the
/// planner and the pipeline take them for the dim ones); the rig file's path.
fn brighter_array(dir: &Path, factor: f64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../rig-configs/bonn-camera-array-sim.toml"),
    )
    .unwrap();
    let cfg = btfrig_core::config::RigConfig::from_toml(&shipped, "bonn-camera-array-sim").unwrap();
    let mut flashes = btfrig_calibrate::leds::processing_leds(&cfg, None).unwrap().unwrap();
    flashes.reference_rate *= factor;
    std::fs::write(dir.join("bright-flashes.toml"), flashes.to_toml()).unwrap();
    let nominal = cfg.dome.as_ref().unwrap().nominal_signal_e_per_s.unwrap();
    let bright = shipped
        .replace("energy_at_1m_j_m2 = 1.2e-4", &format!("energy_at_1m_j_m2 = {:e}", 1.2e-4 * factor))
        .replace(
            "led_calibration = \"builtin:bonn-camera-array-sim-flashes\"",
            "led_calibration = \"bright-flashes.toml\"",
        )
        .replace(
            &format!("nominal_signal_e_per_s = {nominal}"),
            &format!("nominal_signal_e_per_s = {}", nominal * factor),
        );
    assert_eq!(bright.matches("bright-flashes.toml").count(), 1);
    assert!(bright.contains(&format!("nominal_signal_e_per_s = {}", nominal * factor)));
    let rig = dir.join("bright-array.toml");
    std::fs::write(&rig, bright).unwrap();
    rig
}

#[test]
fn bright_flashes_are_captured_one_at_a_time_which_is_the_better_mode() {
    btfrig_sim_backend::install();
    // Flashes 4x brighter and a white sample: about 360 e- per flash facing the sample, 225 e-
    // at the flashes' mean cos θ (0.63), against 12 e- read noise: photon-noise dominated (σ_p²/κ²
    // about 1.6), and 76 flashes still fit the well (a
    // brighter flash would make the forced S-matrix saturation-limited instead). The sample
    // is white as the plan's estimate says.
    let dir = tmp("bright");
    let rig = brighter_array(&dir, 4.0);
    let white = dir.join("white.toml");
    std::fs::write(
        &white,
        "name = \"white\"\ntexels = 64\nseed = 1\nbasis = [\"flat:0.95\"]\n[albedo]\n\
         pattern = { kind = \"noise\", scale_m = 0.005, octaves = 1, gain = 0.5, salt = 1 }\nstops = [[1.0], [1.0]]\n",
    )
    .unwrap();
    let with_rig = |extra: &str| {
        plan(&format!("sample_brightness = 1.0\n{extra}"))
            .replace("builtin:bonn-camera-array-sim", &rig.display().to_string())
            .replace("material = \"leather\"", &format!("material = \"{}\"", white.display()))
    };
    let s = go(with_rig(""), &dir.join("auto"));
    assert_eq!(s.mode, "single-light");
    assert!(s.multiplex_reason.starts_with("multiplexing skipped: photon-noise dominated"), "{}", s.multiplex_reason);
    assert_eq!((s.textures, s.frames), (151, 151));
    assert!(s.multiplex_gain_measured.is_none() && s.time_saved_fraction == 0.0);
    assert!(btfrig_store::verify(&dir.join("auto")).is_ok());
    // Forcing the S-matrix measures what the planner avoided: a loss.
    let forced = go(with_rig("multiplex = \"on\"\n"), &dir.join("on"));
    let (p, m) = (forced.multiplex_gain_predicted, forced.multiplex_gain_measured.unwrap());
    eprintln!("forced s-matrix 151, photon-noise dominated: predicted {p}, measured {m}");
    // Measured 0.944 against 0.893 (the model with each flash's cos θ is within 6 % in every
    // dome and camera-array case, docs/multiplexing.md); every flash taken as facing the
    // sample predicts 0.834, 13 % off, which this bound catches.
    assert!(p < 1.0 && m < 1.0 && (m / p - 1.0).abs() < 0.10, "predicted {p}, measured {m}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_saturating_pattern_fires_the_flashes_at_reduced_power() {
    btfrig_sim_backend::install();
    // Flashes 300x brighter: 76 of them would overfill the well, and a shorter exposure would
    // not dim a flash, so the forced S-matrix fires them at a few percent of their power; the
    // demultiplexer divides that power out again and the gain is the (poor) predicted one.
    let dir = tmp("saturating");
    let rig = brighter_array(&dir, 300.0);
    let text = plan("multiplex = \"on\"\n").replace("builtin:bonn-camera-array-sim", &rig.display().to_string());
    let s = go(text, &dir.join("on"));
    let (p, m) = (s.multiplex_gain_predicted, s.multiplex_gain_measured.unwrap());
    eprintln!("forced s-matrix 151, saturation-limited: predicted {p}, measured {m}");
    assert!(p < 0.2 && (m / p - 1.0).abs() < 0.2, "predicted {p}, measured {m}");
    // Textures keep their scale: the demultiplexed reference flashes are as close to the
    // truth as a gain of {m} allows, not off by the power cut.
    let (mux, single) = (s.reference_mux_texture_rel_rmse.unwrap(), s.reference_texture_rel_rmse.unwrap());
    assert!(mux < 1.0 && mux > single, "demultiplexed {mux} vs single-flash {single}");
    let _ = std::fs::remove_dir_all(&dir);
}
