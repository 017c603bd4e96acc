//! Every fault kind surfaces as the right ErrorKind and retryability, and the faults that
//! do not fail calls (stuck LED, lamp drift) show in the truth and in the frames.

mod common;

use btfrig_hw::{ErrorKind, LedPattern, MoveOptions};
use btfrig_sim::{FaultKind, FaultScenario, FlatFrameSource, FrameSource};
use common::*;

const OPTS: MoveOptions = MoveOptions::with_timeout_s(30.0);

fn faults(text: &str) -> FaultScenario {
    FaultScenario::from_toml(text, "test").unwrap()
}

#[tokio::test(start_paused = true)]
async fn timeout_on_the_nth_call_costs_the_timeout_and_is_retryable() {
    let mut rig = rig(&devices(""), 1, &faults("[[timeouts]]\ndevice = \"robot\"\ncalls = [2]\n"));
    let clock = rig.world.clock().clone();
    rig.robot.move_to_rad([0.1, 0.0, 0.0], OPTS).await.unwrap();
    let t0 = clock.now_s();
    let e = rig.robot.move_to_rad([0.2, 0.0, 0.0], OPTS).await.unwrap_err();
    assert_kind(&e, ErrorKind::Timeout, true);
    assert!(e.to_string().starts_with("robot: timeout: move_to_rad (call 2)"), "{e}");
    assert!((clock.now_s() - t0 - 30.0).abs() < 0.002);
    // The lost command did not move the robot; the retry does.
    assert_eq!(rig.world.commanded().robot, [0.1, 0.0, 0.0]);
    rig.robot.move_to_rad([0.2, 0.0, 0.0], OPTS).await.unwrap();
    assert_eq!(rig.world.commanded().robot, [0.2, 0.0, 0.0]);
    let log = rig.world.fault_log();
    assert_eq!(log.len(), 1);
    assert_eq!((log[0].device.as_str(), log[0].call, log[0].kind), ("robot", 2, FaultKind::Timeout));
}

#[tokio::test(start_paused = true)]
async fn failure_on_the_nth_call_is_fatal_at_once_and_only_that_call() {
    let mut rig = rig(&devices(""), 1, &faults("[[failures]]\ndevice = \"robot\"\ncalls = [2]\n"));
    let clock = rig.world.clock().clone();
    rig.robot.move_to_rad([0.1, 0.0, 0.0], OPTS).await.unwrap();
    let t0 = clock.now_s();
    let e = rig.robot.move_to_rad([0.2, 0.0, 0.0], OPTS).await.unwrap_err();
    assert_kind(&e, ErrorKind::Other, false);
    assert!(e.to_string().starts_with("robot: other: move_to_rad (call 2)"), "{e}");
    // Fails at once (no timeout waited) and commands nothing.
    assert_eq!(clock.now_s(), t0);
    assert_eq!(rig.world.commanded().robot, [0.1, 0.0, 0.0]);
    rig.robot.move_to_rad([0.2, 0.0, 0.0], OPTS).await.unwrap();
    let log = rig.world.fault_log();
    assert_eq!((log.len(), log[0].call, log[0].kind), (1, 2, FaultKind::Failure));
    // The shipped scenario parses, and a call number 0 is refused naming the field.
    let e = FaultScenario::from_toml("[[failures]]\ndevice = \"robot\"\ncalls = [0]\n", "t").unwrap_err();
    assert!(e.to_string().contains("faults.failures[0].calls[0]"), "{e}");
}

