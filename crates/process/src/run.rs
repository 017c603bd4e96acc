//! The run loop: bounded parallel processing, commits in arrival order.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Instant;

use btfrig_core::capture::CapturedFrame;
use btfrig_core::frame::RawFrame;
use btfrig_store::{Dataset, PoseSource, StepExtra, StepHdr, StepId, StepRegistration, StepTiming, StoreError};
use tokio::sync::mpsc;

use crate::preview::{claim_preview, make_preview, MadePreview};
use crate::{PipelineError, Processed, Processor, Totals};

/// Frames processed at the same time (each on its own blocking thread). Two keep both cores
/// of the target machine busy while bounding memory to two frames plus the engine's channel.
pub const MAX_IN_FLIGHT: usize = 2;

/// Stage names as reported in `stage_s` when textures are written (`register`: marker
/// detection and pose estimation, absent with `[registration] method = "nominal"`). With raw
/// frames the stage `write_raw` is added; with previews, [`Totals::stage_s`] has `preview`
/// (building, encoding and writing previews; not in the journal's step timings). Without
/// textures the texture stages run only for the frames that make a preview.
pub const STAGES: [&str; 5] = ["demosaic", "register", "rectify", "radiometry", "write"];

/// Processes every frame from `frames` until the channel closes: process and write on
/// blocking threads (at most [`MAX_IN_FLIGHT`]), commit in arrival order. `on_commit` is
/// called after each commit with the totals so far (for progress displays). Stops at the
/// first error (the frames after it are not committed; a resumed run captures them again).
pub async fn run<S>(
    dataset: Arc<Dataset<S>>,
    processor: Arc<Processor>,
    mut frames: mpsc::Receiver<CapturedFrame>,
    mut on_commit: impl FnMut(&Totals),
) -> Result<Totals, PipelineError>
where
    S: btfrig_store::Storage + Send + Sync + 'static,
{
    type Output =
        (StepId, Vec<btfrig_store::FileRecord>, u32, StepTiming, Processed, Option<MadePreview>, Option<StepHdr>);
    type Job = tokio::task::JoinHandle<Result<Output, PipelineError>>;
    // One value per turn of the loop, never stored: the size difference does not matter.
    #[allow(clippy::large_enum_variant)]
    enum Next {
        Frame(Option<CapturedFrame>),
        Done(Result<Result<Output, PipelineError>, tokio::task::JoinError>),
    }
    let mut totals = Totals::default();
    let mut in_flight: VecDeque<(StepId, Job)> = VecDeque::new();
    let mut open = true;
    while open || !in_flight.is_empty() {
        let full = in_flight.len() >= MAX_IN_FLIGHT;
        // Commit the oldest job as soon as it is done (journal and progress do not lag);
        // receive only while a slot is free: that is the back-pressure on the engine.
        let next = match in_flight.front_mut() {
            Some((_, job)) if full || !open => Next::Done(job.await),
            Some((_, job)) => tokio::select! {
                biased;
                r = job => Next::Done(r),
                f = frames.recv() => Next::Frame(f),
            },
            None => Next::Frame(frames.recv().await),
        };
        match next {
            Next::Frame(None) => open = false,
            Next::Frame(Some(f)) => {
                let step = StepId { light: f.key.light, view: f.key.view };
                let t = processor.truth.as_ref().and_then(|probe| {
                    // The further exposures of a bracket were taken at the same true pose.
                    for b in &f.bracket {
                        probe.take_exposure(b.meta.timestamp_s);
                    }
                    probe.take_exposure(f.frame.meta.timestamp_s)
                });
                let (ds, pr) = (dataset.clone(), processor.clone());
                let job = tokio::task::spawn_blocking(move || {
                    let started = Instant::now();
                    let started_unix_s = unix_now();
                    let out = *pr.outputs();
                    let mut files = Vec::new();
                    let mut stage_s = BTreeMap::new();
                    let frames: Vec<&RawFrame> = std::iter::once(&f.frame).chain(&f.bracket).collect();
                    if out.raw_frames {
                        let tw = Instant::now();
                        for (k, fr) in frames.iter().enumerate() {
                            files.push(ds.write_raw_exposure(step, k, fr)?);
                        }
                        stage_s.insert("write_raw".to_string(), tw.elapsed().as_secs_f64());
                    }
                    let claim = claim_preview(&pr);
                    let preview_due = claim.is_some();
                    let nothing = Processed::nothing;
                    let mut p = if out.textures {
                        pr.process_bracket(step, &frames, &f.joints, t)?
                    } else if preview_due {
                        // Only for the preview: its failure must not fail the step, and without
                        // textures there is nothing to compare with the truth.
                        pr.process_bracket(step, &frames, &f.joints, None).unwrap_or_else(|_| nothing())
                    } else {
                        nothing()
                    };
                    let n = pr.settings().size;
                    if out.textures {
                        let tw = Instant::now();
                        files.push(ds.write_texture(step, &p.texels, n, n)?);
                        if out.texture_previews {
                            files.push(ds.write_texture_preview(step, &p.texels, n, n)?);
                        }
                        p.stage_s.insert("write".to_string(), tw.elapsed().as_secs_f64());
                    }
                    p.stage_s.extend(stage_s);
                    let timing = StepTiming {
                        started_unix_s,
                        wall_s: started.elapsed().as_secs_f64(),
                        hardware_s: Some(f.times.transfer_end_s - f.times.move_start_s),
                        stage_s: p.stage_s.clone(),
                    };
                    let preview = claim.map(|c| make_preview(c, step, &p.texels, n));
                    // The sink gets the texture after the commit; without one it is dropped here.
                    if pr.sink.is_none() || !out.textures {
                        p.texels = Vec::new();
                    }
                    let hdr = pr.hdr_recording().map(|h| StepHdr {
                        exposures_s: frames.iter().map(|fr| fr.meta.exposure_s).collect(),
                        bracket_s: f.times.bracket_s,
                        saturated_photosites: pr.saturated_on_sample(&frames, &f.joints),
                        always_s: h.always_stops.iter().map(|k| k * f.frame.meta.exposure_s).collect(),
                    });
                    Ok((step, files, f.attempts, timing, p, preview, hdr))
                });
                in_flight.push_back((step, job));
            }
            Next::Done(r) => {
                let (step, _) = in_flight.pop_front().expect("a job was awaited");
                let (step, files, attempts, timing, mut p, preview, hdr) =
                    match r.map_err(|e| PipelineError::Join { step, reason: e.to_string() }).and_then(|r| r) {
                        Ok(out) => out,
                        Err(e) => return Err(drain(in_flight, e).await),
                    };
                let ds = dataset.clone();
                // The preview file is replaced only after the commit: it never shows a capture
                // that does not count.
                // A texture's pose record goes with it; a preview-only frame wrote no texture.
                let registration = if processor.outputs().textures { p.registration.clone() } else { None };
                let sink = processor.sink.clone();
                let sink_texels = std::mem::take(&mut p.texels);
                let written = match tokio::task::spawn_blocking(move || {
                    ds.commit_step_with(step, files, attempts, timing, StepExtra { registration, hdr })?;
                    if let Some(s) = sink.filter(|_| !sink_texels.is_empty()) {
                        s.accept(step, &sink_texels);
                    }
                    Ok::<_, StoreError>(preview.map(|made| {
                        let t = Instant::now();
                        let ok = match &made.preview {
                            Some(pv) => ds.write_preview(&pv.png).is_ok(),
                            None => false,
                        };
                        (made, ok, t.elapsed().as_secs_f64())
                    }))
                })
                .await
                .map_err(|e| PipelineError::Join { step, reason: e.to_string() })
                .and_then(|r| r.map_err(PipelineError::from))
                {
                    Ok(w) => w,
                    Err(e) => return Err(drain(in_flight, e).await),
                };
                if let Some((mut made, ok, write_s)) = written {
                    made.claim.cost_s += write_s;
                    *totals.stage_s.entry("preview".to_string()).or_insert(0.0) += made.claim.cost_s;
                    drop(made.claim);
                    match (made.preview, ok) {
                        (Some(pv), true) => {
                            totals.previews += 1;
                            processor.preview.send_replace(Some(Arc::new(pv)));
                        }
                        _ => totals.preview_failures += 1,
                    }
                }
                totals.committed += 1;
                totals.retries += u64::from(attempts.saturating_sub(1));
                for (k, v) in p.stage_s {
                    *totals.stage_s.entry(k).or_insert(0.0) += v;
                }
                match p.error {
                    Some((se, st)) => {
                        totals.sq_err += se;
                        totals.sq_truth += st;
                    }
                    None => totals.without_truth += 1,
                }
                if let Some((se, st)) = p.error_nominal {
                    totals.sq_err_nominal += se;
                    totals.sq_truth_nominal += st;
                }
                totals.lamp.add(step, p.lamp_factor, p.brightness_err);
                if let Some(e) = p.pose_errors {
                    totals.texel_err.add(e.used);
                    totals.nominal_texel_err.add(e.nominal);
                }
                if processor.outputs().textures {
                    match p.registration {
                        Some(StepRegistration { pose: PoseSource::Markers, .. }) => totals.registered += 1,
                        Some(StepRegistration { pose: PoseSource::NominalByPlan, .. }) => totals.nominal_by_plan += 1,
                        Some(StepRegistration { pose: PoseSource::NominalFallback, reason, .. }) => {
                            totals.fallbacks += 1;
                            totals.fallback_steps.push((step, reason.unwrap_or_default()));
                        }
                        None => {}
                    }
                }
                on_commit(&totals);
            }
        }
    }
    Ok(totals)
}

/// Waits for the jobs still in flight (their results are dropped: nothing after a failed step
/// is committed) so that no processing thread outlives the pipeline, then returns `e`.
async fn drain<T>(in_flight: VecDeque<(StepId, tokio::task::JoinHandle<T>)>, e: PipelineError) -> PipelineError {
    for (_, job) in in_flight {
        let _ = job.await;
    }
    e
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}
