//! `report.json` across sessions: each session (one `btfrig run` process, one daemon run)
//! appends its record; the top-level figures are recomputed over all sessions and the
//! journal, so a resumed run reports the whole run, not only its last session.

use std::collections::BTreeMap;
use std::path::Path;

use btfrig_process::TexelErrorTotals;
use serde_json::{json, Value};

/// One session's figures, as kept in `report.json`'s `sessions` list.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Session {
    /// Unix time the session started, seconds.
    pub started_unix_s: f64,
    /// How it ended: `finished`, `paused`, `interrupted` or `aborted`.
    pub status: String,
    /// Why it did not finish.
    pub reason: Option<String>,
    /// Captures committed in this session.
    pub captures: u64,
    /// Wall time of the session, seconds.
    pub wall_s: f64,
    /// Rig-clock time of the session's engine run, seconds.
    pub hardware_s: f64,
    /// Retries of all device operations (the engine's count).
    pub retries: u64,
    /// Sum of squared texture errors against the truth (for the run's relative RMSE).
    pub sq_err: f64,
    /// Sum of squared truth.
    pub sq_truth: f64,
    /// Captures committed without recorded truth.
    pub without_truth: u64,
    /// Warnings of the session.
    pub warnings: Vec<String>,
    /// Sum of squared texture errors had the nominal pose been used (sessions that compared).
    pub sq_err_nominal: f64,
    /// Sum of squared truth of those textures.
    pub sq_truth_nominal: f64,
    /// Texel position error of the poses used against the truth.
    pub texel_err: TexelErrorTotals,
    /// Texel position error of the nominal poses against the truth.
    pub nominal_texel_err: TexelErrorTotals,
}

fn texel_json(t: &TexelErrorTotals) -> Value {
    json!({"frames": t.frames, "sum_mean": t.sum_mean, "max": t.max})
}

fn texel_from_json(v: &Value) -> TexelErrorTotals {
    TexelErrorTotals {
        frames: v["frames"].as_u64().unwrap_or(0),
        sum_mean: v["sum_mean"].as_f64().unwrap_or(0.0),
        max: v["max"].as_f64().unwrap_or(0.0),
    }
}

impl Session {
    /// As stored in `report.json`.
    pub fn to_json(&self) -> Value {
        json!({
            "started_unix_s": self.started_unix_s,
            "status": self.status,
            "reason": self.reason,
            "captures": self.captures,
            "wall_s": self.wall_s,
            "hardware_s": self.hardware_s,
            "retries": self.retries,
            "sq_err": self.sq_err,
            "sq_truth": self.sq_truth,
            "captures_without_truth": self.without_truth,
            "warnings": self.warnings,
            "sq_err_nominal": self.sq_err_nominal,
            "sq_truth_nominal": self.sq_truth_nominal,
            "texel_err": texel_json(&self.texel_err),
            "nominal_texel_err": texel_json(&self.nominal_texel_err),
        })
    }

    fn from_json(v: &Value) -> Session {
        let f = |k: &str| v[k].as_f64().unwrap_or(0.0);
        let u = |k: &str| v[k].as_u64().unwrap_or(0);
        Session {
            started_unix_s: f("started_unix_s"),
            status: v["status"].as_str().unwrap_or("unknown").to_string(),
            reason: v["reason"].as_str().map(str::to_string),
            captures: u("captures"),
            wall_s: f("wall_s"),
            hardware_s: f("hardware_s"),
            retries: u("retries"),
            sq_err: f("sq_err"),
            sq_truth: f("sq_truth"),
            without_truth: u("captures_without_truth"),
            warnings: v["warnings"]
                .as_array()
                .map(|a| a.iter().filter_map(|w| w.as_str().map(str::to_string)).collect())
                .unwrap_or_default(),
            sq_err_nominal: f("sq_err_nominal"),
            sq_truth_nominal: f("sq_truth_nominal"),
            texel_err: texel_from_json(&v["texel_err"]),
            nominal_texel_err: texel_from_json(&v["nominal_texel_err"]),
        }
    }
}

