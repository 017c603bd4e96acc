//! The processing pipeline of a run: from the engine's captured frames to committed textures
//! in a dataset.
//!
//! Per frame, on a blocking thread (never on the async threads that drive the devices):
//! demosaic (a normalisation only for mono sensors), registration (the holder plate's markers
//! detected in the green channel, the sample pose estimated from them with the nominal pose
//! as prior: `btfrig_register::PlateRegistrar`), rectification onto the sample plane with the
//! REGISTERED pose, conversion to radiance factor, the OpenEXR write, then the journal commit
//! with how the pose was found ([`StepRegistration`]). Each stage is timed. The plan's
//! `[registration]` ([`RegistrationPolicy`]) may ask for the nominal pose (kinematics of the
//! commanded joints) instead, and says what a failed registration does: fall back to the
//! nominal pose, recorded and counted as a fallback, or stop ([`PipelineError::Registration`]).
//!
//! On the simulated rig the texture is also compared with the ground truth of the TRUE state
//! at exposure (recorded by [`TruthLog`]), accumulated into an overall relative RMSE, and the
//! texel position error of the pose used and of the nominal pose is measured against the true
//! pose; optionally ([`Processor::with_nominal_comparison`]) the texture is rectified a second
//! time with the nominal pose to measure what registration gained.
//!
//! What is written follows the plan's `[outputs]` ([`Outputs`], set with
//! [`Processor::with_outputs`]): the texture, the raw frame, or both, committed in ONE journal
//! record so a crash never leaves one counted without the other; and, rate-limited, a live
//! preview ([`PreviewSettings`]): `preview.png` in the dataset directory (atomic, never
//! journaled) and the same PNG in memory ([`Processor::subscribe_preview`]) for the HTTP daemon.
//!
//! Back-pressure: [`run`] keeps at most [`MAX_IN_FLIGHT`] frames in processing and commits them
//! in arrival order; while both slots are busy it stops receiving, so the engine's bounded
//! frame channel fills and the engine waits before its next trigger.
#![warn(missing_docs)]

pub mod color;
pub mod dark_flat;
pub mod dome;
pub mod light;

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use btfrig_calib::{
    rectify, to_radiance_factor, vignetting_map, Filter, LinearImage, Radiometry, RectifyError, Region,
};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::PlateConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
pub use btfrig_core::plan::{OnRegistrationFailure, RegistrationMethod, RegistrationPolicy};
use btfrig_core::pose::ScenePose;
use btfrig_engine::CapturedFrame;
use btfrig_markers::GrayImage;
use btfrig_register::{texel_position_error_with_cameras, FrameError, PlateRegistrar, RegisterOptions};
use btfrig_imageio::demosaic::demosaic_bilinear;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::{FrameSource, SensorFormat, TrueState};
use btfrig_store::{Dataset, StepExtra, StepHdr, StepId, StepTiming, StoreError};
pub use btfrig_store::{PoseSource, StepRegistration};
use tokio::sync::{mpsc, watch};

/// Frames processed at the same time (each on its own blocking thread). Two keep both cores
/// of the target machine busy while bounding memory to two frames plus the engine's channel.
pub const MAX_IN_FLIGHT: usize = 2;

/// Stage names as reported in `stage_s` when textures are written (`register`: marker
/// detection and pose estimation, absent with `[registration] method = "nominal"`). With raw
/// frames the stage `write_raw` is added; with previews, [`Totals::stage_s`] has `preview`
/// (building, encoding and writing previews; not in the journal's step timings). Without
/// textures the texture stages run only for the frames that make a preview.
pub const STAGES: [&str; 5] = ["demosaic", "register", "rectify", "radiometry", "write"];

/// What the pipeline writes for each frame (the plan's `[outputs]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// Write the rectified texture (`Dataset::write_texture`).
    pub textures: bool,
    /// Write the raw frame (`Dataset::write_raw`); the dataset's manifest must ask for them.
    pub raw_frames: bool,
    /// Write an 8-bit sRGB preview of each texture (`Dataset::write_texture_preview`, in the
    /// `write` stage); needs `textures` and a manifest that asks for them.
    pub texture_previews: bool,
    /// Keep a live preview, rate-limited; `None`: no preview.
    pub preview: Option<PreviewSettings>,
}

impl Default for Outputs {
    /// Textures only, no preview.
    fn default() -> Self {
        Outputs { textures: true, raw_frames: false, texture_previews: false, preview: None }
    }
}

/// How the live preview is made and how often.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewSettings {
    /// Smallest side of the preview, pixels: a smaller texture is enlarged by a whole factor
    /// (nearest neighbour, so texels stay visible as such).
    pub min_side: usize,
    /// Shortest time between two previews, seconds.
    pub min_interval_s: f64,
    /// Largest share of wall time previews may cost: after a preview that cost `c` seconds
    /// the next waits at least `c / max_share`.
    pub max_share: f64,
}

