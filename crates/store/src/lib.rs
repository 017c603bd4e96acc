//! The dataset store of btfrig: where a measurement run puts its results, crash-safely.
//!
//! Brief overview: a [`Dataset`] is a directory (layout and schemas in
//! `docs/dataset-format.md`) with a [`Manifest`] (what is measured: rig, plan, samplings,
//! texture format), the rectified textures (OpenEXR) and optional raw frames, an append-only
//! [`journal`] and, when the run ends, a [`RunReport`]. The run engine writes a step's files
//! ([`Dataset::write_texture`], [`Dataset::write_raw`]: temporary name, fsync, rename,
//! directory fsync), then journals the step ([`Dataset::commit_step`]: append, fsync). Only
//! a journaled step counts: [`Dataset::open_for_resume`] replays the journal, cuts a torn
//! tail, deletes files no record names, and returns the completed steps so a restarted run
//! repeats none and loses none. [`info`] and [`verify`] serve `btfrig dataset info|verify`.
//! All I/O goes through the [`Storage`] trait: [`FsStorage`] for real, [`MemStorage`] in
//! tests that cut the power at any operation.
//!
//! ```no_run
//! # fn demo(manifest: btfrig_store::Manifest, texels: &[[f32; 3]]) -> Result<(), btfrig_store::StoreError> {
//! use btfrig_store::{Dataset, StepId, StepTiming};
//! let dir = std::path::Path::new("out/run1");
//! let plan = manifest.plan.hash.clone();
//! let ds = Dataset::create(dir, manifest)?;
//! let step = StepId { light: 0, view: 3 };
//! let file = ds.write_texture(step, texels, 256, 256)?;
//! ds.commit_step(step, vec![file], 1, StepTiming::default())?;
//! drop(ds);
//! let (ds, resume) = Dataset::open_for_resume(dir, &plan)?;
//! assert!(resume.completed.contains(&step));
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

// The files, one job each:
// - dataset/:  the dataset directory (mod: create, write, commit, resume; layout, files, info, verify)
// - journal:   the append-only journal
// - manifest:  what a dataset measures
// - storage:   the file-system layer (FsStorage, MemStorage)
// - hash:      content hashes; error: StoreError

mod dataset;
mod error;
mod hash;
pub mod journal;
mod manifest;
mod storage;

pub use dataset::{
    info, info_in, journal_model, journaled_models, verify, verify_in, Dataset, DatasetInfo, Problem, ResumeReport,
    VerifyReport, JOURNAL_FILE, MANIFEST_FILE, PREVIEW_FILE, RAW_DIR, REPORT_FILE, TEXTURES_DIR,
};
pub use error::StoreError;
pub use hash::{content_hash, sha256, HASH_PREFIX};
pub use journal::{FramesRecord, ModelRecord, TornTail};
pub use manifest::{
    manifest_hash, plan_hash, rfc3339_utc, DirectionDeg, Manifest, PlanInfo, RigInfo, Samplings, SkippedStep, Software,
    TextureFormat, TextureRegion, TextureSpec, TimingSummary, MANIFEST_SCHEMA_VERSION,
};
pub use storage::{Entry, FsStorage, MemStorage, Storage, TornAppend};

/// The stable key of a step: indices into the manifest's light and view samplings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepId {
    /// Index into `samplings.light`.
    pub light: u32,
    /// Index into `samplings.view`.
    pub view: u32,
}

impl StepId {
    /// The file stem of this step's files: `l003_v017`.
    pub fn stem(self) -> String {
        format!("l{:03}_v{:03}", self.light, self.view)
    }
}

impl std::fmt::Display for StepId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "(light {}, view {})", self.light, self.view)
    }
}

/// A file a step wrote: path relative to the dataset, size and content hash.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileRecord {
    /// Path relative to the dataset directory (`textures/l003_v017.exr`).
    pub path: String,
    /// Size, bytes.
    pub size: u64,
    /// Content hash ([`content_hash`]: `sha256:<hex>`).
    pub hash: String,
}

/// Timing of one step, as journaled.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StepTiming {
    /// When the step started, Unix seconds (wall clock).
    pub started_unix_s: f64,
    /// Wall time from start to commit, seconds.
    pub wall_s: f64,
    /// Hardware time of the step (simulated rigs: virtual time), seconds, if known.
    pub hardware_s: Option<f64>,
    /// Seconds per pipeline stage for this step.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub stage_s: BTreeMap<String, f64>,
}

