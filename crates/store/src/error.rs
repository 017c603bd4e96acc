//! Errors of the store. Every variant names the file or directory it is about.

use std::io;

use crate::storage::Storage;
use crate::StepId;

/// A failure of the dataset store.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// A storage operation failed.
    #[error("{path}: {op}: {source}")]
    Io {
        /// The operation (`create`, `append`, `fsync`, ...).
        op: &'static str,
        /// The file or directory.
        path: String,
        /// The system error.
        source: io::Error,
    },
    /// The journal is damaged before its last record.
    #[error("{path}: journal damaged at byte {offset}: {reason}")]
    JournalCorrupt {
        /// The journal file.
        path: String,
        /// Byte offset of the first bad record.
        offset: u64,
        /// What is wrong there.
        reason: String,
    },
    /// The dataset or journal belongs to another plan.
    #[error("{path}: belongs to plan {found}, not to plan {expected}")]
    PlanMismatch {
        /// The manifest or journal.
        path: String,
        /// Plan hash found there.
        found: String,
        /// Plan hash asked for.
        expected: String,
    },
    /// `create` found a dataset of the same plan: it should be resumed, not created.
    #[error("{path}: already holds a dataset of this plan ({plan_hash}); resume it instead of creating it")]
    AlreadyExists {
        /// The directory.
        path: String,
        /// Its plan hash.
        plan_hash: String,
    },
    /// `create` found a dataset of another plan.
    #[error("{path}: holds another dataset (plan {plan_hash}, rig {rig:?}, created {created}); it is never overwritten: choose another directory")]
    OtherDataset {
        /// The directory.
        path: String,
        /// Its plan hash.
        plan_hash: String,
        /// Its rig name.
        rig: String,
        /// Its creation time.
        created: String,
    },
    /// `create` found a directory with other contents.
    #[error("{path}: not empty and not a btfrig dataset (found {})", found.join(", "))]
    NotEmpty {
        /// The directory.
        path: String,
        /// Some of the entries found (at most ten).
        found: Vec<String>,
    },
    /// The directory has no manifest.
    #[error("{path}: not a btfrig dataset (no manifest.json)")]
    NotADataset {
        /// The directory.
        path: String,
    },
    /// The manifest does not parse or fails its checks.
    #[error("{path}: bad manifest: {reason}")]
    BadManifest {
        /// The manifest file.
        path: String,
        /// What is wrong.
        reason: String,
    },
    /// The manifest's fixed part (everything but `timing`) is not what the dataset was
    /// created with: an edited sampling, seed, plan or rig would no longer describe the data.
    #[error("{path}: changed since the dataset was created (content hash {found}, the journal's header recorded {expected}); the samplings, seed, plan and rig must stay as the data was captured: restore the original manifest.json (or start a new dataset in another directory)")]
    ManifestChanged {
        /// The manifest file.
        path: String,
        /// The hash journaled at creation.
        expected: String,
        /// The hash of the file now.
        found: String,
    },
    /// A step was given that the plan does not hold.
    #[error("step {step} is not in the plan (lights 0..{lights}, views 0..{views}, or skipped by the plan)")]
    UnknownStep {
        /// The step.
        step: StepId,
        /// Number of light directions.
        lights: usize,
        /// Number of view directions.
        views: usize,
    },
    /// A step already journaled (done or skipped) was written or committed again.
    #[error("step {step} is already journaled as {state}; a resumed run must not repeat it")]
    StepAlreadyJournaled {
        /// The step.
        step: StepId,
        /// `done` or `skipped: <reason>`.
        state: String,
    },
    /// A file handed to `commit_step` is not on disk as recorded.
    #[error("{path}: committed for step {step} with {expected} bytes but has {found:?}")]
    FileNotAsRecorded {
        /// The file.
        path: String,
        /// The step.
        step: StepId,
        /// Recorded size.
        expected: u64,
        /// Size on disk (`None`: missing).
        found: Option<u64>,
    },
    /// A texture of the wrong size, or another bad in-memory input.
    #[error("{what}: {reason}")]
    BadInput {
        /// What was being written.
        what: String,
        /// What is wrong.
        reason: String,
    },
    /// Encoding an image failed.
    #[error(transparent)]
    Image(#[from] btfrig_imageio::ImageIoError),
}

/// Maps a [`Storage`] error of `op` on `path` to [`StoreError::Io`] naming both (the
/// storage's own display of the path).
pub(crate) fn io_err<S: Storage + ?Sized>(
    s: &S,
    op: &'static str,
    path: &str,
) -> impl FnOnce(std::io::Error) -> StoreError {
    let path = s.display(path);
    move |source| StoreError::Io { op, path, source }
}