impl Default for PreviewSettings {
    /// 256 px, at most every 0.5 s and at most 2 % of the time.
    fn default() -> Self {
        PreviewSettings { min_side: 256, min_interval_s: 0.5, max_share: 0.02 }
    }
}

/// A preview image: the rectified texture of one capture, tone-mapped to 8-bit sRGB.
#[derive(Debug, Clone, PartialEq)]
pub struct Preview {
    /// The capture shown.
    pub step: StepId,
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// The PNG file's bytes (what `preview.png` holds).
    pub png: Vec<u8>,
}

/// Tone-maps a linear radiance-factor texture (`width x height`, row-major) to 8-bit sRGB
/// (`RGBRGB...`), enlarged by the smallest whole factor that makes both sides at least
/// `min_side`. Exposure is automatic so dark and glossy captures both show: the 99th
/// percentile of the brightest channel maps to 90 % (gain at most 16, so a black frame stays
/// black rather than showing amplified noise); values are clipped to [0, 1] (NaN to 0) and
/// encoded with the sRGB transfer function. Returns `(width, height, bytes)`.
///
/// # Panics
/// If `texels.len() != width * height`.
pub fn tone_map_preview(texels: &[[f32; 3]], width: usize, height: usize, min_side: usize) -> (usize, usize, Vec<u8>) {
    assert_eq!(texels.len(), width * height, "tone_map_preview: {width}x{height} texels expected");
    let mut peaks: Vec<f32> =
        texels.iter().map(|t| t[0].max(t[1]).max(t[2])).map(|v| if v.is_finite() { v } else { 0.0 }).collect();
    let gain = if peaks.is_empty() {
        1.0
    } else {
        let k = ((peaks.len() - 1) as f64 * 0.99) as usize;
        let (_, p99, _) = peaks.select_nth_unstable_by(k, f32::total_cmp);
        if *p99 > 0.0 {
            (0.9 / *p99).min(16.0)
        } else {
            16.0
        }
    };
    // One lookup per 12-bit input level: the sRGB curve is the costly part otherwise.
    let lut: Vec<u8> = (0..4096)
        .map(|i| {
            let l = f64::from(i) / 4095.0;
            let v = if l <= 0.003_130_8 { 12.92 * l } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 };
            (v * 255.0).round() as u8
        })
        .collect();
    let enc = |v: f32| {
        let x = v * gain;
        let x = if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
        lut[(x * 4095.0).round() as usize]
    };
    let k = if width == 0 || height == 0 { 1 } else { min_side.div_ceil(width.min(height)).max(1) };
    let (w, h) = (width * k, height * k);
    let mut out = Vec::with_capacity(w * h * 3);
    let mut row = Vec::with_capacity(w * 3);
    for y in 0..height {
        row.clear();
        for t in &texels[y * width..(y + 1) * width] {
            let px = [enc(t[0]), enc(t[1]), enc(t[2])];
            for _ in 0..k {
                row.extend_from_slice(&px);
            }
        }
        for _ in 0..k {
            out.extend_from_slice(&row);
        }
    }
    (w, h, out)
}

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
    /// Registration failed and the plan says `on_failure = "fail"`.
    #[error("step {step}: registration failed: {reason}")]
    Registration {
        /// Which capture.
        step: StepId,
        /// Why (the registrar's error: too few markers, degenerate geometry, ...).
        reason: String,
    },
    /// The registrar could not be built from the rig's plate (e.g. an unknown dictionary).
    #[error("registration: {0}")]
    Registrar(#[from] FrameError),
    /// The dataset refused a write or commit.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The dark/flat calibration does not fit the frame (size, f-number).
    #[error("step {step}: dark/flat correction: {source}")]
    DarkFlat {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: btfrig_calib::dark_flat::DarkFlatError,
    },
    /// A dark/flat calibration given to [`Processor::with_dark_flat`] does not fit the camera.
    #[error("dark/flat calibration: {0}")]
    DarkFlatSetup(btfrig_calib::dark_flat::DarkFlatError),
    /// An HDR bracket could not be merged.
    #[error("step {step}: HDR merge: {source}")]
    Hdr {
        /// Which capture.
        step: StepId,
        /// What was wrong.
        source: btfrig_calib::hdr::HdrError,
    },
    /// The light calibration is unusable.
    #[error("light calibration: {0}")]
    Light(#[from] btfrig_calib::light::LightError),
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
    /// Where the pose comes from and what a failed registration does.
    pub registration: RegistrationPolicy,
}

/// Texel position errors of one frame's poses against its true pose (simulated rig only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseErrors {
    /// Mean and maximum over the texture's texels, texels, of the pose used.
    pub used: (f64, f64),
    /// The same for the nominal pose.
    pub nominal: (f64, f64),
}

