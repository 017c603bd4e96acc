//! Steering a dome run as a gonio run is steered (`btfrig_measurement::dome::run_controlled`):
//! pause between steps and resume, progress with an ETA of the remaining rig time, abort that
//! keeps the committed view groups for the same request to resume, and a device fault that
//! pauses the engine until it is resumed, or ends a session that stops on faults as paused.

use std::path::{Path, PathBuf};
use std::time::Duration;

use btfrig_measurement::dome::{run, run_controlled, DomeRunRequest, DomeRunSummary};
use btfrig_measurement::{RunControl, RunEvent, RunOutcome};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("btfrig-dome-control-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One camera, two rotations: 2 x 199 pattern frames plus 4 single-LED reference frames in
/// the first view group, so 402 steps.
const PLAN: &str = "name = \"dome-control\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\n\
                    material = \"leather\"\n[dome]\ncameras = [4]\nrotations = [1, 5]\nsample_brightness = 0.1\n";
const STEPS: usize = 402;

fn request(dir: &Path, faults: Option<&str>) -> DomeRunRequest {
    DomeRunRequest {
        plan_text: PLAN.into(),
        plan_path: dir.join("plan.toml"),
        out: dir.join("data"),
        faults: faults.map(String::from),
        preview: false,
        compressed_model: None,
    }
}

/// Runs `req` under `control`; `steer(event, control)` is called on every event.
fn steered(
    req: &DomeRunRequest,
    stop_on_fault: bool,
    mut steer: impl FnMut(&RunEvent, &RunControl),
) -> (DomeRunSummary, Vec<RunEvent>) {
    let control = RunControl::new();
    let handle = control.clone();
    let mut events = Vec::new();
    let s = run_controlled(req, &control, stop_on_fault, &mut |l| eprintln!("{l}"), &mut |e| {
        steer(e, &handle);
        events.push(e.clone());
    })
    .unwrap_or_else(|e| panic!("{e}"));
    (s, events)
}

/// Resumes from another thread a little later (an operator), so the engine really waits.
fn resume_later(c: &RunControl) {
    let c = c.clone();
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        c.resume().unwrap();
    });
}

fn report_status(dir: &Path) -> String {
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("data/report.json")).unwrap()).unwrap();
    r["status"].as_str().unwrap().to_string()
}

