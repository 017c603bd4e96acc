//! A rig config naming real serial ports (`link = { port, baud }`): `btfrig hw probe --rig`
//! opens them like real controllers. Here the "hardware" is the firmware emulators on
//! pseudo-terminals this test starts itself, so the config knows nothing but device paths.

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_emulated_backend as emulated;
use btfrig_hw::{ScaledClock, SharedClock};
use btfrig_serial::firmware::grbl::{AxisDevice, GrblFirmware};
use btfrig_serial::firmware::lamp::{LampFirmware, LampFirmwareConfig};
use btfrig_serial::firmware::robot::RobotFirmware;
use btfrig_serial::grbl::AxisUnits;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig};

const SMALL: &str = include_str!("../../../rig-configs/bonn-gonio-sim-small.toml");

/// The small sim rig with robot, rail and lamp turned into serial devices on `ports`
/// (role, link table).
fn rig_with_links(links: &[(&str, toml::Table)]) -> Result<RigConfig, String> {
    let mut t: toml::Table = toml::from_str(SMALL).unwrap();
    let devices = t["devices"].as_table_mut().unwrap();
    for (role, link) in links {
        let d = devices[*role].as_table_mut().unwrap();
        d.insert("kind".into(), "serial".into());
        d.insert("link".into(), toml::Value::Table(link.clone()));
    }
    RigConfig::from_toml(&toml::to_string(&t).unwrap(), "test rig").map_err(|e| e.to_string())
}

fn link(port: &std::path::Path, baud: i64) -> toml::Table {
    let mut l = toml::Table::new();
    l.insert("port".into(), port.display().to_string().into());
    l.insert("baud".into(), baud.into());
    l
}

