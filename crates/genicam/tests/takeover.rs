//! A client that dies without closing (SIGKILL) keeps a GigE Vision camera's control privilege
//! until the camera's heartbeat times out; a new client must take the camera over and stream
//! from it. Aravis's `arv-fake-gv-camera-0.8` on 127.0.0.1 in a loopback-only network
//! namespace; the first client is this test binary run again as a child process.

mod support;

use std::net::Ipv4Addr;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use btfrig_genicam::{GenicamCamera, ImageFormat, OpenOptions, PixelFormat, Target, Trigger};

const ROLE: &str = "BTFRIG_TAKEOVER_CLIENT";

fn open_and_stream(tag: &str) -> GenicamCamera {
    let cam = GenicamCamera::open(OpenOptions::new(Target::Address(Ipv4Addr::LOCALHOST))).unwrap();
    let pf = PixelFormat::from_name("BayerRG8").unwrap();
    cam.set_image_format(ImageFormat { width: 160, height: 120, pixel_format: pf }).unwrap();
    cam.set_exposure_us(10_000.0).unwrap();
    cam.set_trigger(Trigger::Software).unwrap();
    cam.start().unwrap();
    for k in 0..3 {
        let f = cam.trigger_software(Duration::from_secs(5)).unwrap_or_else(|e| panic!("{tag}: frame {k}: {e}"));
        assert_eq!((f.width, f.height), (160, 120));
    }
    cam
}

#[test]
fn a_new_client_takes_over_from_a_killed_one() {
    if std::env::var_os(ROLE).is_some() {
        // The first client: stream, say so, then wait to be killed.
        let _cam = open_and_stream("first client");
        println!("STREAMING");
        std::thread::sleep(Duration::from_secs(600));
        return;
    }
    if !support::in_netns("a_new_client_takes_over_from_a_killed_one") {
        return;
    }
    support::assert_loopback_only();
    let mut fake = support::spawn_fake_gv("TAKEOVER");
    std::thread::sleep(Duration::from_millis(500));
    let mut first = Command::new(std::env::current_exe().unwrap())
        .args(["a_new_client_takes_over_from_a_killed_one", "--exact", "--nocapture"])
        .env(ROLE, "1")
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(first.stdout.take().unwrap());
    let mut line = String::new();
    while !line.contains("STREAMING") {
        line.clear();
        assert!(std::io::BufRead::read_line(&mut out, &mut line).unwrap() > 0, "the first client ended");
    }
    first.kill().unwrap();
    first.wait().unwrap();
    let t0 = Instant::now();
    let cam = open_and_stream("second client");
    println!("second client streaming {:.2} s after the kill; {:?}", t0.elapsed().as_secs_f64(), cam.stats().unwrap());
    drop(cam);
    fake.kill().unwrap();
    fake.wait().unwrap();
}