#[tokio::test(start_paused = true)]
async fn disconnect_heals_after_n_calls_or_never() {
    let text = "[[disconnects]]\ndevice = \"camera\"\nat_call = 2\nreconnect_after_calls = 2\n\
                [[disconnects]]\ndevice = \"rail\"\nat_call = 1\n";
    let mut rig = rig(&devices(""), 1, &faults(text));
    rig.camera.set_gain(2.0).await.unwrap();
    for _ in 0..2 {
        let e = rig.camera.capture(30.0).await.unwrap_err();
        assert_kind(&e, ErrorKind::Disconnected, true);
        assert!(e.to_string().contains("camera: disconnected"), "{e}");
    }
    rig.camera.reconnect().await.unwrap();
    rig.camera.capture(30.0).await.unwrap();
    for _ in 0..20 {
        let e = rig.rail.move_to_rad(0.5, OPTS).await.unwrap_err();
        assert_kind(&e, ErrorKind::Disconnected, true);
        assert!(e.message().contains("will not come back"), "{e}");
    }
    // A run engine that caps its retries gives up with the last error.
    let r = retry!(3, rig.rail.move_to_rad(0.5, OPTS));
    assert_eq!(r.unwrap_err().kind(), ErrorKind::Disconnected);
}

#[tokio::test(start_paused = true)]
async fn dropped_frame_times_out_and_corrupt_frame_fails_its_checksum() {
    let text = "[dropped_frames]\nframes = [2]\n[corrupt_frames]\nframes = [3]\n";
    let mut rig = rig(&devices(""), 1, &faults(text));
    let clock = rig.world.clock().clone();
    assert_eq!(rig.camera.capture(30.0).await.unwrap().meta.sequence, 0);

    rig.camera.trigger(30.0).await.unwrap();
    let t0 = clock.now_s();
    let e = rig.camera.read_frame(20.0).await.unwrap_err();
    assert_kind(&e, ErrorKind::Timeout, true);
    assert!(e.to_string().contains("frame 1 did not arrive within 20 s"), "{e}");
    assert!((clock.now_s() - t0 - 20.0).abs() < 0.002);

    let e = rig.camera.capture(30.0).await.unwrap_err();
    assert_kind(&e, ErrorKind::CorruptData, true);
    assert!(e.to_string().contains("frame 2 checksum"), "{e}");

    // Retrying the capture works; the buffer was emptied by the failures.
    let f = rig.camera.capture(30.0).await.unwrap();
    assert_eq!(f.meta.sequence, 3);
    let kinds: Vec<_> = rig.world.fault_log().iter().map(|f| f.kind).collect();
    assert_eq!(kinds, [FaultKind::DroppedFrame, FaultKind::CorruptFrame]);
}

#[tokio::test(start_paused = true)]
async fn device_errors_without_injection_have_the_right_kinds() {
    let mut rig =
        rig(&devices("[robot]\nkind = \"sim\"\n[lamp]\nkind = \"sim\"\ndimmable = false\n"), 1, &FaultScenario::none());
    // Not homed.
    let e = rig.robot.move_to_rad([0.1, 0.0, 0.0], OPTS).await.unwrap_err();
    assert_kind(&e, ErrorKind::NotHomed, false);
    assert!(!rig.robot.is_homed().await.unwrap());
    rig.robot.home(OPTS).await.unwrap();
    assert!(rig.robot.is_homed().await.unwrap());
    // Out of range, naming the joint and the limits.
    let e = rig.robot.move_to_rad([0.0, 2.0, 0.0], OPTS).await.unwrap_err();
    assert_kind(&e, ErrorKind::OutOfRange, false);
    assert!(e.to_string().contains("joint 1") && e.to_string().contains("[-90.0000, 90.0000] deg"), "{e}");
    // A move longer than its timeout: Timeout, then Busy until the axis stops.
    let e = rig.rail.move_to_rad(3.0, MoveOptions::with_timeout_s(1.0)).await.unwrap_err();
    assert_kind(&e, ErrorKind::Timeout, true);
    let e = rig.rail.move_to_rad(3.0, OPTS).await.unwrap_err();
    assert_kind(&e, ErrorKind::Busy, true);
    rig.world.clock().sleep_s(10.0).await;
    rig.rail.move_to_rad(3.0, OPTS).await.unwrap();
    // Missing capability.
    assert_kind(&rig.lamp.set_intensity(0.8).await.unwrap_err(), ErrorKind::Unsupported, false);
    assert_kind(&rig.camera.set_exposure_s(100.0).await.unwrap_err(), ErrorKind::OutOfRange, false);
    // Trigger twice without reading: the first frame is discarded, the second delivered.
    let first = rig.camera.trigger(30.0).await.unwrap();
    let second = rig.camera.trigger(30.0).await.unwrap();
    assert_eq!(rig.camera.read_frame(30.0).await.unwrap().meta.sequence, second);
    assert_eq!(second, first + 1);
    assert_kind(&rig.camera.read_frame(30.0).await.unwrap_err(), ErrorKind::Other, false);
    // Lamp off: wait_ready cannot succeed.
    assert_kind(&rig.lamp.wait_ready(1.0).await.unwrap_err(), ErrorKind::Other, false);
}

