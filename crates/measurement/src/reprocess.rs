//! `btfrig reprocess`: runs the pipeline again on the raw frames a dataset kept
//! (`[outputs] raw_frames = true`), into a new dataset, without the rig and without the
//! simulator, e.g. after a better calibration (`docs/pipeline.md`, "Reprocessing"). A dome or
//! camera-array dataset is demultiplexed again from its view groups' pattern frames
//! (`crate::dome_reprocess`); this module does a gonioreflectometer's.
//!
//! The processing model is loaded as a run loads it ([`crate::model::gonio_model`]), from the
//! rig config recorded in the dataset's manifest and the calibration files it names; a
//! calibration directory given with the request replaces each named file by the file of the
//! same name in it (see [`calibration_file_name`]). Every raw frame of every committed step
//! (with its HDR bracket) goes through the same [`Processor`] and [`btfrig_process::run`] as
//! in a run, with the commanded joints the run used (the plan's directions through the rig's
//! inverse kinematics, as the planner expands them); there is no truth probe, so the report
//! has no truth figures.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use btfrig_core::capture::{CapturedFrame, StepKey, StepTimes};
use btfrig_core::config::{RigConfig, RigKind};
use btfrig_core::kinematics::Gonio;
use btfrig_core::plan::{Plan, PlanContext, ResampleFilter, ValidatedPlan};
use btfrig_process::light::{LampReference, LightCorrection};
use btfrig_process::{ProcessSettings, Processor};
use btfrig_store::journal::StepRecord;
use btfrig_store::{Dataset, Manifest, RunReport, MANIFEST_FILE};
use serde_json::json;
use tokio::sync::mpsc;

use crate::reprocess_io::{
    calibration_dir, check_out_empty, input, read_journaled, read_source, refuse_relative, replace_reference,
    reprocessed_manifest, rig_of,
};
pub use crate::reprocess_io::{calibration_file_name, ReprocessRequest, ReprocessSummary, DARK_FLAT_DIR};
use crate::{ProcessingInfo, RunError};

/// The raw frames of `record` (base exposure first), each checked against its journaled size
/// and content hash.
fn read_raw_frames(dir: &Path, record: &StepRecord) -> Result<Vec<btfrig_core::frame::RawFrame>, RunError> {
    let stem = record.step.stem();
    let mut raw: Vec<&btfrig_store::FileRecord> =
        record.files.iter().filter(|f| f.path.starts_with(&format!("{}/{stem}", btfrig_store::RAW_DIR))).collect();
    // raw/<stem>.exr, then raw/<stem>_e1.exr, _e2, ... (the order of the bracket).
    raw.sort_by_key(|f| {
        f.path.rsplit_once("_e").and_then(|(_, k)| k.trim_end_matches(".exr").parse::<usize>().ok()).unwrap_or(0)
    });
    if raw.is_empty() {
        return Err(input(
            format!("dataset {}, step {}", dir.display(), record.step),
            "the journal names no raw frame of this step",
        ));
    }
    raw.iter()
        .map(|f| {
            let path = dir.join(&f.path);
            let bytes = read_journaled(dir, f)?;
            btfrig_imageio::decode_raw_exr(&path, &bytes)
                .map_err(|e| input(format!("raw frame {}", path.display()), format!("cannot decode it: {e}")))
        })
        .collect()
}

/// The plan of the source (a gonio dataset), validated against the rig config `rig`
/// recorded in its manifest.
fn plan_of(manifest: &Manifest, dir: &Path, rig: RigConfig) -> Result<(RigConfig, Plan, ValidatedPlan), RunError> {
    let origin = format!("{}/{MANIFEST_FILE}", dir.display());
    let plan = Plan::from_toml(&manifest.plan.text, &format!("{origin}: plan.text"))?;
    let mut ctx = PlanContext::with_builtin_names();
    ctx.rig = Some(rig.clone());
    let v = plan.validate(&ctx).map_err(|mut e| {
        e.origin = format!("{origin}: plan.text");
        e
    })?;
    Ok((rig, plan, v))
}

