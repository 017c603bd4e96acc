//! The sinks a run feeds besides the dataset, built by the runner from the plan's outputs,
//! so that every caller (`btfrig run`, `btfrig demo`, `btfrig serve`) gets the same ones:
//! today the streaming compression model of `outputs.compressed_model`
//! (`docs/compression.md`), for gonio plans and dome and camera-array plans alike.
//!
//! [`CompressionSink::start`] makes a `btfrig_compress::sink::StreamingCompressor` before the
//! run; the pipeline hands it every committed texture. After the run,
//! [`CompressionSink::finish`] decides by the run's outcome: a finished run (or one that had
//! nothing left to do) gets its model built, written next to the dataset
//! (`<DIR>.<method>.btfm`), measured against the textures and journaled in the dataset,
//! unless the journal already names that model intact; a run that did not finish gets none
//! (its resume builds it, reading the earlier sessions' textures back from the dataset).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use btfrig_compress::dataset::DatasetSource;
use btfrig_compress::sink::StreamingCompressor;
use btfrig_compress::{file, Method, ModelParams};
use btfrig_core::plan::CompressedModel;
use serde_json::json;

use crate::{RunOutcome, RunRequest};

/// Textures queued between the pipeline and the compression worker.
pub const SINK_CAPACITY: usize = 16;

/// The default model of a run's sink: FMF in YUV with 16/8/8 terms, f16.
pub fn default_stream_params() -> ModelParams {
    let mut p = ModelParams::new(Method::Fmf);
    p.terms = [16, 8, 8];
    p
}

/// The parameters of the model a run builds (`outputs.compressed_model`, or
/// [`RunRequest::compressed_model`]): FMF [`default_stream_params`], PVMF and PCMF (32
/// clusters) with `btfrig compress`'s defaults, PCMF 32 x 8 in a shared basis of
/// [`CompressedModel::SHARED_BASIS_TERMS`].
pub fn stream_params(m: CompressedModel) -> ModelParams {
    match m {
        CompressedModel::Fmf => default_stream_params(),
        CompressedModel::Pvmf => ModelParams::new(Method::Pvmf),
        CompressedModel::Pcmf => ModelParams::new(Method::pcmf(32)),
        CompressedModel::PcmfShared => ModelParams::new(Method::pcmf_shared(32, CompressedModel::SHARED_BASIS_TERMS)),
    }
}

/// The `<method>` of a default model path: `fmf`, `pvmf`, `pcmf`, `pcmf-w<K>` (a shared basis).
pub fn path_label(method: &Method) -> String {
    match method.shared_basis() {
        Some(k) => format!("{}-w{k}", method.name()),
        None => method.name().into(),
    }
}

/// Default model path of a dataset: `<DIR>.<method>.btfm` next to it.
pub fn default_model_path(dir: &Path, method: &str) -> PathBuf {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
    dir.with_file_name(format!("{name}.{method}.{}", file::EXTENSION))
}

/// The model a request builds: [`RunRequest::compressed_model`] if set, else the plan's
/// `outputs.compressed_model`. A plan that does not parse builds none here: the run refuses
/// it with the plan's own validation error.
pub fn requested_model(req: &RunRequest) -> Option<CompressedModel> {
    req.compressed_model.or_else(|| {
        btfrig_core::plan::Plan::from_toml(&req.plan_text, "plan")
            .ok()
            .and_then(|p| p.outputs.compressed_model.model().ok().flatten())
    })
}

/// What became of the model a run was asked for ([`crate::RunSummary::compression`]).
#[derive(Debug, Clone, PartialEq)]
pub enum CompressionOutcome {
    /// Built and journaled by this call.
    Built {
        /// The figures, with the keys `btfrig demo --json` prints (`compression_model`,
        /// `compression_rel_rmse`, `compression_ratio`, the streaming figures, the whole
        /// process's `peak_rss_mib` read after the model was written).
        figures: serde_json::Value,
        /// The journaled model this one replaces because its file was missing or damaged:
        /// what was found.
        replaced_damaged: Option<String>,
    },
    /// A session before built and journaled it, and its file is intact: nothing built.
    BuiltEarlier {
        /// The model file.
        model: PathBuf,
    },
    /// Not built: the run did not finish. Resuming it builds the model.
    NotFinished,
    /// Building or writing it failed (the message says why); the dataset is complete and the
    /// same request builds the model again.
    Failed(String),
}

