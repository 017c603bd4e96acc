//! Model test of crash safety: a seeded random run over the in-memory storage, with the
//! power cut at random operations (torn appends included), checked after every restart
//! against a model of what must have survived.
//!
//! Properties: after any crash the steps the journal reports done are exactly those whose
//! record was fsync'd (plus the step whose record was being appended if, and only if, the
//! whole record happened to survive: its files were already durable); resume never repeats
//! a journaled step and never loses one; every journaled file is whole (size and hash); no
//! file without a record is left behind.

mod common;

use std::collections::{BTreeMap, BTreeSet};

use btfrig_store::{
    content_hash, plan_hash, verify_in, Dataset, MemStorage, RunReport, StepId, StepTiming, Storage, StoreError,
    TextureFormat, TornAppend, JOURNAL_FILE, MANIFEST_FILE,
};
use common::{manifest, raw_frame, texels, H, W};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const PLAN: &str = "[plan]\nname = \"crash model\"\n";

/// Mutating operations of a step before the journal's fsync.
const COMMIT_FSYNC_OP: usize = 11;

/// Which operation failed when the power went.
enum Failed {
    BeforeCommit,
    InCommit(StepId),
}

/// Runs one step: texture, raw frame, commit.
fn run_step(ds: &Dataset<MemStorage>, s: StepId, attempts: u32) -> Result<(), (Failed, StoreError)> {
    let t = ds.write_texture(s, &texels(s), W, H).map_err(|e| (Failed::BeforeCommit, e))?;
    let r = ds.write_raw(s, &raw_frame(s)).map_err(|e| (Failed::BeforeCommit, e))?;
    ds.commit_step(s, vec![t, r], attempts, StepTiming::default()).map_err(|e| (Failed::InCommit(s), e))
}

/// Reopens after a crash, itself possibly cut by another power loss (then retried).
fn reopen(storage: &MemStorage, rng: &mut ChaCha8Rng) -> (Dataset<MemStorage>, btfrig_store::ResumeReport) {
    loop {
        if rng.gen_bool(0.2) {
            storage.fail_after(rng.gen_range(0..4));
        }
        match Dataset::open_for_resume_in(storage.clone(), &plan_hash(PLAN)) {
            Ok(x) => {
                storage.disarm();
                return x;
            }
            Err(StoreError::Io { .. }) => {
                storage.crash(Some(rng.gen_range(0..64)));
            }
            Err(e) => panic!("reopen failed: {e}"),
        }
    }
}

fn check_files(storage: &MemStorage, ds: &Dataset<MemStorage>) {
    let mut named = BTreeSet::from([MANIFEST_FILE.to_string(), JOURNAL_FILE.to_string()]);
    for s in ds.completed() {
        for f in ds.step_record(s).unwrap().files {
            let bytes = storage.read(&f.path).unwrap_or_else(|e| panic!("{}: {e}", f.path));
            assert_eq!(bytes.len() as u64, f.size, "{} partial", f.path);
            assert_eq!(content_hash(&bytes), f.hash, "{} altered", f.path);
            named.insert(f.path);
        }
    }
    let present: BTreeSet<String> = storage.files().into_iter().collect();
    assert_eq!(present, named, "files on storage vs files named by the journal");
}

fn run_seed(seed: u64) -> (usize, usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let storage = MemStorage::new();
    let m = manifest(PLAN, TextureFormat::ExrHalf, true);
    let mut ds = Dataset::create_in(storage.clone(), m).unwrap();
    let expected = ds.expected_steps().clone();
    // Model: steps whose commit returned Ok (record fsync'd), and how often each was committed.
    let mut durable: BTreeSet<StepId> = BTreeSet::new();
    let mut commits: BTreeMap<StepId, u32> = BTreeMap::new();
    let (mut crashes, mut torn_cut) = (0, 0);
    let mut guard = 0;
    while durable.len() < expected.len() {
        guard += 1;
        assert!(guard < 500, "seed {seed}: no progress");
        let todo: Vec<StepId> = expected.difference(&durable).copied().collect();
        let s = todo[rng.gen_range(0..todo.len())];
        if rng.gen_bool(0.4) {
            // A step is 12 mutating operations (2 x [create, write, fsync, rename, fsync dir],
            // then journal append and fsync); cut at any of them or in the next step, and
            // often right between the journal append and its fsync, where records tear.
            let n = if rng.gen_bool(0.3) { COMMIT_FSYNC_OP } else { rng.gen_range(0..24) };
            storage.fail_after(n);
        }
        let failed = match run_step(&ds, s, 1) {
            Ok(()) => {
                durable.insert(s);
                *commits.entry(s).or_default() += 1;
                // A journaled step cannot be committed again, even by a confused caller.
                assert!(matches!(
                    ds.commit_step(s, vec![], 1, StepTiming::default()),
                    Err(StoreError::StepAlreadyJournaled { .. })
                ));
                if !rng.gen_bool(0.15) {
                    continue;
                }
                // A crash between operations: everything was fsync'd, nothing may change.
                Failed::BeforeCommit
            }
            Err((f, StoreError::Io { .. })) => f,
            Err((_, e)) => panic!("seed {seed}: unexpected error {e}"),
        };
        drop(ds);
        crashes += 1;
        let keep = if rng.gen_bool(0.5) { rng.gen_range(0..40) } else { rng.gen_range(0..1000) };
        let torn = storage.crash(Some(keep));
        let (reopened, resume) = reopen(&storage, &mut rng);
        ds = reopened;
        // The record being appended survives only if all of it did.
        let mut want = durable.clone();
        if let (Failed::InCommit(step), Some(TornAppend { kept, len })) = (&failed, torn) {
            if kept == len {
                want.insert(*step);
                *commits.entry(*step).or_default() += 1;
            } else if kept > 0 {
                torn_cut += 1;
            }
        }
        assert_eq!(resume.completed, want, "seed {seed}: journal after crash vs model");
        assert_eq!(ds.completed(), want);
        durable = want;
        check_files(&storage, &ds);
        assert_eq!(
            resume.remaining,
            expected.difference(&durable).copied().collect::<BTreeSet<_>>(),
            "seed {seed}: remaining"
        );
    }
    assert!(commits.values().all(|&n| n == 1), "seed {seed}: a step was committed twice: {commits:?}");
    storage.disarm();
    ds.finish(&RunReport { captures: durable.len() as u64, ..RunReport::default() }).unwrap();
    let v = verify_in(&storage);
    assert!(v.is_ok(), "seed {seed}: {v}");
    (crashes, torn_cut)
}

#[test]
fn after_any_crash_the_journal_holds_exactly_the_synced_steps() {
    let (mut crashes, mut torn) = (0, 0);
    for seed in 0..150 {
        let (c, t) = run_seed(seed);
        crashes += c;
        torn += t;
    }
    // The test must actually exercise crashes and torn records.
    assert!(crashes > 300, "only {crashes} crashes");
    assert!(torn > 50, "only {torn} torn journal records cut");
    println!("{crashes} crashes, {torn} torn journal records cut");
}