/// The light calibration the source run processed with, as recorded in its manifest
/// (`calibration.light`), if it had its own.
fn recorded_light(manifest: &Manifest) -> Result<Option<LightCorrection>, RunError> {
    let Some(l) = manifest.calibration.as_ref().map(|c| &c["light"]).filter(|l| !l.is_null()) else {
        return Ok(None);
    };
    let bad = |field: &str| input("manifest calibration.light", format!("{field} is missing or not a number"));
    let triple = |field: &str| -> Result<[f64; 3], RunError> {
        let a = l[field].as_array().filter(|a| a.len() == 3).ok_or_else(|| bad(field))?;
        let mut out = [0.0; 3];
        for (o, v) in out.iter_mut().zip(a) {
            *o = v.as_f64().ok_or_else(|| bad(field))?;
        }
        Ok(out)
    };
    let mut c = LightCorrection::new(LampReference {
        light: l["light"].as_str().unwrap_or(crate::model::LAMP).to_string(),
        white_rate: triple("white_rate_e_per_s")?,
        plate_albedo: triple("plate_albedo")?,
    });
    c.correct_drift = l["drift_corrected"].as_bool().unwrap_or(true);
    Ok(Some(c))
}

/// The calibrations: the rig config with its references pointed at the files of `dir` where
/// it holds them, the light and dark/flat calibrations, and the files used (part, file).
struct Calibrations {
    rig: RigConfig,
    light: Option<LightCorrection>,
    dark_flat: Option<Arc<btfrig_process::dark_flat::DarkFlat>>,
    used: Vec<(String, String)>,
}

fn calibrations(rig: &RigConfig, manifest: &Manifest, dir: Option<&Path>) -> Result<Calibrations, RunError> {
    let mut rig = rig.clone();
    let mut used = Vec::new();
    let recorded = recorded_light(manifest)?;
    let mut light = recorded.clone();
    replace_reference(dir, "[camera] calibration", &mut rig.camera.calibration, &mut used);
    replace_reference(dir, "[camera] color_calibration", &mut rig.camera.color_calibration, &mut used);
    if let Some(path) = replace_reference(dir, "[lamp] calibration", &mut rig.lamp.calibration, &mut used) {
        if let Some(run_light) = &recorded {
            // The run had its own light calibration: the new file takes its place, drift
            // correction as the run had it.
            let text =
                std::fs::read_to_string(&path).map_err(|source| RunError::Read { path: path.clone(), source })?;
            let origin = path.display().to_string();
            let what = format!("[lamp] calibration {origin}");
            let file = btfrig_calibrate::light::LightCalibrationFile::from_toml(&text, &origin)
                .map_err(|e| input(&what, e.to_string()))?;
            let mut c = crate::model::lamp_correction(&file).map_err(|e| input(&what, e))?;
            c.correct_drift = run_light.correct_drift;
            light = Some(c);
        }
    }
    refuse_relative(&[
        ("[camera] calibration", &rig.camera.calibration),
        ("[camera] color_calibration", &rig.camera.color_calibration),
        ("[lamp] calibration", &rig.lamp.calibration),
    ])?;
    let recorded_dark_flat =
        manifest.calibration.as_ref().and_then(|c| c["dark_flat"]["source"].as_str().map(str::to_string));
    let dark_flat_dir = match dir.map(|d| d.join(DARK_FLAT_DIR)).filter(|d| d.is_dir()) {
        Some(d) => Some(d),
        None => recorded_dark_flat.as_deref().map(PathBuf::from),
    };
    let dark_flat = match dark_flat_dir {
        None => None,
        Some(d) => {
            let (_, cal) = btfrig_calibrate::dark_flat::read_calibration(&d).map_err(|e| {
                input(
                    format!("dark/flat calibration {}", d.display()),
                    format!("{e} (the dataset was processed with it; put a copy in --calibration DIR/{DARK_FLAT_DIR})"),
                )
            })?;
            let (w, h) = (rig.camera.width_px, rig.camera.height_px);
            if (cal.dark.width, cal.dark.height) != (w, h) {
                return Err(input(
                    format!("dark/flat calibration {}", d.display()),
                    format!("it is of a {}x{} sensor, the rig's camera is {w}x{h}", cal.dark.width, cal.dark.height),
                ));
            }
            used.push(("dark_flat".to_string(), d.display().to_string()));
            Some(Arc::new(cal))
        }
    };
    Ok(Calibrations { rig, light, dark_flat, used })
}