/// Which pose a step's texture was rectified with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    /// The pose registered from the holder plate's markers in the frame.
    Markers,
    /// Registration failed and the plan allowed the nominal (kinematic) pose instead.
    NominalFallback,
    /// The plan asked for the nominal pose (`[registration] method = "nominal"`).
    NominalByPlan,
}

impl PoseSource {
    /// The name as journaled.
    pub fn as_str(self) -> &'static str {
        match self {
            PoseSource::Markers => "markers",
            PoseSource::NominalFallback => "nominal-fallback",
            PoseSource::NominalByPlan => "nominal-by-plan",
        }
    }
}

/// How a step's sample pose was found, as journaled with the step (optional: journals
/// written before registration have none).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepRegistration {
    /// The pose the texture was rectified with.
    pub pose: PoseSource,
    /// Ids of the markers the registered pose rests on (its inliers), ascending; empty
    /// unless `pose` is `markers`.
    #[serde(default)]
    pub markers: Vec<u32>,
    /// RMS reprojection error of those markers' corners, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_px: Option<f64>,
    /// Predicted standard deviation of the texel position error from the pose covariance,
    /// texels (worst point of the texture).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texel_sigma: Option<f64>,
    /// Why registration failed (fallbacks only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Where the markers were searched (absent in journals written before it was recorded,
    /// and when no marker search ran). Boxed: most records of a journal are steps, and this
    /// keeps the record enum's variants of similar size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search: Option<Box<StepSearch>>,
}

/// How a step's markers were searched (`docs/registration.md`, "What the windows save").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepSearch {
    /// Windows predicted from the nominal pose and searched first (0: the whole frame only).
    pub windows: u32,
    /// Pixels searched over the frame's pixels (windows, plus 1 after a fallback).
    pub searched_fraction: f64,
    /// Whether the whole frame was searched (a fallback, or the search asked for it).
    pub whole_frame: bool,
    /// Why the windows were not enough (`no-pose`, `marker-outside-windows`): fallbacks only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback: Option<String>,
    /// The fallback's details (which marker, which error).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fallback_detail: Option<String>,
    /// Seconds the detection took (windows and any whole-frame search).
    pub detect_s: f64,
    /// Seconds a whole-frame detection takes on this frame: measured when it ran, else the
    /// run's one reference search scaled by pixels; absent before any reference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub whole_frame_s: Option<f64>,
    /// Seconds this step spent timing the run's reference whole-frame search (0 on all others).
    #[serde(default)]
    pub reference_s: f64,
}

/// The exposures of a step captured with HDR on (`docs/hdr.md`): journaled with the step so
/// the report counts captures by exposures exactly, after a kill too.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepHdr {
    /// Exposure times in the order taken, seconds; the first is the base exposure the
    /// texture's radiometry refers to.
    pub exposures_s: Vec<f64>,
    /// Rig time the exposures beyond the first took, return trips to the pose included, s.
    pub bracket_s: f64,
    /// Photosites saturated in every exposure (their merged values are lower bounds).
    pub saturated_photosites: u64,
    /// Exposure times always bracketing would have taken (the counterfactual the report's
    /// `hdr_time_saved_s` compares with), seconds.
    pub always_s: Vec<f64>,
}

/// What a step's journal record holds besides its files, attempts and timing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepExtra {
    /// How its sample pose was found.
    pub registration: Option<StepRegistration>,
    /// Its exposures, with HDR on.
    pub hdr: Option<StepHdr>,
}

/// The run report (`report.json`), written by [`Dataset::finish`]. Unknown fields are kept
/// in `extra` so later versions can add figures.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RunReport {
    /// Captures made (steps done).
    pub captures: u64,
    /// Wall time of the run, seconds (summed over resumed sessions by the caller).
    pub wall_s: f64,
    /// Hardware time (simulated rigs: virtual time), seconds.
    pub hardware_s: Option<f64>,
    /// Seconds per pipeline stage.
    pub stage_s: BTreeMap<String, f64>,
    /// Steps skipped, by reason.
    pub skipped: BTreeMap<String, u64>,
    /// Retries (attempts beyond the first).
    pub retries: u64,
    /// Warnings raised during the run.
    pub warnings: Vec<String>,
    /// Further figures (e.g. `texture_rel_rmse`).
    #[serde(flatten)]
    pub extra: BTreeMap<String, serde_json::Value>,
}