#[tokio::test(start_paused = true)]
async fn probabilistic_timeouts_occur_at_the_configured_rate() {
    let mut rig = rig(&devices(""), 5, &faults("[[timeouts]]\ndevice = \"camera\"\nprobability = 0.05\n"));
    let n = 4000;
    let mut failures = 0;
    for _ in 0..n {
        match rig.camera.set_gain(1.0).await {
            Ok(()) => {}
            Err(e) => {
                assert_kind(&e, ErrorKind::Timeout, true);
                failures += 1;
            }
        }
    }
    // Binomial(4000, 0.05): mean 200, sd 13.8.
    assert!((failures as f64 - 200.0).abs() < 4.0 * 13.8, "{failures}");
}

#[tokio::test(start_paused = true)]
async fn stuck_leds_show_in_truth_and_frames_but_not_in_reports() {
    let cfg = devices("[led_array]\nkind = \"sim\"\ncount = 20\n");
    let mut rig = rig(&cfg, 1, &scenario("stuck-led"));
    let leds = rig.led_array.as_mut().unwrap();
    leds.set_pattern(&LedPattern { intensities: vec![0.5; 20] }).await.unwrap();
    // The controller reports the pattern quantised to its 4096 PWM steps.
    assert_eq!(leds.pattern().await.unwrap().intensities, vec![2048.0 / 4095.0; 20]);
    leds.all_off().await.unwrap();
    assert_kind(&leds.set_pattern(&LedPattern::all_off(19)).await.unwrap_err(), ErrorKind::OutOfRange, false);
    let mut p = LedPattern::all_off(20);
    p.intensities[17] = 1.0;
    leds.set_pattern(&p).await.unwrap();
    let truth = rig.world.truth();
    assert_eq!(truth.leds[3], 1.0);
    assert_eq!(truth.leds[17], 0.0);
    assert_eq!(truth.leds.iter().sum::<f64>(), 1.0);
    // The flat source sums LED light: the frame shows LED 3 only.
    let frame = rig.camera.capture(30.0).await.unwrap();
    let src = FlatFrameSource::new(16, 12, 1000.0);
    assert_eq!(frame.data[0], src.expected_value(&truth, &rig.camera.settings()));
    assert_eq!(frame.data[0], 64 + 200);
}

#[tokio::test]
async fn stuck_led_beyond_the_array_is_a_config_error() {
    let cfg = devices("[led_array]\nkind = \"sim\"\ncount = 10\n");
    let err = btfrig_sim::SimRig::build(
        &cfg,
        &Default::default(),
        1,
        &scenario("stuck-led"),
        btfrig_hw::TokioClock::shared(),
        source(),
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("faults.stuck_leds[1].index = 17 is out of range: allowed 0..10"), "{err}");
}

