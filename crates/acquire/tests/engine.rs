//! The run engine against the simulated Bonn gonioreflectometer, in virtual time.

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use async_trait::async_trait;
use btfrig_acquire::{
    Command, CommandError, Engine, EngineSettings, EngineStep, Event, ExposureControl, GonioDevices, PauseReason,
    RigDevices, RunHandle, RunOutcome, RunState, RunSummary, StepKind,
};
use btfrig_core::capture::{CapturedFrame, StepKey};
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::Gonio;
use btfrig_core::sampling::Sampling;
use btfrig_hw::CaptureSettings;
use btfrig_hw::{AxisLimits, Device, DeviceError, DeviceInfo, ErrorKind, MoveOptions, Rail, TokioClock};
use btfrig_planner::{plan, PairSelection, PlanRequest, Schedule};
use btfrig_sim::capture::prepare;
use btfrig_sim::{FaultScenario, FlatFrameSource, FrameSource, SensorFormat, SimRig, SimWorld, TrueState};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;

const EXPOSURE_S: f64 = 0.01;

fn cfg() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap()
}

fn schedule(cfg: &RigConfig, pairs: PairSelection) -> Schedule {
    let gonio = Gonio::new(cfg.geometry.clone()).unwrap();
    let s = Sampling::bonn81();
    let bytes = cfg.timing.camera.frame_bytes.unwrap();
    plan(&PlanRequest::new(&gonio, &s, &s, &cfg.timing, EXPOSURE_S, bytes).with_pairs(pairs)).unwrap()
}

/// 40 reachable pairs: lights 0..8 with views 10..15.
fn forty(cfg: &RigConfig) -> Schedule {
    let pairs = (0..8).flat_map(|l| (10..15).map(move |v| (l, v))).collect();
    let s = schedule(cfg, PairSelection::List(pairs));
    assert_eq!(s.captures.len(), 40, "skipped: {:?}", s.skipped);
    s
}

/// A flat frame whose first three samples record the TRUE pose during the exposure (rail,
/// pan + 180, tilt + 180; tenths of a degree), so a test can check that every delivered frame,
/// recaptures included, was exposed at its own step's pose.
struct PoseFrameSource(FlatFrameSource);

impl FrameSource for PoseFrameSource {
    fn format(&self) -> SensorFormat {
        self.0.format()
    }
    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame {
        let mut f = self.0.render(truth, settings, seed);
        let j = &truth.joints;
        let enc = |deg: f64| (deg * 10.0).round().clamp(0.0, 4095.0) as u16;
        f.data[0] = enc(j.rail.to_degrees());
        f.data[1] = enc(j.robot[0].to_degrees() + 180.0);
        f.data[2] = enc(j.robot[1].to_degrees() + 180.0);
        f
    }
}

/// The true (rail, pan, tilt) of a frame from [`PoseFrameSource`], degrees.
fn pose_of(f: &RawFrame) -> [f64; 3] {
    [f.data[0] as f64 / 10.0, f.data[1] as f64 / 10.0 - 180.0, f.data[2] as f64 / 10.0 - 180.0]
}

/// A homed rig with a warm lamp; the clock is read after preparation by the caller.
async fn rig(cfg: &RigConfig, faults: &FaultScenario) -> (GonioDevices, SimWorld) {
    let clock = TokioClock::shared();
    let mut rig = SimRig::from_rig_config(
        cfg,
        faults,
        clock.clone(),
        Arc::new(PoseFrameSource(FlatFrameSource::new(8, 6, 1000.0))),
    )
    .unwrap();
    prepare(&mut rig).await.unwrap();
    let SimRig { world, robot, rail, camera, .. } = rig;
    (GonioDevices { robot, rail, camera, clock }, world)
}

