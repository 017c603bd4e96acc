//! `btfrig dataset verify`: check a dataset without changing it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use crate::error::StoreError;
use crate::hash::content_hash;
use crate::journal::{self, TornTail};
use crate::manifest::manifest_hash;
use crate::storage::{FsStorage, Storage};
use crate::{RunReport, StepId};

use super::files::{read_manifest, tmp_name};
use super::layout::{
    data_files, required_files, JOURNAL_FILE, MANIFEST_FILE, PREVIEWS_DIR, PREVIEW_FILE, RAW_DIR, REPORT_FILE,
    TEXTURES_DIR,
};

/// One thing `verify` found wrong.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Problem {
    /// No manifest: the directory is not a dataset.
    NotADataset {
        /// Entries found (at most ten).
        found: Vec<String>,
    },
    /// The manifest does not parse or is inconsistent.
    Manifest {
        /// What is wrong.
        reason: String,
    },
    /// The manifest's fixed part is not what the journal's header recorded at creation.
    ManifestChanged {
        /// The hash journaled.
        expected: String,
        /// The hash of the file now.
        found: String,
    },
    /// The journal is missing, damaged in the middle, or belongs to another plan.
    Journal {
        /// What is wrong.
        reason: String,
    },
    /// The journal ends in a torn record (a killed run not yet resumed).
    TornJournalTail(TornTail),
    /// A journaled step is not in the plan.
    UnexpectedStep {
        /// The step.
        step: StepId,
    },
    /// A journaled file is missing.
    MissingFile {
        /// Its step.
        step: StepId,
        /// The file.
        path: String,
    },
    /// A journaled file has another size.
    WrongSize {
        /// Its step.
        step: StepId,
        /// The file.
        path: String,
        /// Journaled size.
        expected: u64,
        /// Size on disk.
        found: u64,
    },
    /// A journaled file has another content hash.
    WrongHash {
        /// Its step.
        step: StepId,
        /// The file.
        path: String,
        /// Journaled hash.
        expected: String,
        /// Hash of the file on disk.
        found: String,
    },
    /// A done step's journal record does not name a file the manifest asks of every step
    /// (its texture or its raw frame).
    Unrecorded {
        /// The step.
        step: StepId,
        /// The file it should have recorded.
        path: String,
    },
    /// A file of a view group's journaled raw frames is missing, or has another size or
    /// content hash than journaled.
    GroupFrame {
        /// The view.
        view: u32,
        /// The file.
        path: String,
        /// What is wrong (`missing`, `100 bytes, journaled with 120`, ...).
        what: String,
    },
    /// The manifest keeps raw frames per view group, but a view with journaled textures has no
    /// journaled raw frames.
    NoGroupFrames {
        /// The view.
        view: u32,
    },
    /// A file that no journal record names, or an entry that does not belong in a dataset.
    Orphan {
        /// The path.
        path: String,
    },
    /// Expected steps neither done nor skipped.
    Incomplete {
        /// How many.
        missing: usize,
    },
    /// `report.json` exists but does not parse.
    Report {
        /// What is wrong.
        reason: String,
    },
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Problem::NotADataset { found } => {
                write!(f, "not a btfrig dataset: no {MANIFEST_FILE} (found: {})", found.join(", "))
            }
            Problem::Manifest { reason } => write!(f, "{MANIFEST_FILE}: {reason}"),
            Problem::ManifestChanged { expected, found } => write!(
                f,
                "{MANIFEST_FILE}: changed since the dataset was created (content hash {found}, the journal's header recorded {expected}): it no longer describes the data"
            ),
            Problem::Journal { reason } => write!(f, "{JOURNAL_FILE}: {reason}"),
            Problem::TornJournalTail(t) => write!(f, "{JOURNAL_FILE}: {t}; resuming the run cuts it"),
            Problem::UnexpectedStep { step } => write!(f, "{JOURNAL_FILE}: step {step} is not in the plan"),
            Problem::MissingFile { step, path } => write!(f, "{path}: missing (journaled for step {step})"),
            Problem::WrongSize { step, path, expected, found } => {
                write!(f, "{path}: {found} bytes, journaled with {expected} for step {step}")
            }
            Problem::WrongHash { step, path, expected, found } => {
                write!(f, "{path}: content hash {found}, journaled {expected} for step {step}")
            }
            Problem::Unrecorded { step, path } => {
                write!(f, "{path}: the manifest asks for it, but the journal record of step {step} does not name it")
            }
            Problem::GroupFrame { view, path, what } => {
                write!(f, "{path}: {what} (journaled as a raw frame of view {view}'s group)")
            }
            Problem::NoGroupFrames { view } => write!(
                f,
                "view {view}: textures journaled but no raw frames, though the manifest keeps them per view group"
            ),
            Problem::Orphan { path } => write!(f, "{path}: not named by any journal record"),
            Problem::Incomplete { missing } => {
                write!(f, "incomplete: {missing} expected step(s) neither done nor skipped")
            }
            Problem::Report { reason } => write!(f, "{REPORT_FILE}: {reason}"),
        }
    }
}

