//! The processing pipeline of a run: from the engine's captured frames to committed textures
//! in a dataset.
//!
//! Per frame, on a blocking thread (never on the async threads that drive the devices):
//! demosaic (a normalisation only for mono sensors), rectification onto the sample plane with
//! the NOMINAL pose (kinematics of the commanded joints), conversion to radiance factor, the
//! OpenEXR write, then the journal commit. Each stage is timed. On the simulated rig the
//! texture is also compared with the ground truth of the TRUE state at exposure (recorded by
//! [`TruthLog`]), accumulated into an overall relative RMSE.
//!
//! Back-pressure: [`run`] keeps at most [`MAX_IN_FLIGHT`] frames in processing and commits them
//! in arrival order; while both slots are busy it stops receiving, so the engine's bounded
//! frame channel fills and the engine waits before its next trigger.
#![warn(missing_docs)]

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use btfrig_calib::{rectify, to_radiance_factor, vignetting_map, Filter, LinearImage, Radiometry, RectifyError, Region};
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_engine::CapturedFrame;
use btfrig_render::demosaic::demosaic_bilinear;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::{FrameSource, SensorFormat, TrueState};
use btfrig_store::{Dataset, StepId, StepTiming, StoreError};
use tokio::sync::mpsc;

/// Frames processed at the same time (each on its own blocking thread). Two keep both cores
/// of the target machine busy while bounding memory to two frames plus the engine's channel.
pub const MAX_IN_FLIGHT: usize = 2;

/// Stage names as reported in `stage_s`.
pub const STAGES: [&str; 4] = ["demosaic", "rectify", "radiometry", "write"];

/// Why processing failed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Rectification or radiometric conversion refused its input.
    #[error("step {step}: {source}")]
    Rectify {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: RectifyError,
    },
    /// The dataset refused a write or commit.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A processing thread panicked or was cancelled.
    #[error("step {step}: processing thread failed: {reason}")]
    Join {
        /// Which capture.
        step: StepId,
        /// The join error.
        reason: String,
    },
}

/// Records, for each frame a wrapped source renders, the true state it was rendered from,
/// keyed by the frame's time stamp (the simulated camera stamps each frame with the true
/// state's time), so the pipeline can compare a texture with the truth of its exposure.
pub struct TruthLog {
    inner: Arc<dyn FrameSource>,
    log: Mutex<HashMap<u64, (JointState, f64)>>,
}

impl TruthLog {
    /// Wraps `inner`.
    pub fn new(inner: Arc<dyn FrameSource>) -> Self {
        TruthLog { inner, log: Mutex::new(HashMap::new()) }
    }

    /// Removes and returns the true joints and lamp intensity of the frame stamped
    /// `timestamp_s` (`None` if no frame with that stamp was rendered).
    pub fn take(&self, timestamp_s: f64) -> Option<(JointState, f64)> {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).remove(&timestamp_s.to_bits())
    }
}

impl FrameSource for TruthLog {
    fn format(&self) -> SensorFormat {
        self.inner.format()
    }

    fn render(&self, truth: &TrueState, settings: &btfrig_hw::CaptureSettings, seed: u64) -> RawFrame {
        self.log
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(truth.time_s.to_bits(), (truth.joints, truth.lamp_intensity));
        self.inner.render(truth, settings, seed)
    }
}

/// What to make of each frame.
#[derive(Debug, Clone, Copy)]
pub struct ProcessSettings {
    /// Texture side, texels.
    pub size: usize,
    /// Sample-plane region the texture covers, metres.
    pub region: Region,
    /// Resampling filter.
    pub filter: Filter,
}

/// One processed frame.
#[derive(Debug, Clone)]
pub struct Processed {
    /// Radiance-factor texture, row-major linear sRGB.
    pub texels: Vec<[f32; 3]>,
    /// Seconds per stage (demosaic, rectify, radiometry).
    pub stage_s: BTreeMap<String, f64>,
    /// Sum of squared differences to the ground truth, and of the squared truth (both over
    /// texels and channels); `None` without a truth.
    pub error: Option<(f64, f64)>,
}