/// Collects every delivered frame until the engine drops its sender.
fn consumer(capacity: usize) -> (mpsc::Sender<CapturedFrame>, JoinHandle<Vec<CapturedFrame>>) {
    let (tx, mut rx) = mpsc::channel(capacity);
    let task = tokio::spawn(async move {
        let mut out = Vec::new();
        while let Some(f) = rx.recv().await {
            out.push(f);
        }
        out
    });
    (tx, task)
}

async fn next_matching(rx: &mut broadcast::Receiver<Event>, pred: impl Fn(&Event) -> bool) -> Event {
    loop {
        let e = rx.recv().await.expect("event stream open");
        if pred(&e) {
            return e;
        }
    }
}

/// Every frame once, in schedule order, matching its step; returns the keys.
fn check_delivered(frames: &[CapturedFrame], steps: &[EngineStep]) -> HashSet<StepKey> {
    let mut keys = HashSet::new();
    for w in frames.windows(2) {
        assert!(w[0].index < w[1].index, "out of order: {} then {}", w[0].index, w[1].index);
    }
    for f in frames {
        assert!(keys.insert(f.key), "{} delivered twice", f.key);
        let s = &steps[f.index];
        assert_eq!(f.key, s.key);
        assert_eq!(Some(f.joints), s.joints());
        assert_eq!(f.frame.meta.exposure_s, EXPOSURE_S);
        assert!(f.attempts >= 1);
        let t = &f.times;
        assert!(t.move_start_s <= t.move_end_s && t.move_end_s <= t.trigger_start_s, "{t:?}");
        assert!(t.trigger_start_s < t.trigger_end_s && t.trigger_end_s < t.transfer_end_s, "{t:?}");
        // The frame is the one of the recorded trigger, exposed at this step's pose (within
        // the simulated positioning error, well under a degree).
        let m = &f.frame.meta;
        assert!(t.trigger_start_s <= m.timestamp_s && m.timestamp_s <= t.trigger_end_s, "{t:?} {}", m.timestamp_s);
        let j = s.joints().unwrap();
        let want = [j.rail.to_degrees(), j.robot[0].to_degrees(), j.robot[1].to_degrees()];
        for (got, want) in pose_of(&f.frame).iter().zip(want) {
            assert!((got - want).abs() < 0.8, "step {}: true pose {:?}, commanded {want}", f.index, pose_of(&f.frame));
        }
    }
    keys
}

async fn run_forty(overlap: bool) -> (RunOutcome, Vec<CapturedFrame>, Schedule) {
    let cfg = cfg();
    let sched = forty(&cfg);
    let steps = EngineStep::from_schedule(&sched);
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let settings = EngineSettings { overlap, ..EngineSettings::default() };
    let outcome = Engine::spawn(devices, steps.clone(), HashSet::new(), settings, tx).join().await;
    let frames = frames.await.unwrap();
    assert_eq!(frames.len(), 40);
    let keys = check_delivered(&frames, &steps);
    assert_eq!(keys, steps.iter().map(|s| s.key).collect());
    (outcome, frames, sched)
}