/// One processed frame.
#[derive(Debug, Clone)]
pub struct Processed {
    /// Radiance-factor texture, row-major linear sRGB.
    pub texels: Vec<[f32; 3]>,
    /// Seconds per stage (demosaic, register, rectify, radiometry).
    pub stage_s: BTreeMap<String, f64>,
    /// Sum of squared differences to the ground truth, and of the squared truth (both over
    /// texels and channels); `None` without a truth.
    pub error: Option<(f64, f64)>,
    /// How the pose was found (`None` only for a frame that was not processed).
    pub registration: Option<StepRegistration>,
    /// Texel position errors against the truth; `None` without a truth.
    pub pose_errors: Option<PoseErrors>,
    /// As `error`, had the nominal pose been used; only with
    /// [`Processor::with_nominal_comparison`] and a truth.
    pub error_nominal: Option<(f64, f64)>,
    /// The lamp factor measured on the plate (only with [`Processor::with_light`] and drift
    /// correction, and when the plate was measurable).
    pub lamp_factor: Option<light::LampFactor>,
    /// `sum(texture) / sum(truth at the nominal lamp) - 1`; `None` without a truth.
    pub brightness_err: Option<f64>,
    /// For a merged bracket: photosites saturated in every exposure; `None` for one frame.
    pub saturated_photosites: Option<u64>,
}

impl Processed {
    fn nothing() -> Processed {
        Processed {
            texels: Vec::new(),
            stage_s: BTreeMap::new(),
            error: None,
            registration: None,
            pose_errors: None,
            error_nominal: None,
            lamp_factor: None,
            brightness_err: None,
            saturated_photosites: None,
        }
    }
}

/// Turns raw frames into textures for one rig scene.
pub struct Processor {
    scene: Arc<RigScene>,
    /// The camera model frames are registered and rectified with: the rig's calibrated one
    /// ([`Processor::with_camera`]); by default the scene's (on the simulator: the true lens).
    camera: CameraModel,
    plate: PlateConfig,
    settings: ProcessSettings,
    /// `None` when the plan asks for the nominal pose.
    registrar: Option<PlateRegistrar>,
    compare_nominal: bool,
    outputs: Outputs,
    preview: watch::Sender<Option<Arc<Preview>>>,
    preview_gate: Mutex<PreviewGate>,
    /// The measured colour calibration textures are converted with, if any.
    color: Option<Arc<color::ColorCorrection>>,
    /// Measured dark model and flats ([`Processor::with_dark_flat`]); `None`: the model's.
    dark_flat: Option<Arc<dark_flat::DarkFlat>>,
    /// The light calibration and the plate points of the drift patch.
    light: Option<(light::LightCorrection, Vec<nalgebra::Point2<f64>>)>,
    /// With HDR on: what each step's journal record says of its exposures.
    hdr: Option<HdrRecording>,
    /// Receives every committed texture ([`Processor::with_sink`]).
    sink: Option<Arc<dyn TextureSink>>,
}

/// Receives every committed texture, after its journal commit, in commit order, on a
/// blocking thread: e.g. the streaming compressor of `btfrig-compress`. It must return
/// quickly (queue the work): the pipeline waits for it.
pub trait TextureSink: Send + Sync {
    /// The texture (row-major linear RGB, `size x size`) of the committed `step`.
    fn accept(&self, step: StepId, texels: &[[f32; 3]]);
}

/// What the journal records of each step's exposures when the plan has HDR on
/// ([`Processor::with_hdr_recording`], `btfrig_store::StepHdr`).
#[derive(Debug, Clone, PartialEq)]
pub struct HdrRecording {
    /// The bracket always bracketing would take, as multipliers of the step's base exposure
    /// (first 1): the counterfactual of the report's time saved.
    pub always_stops: Vec<f64>,
}

/// When the next preview may be made.
#[derive(Debug, Default)]
struct PreviewGate {
    /// Not before this (`None`: now).
    next: Option<Instant>,
    /// A preview is being made (its cost, which sets `next`, is not known yet).
    pending: bool,
}

/// The right to make one preview; dropping it (preview written, or its step failed) releases
/// the gate with the cost measured so far.
struct PreviewClaim {
    pr: Arc<Processor>,
    started: Instant,
    cost_s: f64,
}

impl Drop for PreviewClaim {
    fn drop(&mut self) {
        let Some(ps) = self.pr.outputs.preview else { return };
        let wait = (self.cost_s / ps.max_share.max(1e-9)).max(ps.min_interval_s).clamp(0.0, 3600.0);
        let mut g = self.pr.preview_gate.lock().unwrap_or_else(|e| e.into_inner());
        g.next = Some(self.started + Duration::from_secs_f64(wait));
        g.pending = false;
    }
}

/// A claim if a preview is due now (none while another is being made, so frames processed in
/// parallel do not both make one).
fn claim_preview(pr: &Arc<Processor>) -> Option<PreviewClaim> {
    pr.outputs.preview?;
    let mut g = pr.preview_gate.lock().unwrap_or_else(|e| e.into_inner());
    let now = Instant::now();
    if g.pending || g.next.is_some_and(|t| now < t) {
        return None;
    }
    g.pending = true;
    Some(PreviewClaim { pr: pr.clone(), started: now, cost_s: 0.0 })
}

