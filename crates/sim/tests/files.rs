//! Every shipped fault scenario and rig config parses, validates and builds a rig; bad
//! configs are reported all at once with field, value and allowed range.

mod common;

use btfrig_core::config::devices::DevicesConfig;
use btfrig_core::config::timing::TimingConfig;
use btfrig_core::config::RigConfig;
use btfrig_hw::TokioClock;
use btfrig_sim::{DeviceRole, FaultScenario, SimRig};
use common::*;

#[tokio::test]
async fn every_shipped_fault_scenario_parses_validates_and_builds() {
    let dir = repo_root().join("sim/faults");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let s = FaultScenario::from_toml(&text, &path.display().to_string()).unwrap_or_else(|e| panic!("{e}"));
        assert!(!s.description.is_empty(), "{} has no description", path.display());
        // It fits a rig with every device and a Dome II-sized LED array.
        let all = [
            DeviceRole::Robot,
            DeviceRole::Rail,
            DeviceRole::Turntable,
            DeviceRole::Lamp,
            DeviceRole::LedArray,
            DeviceRole::Camera,
        ];
        let mut errors = Vec::new();
        s.validate_for_rig(&all, 198, &mut errors);
        assert!(errors.is_empty(), "{}: {errors:?}", path.display());
        let cfg = devices("[led_array]\nkind = \"sim\"\n[turntable]\nkind = \"sim\"\n");
        SimRig::build(&cfg, &TimingConfig::bonn(), 1, &s, TokioClock::shared(), source())
            .unwrap_or_else(|e| panic!("{e}"));
        names.push(path.file_stem().unwrap().to_string_lossy().into_owned());
    }
    names.sort();
    for needed in ["flaky", "lamp-drift", "none", "stuck-led"] {
        assert!(names.iter().any(|n| n == needed), "sim/faults/{needed}.toml missing: {names:?}");
    }
}

#[tokio::test]
async fn every_rig_config_builds_a_sim_rig() {
    let dir = repo_root().join("rig-configs");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let cfg = RigConfig::from_toml(&text, &path.display().to_string()).unwrap_or_else(|e| panic!("{e}"));
        let d = &cfg.devices;
        let kinds =
            [Some(&d.robot), Some(&d.rail), d.turntable.as_ref(), Some(&d.lamp), d.led_array.as_ref(), Some(&d.camera)];
        if kinds.iter().flatten().any(|e| e.kind != "sim") {
            // Real backends against emulated firmware: the runner builds those rigs
            // (crates/measurement/tests/serial_rig.rs, dome.rs; the GenICam one
            // crates/genicam-backend/tests/demo.rs); the simulator alone refuses them.
            let name = path.file_name().unwrap().to_string_lossy();
            assert!(
                ["bonn-gonio-serial.toml", "bonn-dome-serial.toml", "bonn-gonio-genicam.toml"].contains(&name.as_ref()),
                "{name}: a rig config with non-sim devices that no test builds"
            );
            assert!(SimRig::from_rig_config(&cfg, &FaultScenario::none(), TokioClock::shared(), source()).is_err());
            continue;
        }
        SimRig::from_rig_config(&cfg, &FaultScenario::none(), TokioClock::shared(), source())
            .unwrap_or_else(|e| panic!("{e}"));
        count += 1;
    }
    assert!(count >= 1);
}

#[test]
fn default_rig_config_sections_equal_the_code_defaults() {
    let text = std::fs::read_to_string(repo_root().join("rig-configs/bonn-gonio-sim.toml")).unwrap();
    let cfg = RigConfig::from_toml(&text, "bonn-gonio-sim.toml").unwrap();
    assert_eq!(cfg.timing, TimingConfig::bonn());
}

#[tokio::test]
async fn all_bad_values_are_reported_at_once() {
    let devices: DevicesConfig = toml::from_str(
        "[robot]\nkind = \"sim\"\njitter_deg = [0.1, -0.2, 0.1]\njoint_min_deg = [10.0, -90.0, -360.0]\njoint_max_deg = [5.0, 90.0, 360.0]\n\
         [camera]\nkind = \"sim\"\nexposure_s = 40.0\n\
         [lamp]\nkind = \"kuka\"\n",
    )
    .unwrap();
    let mut timing = TimingConfig::bonn();
    timing.rail.settle_s = -1.0;
    let faults =
        FaultScenario::from_toml("[dropped_frames]\nprobability = 0.1\n[[timeouts]]\ndevice = \"led_array\"\n", "t")
            .unwrap();
    let err = SimRig::build(&devices, &timing, 1, &faults, TokioClock::shared(), source()).err().unwrap();
    let text = err.to_string();
    println!("{text}");
    for expected in [
        "timing.rail.settle_s = -1 is out of range: allowed [0, 3600] s",
        "devices.robot.joint_min_deg[0] = 10 is out of range: allowed below devices.robot.joint_max_deg[0] = 5",
        "devices.robot.jitter_deg[1] = -0.2 is out of range: allowed [0, 10] deg",
        "devices.lamp.kind = \"kuka\" is unknown: allowed \"sim\"",
        "devices.camera.exposure_s = 40 is out of range: allowed exposure_range_s [0.0001, 30]",
        "faults.timeouts[0].device = \"led_array\" is unknown: allowed robot, rail, lamp, camera",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }
    assert!(text.starts_with("6 problems"), "{text}");
}

#[test]
fn unknown_option_and_scenario_field_are_named() {
    let e = FaultScenario::from_toml("[[timeouts]]\ndevice = \"robot\"\nprobabilty = 0.1\n", "x.toml").unwrap_err();
    assert!(e.to_string().contains("probabilty"), "{e}");
    let e = FaultScenario::from_toml("[[timeouts]]\ndevice = \"robto\"\n", "x.toml").unwrap_err();
    assert!(e.to_string().contains("robto"), "{e}");
    let e = FaultScenario::from_toml("[dropped_frames]\nprobability = 1.5\nframes = [0]\n", "x.toml").unwrap_err();
    assert!(e.to_string().contains("faults.dropped_frames.probability = 1.5"), "{e}");
    assert!(e.to_string().contains("faults.dropped_frames.frames[0] = 0"), "{e}");
}

#[tokio::test]
async fn unknown_device_option_is_named() {
    let devices: DevicesConfig = toml::from_str("[rail]\nkind = \"sim\"\njiter_deg = 0.1\n").unwrap();
    let err = SimRig::build(&devices, &TimingConfig::bonn(), 1, &FaultScenario::none(), TokioClock::shared(), source())
        .err()
        .unwrap();
    assert!(err.to_string().starts_with("devices.rail:") && err.to_string().contains("jiter_deg"), "{err}");
}
