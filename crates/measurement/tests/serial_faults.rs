//! Run-level fault tests on the emulated serial rig (rig-configs/bonn-gonio-serial.toml):
//! the tiny plan through `btfrig_measurement::run`, with faults injected into the emulated
//! firmware (`btfrig_emulated_backend::EmulatedBackend::with_link_faults`, docs/serial.md).
//! Each fault ends in a retried step or a paused, resumable run naming the device; nothing
//! captured is lost, and the textures equal those of a fault-free run on the same rig.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use btfrig_emulated_backend::{EmulatedBackend, LinkFault};
use btfrig_measurement::backend::BackendRegistry;
use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest, RunSummary};
use btfrig_serial::firmware::{grbl, robot};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("serial-faults-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn request(dir: &Path) -> RunRequest {
    let plan = include_str!("../../../tests/data/tiny-plan.toml")
        .replace("SEED", "5")
        .replace("FAULTS", "none")
        .replace("builtin:bonn-gonio-sim", "builtin:bonn-gonio-serial");
    RunRequest::from_text(plan, &dir.join("plan.toml"), &dir.join("dataset"))
}

/// The emulated rig's backends, injecting `faults` into its firmware.
fn faulty(faults: Vec<LinkFault>) -> BackendRegistry {
    let backend = EmulatedBackend::new(Arc::new(btfrig_sim_backend::SimBackend)).with_link_faults(faults);
    BackendRegistry::new().with(Arc::new(backend))
}

/// Every texture file's content hash, by file name.
fn textures(dataset: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dataset.join("textures")).unwrap() {
        let p = e.unwrap().path();
        out.insert(
            p.file_name().unwrap().to_string_lossy().into_owned(),
            btfrig_store::content_hash(&std::fs::read(&p).unwrap()),
        );
    }
    out
}

/// Captures the journal records as committed.
fn journal_commits(dataset: &Path) -> usize {
    let j = std::fs::read_to_string(dataset.join("journal.btfj")).unwrap();
    j.matches(r#""pose":"#).count()
}

/// The fault-free run's textures (computed once).
fn reference() -> &'static BTreeMap<String, String> {
    static REF: OnceLock<BTreeMap<String, String>> = OnceLock::new();
    REF.get_or_init(|| {
        let dir = scratch("reference");
        let s = run(&request(&dir), &RunControl::new(), &mut |_| {}).unwrap();
        assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
        assert_eq!((s.captures, s.retries), (12, 0), "{s:?}");
        assert!(s.warnings.is_empty(), "{:?}", s.warnings);
        textures(&dir.join("dataset"))
    })
}

/// Runs `faults` on a fresh dataset; a finished run must have every capture and the
/// reference textures.
fn finished_with(name: &str, faults: Vec<LinkFault>) -> RunSummary {
    let reference = reference();
    let dir = scratch(name);
    let s = run(&request(&dir).with_backends(faulty(faults)), &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
    let ds = dir.join("dataset");
    assert_eq!(s.captures, 12, "{s:?}");
    assert_eq!(journal_commits(&ds), 12);
    assert!(btfrig_store::verify(&ds).is_ok());
    assert_eq!(&textures(&ds), reference, "textures differ from the fault-free run");
    println!("{name}: captures {}, retries {}, warnings {:?}", s.captures, s.retries, s.warnings);
    s
}

#[test]
fn rail_port_closed_mid_move_is_retried_and_nothing_is_lost() {
    btfrig_sim_backend::install();
    let s = finished_with("rail-unplug", vec![LinkFault::Rail(LinkFault::on_move_grbl(3, grbl::Fault::Unplug))]);
    assert!(s.retries >= 1, "{s:?}");
}

#[test]
fn robot_port_closed_mid_move_is_retried_and_nothing_is_lost() {
    btfrig_sim_backend::install();
    let s = finished_with("robot-unplug", vec![LinkFault::Robot(LinkFault::on_move_robot(4, robot::Fault::Unplug))]);
    assert!(s.retries >= 1, "{s:?}");
}

#[test]
fn garbage_on_the_lines_is_skipped() {
    btfrig_sim_backend::install();
    let noise = || b"\xff\xfe\x00 noise\r\n<Bogus|MPos:x,y>\r\nok ok ok what\r\n".to_vec();
    let s = finished_with(
        "garbage",
        vec![
            LinkFault::Rail(grbl::Fault::Garbage(noise())),
            LinkFault::Rail(LinkFault::on_move_grbl(2, grbl::Fault::Garbage(noise()))),
            LinkFault::Robot(robot::Fault::Garbage(noise())),
            LinkFault::Robot(LinkFault::on_move_robot(3, robot::Fault::Garbage(noise()))),
        ],
    );
    // Skipped, not retried, and reported per device.
    assert_eq!(s.retries, 0, "{s:?}");
    for role in ["rail", "robot"] {
        assert!(
            s.warnings.iter().any(|w| w.starts_with(&format!("{role}: ")) && w.contains("undecodable line(s) skipped")),
            "{role}: {:?}",
            s.warnings
        );
    }
}

#[test]
fn camera_without_object_added_is_retried() {
    btfrig_sim_backend::install();
    let s = finished_with("no-object-added", vec![LinkFault::Camera(btfrig_ptp::responder::Fault::DropObjectAdded)]);
    assert!(s.retries >= 1, "{s:?}");
    assert!(s.warnings.iter().any(|w| w.contains("ObjectAdded")), "{:?}", s.warnings);
}

/// A fault no retry helps pauses the run naming `device`; the captures committed before it
/// stay (the reference textures), and the same request without the fault resumes to the end.
fn paused_then_resumed(name: &str, fault: LinkFault, device: &str, says: &str) {
    let reference = reference();
    let dir = scratch(name);
    let ds = dir.join("dataset");
    let req = request(&dir);
    assert!(req.stop_on_fault);
    let s = run(&req.clone().with_backends(faulty(vec![fault])), &RunControl::new(), &mut |_| {}).unwrap();
    let RunOutcome::Paused { reason, fault: Some(f) } = &s.outcome else { panic!("{s:?}") };
    println!("{name}: paused after {} captures: {reason}", s.captures);
    assert_eq!(f.device, device, "{f:?}");
    assert!(reason.contains(device) && reason.contains(says), "{reason}");
    assert!(s.captures >= 1 && s.captures < 12, "{s:?}");
    assert_eq!(journal_commits(&ds), s.captures as usize);
    let before = textures(&ds);
    assert_eq!(before.len(), s.captures as usize);
    for (k, v) in &before {
        assert_eq!(reference.get(k), Some(v), "{k} differs from the fault-free run");
    }
    let r = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(r.outcome, RunOutcome::Finished, "{r:?}");
    assert_eq!((r.captures, r.captures_this_session, r.sessions), (12, 12 - s.captures, 2), "{r:?}");
    assert_eq!(journal_commits(&ds), 12);
    assert!(btfrig_store::verify(&ds).is_ok());
    assert_eq!(&textures(&ds), reference, "resumed textures differ from the fault-free run");
}

#[test]
fn grbl_alarm_pauses_and_the_run_resumes() {
    btfrig_sim_backend::install();
    paused_then_resumed("alarm", LinkFault::Rail(LinkFault::on_move_grbl(5, grbl::Fault::Alarm(1))), "rail", "ALARM:1");
}

#[test]
fn robot_drive_fault_pauses_and_the_run_resumes() {
    btfrig_sim_backend::install();
    paused_then_resumed(
        "drive-fault",
        LinkFault::Robot(LinkFault::on_move_robot(5, robot::Fault::DriveFault)),
        "robot",
        "drive fault",
    );
}