impl Processor {
    /// A processor for `scene` (rig geometry, camera model, sensor, colour) whose holder
    /// plate is `plate` (the rig config's `[plate]`, validated), writing textures only
    /// ([`Outputs::default`]). One marker registrar is built here for the whole run, with the
    /// scene's camera model and the registrar's default settings (their pose tolerance,
    /// 2 degrees / 10 mm from the nominal pose, is a real rig's, not the simulator's jitter).
    pub fn new(scene: Arc<RigScene>, plate: &PlateConfig, settings: ProcessSettings) -> Result<Self, PipelineError> {
        let registrar = match settings.registration.method {
            RegistrationMethod::Markers => {
                Some(PlateRegistrar::new(scene.camera().model().clone(), plate, RegisterOptions::default())?)
            }
            RegistrationMethod::Nominal => None,
        };
        Ok(Processor {
            camera: scene.camera().model().clone(),
            scene,
            plate: plate.clone(),
            settings,
            registrar,
            compare_nominal: false,
            outputs: Outputs::default(),
            preview: watch::Sender::new(None),
            preview_gate: Mutex::new(PreviewGate::default()),
            color: None,
            dark_flat: None,
            light: None,
            hdr: None,
            sink: None,
        })
    }

    /// The same processor handing every committed texture to `sink` (none: `None`).
    pub fn with_sink(mut self, sink: Option<Arc<dyn TextureSink>>) -> Self {
        self.sink = sink;
        self
    }

    /// The same processor registering and rectifying with `camera` (a calibration of the rig's
    /// camera, e.g. from `btfrig_calibrate::processing_camera`) instead of the scene's model;
    /// the simulator keeps rendering with the true lens, and the ground-truth figures cast
    /// pixels back with the true lens, so a calibration error shows in them.
    pub fn with_camera(mut self, camera: CameraModel) -> Result<Self, PipelineError> {
        if let Some(r) = &self.registrar {
            let mut next = PlateRegistrar::new(camera.clone(), &self.plate, r.options.clone())?;
            next.detect = btfrig_markers::DetectParams { camera: Some(camera.clone()), ..r.detect.clone() };
            self.registrar = Some(next);
        }
        self.camera = camera;
        Ok(self)
    }

    /// The same processor converting colours with a measured colour calibration (white
    /// balance, then the model) instead of the rig model's matrix (`docs/color.md`).
    pub fn with_color_correction(mut self, color: Option<color::ColorCorrection>) -> Self {
        self.color = color.map(Arc::new);
        self
    }

    /// The colour calibration in use, if any.
    pub fn color_correction(&self) -> Option<&color::ColorCorrection> {
        self.color.as_deref()
    }

    /// The same processor correcting every frame with a measured dark model and master flat
    /// ([`dark_flat`]) before demosaicing; the radiometric conversion then uses no dark current
    /// and no model vignetting. Refused if the calibration's size is not the camera's.
    pub fn with_dark_flat(mut self, cal: Arc<dark_flat::DarkFlat>) -> Result<Self, PipelineError> {
        let (w, h) = (self.camera.width, self.camera.height);
        if (cal.dark.width, cal.dark.height) != (w, h) {
            let source = btfrig_calib::dark_flat::DarkFlatError::SizeMismatch {
                got_w: w,
                got_h: h,
                cal_w: cal.dark.width,
                cal_h: cal.dark.height,
            };
            return Err(PipelineError::DarkFlatSetup(source));
        }
        self.dark_flat = Some(cal);
        Ok(self)
    }

    /// The camera model frames are registered and rectified with.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// With `on`, each frame that has a truth and was registered is also rectified with the
    /// nominal pose and compared ([`Processed::error_nominal`], [`Totals::texture_rel_rmse_nominal`]):
    /// a second rectification per frame, so off by default.
    pub fn with_nominal_comparison(mut self, on: bool) -> Self {
        self.compare_nominal = on;
        self
    }

    /// The same processor converting with a light calibration (lamp power and colour) and,
    /// if `correction.correct_drift`, correcting each frame by the lamp factor measured on
    /// the plate (see [`light`]).
    pub fn with_light(mut self, correction: light::LightCorrection) -> Result<Self, PipelineError> {
        correction.validate()?;
        let points = light::patch_points(&correction, &self.plate);
        self.light = Some((correction, points));
        Ok(self)
    }

    /// The same processor journaling each step's exposures ([`HdrRecording`]); `None`: HDR off.
    pub fn with_hdr_recording(mut self, hdr: Option<HdrRecording>) -> Self {
        self.hdr = hdr;
        self
    }

