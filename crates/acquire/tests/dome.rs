//! The one engine driving the simulated Bonn LED dome (`RigDevices::Dome`), in virtual time:
//! retries with the gonio's policy, and pause, resume and abort through the `RunHandle`.

use std::collections::HashSet;
use std::sync::Arc;

use btfrig_acquire::dome::{DomeCapture, DomeDevices};
use btfrig_acquire::{
    Engine, EngineSettings, EngineStep, Event, GonioDevices, PauseReason, RigDevices, RunOutcome, RunState, RunSummary,
    StepKind,
};
use btfrig_core::capture::{CapturedFrame, StepKey};
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, CaptureSettings, ErrorKind, MoveOptions, TokioClock, Turntable};
use btfrig_planner::dome::DomeShot;
use btfrig_sim::faults::derive_seed;
use btfrig_sim::rig::{factory_for, BuildContext};
use btfrig_sim::{FaultScenario, FlatFrameSource, FrameSource, SensorFormat, SimRig, TrueState};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;

const EXPOSURE_S: f64 = 0.01;
/// Patterns per rotation in these tests (pattern `p` lights LED `10 p` alone).
const PATTERNS: usize = 6;

fn dome_cfg() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-dome-sim.toml"), "bonn-dome-sim.toml").unwrap()
}

/// A flat frame whose first two samples record the TRUE state during the exposure: the
/// turntable angle (tenths of a degree) and 1 + the index of the brightest LED (0: none lit),
/// so a test can check that every frame, recaptures included, was taken at its step's
/// rotation with its step's pattern.
struct DomeStateSource(FlatFrameSource);

impl FrameSource for DomeStateSource {
    fn format(&self) -> SensorFormat {
        self.0.format()
    }
    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame {
        let mut f = self.0.render(truth, settings, seed);
        f.data[0] = (truth.joints.turntable.to_degrees() * 10.0).round().clamp(0.0, 4095.0) as u16;
        let lit = truth.leds.iter().enumerate().filter(|(_, &v)| v > 0.5).map(|(j, _)| j + 1).max();
        f.data[1] = lit.unwrap_or(0) as u16;
        f
    }
}

/// A homed simulated dome with `cameras` cameras (each its own device and fault gate).
async fn dome(faults: &FaultScenario, cameras: usize) -> DomeDevices {
    let cfg = dome_cfg();
    let clock = TokioClock::shared();
    let source: Arc<dyn FrameSource> = Arc::new(DomeStateSource(FlatFrameSource::new(8, 6, 1000.0)));
    let rig = SimRig::from_rig_config(&cfg, faults, clock.clone(), source.clone()).unwrap();
    let factory = factory_for(&cfg.devices.camera, "devices.camera.kind").unwrap();
    let mut cams: Vec<Box<dyn Camera>> = vec![rig.camera];
    for c in 1..cameras {
        let cx = BuildContext {
            world: &rig.world,
            timing: &cfg.timing,
            faults,
            seed: derive_seed(cfg.rig.seed, "dome-camera", c as u64),
            frames: &source,
        };
        cams.push((factory.camera)(&cx, &cfg.devices.camera.options).unwrap());
    }
    let mut turntable: Box<dyn Turntable> = rig.turntable.expect("a dome has a turntable");
    turntable.home(MoveOptions::default()).await.unwrap();
    DomeDevices { turntable: Some(turntable), leds: rig.led_array.unwrap(), cameras: cams, clock }
}

/// Two rotations of [`PATTERNS`] patterns each; the patterns for `RigDevices::Dome`.
fn steps() -> (Vec<EngineStep>, Vec<Vec<f64>>) {
    let cfg = dome_cfg();
    let d = cfg.require_dome("test").unwrap();
    let patterns = (0..PATTERNS)
        .map(|p| {
            let mut v = vec![0.0; d.led_count()];
            v[10 * p] = 1.0;
            v
        })
        .collect();
    let steps = [1u32, 5]
        .iter()
        .flat_map(|&k| (0..PATTERNS).map(move |p| (k, p)))
        .enumerate()
        .map(|(i, (k, p))| EngineStep {
            key: StepKey { light: i as u32, view: k },
            kind: StepKind::Dome { rotation: k, turntable_rad: d.rotation_rad(k), shot: DomeShot::Pattern(p) },
            exposure_s: EXPOSURE_S,
        })
        .collect();
    (steps, patterns)
}

fn consumer() -> (mpsc::Sender<DomeCapture>, JoinHandle<Vec<DomeCapture>>) {
    let (tx, mut rx) = mpsc::channel(2);
    let task = tokio::spawn(async move {
        let mut out = Vec::new();
        while let Some(c) = rx.recv().await {
            out.push(c);
        }
        out
    });
    (tx, task)
}

