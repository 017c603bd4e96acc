//! Run-level fault tests on the emulated serial rig (rig-configs/bonn-gonio-serial.toml):
//! the tiny plan through `btfrig_runner::run`, with faults injected into the emulated
//! firmware (`RunRequest::link_faults`, docs/serial.md). Each fault ends in a retried step
//! or a paused, resumable run naming the device; nothing captured is lost, and the textures
//! equal those of a fault-free run on the same rig.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use btfrig_runner::emulated::LinkFault;
use btfrig_runner::{run, RunControl, RunOutcome, RunRequest, RunSummary};
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
        textures(&dir.join("dataset"))
    })
}

/// Runs `faults` on a fresh dataset; a finished run must have every capture and the
/// reference textures.
fn finished_with(name: &str, faults: Vec<LinkFault>) -> RunSummary {
    let reference = reference();
    let dir = scratch(name);
    let s = run(&request(&dir).with_link_faults(faults), &RunControl::new(), &mut |_| {}).unwrap();
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
    let s = finished_with("rail-unplug", vec![LinkFault::Rail(LinkFault::on_move_grbl(3, grbl::Fault::Unplug))]);
    assert!(s.retries >= 1, "{s:?}");
}