#[tokio::test(start_paused = true)]
async fn forty_steps_delivered_once_in_order_and_overlap_matches_the_planner() {
    let (outcome, frames, sched) = run_forty(true).await;
    let RunOutcome::Finished(sum) = outcome else { panic!("{outcome:?}") };
    assert_eq!((sum.total, sum.captured, sum.skipped_done, sum.retries), (40, 40, 0, 0));
    assert!(frames.iter().all(|f| f.attempts == 1));
    // A consumer that keeps up: the 4-frame channel never fills and capture never waits on it.
    let q = sum.frame_queue;
    assert_eq!((q.capacity, q.delivered, q.full_waits), (4, 40, 0), "{q:?}");
    assert!(q.max_fill < q.capacity && q.full_wait_s == 0.0, "{q:?}");

    let planned = sched.timing.hardware_s;
    let rel = (sum.hardware_s - planned).abs() / planned;
    let (seq_outcome, _, _) = run_forty(false).await;
    let RunOutcome::Finished(seq) = seq_outcome else { panic!() };
    let seq_sum: f64 = {
        let model = btfrig_planner::TimingModel::new(&cfg().timing);
        let mut prev = sched.start.joints;
        let mut exp = sched.start.exposure_s;
        sched
            .steps()
            .map(|(c, _)| {
                let t = model.step_time(prev.as_ref(), exp, c).sequential_s();
                prev = Some(c.joints);
                exp = Some(c.exposure_s);
                t
            })
            .sum()
    };
    println!(
        "40 steps: overlapped {:.2} s, planner {planned:.2} s ({:+.3} %), sequential measured {:.2} s, \
         sequential model {seq_sum:.2} s",
        sum.hardware_s,
        100.0 * (sum.hardware_s - planned) / planned,
        seq.hardware_s
    );
    assert!(rel < 0.02, "overlapped {} s vs planner {planned} s", sum.hardware_s);
    // The sequential engine run is the planner's step-by-step sum, and clearly slower.
    assert!((seq.hardware_s - seq_sum).abs() / seq_sum < 0.02, "{} vs {seq_sum}", seq.hardware_s);
    assert!(sum.hardware_s < 0.9 * seq.hardware_s, "{} vs {}", sum.hardware_s, seq.hardware_s);
}

#[tokio::test(start_paused = true)]
async fn flaky_rig_full_bonn_plan_completes_with_counted_retries_and_no_duplicates() {
    let cfg = cfg();
    let sched = schedule(&cfg, PairSelection::All);
    let steps = EngineStep::from_schedule(&sched);
    let flaky = FaultScenario::from_toml(include_str!("../../../sim/faults/flaky.toml"), "flaky.toml").unwrap();
    let (devices, world) = rig(&cfg, &flaky).await;
    let (tx, frames) = consumer(8);
    let wall = std::time::Instant::now();
    let outcome = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx).join().await;
    let frames = frames.await.unwrap();
    let RunOutcome::Finished(sum) = outcome else { panic!("{outcome:?}") };
    assert_eq!(frames.len(), steps.len());
    check_delivered(&frames, &steps);
    let faults = world.fault_log();
    let attempts: u32 = frames.iter().map(|f| f.attempts).sum();
    println!(
        "flaky 81x81: {} captures, {} faults injected, {} retries on {} steps, hardware {:.0} s \
         (planner {:.0} s, bound {:.0} s), wall {:.2} s",
        frames.len(),
        faults.len(),
        sum.retries,
        sum.retried_steps.len(),
        sum.hardware_s,
        sched.timing.hardware_s,
        sched.critical_path_s,
        wall.elapsed().as_secs_f64()
    );
    assert!(sum.retries > 0);
    assert!(faults.iter().any(|f| f.kind == btfrig_sim::FaultKind::Disconnected));
    assert!(faults.iter().any(|f| f.kind == btfrig_sim::FaultKind::DroppedFrame));
    // Every retry answers an injected fault (a failed reconnect is a fault but no retry).
    assert!(sum.retries as usize <= faults.len(), "{} retries, {} faults", sum.retries, faults.len());
    assert_eq!(attempts - frames.len() as u32, sum.retries, "per-step attempts add up to the total");
    assert_eq!(sum.retried_steps.iter().map(|r| r.1).sum::<u32>(), sum.retries);
    // Faults cost time: each at most its operation's timeout (60 s for a move), a backoff and
    // a recapture (a move back, trigger and a 5 s transfer: < 15 s here).
    let extra = sum.hardware_s - sched.timing.hardware_s;
    assert!(extra > 0.0);
    assert!(extra < faults.len() as f64 * 75.0, "{extra} s extra for {} faults", faults.len());
}

