//! `btfrig reprocess` of a dome or camera-array dataset: the pattern frames its plan kept
//! (`[outputs] raw_frames = true`: `raw/v<view>_p<pattern>.exr`, one journal `frames` record
//! per view group) are demultiplexed, registered and rectified again, without the rig and
//! without the simulator, into a new dataset (`docs/pipeline.md`, "Reprocessing").
//!
//! Everything a run processes with is rebuilt as the run builds it: the processing model from
//! the rig config recorded in the manifest and the calibration files it names
//! (`crate::dome::dome_processing`, on `crate::model::rig_model`), a calibration directory
//! replacing each named file by the file of the same name in it
//! (`crate::reprocess_io::calibration_file_name`; a dark/flat calibration as `DIR/dark-flat/`);
//! the demultiplexers from the code the run captured with (`crate::raw_schedule::RawSchedule`, recorded in the
//! manifest's `raw_groups`) and the LED powers of the (new) LED calibration
//! (`crate::dome::group_code`); and the frames go through the run's own consumer
//! (`crate::dome::Consumer`: the same `DomeProcessing` register, demultiplex, denoise and
//! texture calls, the same store writes). With the same calibration the textures are the run's
//! bit for bit. There is no truth probe: the report has no truth figures.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use btfrig_acquire::dome::DomeCapture;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{DomePlan, ValidatedDomePlan};
use btfrig_planner::dome::{DomeShot, DomeStep};
use btfrig_store::{Dataset, RunReport};
use serde_json::json;

use crate::raw_schedule::{RawSchedule, RawView};
use crate::reprocess_io::{
    calibration_dir, check_out_empty, input, read_journaled, refuse_relative, replace_reference, ReprocessRequest,
    ReprocessSummary, Source, DARK_FLAT_DIR,
};
use crate::{ProcessingInfo, RunError};

/// Reprocesses the dome or camera-array dataset `src` (its rig config `rig`) into `req.out`;
/// see the module documentation. Nothing is written until every input checked out: the
/// recorded schedule, the plan, the calibration files, every kept frame (present, as
/// journaled), an empty `out`.
pub(crate) fn reprocess(req: &ReprocessRequest, src: Source, rig: RigConfig) -> Result<ReprocessSummary, RunError> {
    let wall = Instant::now();
    let src_dir = req.dataset.as_path();
    let what = format!("dataset {}", src_dir.display());
    let Some(raw) = src.manifest.raw_groups.as_ref() else {
        return Err(input(
            &what,
            format!(
                "it has no raw frames (its manifest has no raw_groups): only a {} run whose plan sets \
                 outputs.raw_frames = true ([outputs] raw_frames = true) can be reprocessed",
                rig.rig.kind.as_str()
            ),
        ));
    };
    let schedule: RawSchedule = serde_json::from_value(raw.clone())
        .map_err(|e| input(&what, format!("its manifest's raw_groups is not a recorded dome schedule: {e}")))?;
    let origin = format!("{}/{}: plan.text", src_dir.display(), btfrig_store::MANIFEST_FILE);
    let v = DomePlan::from_toml(&src.manifest.plan.text, &origin)
        .and_then(|p| p.validate(&rig))
        .map_err(|e| input(&origin, e.to_string()))?;
    if src.frames.is_empty() {
        return Err(input(&what, "it has no journaled view group to reprocess"));
    }
    let cal_dir = calibration_dir(req)?;
    let dir = cal_dir.as_deref();
    let mut cal_rig = rig.clone();
    let mut used = Vec::new();
    replace_reference(dir, "[camera] calibration", &mut cal_rig.camera.calibration, &mut used);
    replace_reference(dir, "[camera] color_calibration", &mut cal_rig.camera.color_calibration, &mut used);
    if let Some(d) = cal_rig.dome.as_mut() {
        replace_reference(dir, "[dome] led_calibration", &mut d.led_calibration, &mut used);
    }
    if let Some(d) = dir.map(|d| d.join(DARK_FLAT_DIR)).filter(|d| d.is_dir()) {
        used.push(("[camera] dark_flat".to_string(), d.display().to_string()));
        cal_rig.camera.dark_flat = Some(d.display().to_string());
    }
    refuse_relative(&[
        ("[camera] calibration", &cal_rig.camera.calibration),
        ("[camera] color_calibration", &cal_rig.camera.color_calibration),
        ("[camera] dark_flat", &cal_rig.camera.dark_flat),
        ("[dome] led_calibration", &cal_rig.dome.as_ref().and_then(|d| d.led_calibration.clone())),
    ])?;
    let size = v.plan.texture_size;
    // The run's loader and the run's code: the model from the config and its files.
    let (processing, calibration, notes) = crate::dome::dome_processing(&cal_rig, None, size)?;
    let code = crate::dome::group_code(schedule.mode.into(), &processing, schedule.pattern_scale)?;
    if code.frames(schedule.leds) != schedule.frames_per_group {
        return Err(input(
            &what,
            format!(
                "its raw_groups records {} frames per view group, its mode {:?} has {}",
                schedule.frames_per_group,
                schedule.mode,
                code.frames(schedule.leds)
            ),
        ));
    }
    // Every kept frame is checked before the new dataset exists.
    for (view, rec) in &src.frames {
        if rec.files.len() != schedule.frames_per_group {
            return Err(input(
                &what,
                format!(
                    "view {view}: {} raw frames journaled, its view groups have {}",
                    rec.files.len(),
                    schedule.frames_per_group
                ),
            ));
        }
        for f in &rec.files {
            read_journaled(src_dir, f)?;
        }
    }
    check_out_empty(&req.out)?;

    let mut manifest = crate::reprocess_io::reprocessed_manifest(&src.manifest);
    let info = ProcessingInfo::of(&processing.model);
    let reprocessed_from = json!({
        "dataset": src_dir.display().to_string(),
        "manifest_hash": src.manifest_hash,
        "calibration_dir": req.calibration.as_ref().map(|d| d.display().to_string()),
        "calibration_files": used.iter().map(|(k, f)| json!({"part": k, "file": f})).collect::<Vec<_>>(),
        "sources": info.to_json()["sources"].clone(),
    });
    manifest.calibration = Some(json!({ "dome": calibration.clone(), "reprocessed_from": reprocessed_from.clone() }));
    let mut dataset =
        Dataset::create(&req.out, manifest).map_err(|source| RunError::Dataset { dir: req.out.clone(), source })?;

    let processed = process(&v, &schedule, &src, src_dir, &processing, &code, &dataset);
    let s = match processed {
        Ok(s) => s,
        Err(e) => {
            // Nothing usable was made: leave no half dataset behind.
            drop(dataset);
            let _ = std::fs::remove_dir_all(&req.out);
            return Err(e);
        }
    };
    let summary = ReprocessSummary {
        out: req.out.clone(),
        steps: s.textures,
        stage_s: BTreeMap::new(),
        registered: s.registered,
        fallbacks: s.fallbacks,
        nominal_by_plan: 0,
        processing: info,
        wall_s: wall.elapsed().as_secs_f64(),
    };
    let mut extra = BTreeMap::new();
    extra.insert("status".to_string(), json!("finished"));
    extra.insert("reprocessed_from".to_string(), reprocessed_from);
    extra.insert("processing".to_string(), summary.processing.to_json());
    extra.insert("calibration".to_string(), calibration);
    extra.insert("registration".to_string(), json!({"registered": s.registered, "fallbacks": s.fallbacks}));
    extra.insert("faults".to_string(), json!(s.faults));
    let mut warnings = notes;
    warnings.extend(s.warnings);
    let report = RunReport {
        captures: s.textures,
        wall_s: summary.wall_s,
        hardware_s: None,
        stage_s: BTreeMap::new(),
        skipped: BTreeMap::new(),
        retries: 0,
        warnings,
        extra,
    };
    dataset.finish(&report).map_err(RunError::Report)?;
    Ok(summary)
}