/// Turns raw frames into textures for one rig scene.
pub struct Processor {
    scene: Arc<RigScene>,
    settings: ProcessSettings,
}

impl Processor {
    /// A processor for `scene` (rig geometry, camera model, sensor, colour).
    pub fn new(scene: Arc<RigScene>, settings: ProcessSettings) -> Self {
        Processor { scene, settings }
    }

    /// The settings.
    pub fn settings(&self) -> &ProcessSettings {
        &self.settings
    }

    /// The radiometric parameters of `frame` (its exposure and gain; the rig's sensor and
    /// manufacturer-style colour matrix).
    pub fn radiometry(&self, frame: &RawFrame) -> Radiometry {
        let sensor = self.scene.sensor();
        let gain = frame.meta.gain.max(1.0);
        let fit = self.scene.colour().colorchecker_matrix();
        Radiometry {
            dn_range: (f64::from(frame.meta.white_level) - f64::from(frame.meta.black_level)).max(1.0),
            exposure_s: frame.meta.exposure_s,
            dn_per_electron: sensor.dn_per_electron(gain),
            dark_e_per_s: sensor.dark_current_e_per_s,
            // RigScene keeps the nominal irradiance private; white_signal_dn(1 s, gain 1) is
            // nominal_irradiance * dn_per_electron(1).
            nominal_irradiance: self.scene.white_signal_dn(1.0, 1.0) / sensor.dn_per_electron(1.0),
            white_balance: fit.white_balance,
            matrix: fit.matrix,
        }
    }

    /// Ground truth of the texture region for true `joints` and `lamp_intensity`, as a
    /// radiance factor relative to the nominal lamp (what [`Processor::process`] estimates).
    pub fn ground_truth(&self, joints: &JointState, lamp_intensity: f64) -> Vec<[f32; 3]> {
        let r = self.settings.region;
        let region = btfrig_render::ground_truth::Region { x_min: r.x_min, x_max: r.x_max, y_min: r.y_min, y_max: r.y_max };
        let n = self.settings.size;
        let mut gt = self.scene.renderer().ground_truth(&self.scene.pose(joints), n, n, Some(region));
        let sensor = self.scene.sensor();
        let k = (lamp_intensity * sensor.dn_per_electron(1.0) / self.scene.white_signal_dn(1.0, 1.0)) as f32;
        for p in &mut gt.data {
            *p = p.map(|c| c * k);
        }
        gt.data
    }

    /// Demosaic, rectify with the nominal pose of `commanded`, convert to radiance factor;
    /// compare with the truth of `truth` (true joints, lamp intensity) when given.
    pub fn process(
        &self,
        step: StepId,
        frame: &RawFrame,
        commanded: &JointState,
        truth: Option<(JointState, f64)>,
    ) -> Result<Processed, PipelineError> {
        let err = |source| PipelineError::Rectify { step, source };
        let mut stage_s = BTreeMap::new();
        let t = Instant::now();
        // For a mono sensor this only normalises to [0, 1] with equal channels.
        let dm = demosaic_bilinear(frame);
        let image = LinearImage { width: dm.width, height: dm.height, data: dm.data };
        stage_s.insert("demosaic".to_string(), t.elapsed().as_secs_f64());

        let t = Instant::now();
        let pose = self.scene.pose(commanded);
        let cam = self.scene.camera().model();
        let s = &self.settings;
        let tex = rectify(&image, cam, &pose, s.region, s.size, s.filter).map_err(err)?;
        drop(image);
        stage_s.insert("rectify".to_string(), t.elapsed().as_secs_f64());

        let t = Instant::now();
        let vig = vignetting_map(cam, &pose, s.region, s.size).map_err(err)?;
        let tex = to_radiance_factor(&tex, &vig, &self.radiometry(frame)).map_err(err)?;
        stage_s.insert("radiometry".to_string(), t.elapsed().as_secs_f64());

        let error = truth.map(|(joints, lamp)| {
            let gt = self.ground_truth(&joints, lamp);
            let mut se = 0.0;
            let mut st = 0.0;
            for (a, b) in tex.data.iter().zip(&gt) {
                for c in 0..3 {
                    let (a, b) = (f64::from(a[c]), f64::from(b[c]));
                    se += (a - b) * (a - b);
                    st += b * b;
                }
            }
            (se, st)
        });
        Ok(Processed { texels: tex.data, stage_s, error })
    }
}