/// The pipeline's settings of a validated plan (a run's and a reprocessing's).
pub(crate) fn process_settings(v: &ValidatedPlan) -> ProcessSettings {
    ProcessSettings {
        size: v.texture.size,
        region: btfrig_imaging::Region {
            x_min: v.texture.region.x_min_m,
            x_max: v.texture.region.x_max_m,
            y_min: v.texture.region.y_min_m,
            y_max: v.texture.region.y_max_m,
        },
        filter: match v.texture.filter {
            ResampleFilter::Bilinear => btfrig_imaging::Filter::Bilinear,
            ResampleFilter::Supersample { n } => btfrig_imaging::Filter::Supersample { n },
            ResampleFilter::Footprint { max } => btfrig_imaging::Filter::Footprint { max },
            ResampleFilter::Ewa => btfrig_imaging::Filter::Ewa,
        },
        registration: v.registration,
    }
}

/// Reprocesses `req.dataset` into `req.out`; see the module documentation. Nothing is written
/// until every input checked out: the source's raw frames (present, as journaled), the plan,
/// the calibration files, an empty `out`.
pub fn reprocess(req: &ReprocessRequest) -> Result<ReprocessSummary, RunError> {
    let wall = Instant::now();
    let src_dir = req.dataset.as_path();
    let src = read_source(src_dir)?;
    let rig = rig_of(&src.manifest, src_dir)?;
    if rig.rig.kind != RigKind::Gonioreflectometer {
        return crate::dome_reprocess::reprocess(req, src, rig);
    }
    let (rig, _plan, v) = plan_of(&src.manifest, src_dir, rig)?;
    if !src.manifest.raw_frames {
        return Err(input(
            format!("dataset {}", src_dir.display()),
            "it has no raw frames (its manifest says raw_frames = false): only a run with `[outputs] raw_frames = true` in its plan can be reprocessed",
        ));
    }
    if src.steps.is_empty() {
        return Err(input(format!("dataset {}", src_dir.display()), "it has no committed step to reprocess"));
    }
    let cal_dir = calibration_dir(req)?;
    let cal = calibrations(&rig, &src.manifest, cal_dir.as_deref())?;
    let model = crate::model::gonio_model(&cal.rig, None, cal.light.clone(), cal.dark_flat.clone())?;
    let processing = ProcessingInfo::of(&model);
    // The commanded joints of each step: the planner's expansion (inverse kinematics of the
    // step's light and view directions) is all a run commands for a step.
    let gonio = Gonio::new(rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    let mut joints = BTreeMap::new();
    for r in &src.steps {
        let (l, vw) = (r.step.light as usize, r.step.view as usize);
        if l >= v.light.len() || vw >= v.view.len() {
            return Err(input(format!("dataset {}", src_dir.display()), format!("step {} is not in its plan", r.step)));
        }
        let j = gonio.ik(v.light.get(l), v.view.get(vw)).map_err(|e| {
            input(format!("dataset {}", src_dir.display()), format!("step {}: the rig cannot reach it: {e}", r.step))
        })?;
        joints.insert(r.step, j);
    }
    // Every raw frame is checked before the new dataset exists.
    for r in &src.steps {
        read_raw_frames(src_dir, r)?;
    }
    check_out_empty(&req.out)?;

    let mut manifest = reprocessed_manifest(&src.manifest);
    let mut record = src.manifest.calibration.clone().unwrap_or_else(|| json!({}));
    if let Some(o) = record.as_object_mut() {
        o.insert(
            "light".into(),
            json!(cal.light.as_ref().map(|l| json!({
                "light": l.reference.light,
                "white_rate_e_per_s": l.reference.white_rate,
                "plate_albedo": l.reference.plate_albedo,
                "drift_corrected": l.correct_drift,
            }))),
        );
    }
    let reprocessed_from = json!({
        "dataset": src_dir.display().to_string(),
        "manifest_hash": src.manifest_hash,
        "calibration_dir": req.calibration.as_ref().map(|d| d.display().to_string()),
        "calibration_files": cal.used.iter().map(|(k, f)| json!({"part": k, "file": f})).collect::<Vec<_>>(),
        "sources": processing.to_json()["sources"].clone(),
    });
    if let Some(o) = record.as_object_mut() {
        o.insert("reprocessed_from".into(), reprocessed_from.clone());
    }
    manifest.calibration = Some(record);
    let dataset =
        Dataset::create(&req.out, manifest).map_err(|source| RunError::Dataset { dir: req.out.clone(), source })?;
    let dataset = Arc::new(dataset);

    let hdr = match &v.exposure {
        btfrig_core::plan::ExposurePolicy::Auto { hdr, .. } if hdr.is_on() => Some(hdr.clone()),
        _ => None,
    };
    let processor = Arc::new(
        Processor::new(model, process_settings(&v))
            .map_err(|e| RunError::Rig(e.to_string()))?
            .with_outputs(btfrig_process::Outputs {
                textures: true,
                raw_frames: false,
                texture_previews: dataset.manifest().texture_previews,
                preview: None,
            })
            .with_hdr_recording(
                hdr.as_ref().map(|h| btfrig_process::HdrRecording { always_stops: crate::hdr::always_stops(h) }),
            ),
    );
    let rt = tokio::runtime::Builder::new_current_thread().enable_time().build().map_err(RunError::Runtime)?;
    let (tx, rx) = mpsc::channel(crate::runtime::FRAME_CHANNEL);
    let steps = src.steps.clone();
    let dir = src_dir.to_path_buf();
    let totals = rt.block_on(async move {
        // Frames are read on a blocking thread and handed over in commit order, at most
        // FRAME_CHANNEL ahead of the pipeline.
        let reader = tokio::task::spawn_blocking(move || {
            for (index, r) in steps.iter().enumerate() {
                let mut frames = read_raw_frames(&dir, r)?;
                let frame = frames.remove(0);
                let captured = CapturedFrame {
                    index,
                    key: StepKey { light: r.step.light, view: r.step.view },
                    frame,
                    bracket: frames,
                    attempts: r.attempts,
                    joints: joints[&r.step],
                    times: StepTimes { bracket_s: r.hdr.as_ref().map_or(0.0, |h| h.bracket_s), ..StepTimes::default() },
                };
                if tx.blocking_send(captured).is_err() {
                    break; // the pipeline stopped at an error, which it returns
                }
            }
            Ok::<(), RunError>(())
        });
        let totals = btfrig_process::run(dataset.clone(), processor, rx, |_| {}).await;
        let read = reader.await.map_err(|e| RunError::Rig(format!("reading the raw frames: {e}")))?;
        read?;
        Ok::<_, RunError>((totals?, dataset))
    });
    let (totals, dataset) = match totals {
        Ok(t) => t,
        Err(e) => {
            // Nothing usable was made: leave no half dataset behind.
            let _ = std::fs::remove_dir_all(&req.out);
            return Err(e);
        }
    };
    let mut dataset =
        Arc::try_unwrap(dataset).map_err(|_| RunError::Rig("dataset still shared after reprocessing".into()))?;
    let summary = ReprocessSummary {
        out: req.out.clone(),
        steps: totals.committed,
        stage_s: totals.stage_s.clone(),
        registered: totals.registered,
        fallbacks: totals.fallbacks,
        nominal_by_plan: totals.nominal_by_plan,
        processing,
        wall_s: wall.elapsed().as_secs_f64(),
    };
    let mut extra = BTreeMap::new();
    extra.insert("status".to_string(), json!("finished"));
    extra.insert("reprocessed_from".to_string(), reprocessed_from);
    extra.insert("processing".to_string(), summary.processing.to_json());
    extra.insert(
        "registration".to_string(),
        json!({"registered": totals.registered, "fallbacks": totals.fallbacks, "nominal_by_plan": totals.nominal_by_plan}),
    );
    let warnings: Vec<String> = totals
        .fallback_steps
        .iter()
        .map(|(step, reason)| format!("step {step}: registration failed, rectified with the nominal pose: {reason}"))
        .collect();
    let report = RunReport {
        captures: totals.committed,
        wall_s: summary.wall_s,
        hardware_s: None,
        stage_s: totals.stage_s,
        skipped: BTreeMap::new(),
        retries: 0,
        warnings,
        extra,
    };
    dataset.finish(&report).map_err(RunError::Report)?;
    Ok(summary)
}

/// A committed step of a gonio dataset that kept its raw frames: what the run commanded for
/// it and its frames (base exposure first), for `btfrig dataset export-recording`.
#[derive(Debug, Clone)]
pub struct KeptCapture {
    /// Which step.
    pub step: StepKey,
    /// Its light direction in the sample frame.
    pub light: btfrig_core::direction::Direction,
    /// Its view direction in the sample frame.
    pub view: btfrig_core::direction::Direction,
    /// The joints the run commanded (the planner's inverse kinematics of the directions).
    pub joints: btfrig_core::kinematics::JointState,
}

/// What a gonio dataset kept of its run: its rig config and each committed step in commit
/// order; [`KeptCaptures::frames`] reads a step's raw frames (checked against the journal).
pub struct KeptCaptures {
    /// The dataset directory.
    pub dir: PathBuf,
    /// The rig config recorded in the manifest, as text.
    pub rig_toml: String,
    /// The same, parsed.
    pub rig: RigConfig,
    /// The committed steps, in commit order.
    pub captures: Vec<KeptCapture>,
    records: Vec<StepRecord>,
}

impl KeptCaptures {
    /// Reads what the gonio dataset `dir` kept; refuses a dataset without raw frames.
    pub fn open(dir: &Path) -> Result<KeptCaptures, RunError> {
        let src = read_source(dir)?;
        let rig = rig_of(&src.manifest, dir)?;
        if rig.rig.kind != RigKind::Gonioreflectometer {
            return Err(input(
                format!("dataset {}", dir.display()),
                "it is a dome or camera-array dataset: only a gonioreflectometer's frames export to a recording so far",
            ));
        }
        if !src.manifest.raw_frames {
            return Err(input(
                format!("dataset {}", dir.display()),
                "it has no raw frames (its manifest says raw_frames = false): only a run with `[outputs] raw_frames = true` in its plan keeps them",
            ));
        }
        let (rig, _plan, v) = plan_of(&src.manifest, dir, rig)?;
        let gonio = Gonio::new(rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
        let mut captures = Vec::with_capacity(src.steps.len());
        for r in &src.steps {
            let (l, vw) = (r.step.light as usize, r.step.view as usize);
            if l >= v.light.len() || vw >= v.view.len() {
                return Err(input(format!("dataset {}", dir.display()), format!("step {} is not in its plan", r.step)));
            }
            let (light, view) = (v.light.get(l), v.view.get(vw));
            let joints = gonio.ik(light, view).map_err(|e| {
                input(format!("dataset {}", dir.display()), format!("step {}: the rig cannot reach it: {e}", r.step))
            })?;
            captures.push(KeptCapture {
                step: StepKey { light: r.step.light, view: r.step.view },
                light,
                view,
                joints,
            });
        }
        Ok(KeptCaptures {
            dir: dir.to_path_buf(),
            rig_toml: src.manifest.rig.config_toml.clone(),
            rig,
            captures,
            records: src.steps,
        })
    }

    /// The raw frames of capture `index` (of [`KeptCaptures::captures`]), base exposure first.
    pub fn frames(&self, index: usize) -> Result<Vec<btfrig_core::frame::RawFrame>, RunError> {
        read_raw_frames(&self.dir, &self.records[index])
    }
}
