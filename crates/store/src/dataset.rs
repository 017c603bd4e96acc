//! The dataset directory: create, write, commit, resume, finish, and `info` / `verify`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::{Mutex, MutexGuard};

use btfrig_core::frame::RawFrame;
use btfrig_imageio::ExrPrecision;

use crate::error::StoreError;
use crate::hash::content_hash;
use crate::journal::{self, Journal, ModelRecord, Record, StepRecord, TornTail};
use crate::manifest::{manifest_fixed_part, manifest_hash, Manifest, TextureFormat, TimingSummary};
use crate::storage::{parent, FsStorage, Storage};
use crate::{FileRecord, RunReport, StepExtra, StepId, StepTiming};

/// The manifest's file name.
pub const MANIFEST_FILE: &str = "manifest.json";
/// The journal's file name.
pub const JOURNAL_FILE: &str = "journal.btfj";
/// The run report's file name.
pub const REPORT_FILE: &str = "report.json";
/// Directory of the rectified textures.
pub const TEXTURES_DIR: &str = "textures";
/// Directory of the raw frames.
pub const RAW_DIR: &str = "raw";
/// Directory of the 8-bit sRGB texture previews.
pub const PREVIEWS_DIR: &str = "previews";
/// The live preview (8-bit sRGB PNG of the latest processed capture): not data, never
/// journaled, replaced atomically by [`Dataset::write_preview`].
pub const PREVIEW_FILE: &str = "preview.png";

/// The files a done step of `manifest` must have written (a journal record naming fewer is
/// refused by [`Dataset::commit_step`] and reported by [`verify`]).
fn required_files(manifest: &Manifest, step: StepId) -> Vec<String> {
    let mut out = Vec::new();
    if manifest.textures {
        out.push(texture_path(step));
    }
    if manifest.raw_frames {
        out.push(raw_path(step));
    }
    if manifest.texture_previews {
        out.push(texture_preview_path(step));
    }
    out
}

fn texture_preview_path(step: StepId) -> String {
    format!("{PREVIEWS_DIR}/{}.png", step.stem())
}

fn texture_path(step: StepId) -> String {
    format!("{TEXTURES_DIR}/{}.exr", step.stem())
}

fn raw_path(step: StepId) -> String {
    format!("{RAW_DIR}/{}.exr", step.stem())
}

/// Exposure `k >= 1` of an HDR bracket (exposure 0 is [`raw_path`]).
fn raw_exposure_path(step: StepId, k: usize) -> String {
    format!("{RAW_DIR}/{}_e{k}.exr", step.stem())
}

fn io_err<S: Storage + ?Sized>(s: &S, op: &'static str, path: &str) -> impl FnOnce(std::io::Error) -> StoreError {
    let path = s.display(path);
    move |source| StoreError::Io { op, path, source }
}

/// Temporary name of `path` while it is written: `.name.tmp` in the same directory, so the
/// rename is atomic and a partial file never has a final name.
fn tmp_name(path: &str) -> String {
    let dir = parent(path);
    let name = &path[if dir.is_empty() { 0 } else { dir.len() + 1 }..];
    if dir.is_empty() {
        format!(".{name}.tmp")
    } else {
        format!("{dir}/.{name}.tmp")
    }
}

/// Writes `bytes` durably under `path`: temporary file, fsync, rename, fsync of the directory.
fn write_atomic<S: Storage + ?Sized>(s: &S, path: &str, bytes: &[u8]) -> Result<FileRecord, StoreError> {
    let tmp = tmp_name(path);
    s.create(&tmp).map_err(io_err(s, "create", &tmp))?;
    s.append(&tmp, bytes).map_err(io_err(s, "write", &tmp))?;
    s.fsync(&tmp).map_err(io_err(s, "fsync", &tmp))?;
    s.rename(&tmp, path).map_err(io_err(s, "rename", &tmp))?;
    s.fsync(parent(path)).map_err(io_err(s, "fsync", parent(path)))?;
    Ok(FileRecord { path: path.to_string(), size: bytes.len() as u64, hash: content_hash(bytes) })
}