/// What `verify` checked and found.
#[derive(Debug, Clone, Default)]
pub struct VerifyReport {
    /// The dataset directory.
    pub dir: String,
    /// Everything wrong; empty when the dataset is sound and complete.
    pub problems: Vec<Problem>,
    /// Files whose size and hash were checked.
    pub files_checked: usize,
    /// Their bytes.
    pub bytes_checked: u64,
    /// Steps expected.
    pub expected: usize,
    /// Steps done.
    pub done: usize,
    /// Steps skipped (by the plan or in the run), with reasons.
    pub skipped: BTreeMap<StepId, String>,
    /// Expected steps neither done nor skipped.
    pub missing: Vec<StepId>,
}

impl VerifyReport {
    /// True if nothing is wrong.
    pub fn is_ok(&self) -> bool {
        self.problems.is_empty()
    }
}

impl std::fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {}/{} steps done, {} skipped, {} missing; {} files ({:.1} MB) hashed",
            self.dir,
            self.done,
            self.expected,
            self.skipped.len(),
            self.missing.len(),
            self.files_checked,
            self.bytes_checked as f64 / 1e6
        )?;
        if self.problems.is_empty() {
            write!(f, "OK")
        } else {
            write!(f, "{} problem(s):", self.problems.len())?;
            for p in &self.problems {
                write!(f, "\n  {p}")?;
            }
            Ok(())
        }
    }
}

/// Checks the dataset in `dir` without changing it: the manifest parses and is consistent;
/// the journal is intact; every journaled file exists with its size and content hash; every
/// expected step is done or skipped; no file is left that no record names.
pub fn verify(dir: &Path) -> VerifyReport {
    verify_in(&FsStorage::new(dir))
}