/// Every capture once, in order, one frame per camera exposed together at its step's true
/// rotation with its step's pattern; returns the keys.
fn check_delivered(caps: &[DomeCapture], steps: &[EngineStep], cameras: usize) -> HashSet<StepKey> {
    let mut keys = HashSet::new();
    for w in caps.windows(2) {
        assert!(w[0].index < w[1].index, "out of order: {} then {}", w[0].index, w[1].index);
    }
    for c in caps {
        let s = &steps[c.index];
        assert!(keys.insert(s.key), "step {} delivered twice", c.index);
        let StepKind::Dome { turntable_rad, shot: DomeShot::Pattern(p), .. } = s.kind else { unreachable!() };
        assert_eq!(c.frames.len(), cameras);
        for f in &c.frames {
            let deg = f.data[0] as f64 / 10.0;
            assert!((deg - turntable_rad.to_degrees()).abs() < 0.5, "step {}: table at {deg} deg", c.index);
            assert_eq!(f.data[1] as usize, 10 * p + 1, "step {}: lit LED", c.index);
            assert_eq!(f.meta.exposure_s, EXPOSURE_S);
        }
        // All cameras trigger together (a recaptured camera exposes later).
        if c.attempts == 1 {
            let t0 = c.frames[0].meta.timestamp_s;
            assert!(c.frames.iter().all(|f| f.meta.timestamp_s == t0), "step {}: cameras apart", c.index);
        }
    }
    keys
}

async fn next_matching(rx: &mut broadcast::Receiver<Event>, pred: impl Fn(&Event) -> bool) -> Event {
    loop {
        let e = rx.recv().await.expect("event stream open");
        if pred(&e) {
            return e;
        }
    }
}

/// A whole run: its summary, its warnings, and the pause reason if it paused on a failure
/// (then aborted).
async fn run_dome(faults: &str, settings: &EngineSettings) -> (RunSummary, Vec<String>, Option<PauseReason>) {
    let faults = FaultScenario::from_toml(faults, "test").unwrap();
    let devices = dome(&faults, 2).await;
    let (steps, patterns) = steps();
    let (tx, caps) = consumer();
    let mut h =
        Engine::spawn(RigDevices::Dome { devices, patterns }, steps.clone(), HashSet::new(), settings.clone(), tx);
    let ev = h.events();
    watch_and_join(h, ev, caps, &steps, 2).await
}

async fn watch_and_join<C>(
    h: btfrig_acquire::RunHandle,
    mut ev: broadcast::Receiver<Event>,
    caps: JoinHandle<Vec<C>>,
    steps: &[EngineStep],
    cameras: usize,
) -> (RunSummary, Vec<String>, Option<PauseReason>)
where
    C: Send + 'static + AsDome,
{
    let mut warnings = Vec::new();
    let mut paused = None;
    loop {
        match ev.recv().await.unwrap() {
            Event::Warning(w) => warnings.push(w),
            Event::Paused { reason } => {
                paused = Some(reason);
                h.abort().unwrap();
            }
            Event::Finished(_) | Event::Aborted(_) => break,
            _ => {}
        }
    }
    let summary = match h.join().await {
        RunOutcome::Finished(s) => s,
        RunOutcome::Aborted { summary, .. } => summary,
    };
    let caps = caps.await.unwrap();
    C::check(&caps, steps, cameras);
    (summary, warnings, paused)
}

/// What the shared run checker does with each rig's captures.
trait AsDome: Sized {
    fn check(caps: &[Self], steps: &[EngineStep], cameras: usize);
}

impl AsDome for DomeCapture {
    fn check(caps: &[Self], steps: &[EngineStep], cameras: usize) {
        check_delivered(caps, steps, cameras);
    }
}

impl AsDome for CapturedFrame {
    fn check(caps: &[Self], _: &[EngineStep], _: usize) {
        assert!(caps.windows(2).all(|w| w[0].index < w[1].index));
    }
}