#[tokio::test(start_paused = true)]
async fn fault_free_full_plan_is_within_two_percent_of_the_critical_path() {
    let cfg = cfg();
    let sched = schedule(&cfg, PairSelection::All);
    let steps = EngineStep::from_schedule(&sched);
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(8);
    let outcome = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx).join().await;
    let frames = frames.await.unwrap();
    let RunOutcome::Finished(sum) = outcome else { panic!("{outcome:?}") };
    assert_eq!(frames.len(), 6480);
    println!(
        "81x81 fault-free: hardware {:.1} s, planner {:.1} s, critical path {:.1} s, naive order {:.1} s",
        sum.hardware_s, sched.timing.hardware_s, sched.critical_path_s, sched.naive_order_hardware_s
    );
    assert!((sum.hardware_s - sched.critical_path_s).abs() / sched.critical_path_s < 0.02);
}

#[tokio::test(start_paused = true)]
async fn permanent_disconnect_pauses_with_a_message_naming_the_camera_then_abort_keeps_done() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let faults = FaultScenario::from_toml(
        "description = \"camera gone for good\"\n[[disconnects]]\ndevice = \"camera\"\nat_call = 30\n",
        "test",
    )
    .unwrap();
    let (devices, _world) = rig(&cfg, &faults).await;
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    let Event::Paused { reason } = next_matching(&mut ev, |e| matches!(e, Event::Paused { .. })).await else {
        unreachable!()
    };
    let PauseReason::StepFailed { device, kind, .. } = &reason else { panic!("{reason:?}") };
    assert_eq!((device.as_str(), *kind), ("camera", ErrorKind::Disconnected));
    let text = reason.to_string();
    assert!(text.contains("camera: disconnected") && text.contains("gave up after 5 retries"), "{text}");
    assert!(text.starts_with("step "), "{text}");
    assert!(matches!(*h.state().borrow(), RunState::Paused(_)));
    // Resuming retries the step; the camera stays away, so the run pauses again.
    h.resume().unwrap();
    next_matching(&mut ev, |e| matches!(e, Event::Resumed)).await;
    next_matching(&mut ev, |e| matches!(e, Event::Paused { .. })).await;
    h.abort().unwrap();
    let RunOutcome::Aborted { done, summary } = h.join().await else { panic!() };
    let frames = frames.await.unwrap();
    let keys = check_delivered(&frames, &steps);
    assert!(!frames.is_empty() && frames.len() < 40, "{}", frames.len());
    assert_eq!(done, keys);
    assert_eq!(summary.captured, frames.len());
    assert_eq!(summary.retries, 10, "5 per attempt of the failing operation, two attempts");
}

#[tokio::test(start_paused = true)]
async fn healing_disconnects_are_reconnected_and_retried() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    // Short outages of the camera and the robot in the middle of the run.
    let faults = FaultScenario::from_toml(
        "description = \"two short outages\"\n\
         [[disconnects]]\ndevice = \"camera\"\nat_call = 20\nreconnect_after_calls = 2\n\
         [[disconnects]]\ndevice = \"robot\"\nat_call = 15\nreconnect_after_calls = 2\n",
        "test",
    )
    .unwrap();
    let (devices, world) = rig(&cfg, &faults).await;
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    let frames = frames.await.unwrap();
    assert_eq!(frames.len(), 40);
    check_delivered(&frames, &steps);
    let mut warnings = Vec::new();
    while let Ok(e) = ev.try_recv() {
        if let Event::Warning(w) = e {
            warnings.push(w);
        }
    }
    assert!(warnings.iter().any(|w| w.contains("camera: disconnected")), "{warnings:?}");
    assert!(warnings.iter().any(|w| w.contains("robot: disconnected")), "{warnings:?}");
    // Each outage (2 calls): the failing call and the reconnect call fail, the retry succeeds.
    assert_eq!(world.fault_log().len(), 4, "{:?}", world.fault_log());
    assert!(warnings.iter().filter(|w| w.contains("reconnect failed")).count() == 2, "{warnings:?}");
    assert_eq!(sum.retries, 2);
    assert_eq!(sum.retried_steps.len(), 2);
}

