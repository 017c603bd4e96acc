//! The LED calibration of the simulated dome against the simulator's true LED powers and
//! colours, and its file's round trip.

use btfrig_calibrate::leds::LedCalibrationFile;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_sim_calibration::leds::{calibrate_leds_simulated, SimLedOptions};

fn rig(name: &str) -> RigConfig {
    let (_, text) = BUILTIN_RIGS.iter().find(|(n, _)| *n == name).expect("an embedded rig");
    RigConfig::from_toml(text, name).expect("a valid rig")
}

fn rms_pct(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |a, x| (a.0 + x * x, a.1 + 1));
    100.0 * (s / n as f64).sqrt()
}

#[test]
fn the_dome_led_calibration_recovers_the_true_powers_and_colours_and_round_trips() {
    let cfg = rig("builtin:bonn-dome-sim");
    let r = calibrate_leds_simulated(&cfg, None, &SimLedOptions::new(&cfg, 7)).unwrap();
    let f = &r.file;
    assert_eq!(f.leds.len(), 198);
    // The true powers spread 10 % RMS; the fit recovers each to a few tenths of a percent.
    let spread = rms_pct(r.true_power.iter().map(|p| p - 1.0));
    let power = rms_pct(f.leds.iter().zip(&r.true_power).map(|(e, t)| e.power / t - 1.0));
    let colour = rms_pct(
        f.leds.iter().zip(&r.true_colour).flat_map(|(e, t)| [e.colour[0] / t[0] - 1.0, e.colour[2] / t[2] - 1.0]),
    );
    let reference = 100.0 * (f.reference_rate / r.true_reference_rate - 1.0);
    eprintln!(
        "spread {spread:.2} %, power error {power:.3} %, colour error {colour:.3} %, reference {reference:+.3} %"
    );
    assert!(spread > 5.0, "{spread}");
    assert!(power < 0.5, "power RMS error {power} %");
    assert!(colour < 0.5, "colour RMS error {colour} %");
    assert!(reference.abs() < 1.0, "reference error {reference} %");
    // Each stated uncertainty is the size of the actual error (within 5 sigma).
    for (j, (e, t)) in f.leds.iter().zip(&r.true_power).enumerate() {
        assert!(
            (e.power - t).abs() < 5.0 * e.power_sigma.max(1e-4),
            "LED {j}: {} vs {t} +- {}",
            e.power,
            e.power_sigma
        );
    }
    let back = LedCalibrationFile::from_toml(&f.to_toml(), "<round trip>").unwrap();
    assert_eq!(&back, f);
}

#[test]
fn an_led_calibration_of_the_wrong_size_or_with_a_bad_value_is_refused_naming_the_field() {
    let cfg = rig("builtin:bonn-dome-sim");
    let file = btfrig_calibrate::leds::processing_leds(&cfg, None).unwrap().expect("the rig names one");
    let mut short = file.clone();
    short.leds.truncate(10);
    let dir = std::env::temp_dir().join(format!("btfrig-leds-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("short.toml"), short.to_toml()).unwrap();
    let mut c = cfg.clone();
    c.dome.as_mut().unwrap().led_calibration = Some("short.toml".into());
    let e = btfrig_calibrate::leds::processing_leds(&c, Some(&dir.join("rig.toml"))).unwrap_err().to_string();
    assert!(e.contains("led_calibration") && e.contains("calibrates 10 lights") && e.contains("198"), "{e}");
    let bad = file.to_toml().replacen("power = ", "power = -", 1);
    let e = LedCalibrationFile::from_toml(&bad, "bad.toml").unwrap_err().to_string();
    assert!(e.contains("bad.toml") && e.contains("leds[0].power") && e.contains("> 0"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