    /// What is journaled of each step's exposures, with HDR on.
    pub fn hdr_recording(&self) -> Option<&HdrRecording> {
        self.hdr.as_ref()
    }

    /// Photosites that see the sample (the footprint of its region from the nominal pose of
    /// `commanded`, `btfrig_calib::exposure::sample_footprint`) and are saturated in every one
    /// of `frames`.
    pub fn saturated_on_sample(&self, frames: &[&RawFrame], commanded: &JointState) -> u64 {
        let Some(first) = frames.first() else { return 0 };
        let fp =
            btfrig_calib::exposure::sample_footprint(&self.camera, &self.scene.pose(commanded), self.settings.region);
        if (fp.width, fp.height) != (first.width, first.height) {
            return 0;
        }
        let saturated = |i: usize| frames.iter().all(|f| f.data.get(i).is_some_and(|&v| v >= f.meta.white_level));
        fp.mask.iter().enumerate().filter(|&(i, &m)| m && saturated(i)).count() as u64
    }

    /// The light correction, if any.
    pub fn light(&self) -> Option<&light::LightCorrection> {
        self.light.as_ref().map(|(l, _)| l)
    }

    /// The same processor writing `outputs`.
    pub fn with_outputs(mut self, outputs: Outputs) -> Self {
        self.outputs = outputs;
        self
    }

    /// The settings.
    pub fn settings(&self) -> &ProcessSettings {
        &self.settings
    }

    /// What is written per frame.
    pub fn outputs(&self) -> &Outputs {
        &self.outputs
    }

    /// The latest preview, updated after each committed step that made one (`None` until the
    /// first): e.g. for an HTTP handler serving "the latest preview frame".
    pub fn subscribe_preview(&self) -> watch::Receiver<Option<Arc<Preview>>> {
        self.preview.subscribe()
    }

    /// The latest preview (see [`Processor::subscribe_preview`]).
    pub fn latest_preview(&self) -> Option<Arc<Preview>> {
        self.preview.borrow().clone()
    }

    /// The radiometric parameters of `frame` (its exposure and gain; the rig's sensor and
    /// manufacturer-style colour matrix).
    pub fn radiometry(&self, frame: &RawFrame) -> Radiometry {
        let sensor = self.scene.sensor();
        let gain = frame.meta.gain.max(1.0);
        let mut fit = self.scene.colour().colorchecker_matrix();
        if let Some(c) = &self.color {
            // The calibration's own white balance, no matrix: its model does the rest.
            fit.white_balance = c.white_balance;
            fit.matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        }
        Radiometry {
            dn_range: (f64::from(frame.meta.white_level) - f64::from(frame.meta.black_level)).max(1.0),
            exposure_s: frame.meta.exposure_s,
            dn_per_electron: sensor.dn_per_electron(gain),
            dark_e_per_s: if self.dark_flat.is_some() { 0.0 } else { sensor.dark_current_e_per_s },
            // RigScene keeps the nominal irradiance private; white_signal_dn(1 s, gain 1) is
            // nominal_irradiance * dn_per_electron(1).
            nominal_irradiance: self.scene.white_signal_dn(1.0, 1.0) / sensor.dn_per_electron(1.0),
            white_balance: fit.white_balance,
            matrix: fit.matrix,
        }
    }

    /// Ground truth of the texture region for true `joints` and `lamp_intensity`, as a
    /// radiance factor relative to the nominal lamp (what [`Processor::process`] estimates).
    /// A texel stands for its area, so the truth is the mean of `k x k` point samples of the
    /// renderer over the texel ([`area_truth_subsamples`]).
    pub fn ground_truth(&self, joints: &JointState, lamp_intensity: f64) -> Vec<[f32; 3]> {
        let r = self.settings.region;
        let region =
            btfrig_render::ground_truth::Region { x_min: r.x_min, x_max: r.x_max, y_min: r.y_min, y_max: r.y_max };
        let n = self.settings.size;
        let k = area_truth_subsamples(n);
        let truth =
            self.scene.renderer().ground_truth(&self.scene.pose(joints), n * k, n * k, Some(region)).box_average(k);
        let sensor = self.scene.sensor();
        let scale = (lamp_intensity * sensor.dn_per_electron(1.0) / self.scene.white_signal_dn(1.0, 1.0)) as f32;
        truth.data.into_iter().map(|p| p.map(|c| c * scale)).collect()
    }

    /// Demosaic, register (or take the nominal pose of `commanded`, per the plan's policy),
    /// rectify with that pose, convert to radiance factor; compare with the truth of `truth`
    /// (true joints, lamp intensity) when given.
    pub fn process(
        &self,
        step: StepId,
        frame: &RawFrame,
        commanded: &JointState,
        truth: Option<(JointState, f64)>,
    ) -> Result<Processed, PipelineError> {
        self.process_bracket(step, &[frame], commanded, truth)
    }