/// A rail whose emergency stop can be pressed: moves fail with a non-retryable error.
struct StoppableRail {
    inner: Box<dyn Rail>,
    stopped: Arc<AtomicBool>,
}

#[async_trait]
impl Device for StoppableRail {
    fn info(&self) -> &DeviceInfo {
        self.inner.info()
    }
}

#[async_trait]
impl Rail for StoppableRail {
    fn limits(&self) -> AxisLimits {
        self.inner.limits()
    }
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.inner.home(opts).await
    }
    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        if self.stopped.load(Ordering::SeqCst) {
            return Err(DeviceError::new(self.name(), ErrorKind::Other, "emergency stop pressed"));
        }
        self.inner.move_to_rad(angle_rad, opts).await
    }
    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        self.inner.position_rad().await
    }
}

#[tokio::test(start_paused = true)]
async fn non_retryable_error_pauses_and_resume_after_the_fix_completes() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let (mut devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let stopped = Arc::new(AtomicBool::new(false));
    devices.rail = Box::new(StoppableRail { inner: devices.rail, stopped: stopped.clone() });
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    next_matching(&mut ev, |e| matches!(e, Event::StepDone { index: 9, .. })).await;
    stopped.store(true, Ordering::SeqCst);
    let Event::Paused { reason } = next_matching(&mut ev, |e| matches!(e, Event::Paused { .. })).await else {
        unreachable!()
    };
    let PauseReason::StepFailed { index, key, device, kind, .. } = &reason else { panic!("{reason:?}") };
    assert_eq!((device.as_str(), *kind), ("rail", ErrorKind::Other));
    assert_eq!(*key, steps[*index].key);
    let text = reason.to_string();
    assert!(text.contains(&format!("step {index} ({key})")), "{text}");
    assert!(text.contains("rail: other: emergency stop pressed (not retryable)"), "{text}");
    // Still paused after a long wait: nothing more is delivered.
    tokio::time::sleep(std::time::Duration::from_secs(3600)).await;
    assert!(matches!(*h.state().borrow(), RunState::Paused(_)));
    stopped.store(false, Ordering::SeqCst);
    h.resume().unwrap();
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    let frames = frames.await.unwrap();
    assert_eq!(frames.len(), 40);
    check_delivered(&frames, &steps);
    assert_eq!(sum.retries, 0, "a non-retryable error is not retried");
}

#[tokio::test(start_paused = true)]
async fn out_of_range_move_pauses_naming_the_rail_and_is_not_retried() {
    let cfg = cfg();
    let mut steps = EngineStep::from_schedule(&forty(&cfg))[..3].to_vec();
    let StepKind::Gonio { joints } = &mut steps[1].kind else { unreachable!() };
    joints.rail = 200f64.to_radians(); // the sim rail ends at 180 deg
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    let Event::Paused { reason } = next_matching(&mut ev, |e| matches!(e, Event::Paused { .. })).await else {
        unreachable!()
    };
    let PauseReason::StepFailed { index, device, kind, .. } = &reason else { panic!("{reason:?}") };
    assert_eq!((*index, device.as_str(), *kind), (1, "rail", ErrorKind::OutOfRange));
    assert!(reason.to_string().contains("(not retryable)"), "{reason}");
    h.abort().unwrap();
    let RunOutcome::Aborted { done, summary } = h.join().await else { panic!() };
    assert_eq!(done, HashSet::from([steps[0].key]));
    assert_eq!(summary.retries, 0);
    assert_eq!(frames.await.unwrap().len(), 1);
}

async fn pause_after(h: &mut RunHandle, ev: &mut broadcast::Receiver<Event>, index: usize) {
    next_matching(ev, |e| matches!(e, Event::StepDone { index: i, .. } if *i == index)).await;
    h.pause().unwrap();
}