/// Feeds the kept frames, rotation by rotation in the plan's order and pattern by pattern,
/// to the run's consumer, over the cameras whose view group was kept at that rotation.
fn process(
    v: &ValidatedDomePlan,
    schedule: &RawSchedule,
    src: &Source,
    src_dir: &Path,
    processing: &btfrig_process::dome::DomeProcessing,
    code: &btfrig_process::dome::GroupCode,
    dataset: &Dataset,
) -> Result<crate::dome::DomeRunSummary, RunError> {
    let mut total = crate::dome::DomeRunSummary::default();
    let by_view: BTreeMap<(usize, u32), RawView> =
        schedule.views.iter().map(|r| ((r.camera, r.rotation), *r)).collect();
    let mut index = 0;
    for &k in &v.rotations {
        let cams: Vec<(usize, RawView)> = v
            .cameras
            .iter()
            .filter_map(|&c| by_view.get(&(c, k)).filter(|r| src.frames.contains_key(&r.view)).map(|r| (c, *r)))
            .collect();
        let Some(&(_, first)) = cams.first() else { continue };
        // The consumer maps frame slots to the plan's cameras: here those kept at rotation k.
        let vk = ValidatedDomePlan { cameras: cams.iter().map(|(c, _)| *c).collect(), ..v.clone() };
        let view_ids: BTreeMap<(usize, u32), u32> = cams.iter().map(|(c, r)| ((*c, k), r.view)).collect();
        let view_id = |c: usize, k: u32| view_ids[&(c, k)];
        let mut consumer =
            crate::dome::Consumer::new(&vk, schedule.leds, processing, code, schedule.pattern_scale, dataset, view_id);
        for p in 0..schedule.frames_per_group {
            let frames = cams
                .iter()
                .map(|(_, r)| {
                    let f = &src.frames[&r.view].files[p];
                    let bytes = read_journaled(src_dir, f)?;
                    let path = src_dir.join(&f.path);
                    btfrig_imageio::decode_raw_exr(&path, &bytes)
                        .map_err(|e| input(format!("raw frame {}", path.display()), format!("cannot decode it: {e}")))
                })
                .collect::<Result<Vec<_>, _>>()?;
            let step = DomeStep { rotation: k, turntable_rad: first.turntable_rad, shot: DomeShot::Pattern(p) };
            consumer.take(DomeCapture { index, step, frames, attempts: 1, time_s: 0.0 })?;
            index += 1;
        }
        let s = consumer.finish();
        total.textures += s.textures;
        total.registered += s.registered;
        total.fallbacks += s.fallbacks;
        total.faults.extend(s.faults);
        total.warnings.extend(s.warnings);
    }
    Ok(total)
}