impl CompressionOutcome {
    /// The outcome as JSON fields of the run summary: `compression_status` (`built`,
    /// `built_earlier`, `not_finished`, `failed`) with `compression_model` and the figures, or
    /// `compression_error`.
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            CompressionOutcome::Built { figures, replaced_damaged } => {
                let mut v = json!({"compression_status": "built", "compression_replaced_damaged": replaced_damaged});
                if let (Some(o), Some(f)) = (v.as_object_mut(), figures.as_object()) {
                    o.extend(f.clone());
                }
                v
            }
            CompressionOutcome::BuiltEarlier { model } => {
                json!({"compression_status": "built_earlier", "compression_model": model.display().to_string()})
            }
            CompressionOutcome::NotFinished => json!({"compression_status": "not_finished"}),
            CompressionOutcome::Failed(e) => json!({"compression_status": "failed", "compression_error": e}),
        }
    }
}

/// What a dataset's journal says of the model a run asks for.
#[derive(Debug, Clone, PartialEq)]
enum JournaledModel {
    /// Journaled, and its file is as journaled (size and content hash).
    Built(PathBuf),
    /// Journaled, but its file is missing or damaged: what was found.
    Damaged(String),
    /// Never journaled (not built, or the run was killed while writing it).
    NotBuilt,
}