/// Running totals of a pipeline.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Totals {
    /// Steps committed.
    pub committed: u64,
    /// Retries (attempts beyond the first) of the committed steps.
    pub retries: u64,
    /// Seconds per stage, summed over frames (thread time, so stages of two frames in
    /// flight overlap in wall time).
    pub stage_s: BTreeMap<String, f64>,
    /// Sum of squared texture errors against the truth.
    pub sq_err: f64,
    /// Sum of squared truth.
    pub sq_truth: f64,
    /// Committed steps that had no recorded truth (not in the error figure).
    pub without_truth: u64,
}

impl Totals {
    /// `sqrt(sum sq_err / sum sq_truth)` over all compared textures, texels and channels.
    pub fn texture_rel_rmse(&self) -> Option<f64> {
        (self.sq_truth > 0.0).then(|| (self.sq_err / self.sq_truth).sqrt())
    }
}

/// Where the pipeline looks up the true state of a frame.
pub type TruthLookup = Arc<dyn Fn(&CapturedFrame) -> Option<(JointState, f64)> + Send + Sync>;

/// Processes every frame from `frames` until the channel closes: process and write on
/// blocking threads (at most [`MAX_IN_FLIGHT`]), commit in arrival order. `on_commit` is
/// called after each commit with the totals so far (for progress displays). Stops at the
/// first error (the frames after it are not committed; a resumed run captures them again).
pub async fn run<S>(
    dataset: Arc<Dataset<S>>,
    processor: Arc<Processor>,
    mut frames: mpsc::Receiver<CapturedFrame>,
    truth: TruthLookup,
    mut on_commit: impl FnMut(&Totals),
) -> Result<Totals, PipelineError>
where
    S: btfrig_store::Storage + Send + Sync + 'static,
{
    type Output = (StepId, Vec<btfrig_store::FileRecord>, u32, StepTiming, Processed);
    type Job = tokio::task::JoinHandle<Result<Output, PipelineError>>;
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
                let t = truth(&f);
                let (ds, pr) = (dataset.clone(), processor.clone());
                let job = tokio::task::spawn_blocking(move || {
                    let started = Instant::now();
                    let started_unix_s = unix_now();
                    let mut p = pr.process(step, &f.frame, &f.joints, t)?;
                    let tw = Instant::now();
                    let n = pr.settings().size;
                    let rec = ds.write_texture(step, &p.texels, n, n)?;
                    p.stage_s.insert("write".to_string(), tw.elapsed().as_secs_f64());
                    let timing = StepTiming {
                        started_unix_s,
                        wall_s: started.elapsed().as_secs_f64(),
                        hardware_s: Some(f.times.transfer_end_s - f.times.move_start_s),
                        stage_s: p.stage_s.clone(),
                    };
                    p.texels = Vec::new();
                    Ok((step, vec![rec], f.attempts, timing, p))
                });
                in_flight.push_back((step, job));
            }
            Next::Done(r) => {
                let (step, _) = in_flight.pop_front().expect("a job was awaited");
                let (step, files, attempts, timing, p) =
                    r.map_err(|e| PipelineError::Join { step, reason: e.to_string() })??;
                let ds = dataset.clone();
                tokio::task::spawn_blocking(move || ds.commit_step(step, files, attempts, timing))
                    .await
                    .map_err(|e| PipelineError::Join { step, reason: e.to_string() })??;
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
                on_commit(&totals);
            }
        }
    }
    Ok(totals)
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}
