//! Why a run could not start or went wrong.

use std::path::PathBuf;

use btfrig_store::StoreError;

use crate::Signal;

/// Why a run could not start or went wrong (not a pause: that is a [`RunOutcome`]).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The plan does not parse or validate (every problem, each naming its field).
    #[error("{0}")]
    Plan(#[from] btfrig_core::plan::PlanErrors),
    /// Something the plan or the request names is unusable (rig config, material, faults).
    #[error("{what}: {message}")]
    Input {
        /// What was named, and where.
        what: String,
        /// What is wrong, and what is allowed.
        message: String,
    },
    /// The plan is for another kind of rig, or another rig, than the one that is to run it
    /// ([`check::check_for_rig`]).
    #[error(
        "the plan is a {plan_kind} for rig {plan_rig}, and the rig here is {rig:?} ({rig_kind}): \
         allowed here are {allowed} for rig {rig:?}"
    )]
    WrongRig {
        /// The plan's format ([`check::PlanKind::describe`]).
        plan_kind: &'static str,
        /// The rig the plan names: `"name" (kind)`, or its `rig.config` as written.
        plan_rig: String,
        /// The name of the rig that is to run it.
        rig: String,
        /// Its kind (`[rig] kind`).
        rig_kind: &'static str,
        /// The plans that rig runs ([`check::PlanKind::allowed`]).
        allowed: &'static str,
    },
    /// The plan captures nothing.
    #[error("{}: the plan captures nothing", plan.display())]
    Empty {
        /// The plan file.
        plan: PathBuf,
    },
    /// The dataset directory cannot be created or resumed (e.g. it holds another dataset).
    #[error("--out {}: {source}", dir.display())]
    Dataset {
        /// The directory.
        dir: PathBuf,
        /// The store's reason.
        source: StoreError,
    },
    /// The planner cannot schedule the plan.
    #[error("planning: {0}")]
    Planner(#[from] btfrig_planner::PlanError),
    /// Devices failed their preflight check: nothing was created.
    #[error(
        "rig {rig:?}: {} device(s) failed the preflight check, nothing was created:\n  {}",
        failures.len(),
        failures.join("\n  ")
    )]
    Preflight {
        /// The rig config's name.
        rig: String,
        /// Per failed device: `devices.ROLE on PORT: what failed`.
        failures: Vec<String>,
    },
    /// The rig could not be built or prepared.
    #[error("rig: {0}")]
    Rig(String),
    /// Processing or writing a capture failed; the captures committed before it are kept.
    #[error("pipeline: {0}")]
    Pipeline(#[from] btfrig_process::PipelineError),
    /// Writing the report failed.
    #[error("writing the report: {0}")]
    Report(StoreError),
    /// The async runtime could not be built.
    #[error("runtime: {0}")]
    Runtime(std::io::Error),
    /// A signal ([`RunControl::interrupt`]) stopped the run while it was planning, before
    /// the dataset was created: nothing was written.
    #[error("interrupted by {} while planning, before the dataset was created: nothing was written", .0.name())]
    Interrupted(Signal),
    /// A [`btfrig_planner::Cancel`] flag stopped the work (a dry run whose client went
    /// away, a time limit).
    #[error("cancelled: {0}")]
    Cancelled(String),
}