#[tokio::test(start_paused = true)]
async fn lamp_follows_warm_up_curve_and_drift() {
    let mut rig = rig(&devices(""), 1, &scenario("lamp-drift"));
    let clock = rig.world.clock().clone();
    rig.lamp.set_on(true).await.unwrap();
    let on = clock.now_s();
    // start 0.7, tau 600 s, drift -0.005 per hour.
    let expect = |t: f64| 1.0 - 0.3 * (-t / 600.0).exp() - 0.005 * t / 3600.0;
    for wait in [0.0, 600.0, 3000.0, 36000.0] {
        clock.sleep_s(wait).await;
        let t = clock.now_s() - on;
        let got = rig.world.truth().lamp_intensity;
        assert!((got - expect(t)).abs() < 1e-9, "t = {t}: {got} vs {}", expect(t));
    }
    // The lamp still reports ready and its setpoint: drift shows only in the light.
    let s = rig.lamp.status().await.unwrap();
    assert_eq!((s.intensity, s.warm_up), (1.0, btfrig_hw::WarmUp::Ready));
    // Setpoint and shutter scale the truth.
    rig.lamp.set_intensity(0.5).await.unwrap();
    let half = rig.world.truth().lamp_intensity;
    assert!((half - 0.5 * expect(clock.now_s() - on)).abs() < 1e-9);
    rig.lamp.set_shutter_open(false).await.unwrap();
    assert_eq!(rig.world.truth().lamp_intensity, 0.0);
}

#[tokio::test(start_paused = true)]
async fn nominal_lamp_ramps_then_holds() {
    let mut rig = rig(&devices(""), 1, &FaultScenario::none());
    let clock = rig.world.clock().clone();
    assert_eq!(rig.world.truth().lamp_intensity, 0.0);
    rig.lamp.set_on(true).await.unwrap();
    clock.sleep_s(90.0).await;
    assert!((rig.world.truth().lamp_intensity - 0.5).abs() < 1e-3);
    assert!(matches!(rig.lamp.health().await.unwrap(), btfrig_hw::Health::Warning(_)));
    rig.lamp.wait_ready(100.0).await.unwrap();
    assert_eq!(rig.world.truth().lamp_intensity, 1.0);
    let src = FlatFrameSource::new(16, 12, 1000.0);
    let frame = rig.camera.capture(30.0).await.unwrap();
    assert_eq!(frame.data[0], 64 + 200);
    assert_eq!(frame.data.len(), src.format().width * src.format().height);
}

#[tokio::test(start_paused = true)]
async fn lamp_drift_can_start_late_and_be_fast_and_bad_values_are_named() {
    // 5 % over a 70 s run: the linear drift starts after the rig's 180 s warm-up wait.
    let text =
        "[lamp_drift]\nstart_fraction = 0.9\nwarm_up_tau_s = 60.0\ndrift_per_hour = -2.6\ndrift_delay_s = 180.0\n";
    let mut rig = rig(&devices(""), 1, &FaultScenario::from_toml(text, "drift.toml").unwrap());
    let clock = rig.world.clock().clone();
    rig.lamp.set_on(true).await.unwrap();
    let on = clock.now_s();
    let expect = |t: f64| 1.0 - 0.1 * (-t / 60.0).exp() - 2.6 * (t - 180.0).max(0.0) / 3600.0;
    for wait in [100.0, 80.0, 70.0] {
        clock.sleep_s(wait).await;
        let t = clock.now_s() - on;
        let got = rig.world.truth().lamp_intensity;
        assert!((got - expect(t)).abs() < 1e-9, "t = {t}: {got} vs {}", expect(t));
    }
    assert!((expect(180.0) - expect(250.0)) > 0.045, "about 5 % over the 70 s after the warm-up");
    let bad =
        "[lamp_drift]\nstart_fraction = 0.9\nwarm_up_tau_s = 60.0\ndrift_per_hour = -20.0\ndrift_delay_s = -1.0\n";
    let err = FaultScenario::from_toml(bad, "bad.toml").err().unwrap().to_string();
    assert!(
        err.contains("faults.lamp_drift.drift_per_hour = -20") && err.contains("faults.lamp_drift.drift_delay_s = -1"),
        "{err}"
    );
}