/// A gonio run of 12 steps on the simulated Bonn gonioreflectometer under `faults`.
async fn run_gonio(faults: &str, settings: &EngineSettings) -> (RunSummary, Vec<String>, Option<PauseReason>) {
    let cfg = RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "gonio").unwrap();
    let faults = FaultScenario::from_toml(faults, "test").unwrap();
    let clock = TokioClock::shared();
    let mut rig =
        SimRig::from_rig_config(&cfg, &faults, clock.clone(), Arc::new(FlatFrameSource::new(8, 6, 1000.0))).unwrap();
    btfrig_sim::capture::prepare(&mut rig).await.unwrap();
    let devices = GonioDevices { robot: rig.robot, rail: rig.rail, camera: rig.camera, clock };
    let steps: Vec<EngineStep> = (0..12)
        .map(|i| EngineStep {
            key: StepKey { light: i, view: 0 },
            kind: StepKind::Gonio {
                joints: btfrig_core::kinematics::JointState {
                    rail: 0.5 + 0.05 * i as f64,
                    robot: [0.0, 0.2, 0.0],
                    turntable: 0.0,
                },
            },
            exposure_s: EXPOSURE_S,
        })
        .collect();
    let (tx, mut rx) = mpsc::channel(2);
    let caps = tokio::spawn(async move {
        let mut out = Vec::new();
        while let Some(c) = rx.recv().await {
            out.push(c);
        }
        out
    });
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), settings.clone(), tx);
    let ev = h.events();
    watch_and_join::<CapturedFrame>(h, ev, caps, &steps, 1).await
}

/// What the engine did about each failure: the part of a warning after the error.
fn policy(warnings: &[String]) -> Vec<&str> {
    warnings.iter().filter_map(|w| w.rsplit_once("; ").map(|(_, p)| p)).collect()
}

#[tokio::test(start_paused = true)]
async fn a_dome_step_that_fails_transiently_is_retried_with_the_gonio_policy() {
    // A short retry budget and a low backoff cap, so the cap shows.
    let settings = EngineSettings { max_retries: 3, backoff_s: 0.25, max_backoff_s: 0.6, ..EngineSettings::default() };
    let (clean, _, _) = run_dome("description = \"none\"\n", &settings).await;
    assert_eq!((clean.captured, clean.retries), (12, 0));

    // The LED controller times out twice on step 3's pattern (its calls 4 and 5): the step
    // is retried with backoff 0.25 s, then 0.5 s, and costs exactly the two 5 s timeouts and
    // those waits; the retries are charged to the step.
    let (sum, warnings, paused) = run_dome("[[timeouts]]\ndevice = \"led_array\"\ncalls = [4, 5]\n", &settings).await;
    assert!(paused.is_none(), "{paused:?}");
    assert_eq!(sum.captured, 12);
    assert_eq!(sum.retried_steps, vec![(StepKey { light: 3, view: 1 }, 2)]);
    assert_eq!(policy(&warnings), vec!["retry 1 of 3 in 0.25 s", "retry 2 of 3 in 0.50 s"], "{warnings:?}");
    assert!(warnings[0].starts_with("step 3 (rotation 1, Pattern(3)): led_array: timeout"), "{}", warnings[0]);
    let extra = sum.hardware_s - clean.hardware_s;
    println!("dome: 2 LED timeouts cost {extra:.3} s of rig time (2 x 5 s + 0.25 s + 0.5 s)");
    assert!((extra - 10.75).abs() < 1e-6, "{extra}");

    // A frame lost on the link (both cameras' 8th read-out): each camera is triggered and
    // read again on its own, as a gonio frame is recaptured.
    let (sum, warnings, _) = run_dome("[dropped_frames]\nframes = [8]\n", &settings).await;
    assert_eq!((sum.captured, sum.retries), (12, 2));
    assert_eq!(sum.retried_steps, vec![(StepKey { light: 7, view: 5 }, 2)]);
    assert_eq!(policy(&warnings), vec!["capture again in 0.25 s"; 2], "{warnings:?}");

    // The same faults on a gonio: the same answers.
    let (g, gw, _) = run_gonio("[[timeouts]]\ndevice = \"rail\"\ncalls = [4, 5]\n", &settings).await;
    assert_eq!((g.captured, g.retries, g.retried_steps.len()), (12, 2, 1));
    assert_eq!(policy(&gw), vec!["retry 1 of 3 in 0.25 s", "retry 2 of 3 in 0.50 s"], "{gw:?}");

    // Four timeouts in a row exhaust the budget (waits 0.25, 0.5, then capped at 0.6 s) and
    // pause the run naming the step and the device, on either rig.
    let four = |dev: &str| format!("[[timeouts]]\ndevice = \"{dev}\"\ncalls = [4, 5, 6, 7]\n");
    let (sum, warnings, paused) = run_dome(&four("led_array"), &settings).await;
    let (_, gw, gpaused) = run_gonio(&four("rail"), &settings).await;
    let want = vec!["retry 1 of 3 in 0.25 s", "retry 2 of 3 in 0.50 s", "retry 3 of 3 in 0.60 s"];
    assert_eq!((policy(&warnings), policy(&gw)), (want.clone(), want), "{warnings:?} {gw:?}");
    let Some(PauseReason::StepFailed {
        index: 3, step: StepKind::Dome { rotation: 1, .. }, device, kind, message, ..
    }) = &paused
    else {
        panic!("{paused:?}")
    };
    assert_eq!((device.as_str(), *kind), ("led_array", ErrorKind::Timeout));
    assert!(message.ends_with("(retryable, gave up after 3 retries)"), "{message}");
    let Some(PauseReason::StepFailed { message: gm, .. }) = &gpaused else { panic!("{gpaused:?}") };
    assert!(gm.ends_with("(retryable, gave up after 3 retries)"), "{gm}");
    assert_eq!(sum.captured, 3);
}