    /// [`Processor::process`] of an HDR bracket (`frames`: the exposures of one pose, the base
    /// exposure first): with more than one frame they are merged per photosite into signal
    /// rate (`btfrig_calib::hdr::merge_bracket`, with the measured dark model and flat if the
    /// processor has them), expressed in the base exposure's normalised DN and demosaiced; the
    /// rest is the single-frame path with the base frame's radiometry. One frame takes the
    /// single-frame path unchanged (no merge).
    pub fn process_bracket(
        &self,
        step: StepId,
        frames: &[&RawFrame],
        commanded: &JointState,
        truth: Option<(JointState, f64)>,
    ) -> Result<Processed, PipelineError> {
        let err = |source| PipelineError::Rectify { step, source };
        let Some(&frame) = frames.first() else {
            return Err(PipelineError::Hdr { step, source: btfrig_calib::hdr::HdrError::Empty });
        };
        let mut stage_s = BTreeMap::new();
        let t = Instant::now();
        let mut saturated_photosites = None;
        // For a mono sensor this only normalises to [0, 1] with equal channels.
        let dm = match (&self.dark_flat, frames.len()) {
            (_, 2..) => {
                let (dm, saturated) = self.demosaic_merged(step, frames)?;
                saturated_photosites = Some(saturated);
                dm
            }
            (Some(cal), _) => {
                dark_flat::demosaic_corrected(frame, cal).map_err(|source| PipelineError::DarkFlat { step, source })?
            }
            (None, _) => demosaic_bilinear(frame),
        };
        let image = LinearImage { width: dm.width, height: dm.height, data: dm.data };
        stage_s.insert(if frames.len() > 1 { "hdr_merge" } else { "demosaic" }.to_string(), t.elapsed().as_secs_f64());

        let nominal = self.scene.pose(commanded);
        let cam = &self.camera;
        let true_cam = self.scene.camera().model();
        let s = &self.settings;
        let (pose, registration) = match &self.registrar {
            None => (nominal, record(PoseSource::NominalByPlan)),
            Some(registrar) => {
                let t = Instant::now();
                let found = self.register(registrar, &image, &nominal);
                stage_s.insert("register".to_string(), t.elapsed().as_secs_f64());
                match found {
                    Ok(r) => r,
                    Err(reason) => match s.registration.on_failure {
                        OnRegistrationFailure::Fail => return Err(PipelineError::Registration { step, reason }),
                        OnRegistrationFailure::Nominal => {
                            (nominal, StepRegistration { reason: Some(reason), ..record(PoseSource::NominalFallback) })
                        }
                    },
                }
            }
        };

        let t = Instant::now();
        let tex = rectify(&image, cam, &pose, s.region, s.size, s.filter).map_err(err)?;
        stage_s.insert("rectify".to_string(), t.elapsed().as_secs_f64());

        let t = Instant::now();
        let mut radiometry = self.radiometry(frame);
        if saturated_photosites.is_some() {
            // The merge subtracted the dark signal.
            radiometry.dark_e_per_s = 0.0;
        }
        let mut lamp_factor = None;
        if let Some((l, points)) = &self.light {
            let d = self.scene.gonio().geometry().lamp_distance_m;
            // A frame whose plate cannot be measured keeps factor 1 (counted in the totals).
            lamp_factor = l
                .correct_drift
                .then(|| light::measure_lamp_factor(l, &image, cam, &pose, d, &radiometry, points).ok())
                .flatten();
            let factor = lamp_factor.map_or([1.0; 3], |f| f.factor);
            radiometry = l.apply(&radiometry, factor);
            if let Some(c) = &self.color {
                // The colour model was fitted to camera RGB balanced with the chart's white:
                // keep that balance, corrected by this frame's lamp factor only.
                radiometry.white_balance = std::array::from_fn(|k| c.white_balance[k] / factor[k]);
            }
        }
        let mut vig = vignetting_map(cam, &pose, s.region, s.size).map_err(err)?;
        if self.dark_flat.is_some() {
            vig = dark_flat::unit_vignetting(vig);
        }
        let mut tex = to_radiance_factor(&tex, &vig, &radiometry).map_err(err)?;
        if let Some(c) = &self.color {
            c.apply(&mut tex.data);
        }
        stage_s.insert("radiometry".to_string(), t.elapsed().as_secs_f64());

        let (mut error, mut pose_errors, mut error_nominal, mut brightness_err) = (None, None, None, None);
        if let Some((joints, lamp)) = truth {
            // Drift-corrected textures estimate the radiance factor under the calibrated
            // (nominal) lamp, the others under the lamp of the exposure.
            let gt_lamp = if self.light().is_some_and(|l| l.correct_drift) { 1.0 } else { lamp };
            let gt = self.ground_truth(&joints, gt_lamp);
            error = Some(squared_error(&tex.data, &gt));
            brightness_err = (gt_lamp > 0.0)
                .then(|| (1.0 + light::brightness_error(&tex.data, &gt)) * gt_lamp - 1.0)
                .filter(|e| e.is_finite());
            let true_pose = self.scene.pose(&joints);
            let used = texel_position_error_with_cameras(&true_pose, true_cam, &pose, cam, s.region, s.size);
            let nominal_err = if registration.pose == PoseSource::Markers {
                texel_position_error_with_cameras(&true_pose, true_cam, &nominal, cam, s.region, s.size)
            } else {
                used
            };
            pose_errors = Some(PoseErrors { used, nominal: nominal_err });
            if self.compare_nominal {
                error_nominal = if registration.pose == PoseSource::Markers {
                    let tex = rectify(&image, cam, &nominal, s.region, s.size, s.filter).map_err(err)?;
                    let mut vig = vignetting_map(cam, &nominal, s.region, s.size).map_err(err)?;
                    if self.dark_flat.is_some() {
                        vig = dark_flat::unit_vignetting(vig);
                    }
                    let mut tex = to_radiance_factor(&tex, &vig, &radiometry).map_err(err)?;
                    if let Some(c) = &self.color {
                        c.apply(&mut tex.data);
                    }
                    Some(squared_error(&tex.data, &gt))
                } else {
                    error
                };
            }
        }
        Ok(Processed {
            texels: tex.data,
            stage_s,
            error,
            registration: Some(registration),
            pose_errors,
            error_nominal,
            lamp_factor,
            brightness_err,
            saturated_photosites,
        })
    }