#[tokio::test(start_paused = true)]
async fn pause_holds_between_steps_and_resume_finishes() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    pause_after(&mut h, &mut ev, 4).await;
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
    // The step under way was finished (its frame delivered), no more.
    assert!((1..=2).contains(&done_at_pause), "{done_at_pause} steps after the pause request");
    tokio::time::sleep(std::time::Duration::from_secs(3600)).await;
    assert!(ev.try_recv().is_err(), "no events while paused");
    h.resume().unwrap();
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    assert_eq!(sum.captured, 40);
    let frames = frames.await.unwrap();
    check_delivered(&frames, &steps);
    // Progress reached the total, and its ETA came from measured step times.
    let mut last = None;
    while let Ok(e) = ev.try_recv() {
        if let Event::Progress { done, total, eta_s } = e {
            last = Some((done, total, eta_s));
        }
    }
    assert_eq!(last, Some((40, 40, Some(0.0))));
}

#[tokio::test(start_paused = true)]
async fn abort_stops_after_the_current_step_and_resume_with_done_skips_them() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), EngineSettings::default(), tx);
    let mut ev = h.events();
    next_matching(&mut ev, |e| matches!(e, Event::StepDone { index: 11, .. })).await;
    h.abort().unwrap();
    let (outcome, devices) = h.join_with_devices().await;
    let RigDevices::Gonio(devices) = devices else { panic!("gonio devices back") };
    let RunOutcome::Aborted { done, summary } = outcome else { panic!("{outcome:?}") };
    let first = frames.await.unwrap();
    assert_eq!(done, check_delivered(&first, &steps));
    assert!((12..=13).contains(&first.len()), "{}", first.len());
    assert_eq!(summary.captured, first.len());

    // Resume on the same devices: only the remaining steps are captured.
    let (tx, frames) = consumer(4);
    let h = Engine::spawn(devices, steps.clone(), done.clone(), EngineSettings::default(), tx);
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    let second = frames.await.unwrap();
    check_delivered(&second, &steps);
    assert_eq!(sum.skipped_done, done.len());
    assert_eq!(sum.captured + sum.skipped_done, 40);
    let mut all: Vec<StepKey> = first.iter().chain(&second).map(|f| f.key).collect();
    all.sort();
    let mut want: Vec<StepKey> = steps.iter().map(|s| s.key).collect();
    want.sort();
    assert_eq!(all, want, "every step exactly once over both runs");
}

#[tokio::test(start_paused = true)]
async fn scattered_done_steps_are_skipped_and_the_rest_captured_at_their_poses() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let done: HashSet<StepKey> = steps.iter().step_by(3).map(|s| s.key).collect();
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let RunOutcome::Finished(sum) =
        Engine::spawn(devices, steps.clone(), done.clone(), EngineSettings::default(), tx).join().await
    else {
        panic!()
    };
    let frames = frames.await.unwrap();
    let keys = check_delivered(&frames, &steps);
    assert!(keys.is_disjoint(&done));
    assert_eq!(keys.len() + done.len(), 40);
    assert_eq!((sum.skipped_done, sum.captured), (done.len(), 40 - done.len()));
}

#[tokio::test(start_paused = true)]
async fn slow_consumer_backpressure_delays_the_run_without_losing_frames() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg))[..10].to_vec();
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, mut rx) = mpsc::channel::<CapturedFrame>(1);
    let consumer = tokio::spawn(async move {
        let mut n = 0;
        while let Some(_f) = rx.recv().await {
            // A consumer twice as slow as the rig's ~5.7 s per frame.
            tokio::time::sleep(std::time::Duration::from_secs(12)).await;
            n += 1;
        }
        n
    });
    let RunOutcome::Finished(sum) =
        Engine::spawn(devices, steps, HashSet::new(), EngineSettings::default(), tx).join().await
    else {
        panic!()
    };
    assert_eq!(consumer.await.unwrap(), 10);
    // With a 1-frame channel the engine can be at most ~2 frames ahead of the consumer.
    assert!(sum.hardware_s > 8.0 * 12.0, "{} s", sum.hardware_s);
    // The frame queue says so: full, and capture waited on it (about 12 - 6 s per frame).
    let q = sum.frame_queue;
    assert_eq!((q.capacity, q.delivered, q.max_fill), (1, 10, 1), "{q:?}");
    assert!(q.full_waits >= 8 && q.full_wait_s > 8.0 * 4.0, "{q:?}");
}

