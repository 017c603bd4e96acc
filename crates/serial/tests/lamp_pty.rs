//! The lamp backend against the emulated lamp controller on a real pseudo-terminal, driving
//! the simulator's lamp. Faults at deterministic points (no timing assertions).

use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::{devices::DevicesConfig, timing::TimingConfig};
use btfrig_hw::{Device, ErrorKind, Lamp, ScaledClock, SharedClock, WarmUp};
use btfrig_serial::firmware::lamp::{Fault, LampFirmware, LampFirmwareConfig};
use btfrig_serial::lamp::{SerialLamp, SerialLampConfig};
use btfrig_serial::transport::SerialConnector;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig, SimWorld};

struct Bench {
    lamp: SerialLamp,
    firmware: LampFirmware,
    world: SimWorld,
    clock: SharedClock,
    dir: std::path::PathBuf,
}

impl Drop for Bench {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

async fn bench(name: &str) -> Bench {
    // Rig time 100x wall time; a 20 s warm-up takes 0.2 s.
    let clock: SharedClock = Arc::new(ScaledClock::new(100.0).unwrap());
    let source = Arc::new(FlatFrameSource::new(4, 4, 100.0));
    let mut timing = TimingConfig::bonn();
    timing.lamp.warm_up_s = 20.0;
    let rig =
        SimRig::build(&DevicesConfig::default(), &timing, 5, &FaultScenario::none(), clock.clone(), source).unwrap();
    let dir = std::env::temp_dir().join(format!("btfrig-lamp-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("lamp");
    let firmware = LampFirmware::spawn(rig.lamp, LampFirmwareConfig::default(), clock.clone(), &link).unwrap();
    let cfg = SerialLampConfig { name: "lamp".into(), poll_s: 0.05, reply_timeout: Duration::from_millis(500) };
    let connector = Arc::new(SerialConnector { path: link.to_string_lossy().into_owned(), baud: 9600 });
    let lamp = SerialLamp::open(cfg, connector, clock.clone()).await.unwrap();
    Bench { lamp, firmware, world: rig.world, clock, dir }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn warm_up_shutter_intensity_hours_and_garbage() {
    let mut b = bench("basic").await;
    let caps = b.lamp.capabilities();
    assert!(caps.has_shutter);
    assert_eq!(caps.intensity_range, Some((0.5, 1.0)));
    assert_eq!(caps.warm_up_s, 20.0);
    assert_eq!(b.lamp.info().model, "emulated-lamp");
    assert_eq!(b.lamp.status().await.unwrap().warm_up, WarmUp::Off);
    assert_eq!(b.lamp.hours().await.unwrap(), 100.0);
    let e = b.lamp.wait_ready(5.0).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Other, "{e}");

    b.lamp.set_on(true).await.unwrap();
    // The setting returns once applied: the simulator's lamp is burning.
    assert!(b.world.truth().lamp_on);
    let s = b.lamp.status().await.unwrap();
    assert!(s.on);
    assert!(
        matches!(s.warm_up, WarmUp::WarmingUp { remaining_s } if remaining_s > 0.0 && remaining_s <= 20.0),
        "{s:?}"
    );
    let e = b.lamp.wait_ready(1.0).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout, "{e}");
    assert!(e.is_retryable());
    b.lamp.wait_ready(60.0).await.unwrap();
    assert_eq!(b.lamp.status().await.unwrap().warm_up, WarmUp::Ready);
    assert!(b.lamp.hours().await.unwrap() > 100.0);

    b.firmware.inject(Fault::Garbage(b"\xff\xfeSTAT 9 9\nnoise\n".to_vec()));
    b.lamp.set_shutter_open(false).await.unwrap();
    assert!(!b.world.truth().lamp_shutter_open);
    assert_eq!(b.world.truth().lamp_intensity, 0.0, "shuttered");
    assert_eq!(b.lamp.skipped_lines(), 2, "two garbage lines skipped");
    b.lamp.set_shutter_open(true).await.unwrap();
    b.lamp.set_intensity(0.75).await.unwrap();
    assert_eq!(b.lamp.status().await.unwrap().intensity, 0.75);
    assert_eq!(b.world.truth().lamp_intensity, 0.75, "ready lamp at its setpoint");
    let e = b.lamp.set_intensity(0.2).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::OutOfRange, "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn port_closed_after_a_setting_reconnects() {
    let mut b = bench("unplug").await;
    b.firmware.inject(Fault::OnNextSetting(Box::new(Fault::Unplug)));
    let e = b.lamp.set_on(true).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
    // The engine's policy: reconnect, re-issue the call.
    b.lamp.reconnect().await.unwrap();
    // Busy (ERR 6) while the controller still applies the first one: retried as the engine would.
    let mut busy = 0;
    loop {
        match b.lamp.set_on(true).await {
            Ok(()) => break,
            Err(e) if e.kind() == ErrorKind::Busy && busy < 100 => {
                busy += 1;
                b.clock.sleep_s(0.05).await;
            }
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(b.lamp.connects(), 2);
    assert!(b.lamp.status().await.unwrap().on);
    assert!(b.world.truth().lamp_on);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_errors_and_a_lost_reply() {
    let mut b = bench("errors").await;
    b.firmware.inject(Fault::Refuse(4, "ignition failed".into()));
    let e = b.lamp.set_on(true).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Other);
    assert!(!e.is_retryable());
    assert!(e.to_string().contains("ERR 4: ignition failed"), "{e}");
    assert!(!b.world.truth().lamp_on);
    b.firmware.inject(Fault::Refuse(6, "burner hot, restrike in 90 s".into()));
    let e = b.lamp.set_on(true).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Busy, "{e}");
    b.lamp.set_on(true).await.unwrap();
    // A reply lost on the line: Timeout (retryable); the next call resynchronises.
    b.firmware.inject(Fault::Swallow);
    let e = b.lamp.status().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout, "{e}");
    assert!(b.lamp.status().await.unwrap().on);
    assert_eq!(b.lamp.connects(), 1);
}