/// The directory that holds the dataset `dir` (its models are written there).
fn holder(dir: &Path) -> &Path {
    dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// The pipeline's texture sink over a [`StreamingCompressor`].
struct SinkAdapter(Arc<StreamingCompressor>);

impl btfrig_process::TextureSink for SinkAdapter {
    fn accept(&self, step: btfrig_store::StepId, texels: &[[f32; 3]]) {
        self.0.accept(step.light, step.view, texels);
    }
}

/// A model built while a run captures (see the module documentation).
pub struct CompressionSink {
    compressor: Arc<StreamingCompressor>,
    dir: PathBuf,
    params: ModelParams,
}

/// An error of building, writing or journaling the model, as text for
/// [`CompressionOutcome::Failed`].
type Failure = String;

impl CompressionSink {
    /// The compressor of the model `req` asks for ([`requested_model`]), or `None`.
    pub fn start(req: &RunRequest) -> Result<Option<CompressionSink>, crate::RunError> {
        requested_model(req).map(|m| CompressionSink::new(m, &req.out)).transpose()
    }

    /// The compressor of model `m` for the dataset `dir` (a gonio run's, [`start`], and a
    /// dome or camera-array run's, `crate::dome`: the compressor reads the dataset's
    /// manifest when the first texture arrives, and lays a dome's captures out by their
    /// per-capture directions, `btfrig_compress::dataset::dome_layout`).
    ///
    /// [`start`]: CompressionSink::start
    pub fn new(m: CompressedModel, dir: &Path) -> Result<CompressionSink, crate::RunError> {
        let params = stream_params(m);
        let compressor =
            StreamingCompressor::new(dir, params.clone(), SINK_CAPACITY).map_err(|e| crate::RunError::Input {
                what: format!("outputs.compressed_model = {:?}", m.name()),
                message: e.to_string(),
            })?;
        Ok(CompressionSink { compressor: Arc::new(compressor), dir: dir.to_path_buf(), params })
    }

    /// The sink the pipeline hands every committed texture to.
    pub fn texture_sink(&self) -> Arc<dyn btfrig_process::TextureSink> {
        Arc::new(SinkAdapter(self.compressor.clone()))
    }

    /// Ends the sink after a run that ended with `outcome`: the model is part of a finished
    /// run's outcome, so a rerun of a finished run builds it when the journal does not name
    /// it intact (a kill while it was being written).
    pub fn finish(self, outcome: &RunOutcome) -> CompressionOutcome {
        if !matches!(outcome, RunOutcome::Finished | RunOutcome::NothingToDo) {
            return CompressionOutcome::NotFinished;
        }
        let replaced_damaged = match self.journaled() {
            Ok(JournaledModel::Built(model)) => return CompressionOutcome::BuiltEarlier { model },
            Ok(JournaledModel::Damaged(what)) => Some(what),
            Ok(JournaledModel::NotBuilt) => None,
            Err(e) => return CompressionOutcome::Failed(e),
        };
        match self.build() {
            Ok(figures) => CompressionOutcome::Built { figures, replaced_damaged },
            Err(e) => CompressionOutcome::Failed(e),
        }
    }

    /// The model of this run's method that the dataset's journal names, and whether its file
    /// is intact.
    fn journaled(&self) -> Result<JournaledModel, Failure> {
        let label = path_label(&self.params.method);
        let models = btfrig_store::journaled_models(&self.dir).map_err(|e| e.to_string())?;
        let Some(rec) = models.iter().rev().find(|m| m.method == label) else { return Ok(JournaledModel::NotBuilt) };
        let path = holder(&self.dir).join(&rec.file);
        let what = match std::fs::read(&path) {
            Err(e) => format!("{}: {e}", path.display()),
            Ok(b) if b.len() as u64 != rec.size => {
                format!("{}: {} bytes, journaled with {}", path.display(), b.len(), rec.size)
            }
            Ok(b) if btfrig_store::content_hash(&b) != rec.hash => {
                format!("{}: content hash {}, journaled {}", path.display(), btfrig_store::content_hash(&b), rec.hash)
            }
            Ok(_) => return Ok(JournaledModel::Built(path)),
        };
        Ok(JournaledModel::Damaged(what))
    }

    /// Deletes the temporary files of this run's model (`<DIR>.<label>[-N].btfm.tmp`) that a
    /// run killed while writing it left next to the dataset; returns them.
    fn remove_stale_tmp(&self, label: &str) -> Result<Vec<PathBuf>, Failure> {
        let name = self.dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let (head, tail) = (format!("{name}.{label}"), format!(".{}.tmp", file::EXTENSION));
        let mut removed = Vec::new();
        let entries = std::fs::read_dir(holder(&self.dir))
            .map_err(|e| format!("cannot list {}: {e}", holder(&self.dir).display()))?;
        for e in entries.flatten() {
            let f = e.file_name().to_string_lossy().into_owned();
            let Some(mid) = f.strip_prefix(&head).and_then(|r| r.strip_suffix(&tail)) else { continue };
            // `<label>` itself or `<label>-N`, never another model's name.
            if mid.is_empty()
                || mid.strip_prefix('-').is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
            {
                std::fs::remove_file(e.path()).map_err(|err| format!("cannot remove {}: {err}", e.path().display()))?;
                removed.push(e.path());
            }
        }
        Ok(removed)
    }

    /// Finishes the model (the remaining passes over the dataset), writes it next to the
    /// dataset (`<DIR>.<method>.btfm`, never replacing a file: a new name then), measures
    /// it against the dataset and journals it in the dataset (`docs/compression.md`: a rerun
    /// finds it there; a kill before that builds it again); the figures as JSON.
    fn build(self) -> Result<serde_json::Value, Failure> {
        let label = path_label(&self.params.method);
        let removed_tmp = self.remove_stale_tmp(&label)?;
        let s = |e: btfrig_compress::CompressError| e.to_string();
        let (model, report) = self.compressor.finish().map_err(s)?;
        let mut out = default_model_path(&self.dir, &label);
        let mut n = 1;
        while out.exists() {
            n += 1;
            out = default_model_path(&self.dir, &format!("{label}-{n}"));
        }
        let mut src = DatasetSource::open(&self.dir).map_err(s)?;
        let t = std::time::Instant::now();
        let rel = btfrig_compress::eval::error_against(&model, &mut src).map_err(s)?.rel_rmse();
        let eval_s = t.elapsed().as_secs_f64();
        let captures = src.layout().n_measured();
        let raw = (captures * model.layout.texels() * 3 * 2) as f64;
        let source = json!({"dataset": self.dir.display().to_string(), "captures": captures,
            "params": self.params, "streaming": report, "rel_rmse_vs_dataset": rel});
        let bytes = file::write(&out, &model, source, false).map_err(s)?;
        drop(model);
        // The rename durable before the journal names the file.
        std::fs::File::open(holder(&self.dir))
            .and_then(|d| d.sync_all())
            .map_err(|e| format!("cannot fsync {}: {e}", holder(&self.dir).display()))?;
        let written = std::fs::read(&out).map_err(|e| format!("cannot read back {}: {e}", out.display()))?;
        btfrig_store::journal_model(
            &self.dir,
            btfrig_store::ModelRecord {
                method: label.clone(),
                file: out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
                size: written.len() as u64,
                hash: btfrig_store::content_hash(&written),
            },
        )
        .map_err(|e| e.to_string())?;
        Ok(json!({
            "compression_removed_tmp": removed_tmp.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
            // The whole process (Linux VmHWM; null elsewhere), the run and every pass of the
            // model included: read after the model is written.
            "peak_rss_mib": crate::peak_rss_mib(),
            "compression_model": out.display().to_string(),
            "compression_method": label,
            "compression_terms": self.params.terms,
            "compression_ratio": raw / bytes as f64,
            "compression_rel_rmse": rel,
            "compression_file_bytes": bytes,
            "compression_sink_blocked_s": report.blocked_s,
            "compression_sink_max_queue": report.max_queue,
            "compression_sink_capacity": report.capacity,
            "compression_streamed": report.streamed,
            "compression_from_disk": report.from_disk,
            "compression_pass1_busy_s": report.pass1_busy_s,
            "compression_finish_s": report.finish_s,
            "compression_eval_s": eval_s,
            "compression_passes": report.passes,
            "compression_builder_peak_bytes": report.builder_peak_bytes,
        }))
    }
}