/// [`verify`] on any storage.
pub fn verify_in<S: Storage + ?Sized>(s: &S) -> VerifyReport {
    let mut r = VerifyReport { dir: s.display(""), ..VerifyReport::default() };
    let (manifest, manifest_bytes) = match read_manifest(s) {
        Ok(m) => m,
        Err(StoreError::NotADataset { .. }) => {
            let found = s.list("").map(|l| l.into_iter().take(10).map(|e| e.name).collect()).unwrap_or_default();
            r.problems.push(Problem::NotADataset { found });
            return r;
        }
        Err(e) => {
            r.problems.push(Problem::Manifest { reason: e.to_string() });
            return r;
        }
    };
    let expected = manifest.samplings.expected_steps();
    r.expected = expected.len();
    let replay = match s.read(JOURNAL_FILE) {
        Err(e) => {
            r.problems.push(Problem::Journal { reason: format!("cannot read: {e}") });
            journal::Replay::default()
        }
        Ok(bytes) => match journal::replay(JOURNAL_FILE, &bytes) {
            Err(e) => {
                r.problems.push(Problem::Journal { reason: e.to_string() });
                journal::Replay::default()
            }
            Ok(rep) => rep,
        },
    };
    if let Some(found) = &replay.plan_hash {
        if *found != manifest.plan.hash {
            r.problems.push(Problem::Journal {
                reason: format!("belongs to plan {found}, the manifest to {}", manifest.plan.hash),
            });
        }
    }
    if let Some(expected) = &replay.manifest_hash {
        let found = manifest_hash(&manifest_bytes);
        if *expected != found {
            r.problems.push(Problem::ManifestChanged { expected: expected.clone(), found });
        }
    }
    if let Some(t) = &replay.torn_tail {
        r.problems.push(Problem::TornJournalTail(t.clone()));
    }
    let mut named = BTreeSet::new();
    for (step, rec) in &replay.done {
        if !expected.contains(step) {
            r.problems.push(Problem::UnexpectedStep { step: *step });
        }
        for need in required_files(&manifest, *step) {
            if !rec.files.iter().any(|f| f.path == need) {
                r.problems.push(Problem::Unrecorded { step: *step, path: need });
            }
        }
        for file in &rec.files {
            named.insert(file.path.clone());
            let bytes = match s.read(&file.path) {
                Ok(b) => b,
                Err(_) => {
                    r.problems.push(Problem::MissingFile { step: *step, path: file.path.clone() });
                    continue;
                }
            };
            r.files_checked += 1;
            r.bytes_checked += bytes.len() as u64;
            if bytes.len() as u64 != file.size {
                r.problems.push(Problem::WrongSize {
                    step: *step,
                    path: file.path.clone(),
                    expected: file.size,
                    found: bytes.len() as u64,
                });
                continue;
            }
            let found = content_hash(&bytes);
            if found != file.hash {
                r.problems.push(Problem::WrongHash {
                    step: *step,
                    path: file.path.clone(),
                    expected: file.hash.clone(),
                    found,
                });
            }
        }
    }
    for (view, rec) in &replay.frames {
        for file in &rec.files {
            named.insert(file.path.clone());
            let what = match s.read(&file.path) {
                Err(_) => Some("missing".to_string()),
                Ok(bytes) => {
                    r.files_checked += 1;
                    r.bytes_checked += bytes.len() as u64;
                    let found = content_hash(&bytes);
                    if bytes.len() as u64 != file.size {
                        Some(format!("{} bytes, journaled with {}", bytes.len(), file.size))
                    } else if found != file.hash {
                        Some(format!("content hash {found}, journaled {}", file.hash))
                    } else {
                        None
                    }
                }
            };
            if let Some(what) = what {
                r.problems.push(Problem::GroupFrame { view: *view, path: file.path.clone(), what });
            }
        }
    }
    if manifest.raw_groups.is_some() {
        let views: BTreeSet<u32> = replay.done.keys().map(|s| s.view).collect();
        for view in views.into_iter().filter(|v| !replay.frames.contains_key(v)) {
            r.problems.push(Problem::NoGroupFrames { view });
        }
    }
    for (step, reason) in &replay.skipped {
        if !expected.contains(step) {
            r.problems.push(Problem::UnexpectedStep { step: *step });
        }
        r.skipped.insert(*step, reason.clone());
    }
    for sk in &manifest.samplings.skipped {
        r.skipped.insert(sk.step, sk.reason.clone());
    }
    r.done = replay.done.len();
    r.missing =
        expected.iter().filter(|s| !replay.done.contains_key(s) && !replay.skipped.contains_key(s)).copied().collect();
    if !r.missing.is_empty() {
        r.problems.push(Problem::Incomplete { missing: r.missing.len() });
    }
    match data_files(s) {
        Ok(files) => {
            for p in files.into_iter().filter(|p| !named.contains(p)) {
                r.problems.push(Problem::Orphan { path: p });
            }
        }
        Err(e) => r.problems.push(Problem::Journal { reason: format!("cannot list data directories: {e}") }),
    }
    // The preview and its temporary name (a run killed while replacing it) are not data.
    let preview_tmp = tmp_name(PREVIEW_FILE);
    let known = [
        MANIFEST_FILE,
        JOURNAL_FILE,
        REPORT_FILE,
        TEXTURES_DIR,
        RAW_DIR,
        PREVIEWS_DIR,
        PREVIEW_FILE,
        preview_tmp.as_str(),
    ];
    for e in s.list("").unwrap_or_default() {
        if !known.contains(&e.name.as_str()) {
            r.problems.push(Problem::Orphan { path: if e.is_dir { format!("{}/", e.name) } else { e.name } });
        }
    }
    if let Ok(bytes) = s.read(REPORT_FILE) {
        if let Err(e) = serde_json::from_slice::<RunReport>(&bytes) {
            r.problems.push(Problem::Report { reason: e.to_string() });
        }
    }
    r
}