/// The manifest, and its bytes as on disk (for [`manifest_hash`]).
fn read_manifest<S: Storage + ?Sized>(s: &S) -> Result<(Manifest, Vec<u8>), StoreError> {
    let bytes = match s.size(MANIFEST_FILE).map_err(io_err(s, "stat", MANIFEST_FILE))? {
        None => return Err(StoreError::NotADataset { path: s.display("") }),
        Some(_) => s.read(MANIFEST_FILE).map_err(io_err(s, "read", MANIFEST_FILE))?,
    };
    let bad = |reason: String| StoreError::BadManifest { path: s.display(MANIFEST_FILE), reason };
    let m: Manifest = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
    let problems = m.problems();
    if !problems.is_empty() {
        return Err(bad(problems.join("; ")));
    }
    Ok((m, bytes))
}

/// What is wrong with a journaled file on disk (missing, another size, another content hash),
/// or `None` when it is as journaled.
fn file_damage<S: Storage + ?Sized>(s: &S, file: &FileRecord) -> Result<Option<String>, StoreError> {
    let Some(size) = s.size(&file.path).map_err(io_err(s, "stat", &file.path))? else {
        return Ok(Some("missing".into()));
    };
    if size != file.size {
        return Ok(Some(format!("{size} bytes, journaled with {}", file.size)));
    }
    let found = content_hash(&s.read(&file.path).map_err(io_err(s, "read", &file.path))?);
    if found != file.hash {
        return Ok(Some(format!("content hash {found}, journaled {}", file.hash)));
    }
    Ok(None)
}

fn list_names<S: Storage + ?Sized>(s: &S, dir: &str) -> Result<Vec<crate::Entry>, StoreError> {
    s.list(dir).map_err(io_err(s, "list", dir))
}

/// Files under the data directories (`textures/`, `raw/`), as dataset-relative paths.
fn data_files<S: Storage + ?Sized>(s: &S) -> Result<Vec<String>, StoreError> {
    let root = list_names(s, "")?;
    let mut out = Vec::new();
    for dir in [TEXTURES_DIR, RAW_DIR, PREVIEWS_DIR] {
        if root.iter().any(|e| e.name == dir && e.is_dir) {
            for e in list_names(s, dir)? {
                out.push(format!("{dir}/{}", e.name));
            }
        }
    }
    Ok(out)
}

/// What [`Dataset::open_for_resume`] found and repaired.
#[derive(Debug, Clone, Default)]
pub struct ResumeReport {
    /// Steps journaled as done: never to be captured again.
    pub completed: BTreeSet<StepId>,
    /// Steps journaled as skipped, with reasons.
    pub skipped: BTreeMap<StepId, String>,
    /// Expected steps neither done nor skipped: what the run still has to do.
    pub remaining: BTreeSet<StepId>,
    /// The torn journal tail that was cut away, if any.
    pub torn_tail: Option<TornTail>,
    /// Files deleted because no journal record names them (partial or uncommitted writes).
    pub removed_orphans: Vec<String>,
    /// True if the journal was missing (crash right after the manifest) and was created.
    pub journal_recreated: bool,
    /// Done steps whose files were found damaged (missing, another size, another content
    /// hash): journaled as retaken, their files deleted, to be captured again. One entry per
    /// damaged file: `textures/l000_v003.exr: missing`.
    pub retaken: Vec<(StepId, String)>,
    /// Journaled files checked (size and content hash) before the journal was trusted.
    pub files_checked: usize,
    /// Their bytes.
    pub bytes_checked: u64,
}