/// Pause and resume, then abort and resume; the ETA after the aborted session's last step
/// against the rig time the paused (complete) run still took from there.
#[test]
fn a_dome_run_pauses_between_steps_aborts_resumably_and_its_eta_is_the_remaining_rig_time() {
    btfrig_sim_backend::install();
    let dir = tmp("pause");
    let mut paused = false;
    let (s, events) = steered(&request(&dir, None), true, |e, c| match e {
        RunEvent::Progress { done: 50, .. } if !paused => {
            paused = true;
            c.pause().unwrap();
        }
        RunEvent::Paused { .. } => resume_later(c),
        _ => {}
    });
    assert!(s.stopped.is_none(), "{:?}", s.stopped);
    assert_eq!((s.textures, s.frames), (2 * 198, STEPS as u64));
    let RunEvent::Started { total, done_before, to_do, planned_hardware_s, resumed, .. } = &events[0] else {
        panic!("first event {:?}", events[0])
    };
    assert_eq!((*total, *done_before, *to_do, *resumed), (STEPS, 0, STEPS, false));
    // The planned rig time bounds the run's from below and comes close (the dry run's figure).
    assert!(*planned_hardware_s <= s.hardware_s && *planned_hardware_s > 0.95 * s.hardware_s, "{planned_hardware_s}");

    // Paused after the step under way, no step while paused, then resumed.
    let at = |f: &dyn Fn(&RunEvent) -> bool| events.iter().position(f).expect("the event");
    let p = at(&|e| matches!(e, RunEvent::Paused { .. }));
    let r = at(&|e| matches!(e, RunEvent::Resumed));
    let RunEvent::Paused { reason, .. } = &events[p] else { unreachable!() };
    assert_eq!(reason, "paused on request");
    let done_at_pause = events[..p]
        .iter()
        .filter_map(|e| if let RunEvent::Progress { done, .. } = e { Some(*done) } else { None })
        .next_back()
        .unwrap();
    assert!((50..=53).contains(&done_at_pause), "paused after {done_at_pause} steps");
    assert_eq!(r, p + 1, "nothing happens while paused: {:?}", &events[p..=r]);
    assert_eq!(report_status(&dir), "finished");

    // Progress: every step once, in order, ending with nothing left.
    let progress: Vec<(usize, Option<f64>)> = events
        .iter()
        .filter_map(|e| if let RunEvent::Progress { done, eta_s, .. } = e { Some((*done, *eta_s)) } else { None })
        .collect();
    assert_eq!(progress.iter().map(|p| p.0).collect::<Vec<_>>(), (1..=STEPS).collect::<Vec<_>>());
    assert_eq!(progress.last().unwrap().1, Some(0.0));
    // Every step delivered once; the dataset's textures: none at the start, then a view
    // group (198 LEDs of camera 4 at one rotation) at a time.
    assert_eq!(events.iter().filter(|e| matches!(e, RunEvent::DomeStepDone { .. })).count(), STEPS);
    let textures: Vec<(u64, u64)> = events
        .iter()
        .filter_map(|e| match e {
            RunEvent::TexturesCommitted { textures, total, .. } => Some((*textures, *total)),
            _ => None,
        })
        .collect();
    assert_eq!(textures, [(0, 396), (198, 396), (396, 396)]);

    // The same plan aborted after 300 steps (in the second view group): the first view group
    // (203 steps) stays committed, the report says aborted.
    let dir2 = tmp("abort");
    let req2 = request(&dir2, None);
    let (a, events) = steered(&req2, true, |e, c| {
        if let RunEvent::Progress { done: 300, .. } = e {
            c.abort().unwrap();
        }
    });
    assert_eq!(a.stopped, Some(RunOutcome::Aborted));
    assert!(events.iter().any(|e| matches!(e, RunEvent::Stopping { reason } if reason == "aborted on request")));
    let n = a.frames as usize;
    assert!((300..=303).contains(&n), "{n} frames");
    assert_eq!(a.textures, 198);
    assert_eq!(report_status(&dir2), "aborted");

    // The simulated rig's timing is seeded, so the complete run took a.hardware_s for its
    // first n steps: the ETA it showed then is the rig time it still took (no move is left).
    let eta = progress[n - 1].1.unwrap();
    let left = s.hardware_s - a.hardware_s;
    eprintln!("after {n} steps: ETA {eta:.3} s, rig time still taken {left:.3} s (run {:.3} s)", s.hardware_s);
    assert!((eta / left - 1.0).abs() < 0.02, "after {n} steps: ETA {eta} s, rig time left {left} s");

    // The same request resumes the aborted run: the second view group only.
    let again = run(&req2, &mut |l| eprintln!("{l}")).unwrap();
    assert_eq!((again.textures, again.views_resumed, again.stopped.clone()), (198, 1, None));
    assert_eq!(report_status(&dir2), "finished");
    let v = btfrig_store::verify(&dir2.join("data"));
    assert!(v.is_ok(), "{v:?}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir2);
}

#[test]
fn a_device_fault_pauses_the_dome_run_until_resumed_unless_the_session_stops_on_faults() {
    btfrig_sim_backend::install();
    let dir = tmp("fault");
    // The LED controller fails for good on its 30th pattern (step 29).
    std::fs::write(dir.join("leds.toml"), "[[failures]]\ndevice = \"led_array\"\ncalls = [30]\n").unwrap();
    let req = request(&dir, Some("leds.toml"));
    let (s, events) = steered(&req, false, |e, c| {
        if let RunEvent::Paused { .. } = e {
            resume_later(c);
        }
    });
    let reasons: Vec<&str> = events
        .iter()
        .filter_map(|e| if let RunEvent::Paused { reason, .. } = e { Some(reason.as_str()) } else { None })
        .collect();
    assert_eq!(reasons.len(), 1, "{reasons:?}");
    assert!(
        reasons[0].starts_with("step 29 (rotation 1, Pattern(29)) failed: led_array")
            && reasons[0].contains("not retryable")
            && reasons[0].ends_with("resume to retry the step"),
        "{}",
        reasons[0]
    );
    assert!(events.iter().any(|e| matches!(e, RunEvent::Resumed)));
    assert!(s.stopped.is_none());
    assert_eq!((s.textures, s.frames), (2 * 198, STEPS as u64));
    // The same fault ends a session that stops on faults (`btfrig run`) as paused, naming the
    // step in the summary and the report; the same request without the fault resumes.
    let _ = std::fs::remove_dir_all(dir.join("data"));
    let s = run(&req, &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
    let Some(RunOutcome::Paused { reason, .. }) = &s.stopped else { panic!("{:?}", s.stopped) };
    assert!(reason.starts_with("step 29 (rotation 1, Pattern(29)) failed: led_array"), "{reason}");
    assert_eq!((s.frames, s.textures), (29, 0));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("data/report.json")).unwrap()).unwrap();
    assert_eq!((r["status"].as_str(), r["captures"].as_u64()), (Some("paused"), Some(0)), "{r}");
    assert_eq!(
        (r["paused_step"]["index"].as_u64(), r["paused_step"]["device"].as_str()),
        (Some(29), Some("led_array"))
    );
    let s = run(&request(&dir, Some("none")), &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
    assert!(s.stopped.is_none());
    assert_eq!((s.frames, s.textures), (STEPS as u64, 2 * 198));
    let _ = std::fs::remove_dir_all(&dir);
}
