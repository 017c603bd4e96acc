//! What every `btfrig reprocess` shares, the gonio's (`crate::reprocess`) and the dome's
//! (`crate::dome_reprocess`): the request and its summary, reading the source dataset (its
//! manifest, rig config and journaled raw files), the calibration directory and the file
//! names it replaces, and the new dataset's manifest and empty output directory.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use btfrig_core::config::RigConfig;
use btfrig_store::journal::StepRecord;
use btfrig_store::{Manifest, JOURNAL_FILE, MANIFEST_FILE};

use crate::{ProcessingInfo, RunError};

/// The subdirectory of a calibration directory that holds a dark/flat calibration
/// (`btfrig calibrate radiometric --out DIR/dark-flat`).
pub const DARK_FLAT_DIR: &str = "dark-flat";

/// What to reprocess.
#[derive(Debug, Clone)]
pub struct ReprocessRequest {
    /// The dataset whose raw frames are processed (read only).
    pub dataset: PathBuf,
    /// The new dataset (created; must not exist or be empty).
    pub out: PathBuf,
    /// Calibration files replacing the ones the rig config names, by file name
    /// ([`calibration_file_name`]); `None`: the dataset's own calibrations.
    pub calibration: Option<PathBuf>,
}

/// What a reprocessing did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReprocessSummary {
    /// The new dataset.
    pub out: PathBuf,
    /// Steps processed (every committed step of the source).
    pub steps: u64,
    /// Seconds per pipeline stage, summed over steps.
    pub stage_s: BTreeMap<String, f64>,
    /// Textures rectified with a registered pose.
    pub registered: u64,
    /// Textures rectified with the nominal pose because registration failed.
    pub fallbacks: u64,
    /// Textures rectified with the nominal pose because the plan says so.
    pub nominal_by_plan: u64,
    /// What frames were processed with (part, source) and what the output lacks.
    pub processing: ProcessingInfo,
    /// Wall time, seconds.
    pub wall_s: f64,
}

pub(crate) fn input(what: impl Into<String>, message: impl Into<String>) -> RunError {
    RunError::Input { what: what.into(), message: message.into() }
}

/// The file a calibration reference of a rig config is looked up as in a calibration
/// directory: `builtin:NAME` is `NAME.toml`, a path is its file name
/// (`calib/lamp-2026.toml` is `lamp-2026.toml`).
pub fn calibration_file_name(reference: &str) -> String {
    match reference.strip_prefix("builtin:") {
        Some(name) => format!("{name}.toml"),
        None => Path::new(reference).file_name().map_or_else(|| reference.to_string(), |n| n.to_string_lossy().into()),
    }
}

/// The source dataset, read only: manifest, committed steps in commit order, view groups'
/// raw frames.
pub(crate) struct Source {
    pub(crate) manifest: Manifest,
    /// Its content hash ([`btfrig_store::manifest_hash`]).
    pub(crate) manifest_hash: String,
    pub(crate) steps: Vec<StepRecord>,
    /// The journaled raw frames of view groups (a dome's), by view.
    pub(crate) frames: BTreeMap<u32, btfrig_store::FramesRecord>,
}

pub(crate) fn read_source(dir: &Path) -> Result<Source, RunError> {
    let what = format!("dataset {}", dir.display());
    let read = |name: &str| {
        let path = dir.join(name);
        std::fs::read(&path).map_err(|source| RunError::Read { path, source })
    };
    let bytes = read(MANIFEST_FILE)?;
    let manifest: Manifest = serde_json::from_slice(&bytes)
        .map_err(|e| input(&what, format!("{MANIFEST_FILE} is not a dataset manifest: {e}")))?;
    let journal = read(JOURNAL_FILE)?;
    let replay = btfrig_store::journal::replay(&dir.join(JOURNAL_FILE).display().to_string(), &journal)
        .map_err(|e| input(&what, e.to_string()))?;
    let frames = replay.frames;
    let mut steps: Vec<StepRecord> = replay.done.into_values().collect();
    // The order the run committed them in.
    steps.sort_by(|a, b| a.timing.started_unix_s.total_cmp(&b.timing.started_unix_s).then(a.step.cmp(&b.step)));
    Ok(Source { manifest, manifest_hash: btfrig_store::manifest_hash(&bytes), steps, frames })
}

