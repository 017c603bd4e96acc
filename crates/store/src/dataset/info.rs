//! `btfrig dataset info`, and the compressed models journaled after a run.

use std::path::Path;

use crate::error::StoreError;
use crate::journal::{self, Journal, ModelRecord, Record, TornTail};
use crate::manifest::{manifest_hash, Manifest, TextureFormat};
use crate::storage::{FsStorage, Storage};

use super::files::read_manifest;
use super::layout::{list_names, JOURNAL_FILE, MANIFEST_FILE, REPORT_FILE};
use crate::error::io_err;

/// Summary of a dataset for `btfrig dataset info`.
#[derive(Debug, Clone)]
pub struct DatasetInfo {
    /// The dataset directory.
    pub dir: String,
    /// The manifest.
    pub manifest: Manifest,
    /// Steps expected.
    pub expected: usize,
    /// Steps journaled done.
    pub done: usize,
    /// Steps journaled skipped during the run.
    pub skipped_in_run: usize,
    /// Retries over the done steps.
    pub retries: u64,
    /// Bytes of all files of the dataset.
    pub bytes_on_disk: u64,
    /// Number of files.
    pub files: usize,
    /// Sum of the journaled steps' wall times, seconds.
    pub step_wall_s: f64,
    /// Sum of the journaled steps' hardware times, seconds, over the steps that report one;
    /// `None` when none does (a dome's textures: the rig time is per view group, in the report).
    pub step_hardware_s: Option<f64>,
    /// A torn journal tail (a killed run not yet resumed).
    pub torn_tail: Option<TornTail>,
    /// True if `report.json` exists and its `status` is `finished` (or absent).
    pub finished: bool,
    /// `report.json`'s `status` and `reason`, when the run that wrote it stopped early
    /// (`paused`, `interrupted`, `aborted`).
    pub stopped: Option<(String, Option<String>)>,
}

impl std::fmt::Display for DatasetInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let m = &self.manifest;
        writeln!(f, "dataset   {}", self.dir)?;
        writeln!(f, "rig       {}", m.rig.name)?;
        writeln!(f, "plan      {}", m.plan.hash)?;
        writeln!(f, "software  {} {} (manifest schema {})", m.software.name, m.software.version, m.schema_version)?;
        writeln!(f, "created   {}  seed {}", m.created_utc, m.seed)?;
        writeln!(
            f,
            "sampling  {} light x {} view directions{}, {} skipped by the plan",
            m.samplings.light.len(),
            m.samplings.view.len(),
            m.samplings.pairs.as_ref().map_or(String::new(), |p| format!(" ({} pairs)", p.len())),
            m.samplings.skipped.len()
        )?;
        let fmt = match m.texture.format {
            TextureFormat::ExrHalf => "OpenEXR half",
            TextureFormat::ExrFloat => "OpenEXR float",
        };
        writeln!(
            f,
            "textures  {}{}x{} {fmt}, region {:.4}x{:.4} m at ({:.4}, {:.4}){}",
            if m.textures { "" } else { "none written (raw frames only); would be " },
            m.texture.width,
            m.texture.height,
            m.texture.region.size_m[0],
            m.texture.region.size_m[1],
            m.texture.region.center_m[0],
            m.texture.region.center_m[1],
            if m.raw_frames {
                ", raw frames kept"
            } else if m.raw_groups.is_some() {
                ", raw frames kept per view group"
            } else {
                ""
            }
        )?;
        let pct = if self.expected == 0 { 100.0 } else { 100.0 * self.done as f64 / self.expected as f64 };
        writeln!(
            f,
            "steps     {}/{} done ({pct:.1}%), {} skipped in the run, {} retries",
            self.done, self.expected, self.skipped_in_run, self.retries
        )?;
        writeln!(f, "size      {} files, {:.1} MB", self.files, self.bytes_on_disk as f64 / 1e6)?;
        write!(f, "timing    steps: {:.1} s wall", self.step_wall_s)?;
        if let Some(h) = self.step_hardware_s {
            write!(f, ", {h:.1} s hardware")?;
        }
        if let Some(t) = &m.timing {
            write!(f, "; run: {:.1} s wall", t.wall_s)?;
            if let Some(h) = t.hardware_s {
                write!(f, ", {h:.1} s hardware")?;
            }
        }
        writeln!(f)?;
        match &self.stopped {
            Some((status, reason)) => {
                write!(f, "state     {status}, resumable")?;
                if let Some(r) = reason {
                    write!(f, ": {r}")?;
                }
            }
            None => write!(f, "state     {}", if self.finished { "finished" } else { "unfinished (resumable)" })?,
        }
        if let Some(t) = &self.torn_tail {
            write!(f, "; {t}")?;
        }
        Ok(())
    }
}

