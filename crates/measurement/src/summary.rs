//! What a session measured and how it ended: the run summary behind report.json.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde_json::json;

use crate::hdr::HdrFigures;
use crate::RunOutcome;
use crate::{backend, light, sinks};

/// The figures of a run over all its sessions (as in `report.json`).
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    /// How this session ended.
    pub outcome: RunOutcome,
    /// The dataset directory.
    pub dataset: PathBuf,
    /// Captures done (the journal's count).
    pub captures: u64,
    /// Captures committed by this session.
    pub captures_this_session: u64,
    /// Captures of the whole plan.
    pub planned_captures: u64,
    /// Pairs not captured, by reason (the plan's skips and steps skipped in the run).
    pub skipped: BTreeMap<String, u64>,
    /// Simulated hardware (rig-clock) time summed over the reported sessions, seconds.
    pub hardware_s: f64,
    /// The planner's lower bound for the whole schedule, seconds.
    pub critical_path_s: f64,
    /// The whole schedule's captures in the naive nested-loop order, seconds.
    pub naive_order_hardware_s: f64,
    /// Wall time summed over the reported sessions, seconds.
    pub wall_s: f64,
    /// Seconds per pipeline stage over every journaled capture.
    pub stage_s: BTreeMap<String, f64>,
    /// Rectified textures against ground truth over the reported sessions' captures.
    pub texture_rel_rmse: Option<f64>,
    /// The same had the nominal pose been used (only from sessions that compared:
    /// [`RunRequest::compare_nominal`]).
    pub texture_rel_rmse_nominal: Option<f64>,
    /// Mean CIEDE2000 on the held-out chart patches of the colour calibration the textures
    /// were converted with (`docs/color.md`); `None` without one.
    pub color_delta_e00_mean: Option<f64>,
    /// Largest CIEDE2000 on those patches.
    pub color_delta_e00_max: Option<f64>,
    /// Journaled textures rectified with a pose registered from the markers.
    pub registered: u64,
    /// Journaled textures rectified with the nominal pose because registration failed.
    pub fallbacks: u64,
    /// Journaled textures rectified with the nominal pose because the plan says so.
    pub nominal_by_plan: u64,
    /// Mean texel position error of the poses used against the true poses, texels, over the
    /// reported sessions' captures (simulated rig).
    pub registration_mean_texel_err: Option<f64>,
    /// Largest texel position error of the poses used, texels.
    pub registration_max_texel_err: Option<f64>,
    /// Mean texel position error of the nominal poses, texels.
    pub nominal_mean_texel_err: Option<f64>,
    /// Largest texel position error of the nominal poses, texels.
    pub nominal_max_texel_err: Option<f64>,
    /// Retries of the journaled captures (attempts beyond the first).
    pub retries: u64,
    /// Warnings of all reported sessions.
    pub warnings: Vec<String>,
    /// Sessions in the report (this one included).
    pub sessions: usize,
    /// Captures journaled by sessions that left no report (killed): their hardware and wall
    /// time and texture error are not in the figures.
    pub unreported_captures: u64,
    /// Peak resident memory of this process so far (Linux `VmHWM`), MiB; `None` where the
    /// system does not say. Shows that memory stays bounded by frames in flight, not captures.
    pub peak_rss_mib: Option<f64>,
    /// This session's lamp figures, with a light calibration only (`RunRequest::light`).
    pub lamp: Option<btfrig_process::light::LampTotals>,
    /// HDR figures over every journaled capture, with HDR on (`[exposure] hdr = "adaptive"`
    /// or `mode = "bracket"`).
    pub hdr: Option<HdrFigures>,
    /// What processing skipped over every journaled capture, and the time that saved.
    pub skips: crate::report::SkipFigures,
    /// Mean wall seconds a journaled capture took to process and write (its journal
    /// timing's `wall_s`); `None` without captures.
    pub processing_s_per_capture: Option<f64>,
    /// This session's frame channel between capture and processing; `None` when no
    /// session ran the engine.
    pub frame_queue: Option<btfrig_acquire::FrameQueueFigures>,
    /// This session's cost of each emulated device's link (serial and PTP backends against
    /// emulated firmware); empty on a rig of in-process simulated devices.
    pub links: Vec<backend::LinkUse>,
    /// What frames were processed with: each part of the processing model and where it came
    /// from (`camera`, `sensor`, `color`, `light`, `dark_flat`), and what the output lacks
    /// because a calibration is absent (`docs/pipeline.md`, "The processing model").
    pub processing: Option<ProcessingInfo>,
    /// Wall seconds the engine waited on robot and rail moves this session beyond the camera
    /// work that overlaps them ([`btfrig_acquire::RunSummary::motion_wait_wall_s`]).
    pub motion_wait_wall_s: f64,
    /// Wall seconds the emulated links added to this session: the motion wait (near zero
    /// for in-process simulated devices, whose moves take rig time only) plus the camera's
    /// PTP coding; `None` without emulated devices (docs/serial.md).
    pub link_added_wall_s: Option<f64>,
    /// Engine events this session's listener lost because it fell behind the engine's event
    /// queue (a warning says so); advisory progress only, frames and journal are complete.
    pub events_dropped: u64,
    /// What became of the compressed model the run was asked for (`outputs.compressed_model`
    /// or [`RunRequest::compressed_model`]); `None` when none was.
    pub compression: Option<sinks::CompressionOutcome>,
    /// The time this session's devices ran on; `None` when no session opened them.
    pub rig_time: Option<backend::RigTime>,
    /// This session's devices' identities by role, as they reported them when opened.
    pub devices: Vec<(&'static str, btfrig_hw::DeviceInfo)>,
    /// The preflight check of this session's devices (`crate::preflight`).
    pub preflight: Vec<crate::preflight::DeviceCheck>,
}