#[tokio::test(start_paused = true)]
async fn a_listener_that_never_reads_counts_dropped_events_and_the_run_still_delivers_every_frame() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg))[..10].to_vec();
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    // Ten steps send 2 events each (StepDone, Progress) and a Finished: 21 into a queue of 4.
    let settings = EngineSettings { event_capacity: 4, ..EngineSettings::default() };
    let mut h = Engine::spawn(devices, steps.clone(), HashSet::new(), settings, tx);
    let mut stalled = h.events();
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    let frames = frames.await.unwrap();
    assert_eq!(frames.len(), 10);
    check_delivered(&frames, &steps);
    assert_eq!(sum.captured, 10);
    assert_eq!(sum.events_dropped, 21 - 4, "every event but the last 4 was overwritten unseen");
    // The listener's side agrees: it lagged by exactly what the engine counted.
    let Err(broadcast::error::RecvError::Lagged(n)) = stalled.recv().await else { panic!("no lag") };
    assert_eq!(n, sum.events_dropped);
}

#[tokio::test(start_paused = true)]
async fn a_listener_that_keeps_up_loses_nothing() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg))[..10].to_vec();
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let settings = EngineSettings { event_capacity: 4, ..EngineSettings::default() };
    let mut h = Engine::spawn(devices, steps, HashSet::new(), settings, tx);
    let mut ev = h.events();
    let listener = tokio::spawn(async move {
        let mut n = 0;
        while let Ok(e) = ev.recv().await {
            n += 1;
            if matches!(e, Event::Finished(_)) {
                break;
            }
        }
        n
    });
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    assert_eq!(frames.await.unwrap().len(), 10);
    assert_eq!((listener.await.unwrap(), sum.events_dropped), (21, 0));
}

#[tokio::test(start_paused = true)]
async fn a_full_command_queue_refuses_the_command_by_name() {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg))[..3].to_vec();
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let h = Engine::spawn(devices, steps, HashSet::new(), EngineSettings::default(), tx);
    // The engine task has not run yet (current-thread runtime): nothing reads the queue.
    for _ in 0..btfrig_acquire::COMMAND_CAPACITY {
        h.resume().unwrap();
    }
    let e = h.pause().unwrap_err();
    assert_eq!(e, CommandError::Full { command: Command::Pause });
    assert!(e.to_string().contains("16 unread commands"), "{e}");
    let RunOutcome::Finished(sum) = h.join().await else { panic!() };
    assert_eq!((sum.captured, frames.await.unwrap().len()), (3, 3));
}

/// Brackets of three kinds on the 40-step schedule: light 1 plans two exposures at the pose,
/// light 2 asks for two more after inspecting its frames (a return trip under overlap), light
/// 3 is inspected and needs nothing more.
struct TestBrackets;

impl ExposureControl for TestBrackets {
    fn planned(&mut self, step: &EngineStep) -> Vec<f64> {
        match step.key.light {
            1 => vec![EXPOSURE_S, EXPOSURE_S / 8.0],
            _ => vec![EXPOSURE_S],
        }
    }
    fn inspects(&self) -> bool {
        true
    }
    fn next(&mut self, step: &EngineStep, frames: &[RawFrame]) -> Option<f64> {
        (step.key.light == 2 && frames.len() < 3).then(|| frames.last().unwrap().meta.exposure_s / 8.0)
    }
}