fn all_files<S: Storage + ?Sized>(s: &S, dir: &str, out: &mut Vec<(String, u64)>) -> Result<(), StoreError> {
    for e in list_names(s, dir)? {
        let p = if dir.is_empty() { e.name.clone() } else { format!("{dir}/{}", e.name) };
        if e.is_dir {
            all_files(s, &p, out)?;
        } else {
            let n = s.size(&p).map_err(io_err(s, "stat", &p))?.unwrap_or(0);
            out.push((p, n));
        }
    }
    Ok(())
}

/// [`DatasetInfo`] of the dataset in `dir` (read only).
pub fn info(dir: &Path) -> Result<DatasetInfo, StoreError> {
    info_in(&FsStorage::new(dir))
}

/// [`info`] on any storage.
pub fn info_in<S: Storage + ?Sized>(s: &S) -> Result<DatasetInfo, StoreError> {
    let (manifest, _) = read_manifest(s)?;
    let bytes = match s.size(JOURNAL_FILE).map_err(io_err(s, "stat", JOURNAL_FILE))? {
        Some(_) => s.read(JOURNAL_FILE).map_err(io_err(s, "read", JOURNAL_FILE))?,
        None => Vec::new(),
    };
    let replay = journal::replay(&s.display(JOURNAL_FILE), &bytes)?;
    let mut files = Vec::new();
    all_files(s, "", &mut files)?;
    // A run that stopped early (paused, interrupted) still writes its report; say so.
    let report: Option<serde_json::Value> = match s.size(REPORT_FILE).map_err(io_err(s, "stat", REPORT_FILE))? {
        Some(_) => Some(
            serde_json::from_slice(&s.read(REPORT_FILE).map_err(io_err(s, "read", REPORT_FILE))?).unwrap_or_default(),
        ),
        None => None,
    };
    let stopped = report.as_ref().and_then(|r| match r["status"].as_str() {
        None | Some("finished") => None,
        Some(st) => Some((st.to_string(), r["reason"].as_str().map(str::to_string))),
    });
    Ok(DatasetInfo {
        dir: s.display(""),
        expected: manifest.samplings.expected_steps().len(),
        done: replay.done.len(),
        skipped_in_run: replay.skipped.len(),
        retries: replay.done.values().map(|r| u64::from(r.attempts.saturating_sub(1))).sum(),
        bytes_on_disk: files.iter().map(|f| f.1).sum(),
        files: files.len(),
        step_wall_s: replay.done.values().map(|r| r.timing.wall_s).sum(),
        step_hardware_s: replay
            .done
            .values()
            .filter_map(|r| r.timing.hardware_s)
            .fold(None, |sum, h| Some(sum.unwrap_or(0.0) + h)),
        torn_tail: replay.torn_tail,
        finished: report.is_some() && stopped.is_none(),
        stopped,
        manifest,
    })
}

/// The compressed models journaled in the dataset in `dir` (`btfrig run --compress`), in
/// journal order (read only).
pub fn journaled_models(dir: &Path) -> Result<Vec<ModelRecord>, StoreError> {
    let s = FsStorage::new(dir);
    let bytes = s.read(JOURNAL_FILE).map_err(io_err(&s, "read", JOURNAL_FILE))?;
    Ok(journal::replay(&s.display(JOURNAL_FILE), &bytes)?.models)
}

/// Journals a compressed model written (durably) next to the dataset in `dir`, after its run
/// ended: the journal is opened as a resume opens it (plan and manifest checked).
pub fn journal_model(dir: &Path, record: ModelRecord) -> Result<(), StoreError> {
    let s = FsStorage::new(dir);
    let (manifest, bytes) = read_manifest(&s)?;
    let hash = manifest_hash(&bytes);
    let (mut j, _) = Journal::open(&s, JOURNAL_FILE, &manifest.plan.hash, Some(&hash))?;
    if let Some(expected) = &j.state().manifest_hash {
        if *expected != hash {
            return Err(StoreError::ManifestChanged {
                path: s.display(MANIFEST_FILE),
                expected: expected.clone(),
                found: hash,
            });
        }
    }
    j.append(&s, Record::Model(record))
}