/// The sessions recorded in the dataset's `report.json`, oldest first; none when there is
/// no report. A report written before sessions were recorded counts as one session with
/// its top-level figures (texture error sums unknown, so left out of the combined error).
pub fn previous_sessions(dir: &Path) -> Vec<Session> {
    let Ok(bytes) = std::fs::read(dir.join(btfrig_store::REPORT_FILE)) else {
        return Vec::new();
    };
    let Ok(v) = serde_json::from_slice::<Value>(&bytes) else {
        return Vec::new();
    };
    if let Some(list) = v["sessions"].as_array() {
        return list.iter().map(Session::from_json).collect();
    }
    vec![Session {
        status: v["status"].as_str().unwrap_or("finished").to_string(),
        captures: v["captures_this_session"].as_u64().or(v["captures"].as_u64()).unwrap_or(0),
        wall_s: v["wall_s"].as_f64().unwrap_or(0.0),
        hardware_s: v["hardware_s"].as_f64().unwrap_or(0.0),
        retries: v["retries"].as_u64().unwrap_or(0),
        ..Session::default()
    }]
}

/// Figures summed over sessions.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SessionTotals {
    /// Sum of wall times.
    pub wall_s: f64,
    /// Sum of rig-clock times.
    pub hardware_s: f64,
    /// Sum of the captures each session reported.
    pub captures: u64,
    /// Sum of engine retries.
    pub retries: u64,
    /// `sqrt(sum sq_err / sum sq_truth)`, when any truth was compared.
    pub texture_rel_rmse: Option<f64>,
    /// Captures without truth.
    pub without_truth: u64,
    /// All warnings, oldest first.
    pub warnings: Vec<String>,
    /// `texture_rel_rmse` had the nominal pose been used, when any session compared.
    pub texture_rel_rmse_nominal: Option<f64>,
    /// Texel position errors of the poses used.
    pub texel_err: TexelErrorTotals,
    /// Texel position errors of the nominal poses.
    pub nominal_texel_err: TexelErrorTotals,
}

/// Sums `sessions`.
pub fn totals(sessions: &[Session]) -> SessionTotals {
    let mut t = SessionTotals::default();
    let (mut se, mut st, mut sen, mut stn) = (0.0, 0.0, 0.0, 0.0);
    for s in sessions {
        t.wall_s += s.wall_s;
        t.hardware_s += s.hardware_s;
        t.captures += s.captures;
        t.retries += s.retries;
        t.without_truth += s.without_truth;
        t.warnings.extend(s.warnings.iter().cloned());
        se += s.sq_err;
        st += s.sq_truth;
        sen += s.sq_err_nominal;
        stn += s.sq_truth_nominal;
        t.texel_err.merge(&s.texel_err);
        t.nominal_texel_err.merge(&s.nominal_texel_err);
    }
    t.texture_rel_rmse = (st > 0.0).then(|| (se / st).sqrt());
    t.texture_rel_rmse_nominal = (stn > 0.0).then(|| (sen / stn).sqrt());
    t
}

/// How the journaled textures' poses were found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PoseCounts {
    /// Registered from the markers.
    pub registered: u64,
    /// Nominal because registration failed.
    pub fallbacks: u64,
    /// Nominal because the plan says so.
    pub nominal_by_plan: u64,
}

/// Counts the journaled steps by how their pose was found (exact across sessions; steps
/// journaled before registration existed count in none).
pub fn journal_poses<S: btfrig_store::Storage>(dataset: &btfrig_store::Dataset<S>) -> PoseCounts {
    let mut c = PoseCounts::default();
    for step in dataset.completed() {
        match dataset.step_record(step).and_then(|r| r.registration).map(|r| r.pose) {
            Some(btfrig_store::PoseSource::Markers) => c.registered += 1,
            Some(btfrig_store::PoseSource::NominalFallback) => c.fallbacks += 1,
            Some(btfrig_store::PoseSource::NominalByPlan) => c.nominal_by_plan += 1,
            None => {}
        }
    }
    c
}

