//! The LED backend against the emulated LED dome controller on a real pseudo-terminal,
//! driving the simulator's LED array. Faults at deterministic points (no timing).

use std::sync::Arc;
use std::time::Duration;

use btfrig_core::config::{devices::DevicesConfig, timing::TimingConfig};
use btfrig_hw::{Device, ErrorKind, Health, LedArray, LedPattern, ScaledClock, SharedClock};
use btfrig_serial::firmware::led::{Fault, LedFirmware};
use btfrig_serial::led::{SerialLedArray, SerialLedConfig};
use btfrig_serial::transport::SerialConnector;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig, SimWorld};

struct Bench {
    leds: SerialLedArray,
    firmware: LedFirmware,
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
    let clock: SharedClock = Arc::new(ScaledClock::new(100.0).unwrap());
    let source = Arc::new(FlatFrameSource::new(4, 4, 100.0));
    let devices: DevicesConfig =
        toml::from_str("[led_array]\nkind = \"sim\"\ncount = 198\nintensity_steps = 4096\n").unwrap();
    let mut rig =
        SimRig::build(&devices, &TimingConfig::bonn(), 3, &FaultScenario::none(), clock.clone(), source).unwrap();
    let dir = std::env::temp_dir().join(format!("btfrig-led-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("leds");
    let firmware = LedFirmware::spawn(rig.led_array.take().unwrap(), &link).unwrap();
    let cfg = SerialLedConfig { name: "led_array".into(), poll_s: 0.002, reply_timeout: Duration::from_secs(1) };
    let connector = Arc::new(SerialConnector { path: link.to_string_lossy().into_owned(), baud: 460_800 });
    let leds = SerialLedArray::open(cfg, connector, clock.clone()).await.unwrap();
    Bench { leds, firmware, world: rig.world, clock, dir }
}

/// A pattern with every kind of value: off, full, and fractions between steps.
fn pattern(n: usize) -> LedPattern {
    LedPattern { intensities: (0..n).map(|i| if i % 5 == 0 { 0.0 } else { (i as f64 / n as f64).sqrt() }).collect() }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn patterns_are_lit_exactly_as_the_direct_path_would() {
    let mut b = bench("basic").await;
    assert_eq!(b.leds.capabilities().count, 198);
    assert_eq!(b.leds.capabilities().intensity_steps, 4096);
    let p = pattern(198);
    b.leds.set_pattern(&p).await.unwrap();
    // What the simulator shows is the direct path's own quantisation of p, bit for bit.
    let quantised: Vec<f64> = p.intensities.iter().map(|v| (v * 4095.0).round() / 4095.0).collect();
    assert_eq!(b.world.truth().leds, quantised);
    assert_eq!(b.leds.pattern().await.unwrap().intensities, quantised);
    assert_eq!(b.leds.temperature_c().await.unwrap(), Some(25.0));
    let e = b.leds.set_pattern(&LedPattern::all_off(10)).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::OutOfRange, "{e}");
    let mut bad = pattern(198);
    bad.intensities[7] = 1.5;
    assert_eq!(b.leds.set_pattern(&bad).await.unwrap_err().kind(), ErrorKind::OutOfRange);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_and_damaged_frames_are_skipped() {
    let mut b = bench("garbage").await;
    // Noise, a frame with a bad CRC, and a valid frame with a stale sequence number.
    let mut noise = b"\x00\xffnoise".to_vec();
    let mut damaged = btfrig_protocols::led::Reply::Ack.encode(1).unwrap();
    *damaged.last_mut().unwrap() ^= 0x55;
    noise.extend(damaged);
    noise.extend(btfrig_protocols::led::Reply::Ack.encode(200).unwrap());
    b.firmware.inject(Fault::Garbage(noise));
    b.leds.set_pattern(&LedPattern::single(198, 4)).await.unwrap();
    assert_eq!(b.world.truth().leds[4], 1.0);
    assert!(b.leds.skipped_frames() >= 2, "garbage and the damaged frame counted: {}", b.leds.skipped_frames());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn port_closed_after_a_trigger_reconnects_and_the_pattern_is_lit() {
    let mut b = bench("unplug").await;
    b.firmware.inject(Fault::OnNextTrigger(Box::new(Fault::Unplug)));
    let p = pattern(198);
    let e = b.leds.set_pattern(&p).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
    b.leds.reconnect().await.unwrap();
    // Re-issued: Busy while the first trigger is still being lit, retried as the engine would.
    let mut busy = 0;
    loop {
        match b.leds.set_pattern(&p).await {
            Ok(()) => break,
            Err(e) if e.kind() == ErrorKind::Busy && busy < 100 => {
                busy += 1;
                b.clock.sleep_s(0.01).await;
            }
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(b.leds.connects(), 2);
    let quantised: Vec<f64> = p.intensities.iter().map(|v| (v * 4095.0).round() / 4095.0).collect();
    assert_eq!(b.world.truth().leds, quantised);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_temperature_is_busy_and_a_driver_fault_is_clear() {
    let mut b = bench("errors").await;
    b.leds.set_pattern(&LedPattern::single(198, 0)).await.unwrap();
    b.firmware.inject(Fault::OverTemperature);
    let e = b.leds.set_pattern(&LedPattern::single(198, 1)).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Busy, "{e}");
    assert!(e.to_string().contains("over temperature"), "{e}");
    assert!(matches!(b.leds.health().await.unwrap(), Health::Warning(_)));
    assert_eq!(b.leds.temperature_c().await.unwrap(), Some(85.0));
    // The controller switches the LEDs off (Busy while it does: retried as the engine would).
    let lit = loop {
        match b.leds.pattern().await {
            Ok(p) => break p,
            Err(e) if e.kind() == ErrorKind::Busy => b.clock.sleep_s(0.01).await,
            Err(e) => panic!("{e}"),
        }
    };
    assert!(lit.intensities.iter().all(|&v| v == 0.0));
    assert!(b.world.truth().leds.iter().all(|&v| v == 0.0));
    b.firmware.inject(Fault::Cooled);
    b.leds.set_pattern(&LedPattern::single(198, 1)).await.unwrap();
    assert_eq!(b.world.truth().leds[1], 1.0);
    b.firmware.inject(Fault::DriverFault);
    match b.leds.health().await.unwrap() {
        Health::Fault(m) => assert!(m.contains("driver fault"), "{m}"),
        h => panic!("{h:?}"),
    }
}