impl std::fmt::Display for ResumeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "resuming: {} steps done, {} skipped, {} to do",
            self.completed.len(),
            self.skipped.len(),
            self.remaining.len()
        )?;
        if let Some(t) = &self.torn_tail {
            write!(f, "; cut {t}")?;
        }
        if !self.removed_orphans.is_empty() {
            write!(f, "; removed {} uncommitted file(s)", self.removed_orphans.len())?;
        }
        for (step, what) in &self.retaken {
            write!(f, "\n  {what}: step {step} is captured again")?;
        }
        Ok(())
    }
}

/// An open dataset being written by a run. Methods take `&self` (except
/// [`Dataset::finish`]) so pipeline threads can share it; the journal is behind a mutex.
#[derive(Debug)]
pub struct Dataset<S: Storage = FsStorage> {
    storage: S,
    manifest: Manifest,
    expected: BTreeSet<StepId>,
    journal: Mutex<Journal>,
}

impl Dataset<FsStorage> {
    /// Creates a dataset in `dir` (created if missing). Refuses, naming what it found, a
    /// directory holding any dataset (another plan: [`StoreError::OtherDataset`]; the same
    /// plan: [`StoreError::AlreadyExists`], resume it) or anything else
    /// ([`StoreError::NotEmpty`]). Never overwrites.
    pub fn create(dir: &Path, manifest: Manifest) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::Io {
            op: "create directory",
            path: dir.display().to_string(),
            source,
        })?;
        Self::create_in(FsStorage::new(dir), manifest)
    }

    /// Reopens the dataset in `dir` to resume the run of the plan with hash `plan_hash`.
    pub fn open_for_resume(dir: &Path, plan_hash: &str) -> Result<(Self, ResumeReport), StoreError> {
        Self::open_for_resume_in(FsStorage::new(dir), plan_hash)
    }
}

