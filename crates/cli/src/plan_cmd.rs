//! `btfrig plan check FILE` and `btfrig plan show FILE`.

use std::path::Path;

use anyhow::Context;
use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::{ExposurePolicy, MaterialRef, OutputFormat, Plan, PlanContext, ValidatedPlan};
use btfrig_planner::{plan as plan_schedule, DiskEstimate, PairSelection, PlanRequest};
use btfrig_render::material::MaterialSpec;
use btfrig_render::rig_scene::RigScene;

/// Reads, parses and validates a plan file; the rig config it names is loaded first so the
/// validation can check that the rig realises the plan's samplings.
pub(crate) fn load(file: &Path) -> anyhow::Result<(Plan, ValidatedPlan)> {
    let text = std::fs::read_to_string(file).with_context(|| format!("cannot read plan {}", file.display()))?;
    let plan = Plan::from_toml(&text, &file.display().to_string())?;
    let mut ctx = PlanContext::with_builtin_names();
    if let Some(rig) = plan.rig_config_path(file) {
        ctx.rig = Some(crate::rig::load(Some(&rig)).with_context(|| format!("{}: rig.config", file.display()))?);
    }
    let validated = plan.validate(&ctx)?;
    Ok((plan, validated))
}

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
        texture_bytes_per_capture: if v.outputs.textures { (v.texture.size * v.texture.size) as u64 * texel_bytes } else { 0 },
    };
    println!("plan {:?} from {} (hash {:016x})", v.name, file.display(), v.plan_hash);
    println!("rig {}, exposure {:.4} s per capture, {} bytes transferred per frame", v.rig.rig.name, exposure_s, frame_bytes);
    for (reason, n) in skip_counts(&list.skipped) {
        println!("skipped by the plan: {n} ({reason})");
    }
    println!("{}", schedule.dry_run(disk));
    println!("planning took {planning_s:.2} s");
    Ok(())
}

/// The plan's material: an embedded name, a file next to the plan, or the default.
pub(crate) fn material(plan: &Plan, v: &ValidatedPlan, file: &Path) -> anyhow::Result<MaterialSpec> {
    match &v.material {
        Some(MaterialRef::Builtin(name)) => crate::material::load(Some(name)),
        Some(MaterialRef::File(_)) => {
            let path = plan.material_path(file).expect("a material file reference has a path");
            crate::material::load(Some(&path.display().to_string()))
        }
        None => crate::material::load(None),
    }
}

/// The exposure per capture: fixed, or auto (white at the policy's fraction of full scale).
pub(crate) fn exposure_s(plan: &Plan, v: &ValidatedPlan, file: &Path) -> anyhow::Result<f64> {
    Ok(match v.exposure {
        ExposurePolicy::Fixed { exposure_s, .. } => exposure_s,
        ExposurePolicy::Auto { white_fraction } => {
            let scene = RigScene::new(&v.rig, &material(plan, v, file)?)?;
            scene.exposure_for_white(white_fraction, 1e-6, 3600.0)
        }
    })
}

/// Bytes the camera transfers per frame (the timing model's, or 2 per photosite).
pub(crate) fn frame_bytes(v: &ValidatedPlan) -> u64 {
    let cam = &v.rig.camera;
    v.rig.timing.camera.frame_bytes.unwrap_or((cam.width_px * cam.height_px) as u64 * 2)
}

pub(crate) fn skip_counts(skipped: &[((usize, usize), btfrig_core::plan::SkipReason)]) -> Vec<(String, usize)> {
    let mut counts: Vec<(String, usize)> = Vec::new();
    for (_, r) in skipped {
        let label = r.label();
        match counts.iter_mut().find(|(l, _)| *l == label) {
            Some((_, n)) => *n += 1,
            None => counts.push((label, 1)),
        }
    }
    counts
}