/// The process's peak resident set size in MiB, from `/proc/self/status` (Linux).
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Where a run's processing model came from, and its notes.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessingInfo {
    /// `(part, source)`.
    pub sources: Vec<(String, String)>,
    /// What the output lacks (e.g. "no light calibration: textures in relative units ...").
    pub notes: Vec<String>,
}

impl ProcessingInfo {
    /// Of `model`.
    pub fn of(model: &btfrig_process::ProcessingModel) -> Self {
        ProcessingInfo {
            sources: model.sources.iter().map(|s| (s.part.to_string(), s.source.clone())).collect(),
            notes: model.notes.clone(),
        }
    }

    /// As a JSON object: `{"sources": {part: source}, "notes": [...]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let sources: serde_json::Map<String, serde_json::Value> =
            self.sources.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
        json!({"sources": sources, "notes": self.notes})
    }
}

impl RunSummary {
    /// `report.json`'s `pipeline` object: whether processing kept ahead of capture. The
    /// frame channel's capacity, the most frames it held and the time capture waited on it
    /// (this session's), and processing per capture against the rig's time per capture.
    pub fn pipeline_json(&self) -> serde_json::Value {
        let q = self.frame_queue.unwrap_or_default();
        json!({
            "frame_queue_capacity": q.capacity,
            "frame_queue_max_fill": q.max_fill,
            "frame_queue_delivered": q.delivered,
            "frame_queue_full_waits": q.full_waits,
            "capture_waited_on_full_queue_s": q.full_wait_s,
            "capture_waited_on_full_queue_wall_s": q.full_wait_wall_s,
            "processing_s_per_capture": self.processing_s_per_capture,
            "hardware_s_per_capture": (self.captures > 0).then(|| self.hardware_s / self.captures as f64),
        })
    }

    /// The summary as one JSON object (the fields `btfrig demo --json` prints).
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = json!({
            "status": self.outcome.status(),
            "reason": self.outcome.reason(),
            "captures": self.captures,
            "captures_this_session": self.captures_this_session,
            "planned_captures": self.planned_captures,
            "skipped": self.skipped,
            "hardware_s": self.hardware_s,
            "critical_path_s": self.critical_path_s,
            "naive_order_hardware_s": self.naive_order_hardware_s,
            "wall_s": self.wall_s,
            "stage_s": self.stage_s,
            "texture_rel_rmse": self.texture_rel_rmse,
            "texture_rel_rmse_nominal": self.texture_rel_rmse_nominal,
            "color_delta_e00_mean": self.color_delta_e00_mean,
            "color_delta_e00_max": self.color_delta_e00_max,
            "registered": self.registered,
            "fallbacks": self.fallbacks,
            "nominal_by_plan": self.nominal_by_plan,
            "registration_mean_texel_err": self.registration_mean_texel_err,
            "registration_max_texel_err": self.registration_max_texel_err,
            "nominal_mean_texel_err": self.nominal_mean_texel_err,
            "nominal_max_texel_err": self.nominal_max_texel_err,
            "retries": self.retries,
            "warnings": self.warnings.len(),
            "sessions": self.sessions,
            "unreported_captures": self.unreported_captures,
            "peak_rss_mib": self.peak_rss_mib,
            "motion_wait_wall_s": self.motion_wait_wall_s,
            "link_added_wall_s": self.link_added_wall_s,
            "events_dropped": self.events_dropped,
            "dataset": self.dataset.display().to_string(),
            "processing_notes": self.processing.as_ref().map(|p| p.notes.clone()),
            "skips": self.skips.to_json(),
            "pipeline": self.pipeline_json(),
        });
        light::add_summary_fields(&mut v, self.lamp.as_ref());
        if let (Some(c), Some(o)) = (&self.compression, v.as_object_mut()) {
            // A model's `peak_rss_mib` is the whole process's, read after the model was
            // written; the figure at the end of the capture stays as `run_peak_rss_mib`.
            o.insert("run_peak_rss_mib".into(), json!(self.peak_rss_mib));
            if let Some(fields) = c.to_json().as_object() {
                o.extend(fields.clone());
            }
        }
        if let (Some(h), Some(o)) = (&self.hdr, v.as_object_mut()) {
            if let Some(fields) = h.to_json().as_object() {
                o.extend(fields.clone());
            }
        }
        v
    }
}
