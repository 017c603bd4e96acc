//! `btfrig plan check FILE` and `btfrig plan show FILE`.

use std::path::Path;

use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::OutputFormat;
use btfrig_planner::{plan as plan_schedule, DiskEstimate, PairSelection, PlanRequest};
use btfrig_runner::plan::{exposure_s, frame_bytes, load, skip_counts};

/// `btfrig plan check`: every problem at once, or a one-paragraph summary.
pub fn check(file: &Path) -> anyhow::Result<()> {
    let (_, v) = load(file)?;
    let list = v.capture_list();
    println!("{}: valid plan {:?} (hash {:016x})", file.display(), v.name, v.plan_hash);
    println!(
        "rig {} ({}), {} light x {} view directions, {} requested pairs, {} captures, {} skipped",
        v.rig.rig.name,
        v.rig_source,
        v.light.len(),
        v.view.len(),
        v.pairs.len(),
        list.captures.len(),
        list.skipped.len()
    );
    Ok(())
}

/// `btfrig plan show`: the dry run — captures, skips by reason, estimated hardware time in
/// the motion-optimised order against the naive order and the lower bound, disk space.
pub fn show(file: &Path) -> anyhow::Result<()> {
    let (plan, v) = load(file)?;
    let list = v.capture_list();
    anyhow::ensure!(!list.captures.is_empty(), "{}: the plan captures nothing", file.display());
    let gonio = Gonio::new(v.rig.geometry.clone())?;
    let exposure_s = exposure_s(&plan, &v, file)?;
    let frame_bytes = frame_bytes(&v);
    let request = PlanRequest::new(&gonio, &v.light, &v.view, &v.rig.timing, exposure_s, frame_bytes)
        .with_pairs(PairSelection::List(list.captures.clone()));
    let started = std::time::Instant::now();
    let schedule = plan_schedule(&request)?;
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
    println!("plan {:?} from {} (hash {:016x})", v.name, file.display(), v.plan_hash);
    println!(
        "rig {}, exposure {:.4} s per capture, {} bytes transferred per frame",
        v.rig.rig.name, exposure_s, frame_bytes
    );
    for (reason, n) in skip_counts(&list.skipped) {
        println!("skipped by the plan: {n} ({reason})");
    }
    println!("{}", schedule.dry_run(disk));
    if let btfrig_core::plan::ExposurePolicy::Auto { hdr, .. } = &v.exposure {
        if let Some(line) = hdr_estimate(hdr, &v, frame_bytes, exposure_s, schedule.captures.len()) {
            println!("{line}");
        }
    }
    println!("planning took {planning_s:.2} s");
    Ok(())
}

/// What HDR may add to the estimate: each further exposure costs its time plus the camera's
/// per-exposure overhead (and an adaptive one two moves, not estimated here).
fn hdr_estimate(
    hdr: &btfrig_core::plan::HdrSettings,
    v: &btfrig_core::plan::ValidatedPlan,
    frame_bytes: u64,
    exposure_s: f64,
    captures: usize,
) -> Option<String> {
    use btfrig_core::plan::HdrMode;
    let overhead = btfrig_calib::exposure::per_exposure_overhead_s(&v.rig.timing.camera, frame_bytes);
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
