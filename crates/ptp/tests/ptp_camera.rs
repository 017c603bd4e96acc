//! The PTP camera backend against the in-process responder serving the simulator's camera,
//! in virtual time; and the run engine capturing through it with a lost ObjectAdded event.

use std::collections::HashSet;
use std::sync::Arc;

use btfrig_acquire::{Engine, EngineSettings, EngineStep, GonioDevices, RunOutcome};
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::Gonio;
use btfrig_core::sampling::Sampling;
use btfrig_hw::{Camera, Device, ErrorKind, SharedClock, TokioClock};
use btfrig_planner::{plan, PairSelection, PlanRequest};
use btfrig_ptp::camera::{PtpCamera, PtpCameraConfig};
use btfrig_ptp::responder::{Fault, PtpResponder, ResponderConfig};
use btfrig_sim::capture::prepare;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig};

fn cfg() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap()
}

fn sim_rig(clock: SharedClock) -> SimRig {
    SimRig::from_rig_config(&cfg(), &FaultScenario::none(), clock, Arc::new(FlatFrameSource::new(8, 6, 1000.0)))
        .unwrap()
}

/// The simulator's camera behind a PTP responder, and the backend on it.
async fn ptp(camera: Box<dyn Camera>, clock: SharedClock) -> (PtpCamera, PtpResponder) {
    let capabilities = camera.capabilities();
    let (responder, transport) = PtpResponder::spawn(camera, ResponderConfig::default());
    let cfg = PtpCameraConfig { name: "camera".into(), capabilities, op_timeout_s: 5.0, read_margin_s: 1.0 };
    (PtpCamera::open(cfg, Box::new(transport), clock).await.unwrap(), responder)
}

#[tokio::test(start_paused = true)]
async fn frames_through_ptp_equal_the_direct_ones() {
    let clock = TokioClock::shared();
    let mut direct = sim_rig(clock.clone());
    let via = sim_rig(clock.clone());
    let (mut cam, _responder) = ptp(via.camera, clock.clone()).await;
    assert_eq!(cam.info().model, "btfrig emulated PTP camera");
    assert_eq!(cam.settings(), direct.camera.settings(), "settings read from the camera at open");
    for (exposure, gain) in [(0.05, 2.0), (1.0 / 3.0, 1.5), (0.013_7, 1.0)] {
        direct.camera.set_exposure_s(exposure).await.unwrap();
        direct.camera.set_gain(gain).await.unwrap();
        cam.set_exposure_s(exposure).await.unwrap();
        cam.set_gain(gain).await.unwrap();
        let a = direct.camera.capture(30.0).await.unwrap();
        let b = cam.capture(30.0).await.unwrap();
        assert_eq!(a.data, b.data);
        assert_eq!((a.width, a.height), (b.width, b.height));
        // Exposure and gain cross as f64 bits: the frame records exactly what was asked.
        assert_eq!(b.meta.exposure_s, exposure);
        assert_eq!(b.meta.gain, gain);
        assert_eq!(a.meta.sequence, b.meta.sequence);
    }
    // Out of the configured range: refused by the backend; inside it but refused by the
    // camera: InvalidDevicePropValue, the same kind.
    assert_eq!(cam.set_exposure_s(1e3).await.unwrap_err().kind(), ErrorKind::OutOfRange);
    cam.set_f_number(5.6).await.unwrap();
    assert_eq!(cam.settings().f_number, Some(5.6));
    assert_eq!(cam.read_frame(1.0).await.unwrap_err().kind(), ErrorKind::Other, "nothing triggered");
}

#[tokio::test(start_paused = true)]
async fn faults_map_to_retryable_kinds() {
    let clock = TokioClock::shared();
    let rig = sim_rig(clock.clone());
    let (mut cam, responder) = ptp(rig.camera, clock.clone()).await;
    responder.inject(Fault::DropObjectAdded);
    let e = cam.trigger(5.0).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout, "{e}");
    assert!(e.to_string().contains("no ObjectAdded"), "{e}");
    assert_eq!(cam.missed_events(), 1);
    // The retry from the trigger works.
    let f = cam.capture(5.0).await.unwrap();
    assert_eq!(f.data.len(), 48);
    responder.inject(Fault::CorruptObject);
    cam.trigger(5.0).await.unwrap();
    let e = cam.read_frame(30.0).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::CorruptData, "{e}");
    assert!(e.is_retryable());
    cam.capture(5.0).await.unwrap();
    drop(responder);
    let e = cam.capture(5.0).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
}

/// 40 steps of the Bonn plan, through the engine; the first capture's ObjectAdded is lost.
#[tokio::test(start_paused = true)]
async fn engine_retries_a_capture_whose_object_added_never_came() {
    let cfg = cfg();
    let gonio = Gonio::new(cfg.geometry.clone()).unwrap();
    let s = Sampling::bonn81();
    let pairs = (0..8).flat_map(|l| (10..15).map(move |v| (l, v))).collect();
    let req = PlanRequest::new(&gonio, &s, &s, &cfg.timing, 0.01, cfg.timing.camera.frame_bytes.unwrap())
        .with_pairs(PairSelection::List(pairs));
    let steps = EngineStep::from_schedule(&plan(&req).unwrap());
    assert_eq!(steps.len(), 40);

    let clock = TokioClock::shared();
    let mut rig = sim_rig(clock.clone());
    prepare(&mut rig).await.unwrap();
    let SimRig { robot, rail, camera, .. } = rig;
    let (cam, responder) = ptp(camera, clock.clone()).await;
    let devices = GonioDevices { robot, rail, camera: Box::new(cam), clock: clock.clone() };
    let (tx, mut rx) = tokio::sync::mpsc::channel::<btfrig_core::capture::CapturedFrame>(64);
    let collect = tokio::spawn(async move {
        let mut out = Vec::new();
        while let Some(f) = rx.recv().await {
            out.push(f);
        }
        out
    });
    let handle = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    // Armed before the run starts: the responder applies it to the first InitiateCapture.
    responder.inject(Fault::DropObjectAdded);
    let outcome = handle.join().await;
    let frames = collect.await.unwrap();
    let RunOutcome::Finished(summary) = outcome else { panic!("{outcome:?}") };
    assert_eq!(summary.captured, 40);
    assert_eq!(frames.len(), 40, "no frame lost");
    let keys: HashSet<_> = frames.iter().map(|f| f.key).collect();
    assert_eq!(keys.len(), 40, "each step once");
    assert!(summary.retries >= 1, "{summary:?}");
    let retried: Vec<_> = frames.iter().filter(|f| f.attempts > 1).map(|f| f.index).collect();
    assert_eq!(retried, vec![0], "the first capture was retried");
}
