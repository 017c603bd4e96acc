//! Issue 3 acceptance: crash safety of a real `btfrig run` process. The same plan
//! (`tests/data/crash-small.toml`: 60 captures on the small-camera simulated rig, fixed seed)
//! runs once uninterrupted into `A`; into `B` it is started and SIGKILLed several times, then
//! left to finish. Each kill is aimed at an event, not at a moment of the clock: the first as
//! soon as the journal file exists (start-up), the others once the journal holds a seeded
//! number of committed steps (the kill then lands in the next step's work). `B` must equal
//! `A`: the same captures, byte-identical textures (and journal hashes), no step journaled
//! twice, and `dataset verify` passes on both.

mod support;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use support::*;

const KILLS: usize = 5;

fn spawn_run(plan: &Path, out: &Path, log: &Path) -> Child {
    let log = std::fs::OpenOptions::new().create(true).append(true).open(log).unwrap();
    btfrig()
        .args(["run", "--plan"])
        .arg(plan)
        .arg("--out")
        .arg(out)
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .stdin(Stdio::null())
        .spawn()
        .expect("btfrig starts")
}

/// Step -> (texture path, journaled hash, file bytes) of a finished dataset.
fn textures(dir: &Path) -> BTreeMap<Step, (String, String, Vec<u8>)> {
    read_journal(dir)
        .committed()
        .into_iter()
        .map(|(step, files)| {
            assert_eq!(files.len(), 1, "{step:?}: {files:?}");
            let (path, hash) = files[0].clone();
            let bytes = std::fs::read(dir.join(&path)).unwrap_or_else(|e| panic!("{path}: {e}"));
            (step, (path, hash, bytes))
        })
        .collect()
}

/// Waits until `ready()` holds, polling; panics naming `what` if the run exits first.
fn wait_for(child: &mut Child, log: &Path, what: &str, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the run exited ({status}) before {what}; log {}", log.display());
        }
        assert!(t0.elapsed() < Duration::from_secs(600), "no {what} after 600 s; log {}", log.display());
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn a_run_killed_at_journal_step_counts_and_resumed_equals_an_uninterrupted_one() {
    let plan = repo("tests/data/crash-small.toml");
    let dir = scratch("run-kill");
    let (a, b) = (dir.join("A"), dir.join("B"));
    let log = dir.join("btfrig.log");

    // A, uninterrupted.
    let t0 = Instant::now();
    let o = btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&a).output().unwrap();
    assert!(o.status.success(), "uninterrupted run failed:\n{}", text(&o));
    let reference = textures(&a);
    let total = reference.len();
    assert_eq!(total, 60);
    eprintln!("uninterrupted: {:.2} s wall", t0.elapsed().as_secs_f64());

    // B: kill 0 once the journal file exists (its header written, no step yet, as a rule);
    // kills 1.. once the journal holds `done_before` + a seeded 1..=8 more committed steps,
    // so at most 32 + the start-up kill's steps of 60: every kill lands with steps to go.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6b696c6c);
    let mut done_before = 0;
    for k in 0..KILLS {
        let mut child = spawn_run(&plan, &b, &log);
        let target = if k == 0 { 0 } else { done_before + rng.gen_range(1..=8) };
        if k == 0 {
            wait_for(&mut child, &log, "a journal file", || b.join("journal.btfj").is_file());
        } else {
            wait_for(&mut child, &log, &format!("{target} journaled steps"), || journaled_steps(&b) >= target);
        }
        let finished_first = child.try_wait().unwrap();
        child.kill().unwrap(); // SIGKILL on Unix
        child.wait().unwrap();
        assert!(finished_first.is_none(), "kill {k}: the run had exited ({finished_first:?}) before the kill");
        let done = journaled_steps(&b);
        let torn = read_journal(&b).torn_tail.is_some();
        eprintln!(
            "kill {k}: at {target} journaled steps, {done}/{total} after the kill ({:+} this session){}",
            done as i64 - done_before as i64,
            if torn { ", torn journal tail" } else { "" },
        );
        // Nothing journaled is ever lost, the kill came after the awaited step count, and the
        // run was still going (steps left to capture).
        assert!(
            done >= done_before.max(target) && done < total,
            "kill {k}: {done} after {done_before}, target {target}"
        );
        // A killed run's dataset is not taken for a complete one.
        let v = btfrig().args(["dataset", "verify"]).arg(&b).output().unwrap();
        assert!(!v.status.success(), "verify passed on a dataset with {done}/{total} steps:\n{}", text(&v));
        done_before = done;
    }

    // Let it finish.
    let o = btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&b).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));

    // The same captures, the same texture bytes and journal hashes; no step twice in B.
    let resumed = textures(&b); // panics on a step journaled twice
    assert_eq!(resumed.keys().collect::<Vec<_>>(), reference.keys().collect::<Vec<_>>(), "captured steps differ");
    let mut differ = Vec::new();
    for (step, (path, hash, bytes)) in &reference {
        let (p, h, by) = &resumed[step];
        assert_eq!(p, path);
        if h != hash || by != bytes {
            differ.push(*step);
        }
    }
    assert!(
        differ.is_empty(),
        "{} of {total} textures differ between A and B, e.g. {:?}",
        differ.len(),
        &differ[..differ.len().min(5)]
    );
    let on_disk = std::fs::read_dir(b.join("textures")).unwrap().count();
    assert_eq!(on_disk, total, "files in B/textures beyond the journaled ones");
    let report = read_json(&b.join("report.json"));
    assert_eq!(report["captures"], 60, "{report}");
    verify(&a);
    verify(&b);
    eprintln!("whole test: {:.1} s wall", t0.elapsed().as_secs_f64());
}
