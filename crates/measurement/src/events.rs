//! What a run tells its watcher: progress events, faults, how it ended.

use std::collections::BTreeMap;
use std::path::PathBuf;

use crate::Signal;

/// What a run tells its observer.
#[derive(Debug, Clone, PartialEq)]
pub enum RunEvent {
    /// The plan validated; the schedule of this many captures is being planned (before
    /// the dataset is created).
    Planning {
        /// Captures of the whole plan.
        captures: usize,
    },
    /// The dataset is open and the schedule planned; the rig is being prepared.
    Started {
        /// The dataset directory.
        dataset: PathBuf,
        /// True when an existing dataset of the same plan is resumed.
        resumed: bool,
        /// Captures done before this session.
        done_before: usize,
        /// Captures this session has to do.
        to_do: usize,
        /// Captures of the whole plan.
        total: usize,
        /// The planner's hardware time for the whole plan, seconds.
        planned_hardware_s: f64,
        /// The planner's lower bound, seconds.
        critical_path_s: f64,
        /// What resuming found and repaired (torn journal tail, orphans), if anything.
        repaired: Option<String>,
    },
    /// A capture was delivered by the engine.
    StepDone {
        /// Light index.
        light: u32,
        /// View index.
        view: u32,
        /// 1 + retries.
        attempts: u32,
    },
    /// Progress of the whole plan.
    Progress {
        /// Captures done (before and in this session).
        done: usize,
        /// Captures of the whole plan.
        total: usize,
        /// Remaining rig time from measured step times, seconds.
        eta_s: Option<f64>,
    },
    /// Something was retried or went wrong, but the run goes on.
    Warning(String),
    /// The engine is paused.
    Paused {
        /// Why.
        reason: String,
        /// The failed step, when a step failed.
        fault: Option<Fault>,
    },
    /// The engine goes on after a pause.
    Resumed,
    /// The pipeline committed a capture (textures, journal, preview written).
    Committed {
        /// Captures committed by this session so far.
        committed: u64,
        /// Previews written by this session so far (`preview.png` replaced each time).
        previews: u64,
        /// Captures delivered by the engine and not yet committed (the pipeline's queue).
        queued: u64,
        /// Seconds per pipeline stage summed over this session's commits.
        stage_s: BTreeMap<String, f64>,
    },
    /// The session is ending: the frames in flight are processed and committed first.
    Stopping {
        /// Why.
        reason: String,
    },
    /// A dome run's step was delivered by the engine: one pattern (or reference light) at one
    /// rotation, a frame per camera ([`dome::run_controlled`]; gonio runs send `StepDone`).
    DomeStepDone {
        /// Position in the schedule.
        index: usize,
        /// The turntable rotation index (0 on a camera array).
        rotation: u32,
        /// 1 + retries.
        attempts: u32,
    },
    /// What a dome run's dataset holds: sent once when the session starts (what earlier
    /// sessions committed) and after every view group it commits (every light's texture of
    /// one camera at one rotation, committed at once after demultiplexing).
    TexturesCommitted {
        /// Textures in the dataset, earlier sessions included.
        textures: u64,
        /// Textures of the whole plan (lights x views).
        total: u64,
        /// Previews written by this session so far (`preview.png` replaced after each view
        /// group when [`dome::DomeRunRequest::preview`] asks for it).
        previews: u64,
        /// Seconds per processing stage summed over this session's view groups.
        stage_s: BTreeMap<String, f64>,
    },
}

/// A step that failed with an error no retry helps (or that ran out of retries).
#[derive(Debug, Clone, PartialEq)]
pub struct Fault {
    /// Position of the step in the schedule.
    pub index: usize,
    /// Light index of the capture.
    pub light: u32,
    /// View index of the capture.
    pub view: u32,
    /// The device that failed.
    pub device: String,
    /// The error's kind (`timeout`, `other`, ...).
    pub kind: String,
    /// The device error and what the engine did.
    pub message: String,
}

/// How a session ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// Every capture of the plan is done.
    Finished,
    /// Every capture was already done; nothing was run and the report is unchanged.
    NothingToDo,
    /// A step failed in a way no retry helps; fix the cause and run again to resume.
    Paused {
        /// Why, as one line.
        reason: String,
        /// The failed step.
        fault: Option<Fault>,
    },
    /// Interrupted by a signal (Ctrl-C, SIGTERM); resumable.
    Interrupted(Signal),
    /// Aborted on request; resumable.
    Aborted,
}

impl RunOutcome {
    /// The `status` written to `report.json`.
    pub fn status(&self) -> &'static str {
        match self {
            RunOutcome::Finished | RunOutcome::NothingToDo => "finished",
            RunOutcome::Paused { .. } => "paused",
            RunOutcome::Interrupted(_) => "interrupted",
            RunOutcome::Aborted => "aborted",
        }
    }

    /// Why the run did not finish.
    pub fn reason(&self) -> Option<String> {
        match self {
            RunOutcome::Paused { reason, .. } => Some(reason.clone()),
            RunOutcome::Interrupted(signal) => Some(format!("interrupted ({})", signal.name())),
            RunOutcome::Aborted => Some("aborted on request".into()),
            _ => None,
        }
    }
}