/// What processing skipped over the journaled steps, and the time that saved
/// (`docs/registration.md`, "What the windows save"; `report.json`'s `skips`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SkipFigures {
    /// Steps whose markers were searched (a journaled search record).
    pub searched: u64,
    /// Of those, searched in predicted windows only: whole-frame searches avoided.
    pub in_windows: u64,
    /// Searched in the whole frame after the windows, by cause (`no-pose`,
    /// `marker-outside-windows`).
    pub fallbacks: BTreeMap<String, u64>,
    /// The first [`FALLBACK_STEPS_LISTED`] fallback steps with their details.
    pub fallback_steps: Vec<(btfrig_store::StepId, String)>,
    /// Searched in the whole frame only (the search asked for it).
    pub whole_frame_only: u64,
    /// Mean over searched steps of the pixels searched over the frame's pixels.
    pub mean_searched_fraction: f64,
    /// Seconds the detections took, over the steps with a whole-frame figure.
    pub detect_s: f64,
    /// Seconds whole-frame detections would have taken on the same steps.
    pub whole_frame_s: f64,
    /// Searched steps without a whole-frame figure (registered before the reference).
    pub without_estimate: u64,
    /// Seconds spent on the run's reference whole-frame search.
    pub reference_s: f64,
    /// Frames that did not need their own registration: the further exposures of merged
    /// HDR brackets, registered once per step.
    pub registrations_reused: u64,
    /// Steps with HDR on whose policy took fewer exposures than always bracketing would
    /// have (`None`: HDR off); their rig time saved is `hdr.hdr_time_saved_s`.
    pub hdr_brackets_not_needed: Option<u64>,
}

/// Fallback steps listed by name in [`SkipFigures::fallback_steps`].
pub const FALLBACK_STEPS_LISTED: usize = 20;

impl SkipFigures {
    /// `whole_frame_s - detect_s - reference_s`: detection time the windows saved, net of
    /// the reference search that measured it.
    pub fn search_time_saved_s(&self) -> f64 {
        self.whole_frame_s - self.detect_s - self.reference_s
    }

    /// As `report.json`'s `skips` object.
    pub fn to_json(&self) -> Value {
        json!({
            "marker_searches": self.searched,
            "whole_frame_searches_avoided": self.in_windows,
            "search_fallbacks": self.fallbacks,
            "search_fallback_steps": self.fallback_steps.iter()
                .map(|(s, d)| json!({"light": s.light, "view": s.view, "reason": d}))
                .collect::<Vec<_>>(),
            "whole_frame_only": self.whole_frame_only,
            "mean_searched_fraction": self.mean_searched_fraction,
            "detect_s": self.detect_s,
            "whole_frame_detect_s": self.whole_frame_s,
            "steps_without_whole_frame_figure": self.without_estimate,
            "reference_search_s": self.reference_s,
            "search_time_saved_s": self.search_time_saved_s(),
            "registrations_reused": self.registrations_reused,
            "hdr_brackets_not_needed": self.hdr_brackets_not_needed,
        })
    }
}

/// The skip figures of every journaled step (exact across sessions).
pub fn journal_skips<S: btfrig_store::Storage>(dataset: &btfrig_store::Dataset<S>) -> SkipFigures {
    let mut f = SkipFigures::default();
    let mut fraction_sum = 0.0;
    let mut hdr_steps = 0u64;
    let mut not_needed = 0u64;
    for step in dataset.completed() {
        let Some(r) = dataset.step_record(step) else { continue };
        if let Some(h) = &r.hdr {
            hdr_steps += 1;
            not_needed += u64::from(h.exposures_s.len() < h.always_s.len());
        }
        let Some(reg) = &r.registration else { continue };
        if reg.pose != btfrig_store::PoseSource::NominalByPlan {
            let exposures = r.hdr.as_ref().map_or(1, |h| h.exposures_s.len());
            f.registrations_reused += exposures.saturating_sub(1) as u64;
        }
        let Some(s) = &reg.search else { continue };
        f.searched += 1;
        fraction_sum += s.searched_fraction;
        match (&s.fallback, s.whole_frame) {
            (Some(cause), _) => {
                *f.fallbacks.entry(cause.clone()).or_insert(0) += 1;
                if f.fallback_steps.len() < FALLBACK_STEPS_LISTED {
                    f.fallback_steps.push((step, s.fallback_detail.clone().unwrap_or_else(|| cause.clone())));
                }
            }
            (None, true) => f.whole_frame_only += 1,
            (None, false) => f.in_windows += 1,
        }
        f.reference_s += s.reference_s;
        match s.whole_frame_s {
            Some(w) => {
                f.whole_frame_s += w;
                f.detect_s += s.detect_s;
            }
            None => f.without_estimate += 1,
        }
    }
    if f.searched > 0 {
        f.mean_searched_fraction = fraction_sum / f.searched as f64;
    }
    f.hdr_brackets_not_needed = (hdr_steps > 0).then_some(not_needed);
    f
}

