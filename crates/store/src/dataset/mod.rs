//! The dataset directory: create, write, commit, resume, finish; `info` and `verify` in their
//! own files.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::{Mutex, MutexGuard};

use btfrig_core::frame::RawFrame;
use btfrig_imageio::ExrPrecision;

use crate::error::{io_err, StoreError};
use crate::journal::{FramesRecord, Journal, Record, StepRecord, TornTail};
use crate::manifest::{manifest_fixed_part, manifest_hash, Manifest, TextureFormat, TimingSummary};
use crate::storage::{parent, FsStorage, Storage};
use crate::{FileRecord, RunReport, StepExtra, StepId, StepTiming};

mod files;
mod info;
mod layout;
mod verify;

use files::{file_damage, read_manifest, tmp_name, write_atomic};
pub use info::{info, info_in, journal_model, journaled_models, DatasetInfo};
use layout::{
    data_files, group_frame_path, list_names, raw_exposure_path, raw_path, required_files, texture_path,
    texture_preview_path,
};
pub use layout::{JOURNAL_FILE, MANIFEST_FILE, PREVIEWS_DIR, PREVIEW_FILE, RAW_DIR, REPORT_FILE, TEXTURES_DIR};
pub use verify::{verify, verify_in, Problem, VerifyReport};

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
    /// damaged file: `textures/l000_v003.exr: missing`. With raw frames per view group, also
    /// one entry per view group taken again because a crash left its frames without all its
    /// textures or the reverse (`view 3's group: its textures are incomplete (2 of 5
    /// journaled)`, step `l000_v003`).
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
        if manifest.raw_frames || manifest.raw_groups.is_some() {
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
        // A view group's damaged raw frames send the group back to be captured, with every
        // texture of its view: a texture is never kept without the frames it was made from.
        let mut damaged: Vec<(u32, Vec<String>)> = Vec::new();
        for (view, rec) in &journal.state().frames {
            let mut found = Vec::new();
            for file in &rec.files {
                report.files_checked += 1;
                report.bytes_checked += file.size;
                if let Some(what) = file_damage(&storage, file)? {
                    found.push(format!("{}: {what}", file.path));
                }
            }
            if !found.is_empty() {
                damaged.push((*view, found));
            }
        }
        for (view, found) in damaged {
            retaken_files.extend(journal.state().frames[&view].files.iter().map(|f| f.path.clone()));
            let reason = found.join("; ");
            journal.append(&storage, Record::RetakeFrames { view, reason: reason.clone() })?;
            let steps: Vec<StepId> = journal.state().done.keys().filter(|s| s.view == view).copied().collect();
            for step in steps {
                retaken_files.extend(journal.state().done[&step].files.iter().map(|f| f.path.clone()));
                let why = format!("the raw frames of its view group are damaged ({reason})");
                journal.append(&storage, Record::Retake { step, reason: why })?;
            }
            report.retaken.extend(found.into_iter().map(|what| (StepId { light: 0, view }, what)));
        }
        let expected = manifest.samplings.expected_steps();
        // A view group counts only with its raw frames and all its textures journaled (a run
        // commits the frames, then the textures one by one): after a crash in between, the
        // group is taken again as a whole, frames and textures, so the kept frames are always
        // the ones the textures were made from.
        if manifest.raw_groups.is_some() {
            let st = journal.state();
            let mut views: BTreeSet<u32> = st.frames.keys().copied().collect();
            views.extend(st.done.keys().map(|s| s.view));
            let mut partial = Vec::new();
            for view in views {
                let of_view = expected.iter().filter(|s| s.view == view && !st.skipped.contains_key(s));
                let (all, done) = of_view.fold((0, 0), |(a, d), s| (a + 1, d + usize::from(st.done.contains_key(s))));
                let why = match st.frames.contains_key(&view) {
                    true if done < all => format!("its textures are incomplete ({done} of {all} journaled)"),
                    false if done > 0 => "its raw frames are not journaled".to_string(),
                    _ => continue,
                };
                partial.push((view, why));
            }
            for (view, why) in partial {
                let what = format!("view {view}'s group: {why}");
                if let Some(rec) = journal.state().frames.get(&view) {
                    retaken_files.extend(rec.files.iter().map(|f| f.path.clone()));
                    journal.append(&storage, Record::RetakeFrames { view, reason: why.clone() })?;
                }
                let steps: Vec<StepId> = journal.state().done.keys().filter(|s| s.view == view).copied().collect();
                for step in steps {
                    retaken_files.extend(journal.state().done[&step].files.iter().map(|f| f.path.clone()));
                    journal.append(&storage, Record::Retake { step, reason: what.clone() })?;
                }
                report.retaken.push((StepId { light: 0, view }, what));
            }
        }
        for dir in [
            manifest.textures.then_some(TEXTURES_DIR),
            (manifest.raw_frames || manifest.raw_groups.is_some()).then_some(RAW_DIR),
            manifest.texture_previews.then_some(PREVIEWS_DIR),
        ]
        .into_iter()
        .flatten()
        {
            storage.create_dir(dir).map_err(io_err(&storage, "create directory", dir))?;
        }
        let state = journal.state();
        let named: BTreeSet<&str> = state
            .done
            .values()
            .flat_map(|r| r.files.iter())
            .chain(state.frames.values().flat_map(|r| r.files.iter()))
            .map(|f| f.path.as_str())
            .collect();
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

    /// Writes frame `pattern` of view `view`'s group of raw frames (a dome's pattern frames of
    /// one camera at one rotation) to `raw/v<view>_p<pattern>.exr`, durably, as
    /// [`Dataset::write_raw`] writes a frame; [`Dataset::commit_frames`] journals the group.
    /// Fails unless the manifest keeps raw frames per view group (`raw_groups`), or when the
    /// view's group is already journaled.
    pub fn write_group_frame(&self, view: u32, pattern: usize, frame: &RawFrame) -> Result<FileRecord, StoreError> {
        let path = group_frame_path(view, pattern);
        self.check_group_open(view, &self.journal(), &path)?;
        let bytes = btfrig_imageio::encode_raw_exr(Path::new(&path), frame)?;
        write_atomic(&self.storage, &path, &bytes)
    }

    /// Journals view `view`'s group of raw frames (`files` in pattern order, as
    /// [`Dataset::write_group_frame`] returned them, checked present with their sizes). The
    /// record is fsync'd before this returns; commit it before any texture of the view, so a
    /// crash never leaves a texture without its frames.
    pub fn commit_frames(&self, view: u32, files: Vec<FileRecord>) -> Result<(), StoreError> {
        let mut journal = self.journal();
        let what = format!("{RAW_DIR}/v{view:03}_p*.exr");
        self.check_group_open(view, &journal, &what)?;
        if files.is_empty() {
            return Err(StoreError::BadInput {
                what: self.storage.display(&what),
                reason: "a view group's raw frames committed without any frame".into(),
            });
        }
        for (k, f) in files.iter().enumerate() {
            if f.path != group_frame_path(view, k) {
                return Err(StoreError::BadInput {
                    what: self.storage.display(&f.path),
                    reason: format!("frame {k} of view {view}'s group must be {}", group_frame_path(view, k)),
                });
            }
            let found = self.storage.size(&f.path).map_err(io_err(&self.storage, "stat", &f.path))?;
            if found != Some(f.size) {
                return Err(StoreError::BadInput {
                    what: self.storage.display(&f.path),
                    reason: format!("{found:?} bytes on disk, committed with {} bytes", f.size),
                });
            }
        }
        journal.append(&self.storage, Record::Frames(FramesRecord { view, files }))
    }

    /// The journal record of view `view`'s raw frames, if journaled.
    pub fn frames_record(&self, view: u32) -> Option<FramesRecord> {
        self.journal().state().frames.get(&view).cloned()
    }

    /// Fails unless the manifest keeps raw frames per view group, `view` is one of its views,
    /// and its group is not journaled yet (`what` names the file in the error).
    fn check_group_open(&self, view: u32, journal: &Journal, what: &str) -> Result<(), StoreError> {
        let bad = |reason: String| StoreError::BadInput { what: self.storage.display(what), reason };
        if self.manifest.raw_groups.is_none() {
            return Err(bad("the manifest keeps no raw frames per view group (raw_groups is absent)".into()));
        }
        let views = self.manifest.samplings.view.len();
        if view as usize >= views {
            return Err(bad(format!("view {view} is not in the dataset (views 0..{views})")));
        }
        if journal.state().frames.contains_key(&view) {
            return Err(bad(format!("the raw frames of view {view} are already journaled")));
        }
        Ok(())
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
