//! GigE Vision over loopback, each test in a network namespace of its own with only `lo`
//! (support/mod.rs): Aravis's `arv-fake-gv-camera-0.8` (Debian's aravis-tools) started by the
//! test on 127.0.0.1, killed and restarted; and our fed fake camera, whose pixels must arrive
//! bit for bit.

mod support;

use std::net::Ipv4Addr;
use std::process::Child;
use std::time::{Duration, Instant};

use btfrig_genicam::{
    Error, FedFakeCamera, FeedFrame, GenicamCamera, ImageFormat, OpenOptions, PixelFormat, Target, Trigger,
};
use btfrig_hw::ErrorKind;
use rand::{Rng, SeedableRng};

const LOOPBACK: Ipv4Addr = Ipv4Addr::LOCALHOST;

/// Starts `arv-fake-gv-camera-0.8` on 127.0.0.1 and waits until it answers (an open succeeds).
fn start_fake_gv() -> Child {
    let child = support::spawn_fake_gv("GV01");
    let t0 = Instant::now();
    loop {
        match GenicamCamera::open(OpenOptions::new(Target::Address(LOOPBACK))) {
            Ok(c) if c.info().serial == "GV01" => return child,
            Ok(c) => panic!("another camera answers on 127.0.0.1: {:?}", c.info()),
            Err(e) if t0.elapsed() < Duration::from_secs(20) => {
                let _ = e;
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("the fake camera did not come up within 20 s: {e}"),
        }
    }
}

fn configure(cam: &GenicamCamera, name: &str, width: u32, height: u32, exposure_us: f64, gain: f64) -> PixelFormat {
    let pixel_format = PixelFormat::from_name(name).unwrap();
    cam.set_image_format(ImageFormat { width, height, pixel_format }).unwrap();
    assert_eq!(cam.set_exposure_us(exposure_us).unwrap(), exposure_us);
    assert_eq!(cam.set_gain(gain).unwrap(), gain);
    cam.set_trigger(Trigger::Software).unwrap();
    cam.start().unwrap();
    pixel_format
}

#[test]
fn external_fake_camera_frames_kill_and_restart() {
    if !support::in_netns("external_fake_camera_frames_kill_and_restart") {
        return;
    }
    support::assert_loopback_only();
    let mut fake = start_fake_gv();
    let cam = GenicamCamera::open(OpenOptions {
        control_timeout: Duration::from_secs(10),
        ..OpenOptions::new(Target::Address(LOOPBACK))
    })
    .unwrap();
    let info = cam.info();
    println!("{info:?}");
    assert_eq!((info.model.as_str(), info.serial.as_str()), ("Fake", "GV01"));

    // The external camera keeps its registers between clients: everything is set each time.
    for (name, w, h, exposure_us, gain) in
        [("Mono8", 512, 256, 2000.0, 3.0), ("Mono16", 128, 96, 500.0, 1.0), ("BayerRG8", 640, 480, 12_000.0, 0.0)]
    {
        let pf = configure(&cam, name, w, h, exposure_us, gain);
        for _ in 0..4 {
            let f = cam.trigger_software(Duration::from_secs(5)).unwrap();
            assert_eq!((f.width, f.height, f.pixel_format), (w, h, pf), "{name}");
            assert_eq!(f.data.len(), pf.image_bytes(w as usize, h as usize));
            assert_eq!((f.exposure_us, f.gain), (exposure_us, gain));
        }
    }
    let before = cam.stats().unwrap();
    assert_eq!((before.completed, before.failures, before.timeouts), (12, 0, 0), "{before:?}");

    // Killed: the next frame fails with a retryable kind, within the wait (no hang).
    fake.kill().unwrap();
    fake.wait().unwrap();
    let t0 = Instant::now();
    let e = cam.trigger_software(Duration::from_secs(2)).unwrap_err();
    println!("after the kill: {e} ({:?}) after {:.2} s", e.kind(), t0.elapsed().as_secs_f64());
    assert!(e.kind().is_retryable(), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(20), "{:?}", t0.elapsed());
    // Reconnecting while it is away: a clear disconnected state, not a hang.
    let t0 = Instant::now();
    let e = cam.reconnect().unwrap_err();
    println!("reconnect while away: {e} after {:.2} s", t0.elapsed().as_secs_f64());
    assert!(matches!(e, Error::Disconnected { .. }), "{e:?}");
    assert_eq!(e.kind(), ErrorKind::Disconnected);
    // Bounded by the control timeout plus the wait for a control privilege (10 + 5 s): a hang
    // would not end.
    assert!(t0.elapsed() < Duration::from_secs(25), "{:?}", t0.elapsed());

    // Restarted: reconnect re-applies the settings and frames flow again.
    let mut fake = start_fake_gv();
    cam.reconnect().unwrap();
    let f = cam.trigger_software(Duration::from_secs(5)).unwrap();
    assert_eq!((f.width, f.height, f.pixel_format.name()), (640, 480, "BayerRG8"));
    assert_eq!((f.exposure_us, f.gain), (12_000.0, 0.0));
    let after = cam.stats().unwrap();
    println!("{after:?}");
    // The reconnect asked while the camera was away may still have been opening when it came
    // back (the handle stopped waiting at its control timeout, the owner thread did not).
    assert!(after.reconnects >= 1, "{after:?}");
    assert!(f.sequence > 0);
    fake.kill().unwrap();
    fake.wait().unwrap();
}

#[test]
fn fed_pixels_arrive_bit_exact() {
    if !support::in_netns("fed_pixels_arrive_bit_exact") {
        return;
    }
    support::assert_loopback_only();
    let fed = FedFakeCamera::start(LOOPBACK, "BTFRIG-TEST").unwrap();
    fed.set_temperature_c(31.5);
    let cam = GenicamCamera::open(OpenOptions::new(Target::Address(LOOPBACK))).unwrap();
    let info = cam.info();
    assert_eq!(info.serial, "BTFRIG-TEST", "reached another camera: {info:?}");
    for f in ["BayerRG12", "BayerRG16", "BayerGB12", "Mono12", "Mono16", "Mono8"] {
        assert!(info.pixel_formats.iter().any(|p| p == f), "{f} missing: {:?}", info.pixel_formats);
    }
    assert!(info.has_temperature);

    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(26);
    let feed = fed.feed();
    // Exposure in microseconds that is no whole number: the float register keeps it exactly.
    for (name, w, h, exposure_us, gain) in [
        ("BayerRG12", 320, 240, 1234.5678, 6.0),
        ("BayerRG16", 200, 100, 20_000.125, 0.0),
        ("Mono8", 64, 64, 100.0, 12.5),
        ("Mono12", 96, 80, 777.0, 3.0),
    ] {
        let pf = configure(&cam, name, w, h, exposure_us, gain);
        let max: u16 = if pf.bits() >= 16 { u16::MAX } else { (1 << pf.bits()) - 1 };
        for _ in 0..3 {
            let samples: Vec<u16> = (0..w * h).map(|_| rng.gen_range(0..=max)).collect();
            let bytes = pf.pack(&samples).unwrap();
            feed.set_next(FeedFrame { width: w, height: h, pixel_format: pf.code(), bytes });
            let f = cam.trigger_software(Duration::from_secs(5)).unwrap();
            assert_eq!((f.width, f.height, f.pixel_format), (w, h, pf));
            assert_eq!(
                pf.unpack(&f.data, w as usize, h as usize).unwrap(),
                samples,
                "{name}: pixels changed on the way"
            );
            assert_eq!((f.exposure_us, f.gain), (exposure_us, gain));
            assert_eq!(f.temperature_c, Some(31.5));
        }
    }
    assert_eq!((feed.fills(), feed.misses()), (12, 0));
    let stats = cam.stats().unwrap();
    println!("{stats:?}");
    assert_eq!((stats.completed, stats.failures, stats.timeouts, stats.skipped_ids), (12, 0, 0, 0));
}