async fn run_brackets(overlap: bool, control: Option<TestBrackets>) -> (RunSummary, Vec<CapturedFrame>) {
    let cfg = cfg();
    let steps = EngineStep::from_schedule(&forty(&cfg));
    let (devices, _world) = rig(&cfg, &FaultScenario::none()).await;
    let (tx, frames) = consumer(4);
    let settings = EngineSettings { overlap, ..EngineSettings::default() };
    let handle = match control {
        Some(c) => Engine::spawn_with_exposure(devices, steps, HashSet::new(), settings, tx, Box::new(c)),
        None => Engine::spawn(devices, steps, HashSet::new(), settings, tx),
    };
    let RunOutcome::Finished(sum) = handle.join().await else { panic!("not finished") };
    (sum, frames.await.unwrap())
}

#[tokio::test(start_paused = true)]
async fn brackets_are_taken_at_the_step_pose_and_cost_only_their_own_time() {
    let steps = EngineStep::from_schedule(&forty(&cfg()));
    for overlap in [true, false] {
        let (single, _) = run_brackets(overlap, None).await;
        let (sum, frames) = run_brackets(overlap, Some(TestBrackets)).await;
        assert_eq!(frames.len(), 40);
        let mut extra = 0.0;
        for f in &frames {
            let s = &steps[f.index];
            let all: Vec<&RawFrame> = std::iter::once(&f.frame).chain(&f.bracket).collect();
            let exposures: Vec<f64> = all.iter().map(|fr| fr.meta.exposure_s).collect();
            let want = match s.key.light {
                1 => vec![EXPOSURE_S, EXPOSURE_S / 8.0],
                2 => vec![EXPOSURE_S, EXPOSURE_S / 8.0, EXPOSURE_S / 64.0],
                _ => vec![EXPOSURE_S],
            };
            assert_eq!(exposures, want, "step {}", f.index);
            // Every exposure at this step's pose (return trips included), in time order, the
            // last one the recorded trigger.
            for fr in &all {
                let j = s.joints().unwrap();
                let want = [j.rail.to_degrees(), j.robot[0].to_degrees(), j.robot[1].to_degrees()];
                for (got, want) in pose_of(fr).iter().zip(want) {
                    assert!((got - want).abs() < 0.8, "step {}: exposure at {:?}", f.index, pose_of(fr));
                }
            }
            assert!(all.windows(2).all(|w| w[0].meta.timestamp_s < w[1].meta.timestamp_s));
            let t = &f.times;
            let last = all.last().unwrap().meta.timestamp_s;
            assert!(t.trigger_start_s <= last && last <= t.trigger_end_s, "{t:?} {last}");
            assert_eq!(t.bracket_s > 0.0, all.len() > 1, "step {}: {t:?}", f.index);
            extra += t.bracket_s;
        }
        // A bracket costs the rig its own time and nothing else: the inspected single-exposure
        // steps keep the overlap of their read-out with the next move.
        let added = sum.hardware_s - single.hardware_s;
        println!(
            "overlap {overlap}: single exposures {:.2} s, with brackets {:.2} s (+{added:.2} s), bracket time {extra:.2} s",
            single.hardware_s, sum.hardware_s
        );
        assert!((added - extra).abs() < 0.01 * single.hardware_s, "added {added} s, brackets {extra} s");
        // Light 2 (5 steps) costs two exposures each with a return trip under overlap.
        assert!(extra > 5.0 * 2.0 * 5.0, "{extra}");
    }
}

#[test]
fn backoff_doubles_and_is_capped() {
    let s = EngineSettings { backoff_s: 0.5, max_backoff_s: 3.0, ..EngineSettings::default() };
    let w: Vec<f64> = (0..5).map(|k| s.backoff_for(k)).collect();
    assert_eq!(w, vec![0.5, 1.0, 2.0, 3.0, 3.0]);
}