#[tokio::test(start_paused = true)]
async fn a_dome_run_pauses_resumes_and_aborts_through_its_run_handle() {
    let settings = EngineSettings::default();
    // The LED controller fails for good on its 9th call (step 8's pattern).
    let faults = FaultScenario::from_toml("[[failures]]\ndevice = \"led_array\"\ncalls = [9]\n", "test").unwrap();
    let devices = dome(&faults, 2).await;
    let (steps, patterns) = steps();
    let (tx, caps) = consumer();
    let mut h = Engine::spawn(RigDevices::Dome { devices, patterns }, steps.clone(), HashSet::new(), settings, tx);
    let mut ev = h.events();

    // Pause on request: the step under way is delivered, then nothing while paused.
    next_matching(&mut ev, |e| matches!(e, Event::StepDone { index: 1, .. })).await;
    h.pause().unwrap();
    let mut done_at_pause = 0;
    loop {
        match ev.recv().await.unwrap() {
            Event::StepDone { .. } => done_at_pause += 1,
            Event::Paused { reason } => {
                assert_eq!(reason, PauseReason::Requested);
                break;
            }
            _ => {}
        }
    }
    assert!(done_at_pause <= 1, "{done_at_pause} steps after the pause request");
    tokio::time::sleep(std::time::Duration::from_secs(3600)).await;
    assert!(ev.try_recv().is_err(), "no events while paused");
    assert!(matches!(*h.state().borrow(), RunState::Paused(PauseReason::Requested)));
    h.resume().unwrap();
    next_matching(&mut ev, |e| matches!(e, Event::Resumed)).await;

    // A device fault pauses on the step, named as a dome step; a resume retries it.
    let Event::Paused { reason } = next_matching(&mut ev, |e| matches!(e, Event::Paused { .. })).await else {
        unreachable!()
    };
    let text = reason.to_string();
    assert!(
        text.starts_with("step 8 (rotation 5, Pattern(2)) failed: led_array: other:")
            && text.ends_with("(not retryable); fix the cause and resume to retry the step"),
        "{text}"
    );
    h.resume().unwrap();

    // Abort after step 9: the step under way finishes, the rest is left for a resume.
    next_matching(&mut ev, |e| matches!(e, Event::StepDone { index: 9, .. })).await;
    h.abort().unwrap();
    let (outcome, devices) = h.join_with_devices().await;
    let RunOutcome::Aborted { done, summary } = outcome else { panic!("{outcome:?}") };
    let first = caps.await.unwrap();
    assert_eq!(done, check_delivered(&first, &steps, 2));
    assert!((10..=11).contains(&first.len()), "{}", first.len());
    assert_eq!((summary.captured, summary.retries), (first.len(), 0));

    // A new run on the same devices with that `done` captures exactly the rest; its progress
    // ends at the total with an ETA of 0 measured from its own steps.
    let RigDevices::Dome { devices, patterns } = devices else { panic!("dome devices back") };
    let (tx, caps) = consumer();
    let mut h = Engine::spawn(
        RigDevices::Dome { devices, patterns },
        steps.clone(),
        done.clone(),
        EngineSettings::default(),
        tx,
    );
    let mut ev = h.events();
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    let second = caps.await.unwrap();
    let keys = check_delivered(&second, &steps, 2);
    assert!(keys.is_disjoint(&done));
    assert_eq!((sum.skipped_done, sum.captured), (done.len(), 12 - done.len()));
    let mut last = None;
    while let Ok(e) = ev.try_recv() {
        if let Event::Progress { done, total, eta_s } = e {
            last = Some((done, total, eta_s));
        }
    }
    assert_eq!(last, Some((12, 12, Some(0.0))));
}

#[tokio::test(start_paused = true)]
#[should_panic(expected = "a dome takes StepKind::Dome steps")]
async fn a_gonio_step_on_a_dome_is_refused_by_name() {
    let devices = dome(&FaultScenario::none(), 1).await;
    let (mut steps, patterns) = steps();
    steps[4].kind = StepKind::Gonio { joints: Default::default() };
    let (tx, _caps) = consumer();
    let _ = Engine::spawn(RigDevices::Dome { devices, patterns }, steps, HashSet::new(), EngineSettings::default(), tx);
}