    /// Merges a bracket (base exposure first) and demosaics it in the base exposure's
    /// normalised DN (`(DN - dark) / (white - black)` of a frame at the base's exposure and
    /// gain, above 1 where the base saturated); also returns the photosites saturated in
    /// every exposure.
    fn demosaic_merged(
        &self,
        step: StepId,
        frames: &[&RawFrame],
    ) -> Result<(btfrig_imageio::demosaic::CameraRgbImage, u64), PipelineError> {
        use btfrig_calib::hdr::{merge_bracket, MergeOptions, NoiseModel, NominalCalibration};
        let base = frames[0];
        let sensor = self.scene.sensor();
        let noise = NoiseModel { electrons_per_dn: sensor.electrons_per_dn, read_noise_e: sensor.read_noise_e };
        let opts = MergeOptions::default();
        let hdr_err = |source| PipelineError::Hdr { step, source };
        let merged = match &self.dark_flat {
            Some(cal) => {
                let mc = cal
                    .merge_calibration(base.meta.f_number)
                    .map_err(|source| PipelineError::DarkFlat { step, source })?;
                let mut m = merge_bracket(frames, &mc, &noise, &opts).map_err(hdr_err)?;
                mc.replace_defects(&mut m.rate, base.meta.bayer.is_some());
                m
            }
            None => {
                let nominal = NominalCalibration {
                    dark_current_e_per_s: sensor.dark_current_e_per_s,
                    electrons_per_dn: sensor.electrons_per_dn,
                };
                merge_bracket(frames, &nominal, &noise, &opts).map_err(hdr_err)?
            }
        };
        let range = (f64::from(base.meta.white_level) - f64::from(base.meta.black_level)).max(1.0);
        let scale = base.meta.exposure_s * sensor.dn_per_electron(base.meta.gain.max(1.0)) / range;
        let values: Vec<f32> = merged.rate.iter().map(|&r| (f64::from(r) * scale) as f32).collect();
        let dm = btfrig_imageio::demosaic::demosaic_bilinear_values(base.width, base.height, base.meta.bayer, &values);
        Ok((dm, merged.saturated_everywhere() as u64))
    }

    /// Registers `image` (its green channel: half of a Bayer sensor's photosites) against the
    /// plate; the pose and its record, or the reason it failed.
    fn register(
        &self,
        registrar: &PlateRegistrar,
        image: &LinearImage,
        nominal: &ScenePose,
    ) -> Result<(ScenePose, StepRegistration), String> {
        let green: Vec<f32> = image.data.iter().map(|p| p[1]).collect();
        let gray = GrayImage::new(image.width, image.height, &green).map_err(|e| e.to_string())?;
        let r = registrar.register_image(&gray, nominal).map_err(|e| e.to_string())?.registration;
        let s = &self.settings;
        let sigma = r.texel_sigma(registrar.camera(), s.region, s.size);
        let rec = StepRegistration {
            markers: r.inlier_markers.clone(),
            rms_px: Some(r.rms_px),
            texel_sigma: sigma.is_finite().then_some(sigma),
            ..record(PoseSource::Markers)
        };
        Ok((r.pose, rec))
    }
}

/// A registration record with only its pose source set.
fn record(pose: PoseSource) -> StepRegistration {
    StepRegistration { pose, markers: Vec::new(), rms_px: None, texel_sigma: None, reason: None }
}

