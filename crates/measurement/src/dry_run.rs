//! The dry run of a plan: captures, skips, estimated hardware time against the naive order
//! and the lower bound, disk space, and what HDR may add. Shared by `btfrig plan show` and
//! the daemon's `POST /api/v1/plans/dry-run`, so both say the same.

use std::path::Path;

use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::{ExposurePolicy, HdrMode, HdrSettings, OutputFormat, ValidatedPlan};
use btfrig_planner::{plan as plan_schedule, Cancel, DiskEstimate, PairSelection, PlanRequest};

use crate::plan::{exposure_s, frame_bytes, load_text, skip_counts};
use crate::RunError;

/// What a plan will do, before doing it.
#[derive(Debug, Clone, PartialEq)]
pub struct DryRun {
    /// The plan's name.
    pub name: String,
    /// The plan's hash (identifies its dataset).
    pub plan_hash: u64,
    /// The rig config's name.
    pub rig: String,
    /// Base exposure per capture, seconds.
    pub exposure_s: f64,
    /// Bytes transferred per frame.
    pub frame_bytes: u64,
    /// Pairs the plan itself skips, by reason.
    pub plan_skips: Vec<(String, usize)>,
    /// The planner's estimate of the schedule.
    pub schedule: btfrig_planner::DryRun,
    /// What HDR brackets may add, not in the schedule's estimate; `None` with HDR off.
    pub hdr: Option<String>,
    /// Wall time the planner took, seconds.
    pub planning_s: f64,
}

/// Validates `text` (named `file`, which anchors its relative paths) and plans it.
pub fn dry_run(text: &str, file: &Path) -> Result<DryRun, RunError> {
    dry_run_cancellable(text, file, &Cancel::new())
}

/// [`dry_run`], stopped with [`RunError::Cancelled`] soon after `cancel` is set (the
/// daemon sets it when the request's client goes away, its time limit passes or the daemon
/// shuts down). Validation is bounded by the plan limits; the planning checks the flag in
/// its loops.
pub fn dry_run_cancellable(text: &str, file: &Path, cancel: &Cancel) -> Result<DryRun, RunError> {
    let cancelled = || RunError::Cancelled("the dry run was cancelled before it finished".into());
    let (plan, v) = load_text(text, file)?;
    if cancel.is_cancelled() {
        return Err(cancelled());
    }
    let list = v.capture_list();
    if list.captures.is_empty() {
        return Err(RunError::Empty { plan: file.into() });
    }
    let gonio = Gonio::new(v.rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    let exposure_s = exposure_s(&plan, &v, file, None)?;
    let frame_bytes = frame_bytes(&v);
    let request = PlanRequest::new(&gonio, &v.light, &v.view, &v.rig.timing, exposure_s, frame_bytes)
        .with_pairs(PairSelection::List(list.captures.clone()))
        .with_cancel(cancel);
    let started = std::time::Instant::now();
    let schedule = match plan_schedule(&request) {
        Err(btfrig_planner::PlanError::Cancelled) => return Err(cancelled()),
        r => r?,
    };
    let planning_s = started.elapsed().as_secs_f64();
    let cam = &v.rig.camera;
    let photosites = (cam.width_px * cam.height_px) as u64;
    let texel_bytes = match v.outputs.format {
        OutputFormat::ExrHalf => 6,
        OutputFormat::ExrFloat => 12,
    };
    let disk = DiskEstimate {
        // Raw frames are stored as single-channel float OpenEXR.
        raw_bytes_per_capture: if v.outputs.raw_frames { photosites * 4 } else { 0 },
        texture_bytes_per_capture: if v.outputs.textures {
            (v.texture.size * v.texture.size) as u64 * texel_bytes
        } else {
            0
        },
    };
    let hdr = match &v.exposure {
        ExposurePolicy::Auto { hdr, .. } => hdr_estimate(hdr, &v, frame_bytes, exposure_s, schedule.captures.len()),
        _ => None,
    };
    Ok(DryRun {
        name: v.name.clone(),
        plan_hash: v.plan_hash,
        rig: v.rig.rig.name.clone(),
        exposure_s,
        frame_bytes,
        plan_skips: skip_counts(&list.skipped),
        schedule: schedule.dry_run(disk),
        hdr,
        planning_s,
    })
}

/// What HDR may add to the estimate: each further exposure costs its time plus the camera's
/// per-exposure overhead (and an adaptive one two moves, not estimated here).
fn hdr_estimate(
    hdr: &HdrSettings,
    v: &ValidatedPlan,
    frame_bytes: u64,
    exposure_s: f64,
    captures: usize,
) -> Option<String> {
    let overhead = btfrig_imaging::exposure::per_exposure_overhead_s(&v.rig.timing.camera, frame_bytes);
    let per = |stops: &[f64]| stops.iter().skip(1).map(|k| k * exposure_s + overhead).sum::<f64>();
    match &hdr.mode {
        HdrMode::Off => None,
        HdrMode::Always(stops) => {
            let added = per(stops) * captures as f64;
            Some(format!(
                "HDR bracket      {} exposures per capture (stops {stops:?}): +{} ({added:.0} s), not in the estimate above",
                stops.len(),
                btfrig_planner::format_hms(added)
            ))
        }
        HdrMode::Adaptive => {
            let stops: Vec<f64> = (0..hdr.max_exposures).map(|k| hdr.stop_ratio.powi(k as i32)).collect();
            Some(format!(
                "HDR adaptive     1 to {} exposures per capture, decided on the frames: each further exposure {overhead:.2} s + its time plus a return trip; at most +{:.0} s if every capture needed all (not in the estimate above)",
                hdr.max_exposures,
                per(&stops) * captures as f64
            ))
        }
    }
}
