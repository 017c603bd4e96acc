//! The robot backend against the emulated robot controller on a real pseudo-terminal,
//! driving the simulator's robot. Faults at deterministic points (no timing).

use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::{devices::DevicesConfig, timing::TimingConfig};
use btfrig_hw::{Device, ErrorKind, MoveOptions, Robot, ScaledClock, SharedClock};
use btfrig_serial::firmware::robot::{Fault, RobotFirmware};
use btfrig_serial::robot::{SerialRobot, SerialRobotConfig};
use btfrig_serial::transport::SerialConnector;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig, SimWorld};

struct Bench {
    robot: SerialRobot,
    firmware: RobotFirmware,
    world: SimWorld,
    clock: SharedClock,
    dir: std::path::PathBuf,
}

impl Drop for Bench {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn bench(name: &str) -> Bench {
    let clock: SharedClock = Arc::new(ScaledClock::new(100.0).unwrap());
    let source = Arc::new(FlatFrameSource::new(4, 4, 100.0));
    let rig = SimRig::build(
        &DevicesConfig::default(),
        &TimingConfig::bonn(),
        11,
        &FaultScenario::none(),
        clock.clone(),
        source,
    )
    .unwrap();
    let dir = std::env::temp_dir().join(format!("btfrig-robot-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("robot");
    let joint_limits = rig.robot.joint_limits();
    let firmware = RobotFirmware::spawn(rig.robot, &link).unwrap();
    let cfg =
        SerialRobotConfig { name: "robot".into(), joint_limits, poll_s: 0.05, reply_timeout: Duration::from_secs(2) };
    let connector = Arc::new(SerialConnector { path: link.to_string_lossy().into_owned(), baud: 115_200 });
    Bench { robot: SerialRobot::new(cfg, connector, clock.clone()), firmware, world: rig.world, clock, dir }
}

const OPTS: MoveOptions = MoveOptions { timeout_s: 300.0 };

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exact_targets_errors_and_garbage() {
    let mut b = bench("moves");
    assert_eq!(b.robot.move_to_rad([0.1, 0.0, 0.0], OPTS).await.unwrap_err().kind(), ErrorKind::NotHomed);
    assert!(!b.robot.is_homed().await.unwrap());
    b.robot.home(OPTS).await.unwrap();
    let target = [30f64.to_radians(), -1.0 / 3.0, std::f64::consts::PI];
    b.firmware.inject(Fault::Garbage(b"\xff\x00junk*ZZ\n7 OK*00\n".to_vec()));
    let got = b.robot.move_to_rad(target, OPTS).await.unwrap();
    // Radians cross the wire bit for bit: the simulator was commanded exactly the target.
    assert_eq!(got, target);
    assert_eq!(b.world.commanded().robot, target);
    assert_eq!(b.robot.skipped_lines(), 2, "two garbage lines skipped");
    // An inverse-kinematics residue (cos(pi/2)-sized) crosses exactly too, not as 0.
    let tiny = [15f64.to_radians(), -4.163_336_342_344_337_6e-17, 60f64.to_radians()];
    assert_eq!(b.robot.move_to_rad(tiny, OPTS).await.unwrap(), tiny);
    assert_eq!(b.world.commanded().robot, tiny);
    let e = b.robot.move_to_rad([0.0, 2.0, 0.0], OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::OutOfRange, "{e}");
    assert!(e.to_string().contains("joint 1"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unplugged_mid_move_then_resumed() {
    let mut b = bench("unplug");
    b.robot.home(OPTS).await.unwrap();
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::Unplug)));
    let target = [1.0, 0.5, -2.0];
    let e = b.robot.move_to_rad(target, OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
    // The engine's policy: reconnect, re-issue; Busy (the first move still running) retried.
    b.robot.reconnect().await.unwrap();
    let mut attempts = 0;
    let got = loop {
        match b.robot.move_to_rad(target, OPTS).await {
            Ok(j) => break j,
            Err(e) if e.kind() == ErrorKind::Busy && attempts < 100 => {
                attempts += 1;
                b.clock.sleep_s(0.5).await;
            }
            Err(e) => panic!("{e}"),
        }
    };
    assert_eq!(got, target);
    assert_eq!(b.robot.connects(), 2);
    let truth = b.world.truth().joints.robot;
    assert!((0..3).all(|i| (truth[i] - target[i]).abs() < 0.01), "{truth:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn drive_fault_is_clear_and_not_retryable() {
    let mut b = bench("fault");
    b.robot.home(OPTS).await.unwrap();
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::DriveFault)));
    let e = b.robot.move_to_rad([0.2, 0.1, 0.0], OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Other);
    assert!(!e.is_retryable());
    assert!(e.to_string().contains("drive fault"), "{e}");
    let e = b.robot.move_to_rad([0.2, 0.1, 0.0], OPTS).await.unwrap_err();
    assert!(e.to_string().contains("ERR 21"), "{e}");
    assert!(matches!(b.robot.health().await.unwrap(), btfrig_hw::Health::Fault(_)));
}