/// Sum of squared differences and of the squared truth over texels and channels.
fn squared_error(tex: &[[f32; 3]], gt: &[[f32; 3]]) -> (f64, f64) {
    let mut se = 0.0;
    let mut st = 0.0;
    for (a, b) in tex.iter().zip(gt) {
        for c in 0..3 {
            let (a, b) = (f64::from(a[c]), f64::from(b[c]));
            se += (a - b) * (a - b);
            st += b * b;
        }
    }
    (se, st)
}

/// Texel position errors summed over frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TexelErrorTotals {
    /// Frames measured (with a finite error).
    pub frames: u64,
    /// Sum of the frames' mean errors, texels.
    pub sum_mean: f64,
    /// Largest error of any texel of any frame, texels.
    pub max: f64,
}

impl TexelErrorTotals {
    /// Adds one frame's `(mean, max)`; non-finite values (no texel measurable) are left out.
    pub fn add(&mut self, (mean, max): (f64, f64)) {
        if mean.is_finite() && max.is_finite() {
            self.frames += 1;
            self.sum_mean += mean;
            self.max = self.max.max(max);
        }
    }

    /// Adds another total.
    pub fn merge(&mut self, o: &TexelErrorTotals) {
        self.frames += o.frames;
        self.sum_mean += o.sum_mean;
        self.max = self.max.max(o.max);
    }

    /// Mean over frames of the per-frame mean error (every frame has the same texels, so
    /// this is the mean over all texels), `None` without frames.
    pub fn mean(&self) -> Option<f64> {
        (self.frames > 0).then(|| self.sum_mean / self.frames as f64)
    }

    /// The largest texel error, `None` without frames.
    pub fn max(&self) -> Option<f64> {
        (self.frames > 0).then_some(self.max)
    }
}

/// Point samples per texel axis of the pipeline's area-averaged ground truth: 4 (as the
/// rectification benchmarks use) while the fine grid stays within 512 x 512, fewer for larger
/// textures (2 at 256 texels, 1 from 512 on), so the truth costs at most about as much as a
/// 512-texel point-sampled one.
pub fn area_truth_subsamples(size: usize) -> usize {
    (512 / size.max(1)).clamp(1, 4)
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
    /// Previews written (`preview.png` replaced and the in-memory preview updated).
    pub previews: u64,
    /// Previews that failed to encode or write (not fatal: a preview is not data).
    pub preview_failures: u64,
    /// Committed textures rectified with a registered pose.
    pub registered: u64,
    /// Committed textures rectified with the nominal pose because registration failed.
    pub fallbacks: u64,
    /// Committed textures rectified with the nominal pose because the plan asked for it.
    pub nominal_by_plan: u64,
    /// The fallback steps with the reason registration failed, in commit order.
    pub fallback_steps: Vec<(StepId, String)>,
    /// Texel position error of the poses used, against the truth.
    pub texel_err: TexelErrorTotals,
    /// Texel position error of the nominal poses, against the truth.
    pub nominal_texel_err: TexelErrorTotals,
    /// Sum of squared texture errors had the nominal pose been used (only with
    /// [`Processor::with_nominal_comparison`]).
    pub sq_err_nominal: f64,
    /// Sum of squared truth of the frames in `sq_err_nominal`.
    pub sq_truth_nominal: f64,
    /// Lamp factors measured on the plate and texture brightness against the truth at the
    /// nominal lamp.
    pub lamp: light::LampTotals,
}

impl Totals {
    /// `sqrt(sum sq_err / sum sq_truth)` over all compared textures, texels and channels.
    pub fn texture_rel_rmse(&self) -> Option<f64> {
        (self.sq_truth > 0.0).then(|| (self.sq_err / self.sq_truth).sqrt())
    }

    /// The same had every texture been rectified with the nominal pose (`None` unless the
    /// processor compared).
    pub fn texture_rel_rmse_nominal(&self) -> Option<f64> {
        (self.sq_truth_nominal > 0.0).then(|| (self.sq_err_nominal / self.sq_truth_nominal).sqrt())
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
                let t = truth(&f);
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

/// A preview made on a processing thread, to be written after the step's commit.
struct MadePreview {
    /// `None` if encoding failed.
    preview: Option<Preview>,
    claim: PreviewClaim,
}

fn make_preview(mut claim: PreviewClaim, step: StepId, texels: &[[f32; 3]], n: usize) -> MadePreview {
    let started = Instant::now();
    let min_side = claim.pr.outputs().preview.map_or(0, |p| p.min_side);
    let preview = (texels.len() == n * n && n > 0)
        .then(|| {
            let (width, height, rgb) = tone_map_preview(texels, n, n, min_side);
            let name = std::path::Path::new(btfrig_store::PREVIEW_FILE);
            let png = btfrig_imageio::encode_srgb8_png(name, width, height, &rgb).ok()?;
            Some(Preview { step, width, height, png })
        })
        .flatten();
    claim.cost_s += started.elapsed().as_secs_f64();
    MadePreview { preview, claim }
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}
