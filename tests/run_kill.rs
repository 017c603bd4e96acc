//! Issue 3 acceptance: crash safety of a real `btfrig run` process. The same plan
//! (`tests/data/crash-small.toml`: 60 captures on the small-camera simulated rig, fixed seed)
//! runs once uninterrupted into `A`; into `B` it is started, SIGKILLed at seeded random
//! moments and restarted, several times, then left to finish. `B` must equal `A`: the same
//! captures, byte-identical textures (and journal hashes), no step journaled twice, and
//! `dataset verify` passes on both.

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

#[test]
fn a_run_killed_at_random_moments_and_resumed_equals_an_uninterrupted_one() {
    let plan = repo("tests/data/crash-small.toml");
    let dir = scratch("run-kill");
    let (a, b) = (dir.join("A"), dir.join("B"));
    let log = dir.join("btfrig.log");

    // A, uninterrupted; watched to learn how long start-up and each step take here.
    let t0 = Instant::now();
    let mut child = spawn_run(&plan, &a, &log);
    let mut first_step_s = None;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if first_step_s.is_none() && journaled_steps(&a) > 0 {
            first_step_s = Some(t0.elapsed().as_secs_f64());
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    let run_s = t0.elapsed().as_secs_f64();
    assert!(status.success(), "uninterrupted run failed; log {}", log.display());
    let reference = textures(&a);
    let total = reference.len();
    assert_eq!(total, 60);
    let first_step_s = first_step_s.unwrap_or(run_s);
    let per_step_s = (run_s - first_step_s) / (total - 1) as f64;
    eprintln!(
        "uninterrupted: {run_s:.2} s wall, first step journaled after {first_step_s:.2} s, {per_step_s:.4} s per step"
    );

    // B: killed at seeded random moments within the expected duration of each session.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6b696c6c);
    let mut mid_run = 0;
    let mut done_before = 0;
    for k in 0..KILLS {
        let remaining = total - done_before;
        let expected_s = first_step_s + remaining as f64 * per_step_s;
        let delay_s = expected_s * rng.gen_range(0.15..0.9);
        let mut child = spawn_run(&plan, &b, &log);
        std::thread::sleep(Duration::from_secs_f64(delay_s));
        let finished_first = child.try_wait().unwrap().is_some();
        child.kill().unwrap(); // SIGKILL on Unix
        child.wait().unwrap();
        let done = journaled_steps(&b);
        let torn = b.join("journal.btfj").is_file() && read_journal(&b).torn_tail.is_some();
        eprintln!(
            "kill {k}: after {:.0} ms, {done}/{total} steps journaled ({:+} this session){}{}",
            delay_s * 1e3,
            done as i64 - done_before as i64,
            if finished_first { ", the process had already finished" } else { "" },
            if torn { ", torn journal tail" } else { "" },
        );
        // Nothing journaled is ever lost, and a kill never commits beyond the plan.
        assert!(done >= done_before && done <= total, "{done} after {done_before}");
        // A killed run's dataset is not taken for a complete one.
        if done < total {
            let v = btfrig().args(["dataset", "verify"]).arg(&b).output().unwrap();
            assert!(!v.status.success(), "verify passed on a dataset with {done}/{total} steps:\n{}", text(&v));
        }
        if !finished_first && done > 0 && done < total {
            mid_run += 1;
        }
        done_before = done;
    }
    assert!(mid_run >= 2, "only {mid_run} of {KILLS} kills landed mid-run (some but not all steps journaled)");

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