#[test]
fn probe_opens_the_ports_a_rig_config_names() {
    btfrig_sim_backend::install();
    let dir = std::env::temp_dir().join(format!("btfrig-real-ports-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The controllers: emulated firmware of a simulated rig, on ptys at known paths.
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let clock: SharedClock = Arc::new(ScaledClock::new(100.0).unwrap());
    let sim_cfg = RigConfig::from_toml(SMALL, "small").unwrap();
    let sim = SimRig::from_rig_config(
        &sim_cfg,
        &FaultScenario::none(),
        clock.clone(),
        Arc::new(FlatFrameSource::new(4, 4, 1.0)),
    )
    .unwrap();
    let (robot_port, rail_port, lamp_port) = (dir.join("robot"), dir.join("rail"), dir.join("lamp"));
    let firmware = {
        let _rt = rt.enter();
        (
            RobotFirmware::spawn(sim.robot, &robot_port).unwrap(),
            GrblFirmware::spawn_with_units(AxisDevice::Rail(sim.rail), &rail_port, AxisUnits::Radians).unwrap(),
            LampFirmware::spawn(sim.lamp, LampFirmwareConfig::default(), clock, &lamp_port).unwrap(),
        )
    };

    let mut rail_link = link(&rail_port, 115_200);
    rail_link.insert("units".into(), "rad".into());
    let rig =
        rig_with_links(&[("robot", link(&robot_port, 115_200)), ("rail", rail_link), ("lamp", link(&lamp_port, 9600))])
            .unwrap();
    let probed = btfrig_sim_backend::probe(&rig).unwrap();
    for p in &probed {
        println!("{:<6} {:<6} {:?} {:?}: {}", p.role, p.kind, p.link, p.info, p.health);
    }
    let get = |role: &str| probed.iter().find(|p| p.role == role).unwrap_or_else(|| panic!("{role} not probed"));
    for (role, port, baud) in
        [("robot", &robot_port, 115_200), ("rail", &rail_port, 115_200), ("lamp", &lamp_port, 9600)]
    {
        let p = get(role);
        assert_eq!(p.kind, "serial");
        assert_eq!(p.link.as_deref(), Some(format!("{} at {baud} baud", port.display()).as_str()));
        assert_eq!(p.health, "Ok", "{role}: {p:?}");
    }
    // The robot controller said who it is; the simulated camera answered as itself.
    assert!(!get("robot").info.model.is_empty() && get("robot").info.serial.is_some(), "{:?}", get("robot"));
    assert_eq!(get("camera").kind, "sim");

    // Homing state: the emulated robot and rail start unhomed; probing moved nothing.
    assert_eq!(get("robot").homed, Some(false), "{:?}", get("robot"));
    assert!(probed.iter().all(|p| p.failure.is_none()), "{probed:?}");
    // A run accepts real controllers now (on the wall clock, after preflight).
    emulated::check(&rig.devices).unwrap();

    // A port with nothing behind it fails that device, naming the port; the others still answer.
    let rig =
        rig_with_links(&[("robot", link(&dir.join("unplugged"), 115_200)), ("lamp", link(&lamp_port, 9600))]).unwrap();
    let probed = btfrig_sim_backend::probe(&rig).unwrap();
    let robot = probed.iter().find(|p| p.role == "robot").unwrap();
    let failure = robot.failure.as_deref().unwrap_or_default();
    assert!(failure.contains("unplugged") && failure.contains("No such file"), "{robot:?}");
    assert_eq!(robot.link.as_deref(), Some(format!("{} at 115200 baud", dir.join("unplugged").display()).as_str()));
    let lamp = probed.iter().find(|p| p.role == "lamp").unwrap();
    assert!(lamp.failure.is_none() && lamp.health == "Ok", "{lamp:?}");

    drop(firmware);
    drop(rt);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_link_options_are_named() {
    btfrig_sim_backend::install();
    let port = std::path::Path::new("/dev/ttyUSB0");
    let cases: [(toml::Table, &str); 4] = [
        (link(port, 12_345), "devices.robot.link.baud = 12345 is not a supported rate: allowed 1200,"),
        (
            {
                let mut l = link(port, 115_200);
                l.insert("emulated".into(), true.into());
                l
            },
            "devices.robot.link: emulated = true and a port/baud",
        ),
        (
            {
                let mut l = toml::Table::new();
                l.insert("baud".into(), 115_200.into());
                l
            },
            "devices.robot.link.port is missing",
        ),
        (
            {
                let mut l = link(port, 115_200);
                l.insert("parity".into(), "even".into());
                l
            },
            "devices.robot.link.parity is unknown: allowed emulated, poll_s, reply_timeout_ms, port, baud",
        ),
    ];
    for (l, want) in cases {
        let rig = rig_with_links(&[("robot", l)]).unwrap();
        let e = emulated::check_probe(&rig.devices).unwrap_err();
        assert!(e.starts_with(want), "{e}\nwanted: {want}");
    }
}

/// A mixed bench rig: robot, rail and lamp are "real" controllers on the ports the rig
/// config names (firmware on ptys this test starts, in front of devices of its own on a
/// clock 100x faster than the wall), the camera is simulated. `run` checks the controllers
/// first, runs on the wall clock and records it, with each controller's identity.
#[test]
fn a_run_drives_real_controllers_on_the_wall_clock() {
    btfrig_sim_backend::install();
    let dir = std::env::temp_dir().join(format!("btfrig-real-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let clock: SharedClock = Arc::new(ScaledClock::new(100.0).unwrap());
    let mut sim_cfg = RigConfig::from_toml(SMALL, "small").unwrap();
    // The lamp controller reports its warm-up and the run waits it out on the wall clock.
    sim_cfg.timing.lamp.warm_up_s = 1.0;
    let sim = SimRig::from_rig_config(
        &sim_cfg,
        &FaultScenario::none(),
        clock.clone(),
        Arc::new(FlatFrameSource::new(4, 4, 1.0)),
    )
    .unwrap();
    let (robot_port, rail_port, lamp_port) = (dir.join("robot"), dir.join("rail"), dir.join("lamp"));
    let firmware = {
        let _rt = rt.enter();
        (
            RobotFirmware::spawn(sim.robot, &robot_port).unwrap(),
            GrblFirmware::spawn_with_units(AxisDevice::Rail(sim.rail), &rail_port, AxisUnits::Radians).unwrap(),
            LampFirmware::spawn(sim.lamp, LampFirmwareConfig::default(), clock, &lamp_port).unwrap(),
        )
    };
    let mut rail_link = link(&rail_port, 115_200);
    rail_link.insert("units".into(), "rad".into());
    let rig =
        rig_with_links(&[("robot", link(&robot_port, 115_200)), ("rail", rail_link), ("lamp", link(&lamp_port, 9600))])
            .unwrap();
    assert_eq!(btfrig_measurement::backend::RigTime::for_rig(&rig), btfrig_measurement::backend::RigTime::Wall);
    let mut t: toml::Table = toml::from_str(SMALL).unwrap();
    t["devices"] = toml::Value::try_from(&rig.devices).unwrap();
    // The simulated camera's 12 MB transfer would take 5 s per frame on the wall clock.
    t["timing"]["camera"]["frame_bytes"] = 38_400.into();
    std::fs::write(dir.join("rig.toml"), toml::to_string(&t).unwrap()).unwrap();
    let plan = include_str!("../../../tests/data/tiny-plan.toml")
        .replace("SEED", "5")
        .replace("FAULTS", "none")
        .replace("builtin:bonn-gonio-sim", "rig.toml")
        .replace("max_captures = 12", "max_captures = 2")
        // The simulated camera sees the simulated world, where nothing the real controllers do
        // happens (its stand-in lamp stays dark): no markers to register.
        .replace("[exposure]", "[registration]\nmethod = \"nominal\"\n[exposure]")
        // ... and a dark frame would drive an automatic exposure to its longest.
        .replace("mode = \"auto\"", "mode = \"fixed\"\nexposure_s = 0.01");
    assert!(plan.contains("max_captures = 2"), "{plan}");
    let out = dir.join("dataset");
    let req = btfrig_measurement::RunRequest::from_text(plan, &dir.join("plan.toml"), &out);
    let s = btfrig_measurement::run(&req, &btfrig_measurement::RunControl::new(), &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.outcome, btfrig_measurement::RunOutcome::Finished, "{s:?}");
    assert_eq!(s.captures, 2);
    assert_eq!(s.rig_time, Some(btfrig_measurement::backend::RigTime::Wall));
    // Preflight asked the real robot who it is and found it unhomed; the run homed it.
    let pre = s.preflight.iter().find(|d| d.role == "robot").unwrap();
    assert!(pre.failure.is_none() && pre.identity.as_ref().is_some_and(|i| i.serial.is_some()), "{pre:?}");
    assert_eq!(pre.port.as_deref(), Some(format!("{} at 115200 baud", robot_port.display()).as_str()));
    let robot = s.devices.iter().find(|(r, _)| *r == "robot").unwrap();
    assert_eq!(robot.1.backend, "serial-robot");
    assert_eq!(s.devices.iter().find(|(r, _)| *r == "camera").unwrap().1.backend, "sim");
    // The links are the real ports at their own baud rates.
    let lamp = s.links.iter().find(|l| l.role == "lamp").unwrap();
    assert_eq!(lamp.target, format!("{} at 9600 baud", lamp_port.display()));
    eprintln!("mixed rig: {:.2} s wall, {:.2} s rig time, links {:?}", s.wall_s, s.hardware_s, s.links);
    drop(firmware);
    drop(rt);
    let _ = std::fs::remove_dir_all(&dir);
}