/// Mean over the journaled steps of their processing wall time (journal timing `wall_s`:
/// from the frame's arrival in processing to its texture written); `None` without steps.
pub fn journal_mean_step_wall_s<S: btfrig_store::Storage>(dataset: &btfrig_store::Dataset<S>) -> Option<f64> {
    let walls: Vec<f64> =
        dataset.completed().into_iter().filter_map(|s| dataset.step_record(s)).map(|r| r.timing.wall_s).collect();
    (!walls.is_empty()).then(|| walls.iter().sum::<f64>() / walls.len() as f64)
}

/// Stage times summed over every journaled step (exact across sessions, killed ones too).
pub fn journal_stage_s<S: btfrig_store::Storage>(dataset: &btfrig_store::Dataset<S>) -> (BTreeMap<String, f64>, u64) {
    let mut stage_s = BTreeMap::new();
    let mut retries = 0;
    for step in dataset.completed() {
        if let Some(r) = dataset.step_record(step) {
            for (k, v) in &r.timing.stage_s {
                *stage_s.entry(k.clone()).or_insert(0.0) += v;
            }
            retries += u64::from(r.attempts.saturating_sub(1));
        }
    }
    (stage_s, retries)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sessions_round_trip_and_sum() {
        let a = Session {
            started_unix_s: 1.0,
            status: "paused".into(),
            reason: Some("robot: other: boom".into()),
            captures: 10,
            wall_s: 2.0,
            hardware_s: 100.0,
            retries: 1,
            sq_err: 1.0,
            sq_truth: 100.0,
            without_truth: 0,
            warnings: vec!["w1".into()],
            sq_err_nominal: 2.0,
            sq_truth_nominal: 100.0,
            texel_err: TexelErrorTotals { frames: 10, sum_mean: 0.05, max: 0.02 },
            nominal_texel_err: TexelErrorTotals { frames: 10, sum_mean: 1.0, max: 0.3 },
        };
        let b = Session {
            status: "finished".into(),
            captures: 5,
            wall_s: 1.5,
            hardware_s: 50.0,
            sq_err: 3.0,
            sq_truth: 300.0,
            texel_err: TexelErrorTotals { frames: 5, sum_mean: 0.05, max: 0.04 },
            ..Session::default()
        };
        assert_eq!(Session::from_json(&a.to_json()), a);
        let t = totals(&[a, b]);
        assert_eq!(t.captures, 15);
        assert!((t.hardware_s - 150.0).abs() < 1e-12 && (t.wall_s - 3.5).abs() < 1e-12);
        // Pooled over all texels, not the mean of the sessions' figures.
        assert!((t.texture_rel_rmse.unwrap() - (4.0f64 / 400.0).sqrt()).abs() < 1e-15);
        assert_eq!(t.warnings, vec!["w1".to_string()]);
        // Only the session that compared with the nominal pose counts for that figure.
        assert!((t.texture_rel_rmse_nominal.unwrap() - (2.0f64 / 100.0).sqrt()).abs() < 1e-15);
        // Mean over all 15 frames of their per-frame means; max over both sessions.
        assert!((t.texel_err.mean().unwrap() - 0.1 / 15.0).abs() < 1e-15);
        assert_eq!(t.texel_err.max(), Some(0.04));
        assert_eq!(t.nominal_texel_err.frames, 10);
        assert_eq!(totals(&[]).texture_rel_rmse, None);
    }
}