impl<S: Storage> Dataset<S> {
    /// [`Dataset::create`] on any storage (whose root is the dataset directory).
    pub fn create_in(storage: S, manifest: Manifest) -> Result<Self, StoreError> {
        let problems = manifest.problems();
        if !problems.is_empty() {
            return Err(StoreError::BadManifest { path: storage.display(MANIFEST_FILE), reason: problems.join("; ") });
        }
        let root = list_names(&storage, "")?;
        if root.iter().any(|e| e.name == MANIFEST_FILE) {
            // Look at it leniently: even a manifest of another schema names its plan. One that
            // is not JSON is named with the line where it breaks.
            let bytes = storage.read(MANIFEST_FILE).map_err(io_err(&storage, "read", MANIFEST_FILE))?;
            let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| StoreError::BadManifest {
                path: storage.display(MANIFEST_FILE),
                reason: format!("does not parse as JSON: {e}"),
            })?;
            if !v["plan"]["hash"].is_string() {
                return Err(StoreError::BadManifest {
                    path: storage.display(MANIFEST_FILE),
                    reason: "no plan.hash (a string): not a btfrig manifest, or damaged".into(),
                });
            }
            let get = |a: &str, b: Option<&str>| {
                let x = &v[a];
                let x = b.map_or(x, |b| &x[b]);
                x.as_str().unwrap_or("?").to_string()
            };
            let found = get("plan", Some("hash"));
            if found == manifest.plan.hash {
                return Err(StoreError::AlreadyExists { path: storage.display(""), plan_hash: found });
            }
            return Err(StoreError::OtherDataset {
                path: storage.display(""),
                plan_hash: found,
                rig: get("rig", Some("name")),
                created: get("created_utc", None),
            });
        }
        if !root.is_empty() {
            let found = root.iter().take(10).map(|e| if e.is_dir { format!("{}/", e.name) } else { e.name.clone() });
            return Err(StoreError::NotEmpty { path: storage.display(""), found: found.collect() });
        }
        if manifest.textures {
            storage.create_dir(TEXTURES_DIR).map_err(io_err(&storage, "create directory", TEXTURES_DIR))?;
        }
        if manifest.raw_frames {
            storage.create_dir(RAW_DIR).map_err(io_err(&storage, "create directory", RAW_DIR))?;
        }
        if manifest.texture_previews {
            storage.create_dir(PREVIEWS_DIR).map_err(io_err(&storage, "create directory", PREVIEWS_DIR))?;
        }
        // The manifest first: once it exists the directory is this dataset, and a crash
        // before the journal is written leaves a dataset with nothing done (resume recreates it).
        let json = serde_json::to_vec_pretty(&manifest).expect("manifest serialises");
        write_atomic(&storage, MANIFEST_FILE, &json)?;
        let journal = Journal::create(&storage, JOURNAL_FILE, &manifest.plan.hash, Some(&manifest_hash(&json)))?;
        let expected = manifest.samplings.expected_steps();
        Ok(Dataset { storage, manifest, expected, journal: Mutex::new(journal) })
    }

    /// [`Dataset::open_for_resume`] on any storage: checks the manifest (plan hash, and that
    /// it is as created), replays the journal (cutting a torn tail), checks every journaled
    /// file (size and content hash) and journals the steps of damaged ones as retaken, deletes
    /// files no journal record names, and reports the completed steps.
    pub fn open_for_resume_in(storage: S, plan_hash: &str) -> Result<(Self, ResumeReport), StoreError> {
        let (manifest, manifest_bytes) = read_manifest(&storage)?;
        if manifest.plan.hash != plan_hash {
            return Err(StoreError::PlanMismatch {
                path: storage.display(MANIFEST_FILE),
                found: manifest.plan.hash,
                expected: plan_hash.into(),
            });
        }
        let mut report = ResumeReport::default();
        let found_hash = manifest_hash(&manifest_bytes);
        let mut journal = if storage.size(JOURNAL_FILE).map_err(io_err(&storage, "stat", JOURNAL_FILE))?.is_none() {
            report.journal_recreated = true;
            Journal::create(&storage, JOURNAL_FILE, plan_hash, Some(&found_hash))?
        } else {
            let (j, torn) = Journal::open(&storage, JOURNAL_FILE, plan_hash, Some(&found_hash))?;
            report.torn_tail = torn;
            j
        };
        if let Some(expected) = &journal.state().manifest_hash {
            if *expected != found_hash {
                return Err(StoreError::ManifestChanged {
                    path: storage.display(MANIFEST_FILE),
                    expected: expected.clone(),
                    found: found_hash,
                });
            }
        }
        // Trust no journaled file unchecked: a damaged one sends its step back to be captured.
        // The retake record is durable before the files are deleted (as orphans, below).
        let mut damaged: Vec<(StepId, Vec<String>)> = Vec::new();
        for (step, rec) in &journal.state().done {
            let mut found = Vec::new();
            for file in &rec.files {
                report.files_checked += 1;
                report.bytes_checked += file.size;
                if let Some(what) = file_damage(&storage, file)? {
                    found.push(format!("{}: {what}", file.path));
                }
            }
            if !found.is_empty() {
                damaged.push((*step, found));
            }
        }
        let mut retaken_files = BTreeSet::new();
        for (step, found) in damaged {
            let files = journal.state().done[&step].files.iter().map(|f| f.path.clone());
            retaken_files.extend(files);
            journal.append(&storage, Record::Retake { step, reason: found.join("; ") })?;
            report.retaken.extend(found.into_iter().map(|what| (step, what)));
        }
        let expected = manifest.samplings.expected_steps();
        for dir in [
            manifest.textures.then_some(TEXTURES_DIR),
            manifest.raw_frames.then_some(RAW_DIR),
            manifest.texture_previews.then_some(PREVIEWS_DIR),
        ]
        .into_iter()
        .flatten()
        {
            storage.create_dir(dir).map_err(io_err(&storage, "create directory", dir))?;
        }
        let state = journal.state();
        let named: BTreeSet<&str> = state.done.values().flat_map(|r| r.files.iter().map(|f| f.path.as_str())).collect();
        let mut dirs_touched = BTreeSet::new();
        for path in data_files(&storage)? {
            if !named.contains(path.as_str()) {
                storage.remove(&path).map_err(io_err(&storage, "remove", &path))?;
                dirs_touched.insert(parent(&path).to_string());
                // A retaken step's files are named in `retaken`, not as uncommitted.
                if !retaken_files.contains(&path) {
                    report.removed_orphans.push(path);
                }
            }
        }
        for e in list_names(&storage, "")? {
            // Temporary manifest or report of an interrupted create or finish.
            if !e.is_dir && e.name.starts_with('.') && e.name.ends_with(".tmp") {
                storage.remove(&e.name).map_err(io_err(&storage, "remove", &e.name))?;
                dirs_touched.insert(String::new());
                report.removed_orphans.push(e.name);
            }
        }
        for d in dirs_touched {
            storage.fsync(&d).map_err(io_err(&storage, "fsync", &d))?;
        }
        report.completed = state.done.keys().copied().collect();
        report.skipped = state.skipped.clone();
        report.remaining = expected
            .iter()
            .filter(|s| !report.completed.contains(s) && !report.skipped.contains_key(s))
            .copied()
            .collect();
        Ok((Dataset { storage, manifest, expected, journal: Mutex::new(journal) }, report))
    }

    fn journal(&self) -> MutexGuard<'_, Journal> {
        // The journal's in-memory state changes only after a successful fsync: a panic
        // elsewhere cannot leave it inconsistent.
        self.journal.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Fails unless `step` is expected and not yet journaled.
    fn check_open(&self, step: StepId, journal: &Journal) -> Result<(), StoreError> {
        if !self.expected.contains(&step) {
            return Err(StoreError::UnknownStep {
                step,
                lights: self.manifest.samplings.light.len(),
                views: self.manifest.samplings.view.len(),
            });
        }
        let st = journal.state();
        if st.done.contains_key(&step) {
            return Err(StoreError::StepAlreadyJournaled { step, state: "done".into() });
        }
        if let Some(r) = st.skipped.get(&step) {
            return Err(StoreError::StepAlreadyJournaled { step, state: format!("skipped: {r}") });
        }
        Ok(())
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The storage (e.g. to read a file back).
    pub fn storage(&self) -> &S {
        &self.storage
    }

    /// The steps a complete dataset holds (pairs minus the plan's skips).
    pub fn expected_steps(&self) -> &BTreeSet<StepId> {
        &self.expected
    }

    /// Steps journaled as done.
    pub fn completed(&self) -> BTreeSet<StepId> {
        self.journal().state().done.keys().copied().collect()
    }

    /// The journal record of a done step.
    pub fn step_record(&self, step: StepId) -> Option<StepRecord> {
        self.journal().state().done.get(&step).cloned()
    }

    /// Writes the rectified texture of `step` (`width x height` row-major linear RGB) as
    /// OpenEXR in the manifest's format to `textures/<stem>.exr`, durably, and returns its
    /// record for [`Dataset::commit_step`]. Retrying a step simply writes again. Fails unless
    /// the manifest asks for textures.
    pub fn write_texture(
        &self,
        step: StepId,
        texels: &[[f32; 3]],
        width: usize,
        height: usize,
    ) -> Result<FileRecord, StoreError> {
        self.check_open(step, &self.journal())?;
        let path = texture_path(step);
        if !self.manifest.textures {
            return Err(StoreError::BadInput {
                what: self.storage.display(&path),
                reason: "the manifest has textures = false".into(),
            });
        }
        let spec = &self.manifest.texture;
        if (width, height) != (spec.width as usize, spec.height as usize) {
            return Err(StoreError::BadInput {
                what: self.storage.display(&path),
                reason: format!("texture is {width}x{height}, the manifest says {}x{}", spec.width, spec.height),
            });
        }
        let precision = match spec.format {
            TextureFormat::ExrHalf => ExrPrecision::Half,
            TextureFormat::ExrFloat => ExrPrecision::Float,
        };
        let bytes = btfrig_imageio::encode_rgb_exr(Path::new(&path), width, height, texels, precision)?;
        write_atomic(&self.storage, &path, &bytes)
    }

    /// Writes the 8-bit sRGB preview of `step`'s texture (`width x height` linear RGB, the
    /// values [`Dataset::write_texture`] writes) to `previews/<stem>.png`, durably, and returns
    /// its record for [`Dataset::commit_step`]: linear 1.0 (a white reflector facing the
    /// nominal lamp) is 255, brighter texels clip, no tone mapping (`btfrig_imageio::
    /// linear_to_srgb8`), so previews of one dataset compare. Fails unless the manifest asks
    /// for texture previews.
    pub fn write_texture_preview(
        &self,
        step: StepId,
        texels: &[[f32; 3]],
        width: usize,
        height: usize,
    ) -> Result<FileRecord, StoreError> {
        self.check_open(step, &self.journal())?;
        let path = texture_preview_path(step);
        if !self.manifest.texture_previews {
            return Err(StoreError::BadInput {
                what: self.storage.display(&path),
                reason: "the manifest has texture_previews = false".into(),
            });
        }
        let rgb = btfrig_imageio::linear_to_srgb8(texels, 1.0);
        let bytes = btfrig_imageio::encode_srgb8_png(Path::new(&path), width, height, &rgb)?;
        write_atomic(&self.storage, &path, &bytes)
    }

    /// Writes the raw frame of `step` to `raw/<stem>.exr` (see `btfrig_imageio::write_raw_exr`:
    /// one 32-bit float channel holding the DNs exactly, lossless, the frame's metadata as JSON
    /// in the header), durably. Fails unless the manifest asks for raw frames.
    pub fn write_raw(&self, step: StepId, frame: &RawFrame) -> Result<FileRecord, StoreError> {
        self.write_raw_exposure(step, 0, frame)
    }

    /// Writes exposure `k` of `step`'s HDR bracket as [`Dataset::write_raw`] does: exposure 0
    /// (the base) to `raw/<stem>.exr`, exposure `k >= 1` to `raw/<stem>_e<k>.exr`.
    pub fn write_raw_exposure(&self, step: StepId, k: usize, frame: &RawFrame) -> Result<FileRecord, StoreError> {
        self.check_open(step, &self.journal())?;
        let path = if k == 0 { raw_path(step) } else { raw_exposure_path(step, k) };
        if !self.manifest.raw_frames {
            return Err(StoreError::BadInput {
                what: self.storage.display(&path),
                reason: "the manifest has raw_frames = false".into(),
            });
        }
        let bytes = btfrig_imageio::encode_raw_exr(Path::new(&path), frame)?;
        write_atomic(&self.storage, &path, &bytes)
    }

    /// Journals `step` as done with the files it wrote (checked present with their sizes),
    /// the attempts it took and its timing. The record is fsync'd before this returns: from
    /// then on the step counts, and a resumed run will not repeat it. `files` must name every
    /// file the manifest asks of a step (its texture, its raw frame), so one record counts
    /// them together: a crash never leaves one counted without the other.
    pub fn commit_step(
        &self,
        step: StepId,
        files: Vec<FileRecord>,
        attempts: u32,
        timing: StepTiming,
    ) -> Result<(), StoreError> {
        self.commit_step_with(step, files, attempts, timing, StepExtra::default())
    }

    /// [`Dataset::commit_step`] with how the step's sample pose was found and its exposures,
    /// journaled in the same record.
    pub fn commit_step_with(
        &self,
        step: StepId,
        files: Vec<FileRecord>,
        attempts: u32,
        timing: StepTiming,
        extra: StepExtra,
    ) -> Result<(), StoreError> {
        let mut journal = self.journal();
        self.check_open(step, &journal)?;
        for need in required_files(&self.manifest, step) {
            if !files.iter().any(|f| f.path == need) {
                let named: Vec<&str> = files.iter().map(|f| f.path.as_str()).collect();
                return Err(StoreError::BadInput {
                    what: self.storage.display(&need),
                    reason: format!(
                        "step {step} committed without it (files: [{}]); the manifest asks for textures = {}, raw_frames = {}, texture_previews = {}",
                        named.join(", "),
                        self.manifest.textures,
                        self.manifest.raw_frames,
                        self.manifest.texture_previews
                    ),
                });
            }
        }
        for f in &files {
            let found = self.storage.size(&f.path).map_err(io_err(&self.storage, "stat", &f.path))?;
            if found != Some(f.size) {
                return Err(StoreError::FileNotAsRecorded {
                    path: self.storage.display(&f.path),
                    step,
                    expected: f.size,
                    found,
                });
            }
        }
        let StepExtra { registration, hdr } = extra;
        journal.append(&self.storage, Record::Step(StepRecord { step, files, attempts, timing, registration, hdr }))
    }

    /// Replaces [`PREVIEW_FILE`] with `png` (temporary file, rename: a reader never sees a
    /// partial image). Not journaled and not fsync'd: the preview is a live view, not data, and
    /// after a crash it may be stale or missing.
    pub fn write_preview(&self, png: &[u8]) -> Result<(), StoreError> {
        let s = &self.storage;
        let tmp = tmp_name(PREVIEW_FILE);
        s.create(&tmp).map_err(io_err(s, "create", &tmp))?;
        s.append(&tmp, png).map_err(io_err(s, "write", &tmp))?;
        s.rename(&tmp, PREVIEW_FILE).map_err(io_err(s, "rename", &tmp))
    }

    /// Journals `step` as skipped during the run (e.g. a marker occluded), so a resumed run
    /// does not try it again.
    pub fn skip_step(&self, step: StepId, reason: &str) -> Result<(), StoreError> {
        let mut journal = self.journal();
        self.check_open(step, &journal)?;
        journal.append(&self.storage, Record::Skip { step, reason: reason.into() })
    }

    /// Ends the run: writes `report.json` and the manifest's timing summary (both atomically).
    /// Steps still missing are allowed (a stopped run); `verify` lists them. The manifest's
    /// bytes before `timing` are kept as they are on disk, so its journaled hash still holds.
    pub fn finish(&mut self, report: &RunReport) -> Result<(), StoreError> {
        let json = serde_json::to_vec_pretty(report).expect("report serialises");
        write_atomic(&self.storage, REPORT_FILE, &json)?;
        let summary = {
            let j = self.journal();
            let st = j.state();
            TimingSummary {
                first_step_unix_s: st
                    .done
                    .values()
                    .map(|r| r.timing.started_unix_s)
                    .fold(f64::INFINITY, f64::min)
                    .min(now()),
                finished_unix_s: now(),
                wall_s: report.wall_s,
                hardware_s: report.hardware_s,
                steps_done: st.done.len() as u64,
                steps_skipped: (st.skipped.len() + self.manifest.samplings.skipped.len()) as u64,
                retries: st.done.values().map(|r| u64::from(r.attempts.saturating_sub(1))).sum(),
            }
        };
        self.manifest.timing = Some(summary);
        let json = serde_json::to_vec_pretty(&self.manifest).expect("manifest serialises");
        let old = self.storage.read(MANIFEST_FILE).map_err(io_err(&self.storage, "read", MANIFEST_FILE))?;
        let (fixed, fresh) = (manifest_fixed_part(&old), manifest_fixed_part(&json));
        let mut bytes = fixed.to_vec();
        bytes.extend_from_slice(&json[fresh.len()..]);
        write_atomic(&self.storage, MANIFEST_FILE, &bytes)?;
        Ok(())
    }
}

fn now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}

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
            if m.raw_frames { ", raw frames kept" } else { "" }
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