/// The bytes of the journaled file `f` of the dataset `dir`, checked against its journaled
/// size and content hash.
pub(crate) fn read_journaled(dir: &Path, f: &btfrig_store::FileRecord) -> Result<Vec<u8>, RunError> {
    let path = dir.join(&f.path);
    let bytes = std::fs::read(&path).map_err(|e| {
        input(format!("raw frame {}", path.display()), format!("cannot read it ({e}): it is missing or unreadable"))
    })?;
    let hash = btfrig_store::content_hash(&bytes);
    if bytes.len() as u64 != f.size || hash != f.hash {
        return Err(input(
            format!("raw frame {}", path.display()),
            format!(
                "it is damaged: {} bytes, {hash}; the journal recorded {} bytes, {} (btfrig dataset verify lists every damaged file)",
                bytes.len(),
                f.size,
                f.hash
            ),
        ));
    }
    Ok(bytes)
}

/// Points `reference` (a calibration reference of the rig config, `field` naming it) at the
/// file of the same name in `dir` ([`calibration_file_name`]) when `dir` holds one, by its
/// absolute path (the model's loaders then read, check and name it as any calibration file),
/// and records it in `used`.
pub(crate) fn replace_reference(
    dir: Option<&Path>,
    field: &str,
    reference: &mut Option<String>,
    used: &mut Vec<(String, String)>,
) -> Option<PathBuf> {
    let (dir, r) = (dir?, reference.as_deref()?);
    let path = dir.join(calibration_file_name(r));
    path.is_file().then(|| {
        used.push((field.to_string(), path.display().to_string()));
        *reference = Some(path.display().to_string());
        path
    })
}

/// Refuses a relative calibration path that no file of the calibration directory replaced:
/// it has no base to resolve against (the manifest keeps the rig config's text, not where it
/// was).
pub(crate) fn refuse_relative(references: &[(&str, &Option<String>)]) -> Result<(), RunError> {
    for (field, reference) in references {
        if let Some(r) = reference.as_deref().filter(|r| !r.starts_with("builtin:") && !Path::new(r).is_absolute()) {
            return Err(input(
                format!("the dataset's rig config: {field} = {r:?}"),
                format!(
                    "a relative calibration file cannot be found from a dataset: give --calibration DIR with {} in it",
                    calibration_file_name(r)
                ),
            ));
        }
    }
    Ok(())
}

/// The rig config recorded in the source's manifest.
pub(crate) fn rig_of(manifest: &Manifest, dir: &Path) -> Result<RigConfig, RunError> {
    let origin = format!("{}/{MANIFEST_FILE}: rig.config_toml", dir.display());
    RigConfig::from_toml(&manifest.rig.config_toml, &origin).map_err(|e| input(origin, e.to_string()))
}

/// The request's calibration directory, absolute: the files' paths go into the rig config,
/// which has no base directory here.
pub(crate) fn calibration_dir(req: &ReprocessRequest) -> Result<Option<PathBuf>, RunError> {
    if let Some(d) = req.calibration.as_deref().filter(|d| !d.is_dir()) {
        return Err(input(format!("--calibration {}", d.display()), "not a directory"));
    }
    req.calibration
        .as_deref()
        .map(|d| d.canonicalize().map_err(|source| RunError::Read { path: d.into(), source }))
        .transpose()
}

/// Refuses an `out` that holds anything: reprocessing writes a new dataset.
pub(crate) fn check_out_empty(out: &Path) -> Result<(), RunError> {
    if let Ok(mut entries) = std::fs::read_dir(out) {
        if entries.next().is_some() {
            return Err(input(
                format!("--out {}", out.display()),
                "the directory is not empty: reprocessing writes a new dataset and overwrites nothing; name a new or empty directory",
            ));
        }
    }
    Ok(())
}

/// The manifest of a dataset reprocessed from `source`'s: created now, no rig timing, textures
/// only (its frames stay the source's).
pub(crate) fn reprocessed_manifest(source: &btfrig_store::Manifest) -> btfrig_store::Manifest {
    let mut manifest = source.clone();
    let now =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0);
    manifest.created_unix_s = now;
    manifest.created_utc = btfrig_store::rfc3339_utc(now as i64);
    manifest.timing = None;
    manifest.raw_frames = false;
    manifest.raw_groups = None;
    manifest.textures = true;
    manifest
}
