//! The GRBL backend against the emulated controller on a real pseudo-terminal: the
//! backend opens the tty with the `serialport` crate; the controller drives the
//! simulator's rail. Faults are injected at deterministic points (no timing).

use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::{devices::DevicesConfig, timing::TimingConfig};
use btfrig_hw::{Device, ErrorKind, MoveOptions, Rail, ScaledClock, SharedClock};
use btfrig_protocols::grbl::Axis;
use btfrig_serial::firmware::grbl::{AxisDevice, Fault, GrblFirmware};
use btfrig_serial::grbl::{AxisUnits, GrblAxis, GrblAxisConfig};
use btfrig_serial::transport::SerialConnector;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig, SimWorld};

/// Rig time runs 100x wall time, so a 30 s homing cycle takes 0.3 s.
const SPEED: f64 = 100.0;

struct Bench {
    axis: GrblAxis,
    firmware: GrblFirmware,
    world: SimWorld,
    clock: SharedClock,
    _dir: TempDir,
}

struct TempDir(std::path::PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn bench(name: &str) -> Bench {
    bench_in(name, AxisUnits::Degrees)
}

fn bench_in(name: &str, units: AxisUnits) -> Bench {
    let clock: SharedClock = Arc::new(ScaledClock::new(SPEED).unwrap());
    let source = Arc::new(FlatFrameSource::new(4, 4, 100.0));
    let rig = SimRig::build(
        &DevicesConfig::default(),
        &TimingConfig::bonn(),
        7,
        &FaultScenario::none(),
        clock.clone(),
        source,
    )
    .unwrap();
    let dir = std::env::temp_dir().join(format!("btfrig-grbl-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("rail");
    let limits = rig.rail.limits();
    let firmware = GrblFirmware::spawn_with_units(AxisDevice::Rail(rig.rail), &link, units).unwrap();
    let cfg = GrblAxisConfig {
        name: "rail".into(),
        model: "emulated GRBL".into(),
        axis: Axis::X,
        limits,
        poll_s: 0.05,
        reply_timeout: Duration::from_secs(2),
        units,
    };
    let connector = Arc::new(SerialConnector { path: link.to_string_lossy().into_owned(), baud: 115_200 });
    Bench { axis: GrblAxis::new(cfg, connector, clock.clone()), firmware, world: rig.world, clock, _dir: TempDir(dir) }
}

/// What the run engine does with a failed call: retry a retryable error (after
/// `reconnect` for `Disconnected`), at most 20 times; give up on the rest.
macro_rules! retried {
    ($b:expr, $call:expr) => {{
        let mut attempts = 0;
        loop {
            match $call {
                Ok(v) => break Ok(v),
                Err(e) if e.is_retryable() && attempts < 20 => {
                    attempts += 1;
                    if e.kind() == ErrorKind::Disconnected {
                        let _ = $b.axis.reconnect().await;
                    }
                    $b.clock.sleep_s(0.5).await;
                }
                Err(e) => break Err(e),
            }
        }
    }};
}

const OPTS: MoveOptions = MoveOptions { timeout_s: 120.0 };

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn moves_and_soft_limits_through_a_real_tty() {
    let mut b = bench("moves");
    // Before homing the controller is locked: error:9 -> NotHomed.
    let e = b.axis.move_to_rad(0.5, OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::NotHomed, "{e}");
    b.axis.home(OPTS).await.unwrap();
    let target = 45f64.to_radians();
    let reported = b.axis.move_to_rad(target, OPTS).await.unwrap();
    assert!((reported - target).abs() < 1e-12, "{reported}");
    assert!((b.axis.position_rad().await.unwrap() - target).abs() < 1e-12);
    // The simulated rail truly went there (within its positioning error).
    let truth = b.world.truth().joints.rail;
    assert!((truth - target).abs() < 1f64.to_radians(), "true rail {truth}");
    // Beyond travel: ALARM:2 (soft limit) -> OutOfRange, not retryable; the backend
    // unlocks, so the next move works and the position was kept.
    let e = b.axis.move_to_rad(200f64.to_radians(), OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::OutOfRange, "{e}");
    assert!(e.to_string().contains("ALARM:2"), "{e}");
    assert!((b.axis.position_rad().await.unwrap() - target).abs() < 1e-12);
    b.axis.move_to_rad(10f64.to_radians(), OPTS).await.unwrap();
    assert_eq!(b.axis.connects(), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn port_closed_mid_move_reconnects_and_resumes() {
    let mut b = bench("unplug");
    b.axis.home(OPTS).await.unwrap();
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::Unplug)));
    let target = 120f64.to_radians();
    let e = b.axis.move_to_rad(target, OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
    assert!(e.is_retryable());
    // The engine's policy: reconnect, then issue the same move again.
    let reported = retried!(b, b.axis.move_to_rad(target, OPTS).await).unwrap();
    assert!((reported - target).abs() < 1e-12);
    assert!(b.axis.connects() >= 2, "reopened the port");
    let truth = b.world.truth().joints.rail;
    assert!((truth - target).abs() < 1f64.to_radians(), "true rail {truth}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_on_the_line_is_skipped() {
    let mut b = bench("garbage");
    b.axis.home(OPTS).await.unwrap();
    b.firmware.inject(Fault::Garbage(b"\x00\xff\xfe#@%&\r\n\x13\x11no\xc3ise\r\n<Idle|MPos:zz>\r\n".to_vec()));
    let target = 30f64.to_radians();
    let reported = b.axis.move_to_rad(target, OPTS).await.unwrap();
    assert!((reported - target).abs() < 1e-12);
    assert_eq!(b.axis.skipped_lines(), 3, "three garbage lines skipped");
    // Garbage mid-move too.
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::Garbage(vec![0x55; 300]))));
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::Garbage(b"\r\n".to_vec()))));
    let reported = b.axis.move_to_rad(60f64.to_radians(), OPTS).await.unwrap();
    assert!((reported - 60f64.to_radians()).abs() < 1e-12);
    assert_eq!(b.axis.skipped_lines(), 4, "plus one oversized line");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_alarm_is_a_clear_non_retryable_error() {
    let mut b = bench("alarm");
    b.axis.home(OPTS).await.unwrap();
    b.firmware.inject(Fault::OnNextMove(Box::new(Fault::Alarm(1))));
    let e = b.axis.move_to_rad(90f64.to_radians(), OPTS).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Other, "{e}");
    assert!(!e.is_retryable());
    assert!(e.to_string().contains("ALARM:1") && e.to_string().contains("hard limit"), "{e}");
    // Locked until homed: position and moves say so, health reports the fault.
    assert_eq!(b.axis.position_rad().await.unwrap_err().kind(), ErrorKind::NotHomed);
    assert!(matches!(b.axis.health().await.unwrap(), btfrig_hw::Health::Fault(_)));
    // Homing (retried while the interrupted motion winds down: error:8 -> Busy) recovers.
    retried!(b, b.axis.home(OPTS).await).unwrap();
    let reported = b.axis.move_to_rad(90f64.to_radians(), OPTS).await.unwrap();
    assert!((reported - 90f64.to_radians()).abs() < 1e-12);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn radian_units_cross_bit_for_bit() {
    // 0.1 rad: to_degrees().to_radians() is not the same f64, so a degree axis would
    // command the simulator a neighbouring value (and its jitter, keyed by the bits, differs).
    let target = 0.1f64;
    assert_ne!(target.to_degrees().to_radians(), target);
    let mut b = bench_in("radians", AxisUnits::Radians);
    b.axis.home(OPTS).await.unwrap();
    assert_eq!(b.axis.move_to_rad(target, OPTS).await.unwrap(), target);
    assert_eq!(b.world.commanded().rail, target);
}
