//! The exposure control of a run with HDR on (`docs/hdr.md`): the engine's
//! [`ExposureControl`] built from the plan's `[exposure]`, and the report's HDR figures read
//! back from the journal.
//!
//! Per step: the base exposure is predicted from the last capture of the same view (its
//! metered base, scaled by the ratio of the lamp's cosine at the sample between the two
//! lights; the first capture of a view takes the plan's white-reference exposure), at most
//! three stops shorter than the white-reference exposure and never longer (the holder plate
//! and its markers must not saturate in the base). The engine takes it, and the frame is metered
//! on the sample's footprint (`btfrig_imaging::exposure`) when it arrives; the adaptive policy
//! asks for shorter exposures while the sample saturates and longer ones while it is
//! underexposed, up to `max_exposures`. With `mode = "bracket"` every step takes the base
//! times the plan's stops, metered only to predict the next base.

use std::collections::{BTreeMap, HashMap, VecDeque};

use btfrig_acquire::{EngineStep, ExposureControl};
use btfrig_core::camera::CameraModel;
use btfrig_core::capture::StepKey;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::plan::{HdrMode, HdrSettings};
use btfrig_imaging::exposure::{meter, sample_footprint, BracketMode, Footprint, HdrPolicy, MeterLevels, Metering};
use btfrig_imaging::hdr::{NoiseModel, NominalCalibration};
use btfrig_imaging::Region;
use btfrig_store::Dataset;
use serde_json::json;

/// Footprints and meterings kept for the steps in flight (the engine inspects a step while
/// planning the next one).
const STEPS_KEPT: usize = 4;

/// The base exposure may be this many stops (factor 2 each) shorter than the white reference.
const BASE_STOPS: i32 = 3;

/// The multipliers of the base exposure that always bracketing takes: the plan's stops, or for
/// adaptive HDR `max_exposures` exposures `stop_ratio` apart, shortest last.
pub(crate) fn always_stops(hdr: &HdrSettings) -> Vec<f64> {
    match &hdr.mode {
        HdrMode::Always(stops) => stops.clone(),
        HdrMode::Off => vec![1.0],
        HdrMode::Adaptive => (0..hdr.max_exposures).map(|k| hdr.stop_ratio.powi(k as i32)).collect(),
    }
}

/// What the exposure control needs to know of the rig.
pub(crate) struct HdrRig {
    /// The camera model frames are processed with (footprints are projected through it).
    pub camera: CameraModel,
    /// Nominal poses of the steps.
    pub gonio: Gonio,
    /// The texture's region of the sample plane.
    pub region: Region,
    /// The sensor's noise and dark model (metering rates).
    pub noise: NoiseModel,
    pub nominal: NominalCalibration,
    /// The camera's exposure range, seconds.
    pub exposure_range_s: (f64, f64),
}

/// The engine's exposure control for a plan with HDR on.
pub(crate) struct HdrControl {
    policy: HdrPolicy,
    rig: HdrRig,
    /// The plan's white-reference exposure: the first guess at a view.
    reference_s: f64,
    /// Cosine of each step's light zenith angle (sample frame).
    light_cos: HashMap<StepKey, f64>,
    /// Per view: the last metered base exposure times its light's cosine.
    base_by_view: HashMap<u32, f64>,
    /// Footprint and meterings of the steps in flight, oldest first.
    steps: VecDeque<InFlight>,
}

/// A step whose frames are being inspected: its footprint and the meterings of its frames.
struct InFlight {
    key: StepKey,
    footprint: Footprint,
    /// `(exposure_s, metering)` per frame metered so far, in the order taken.
    taken: Vec<(f64, Metering)>,
}

impl HdrControl {
    /// The control for `hdr` (not off) whose first guess at every view is `reference_s`;
    /// `light_cos` gives each step's light cosine.
    pub(crate) fn new(hdr: &HdrSettings, rig: HdrRig, reference_s: f64, light_cos: HashMap<StepKey, f64>) -> Self {
        let mode = match &hdr.mode {
            HdrMode::Off => BracketMode::Off,
            HdrMode::Adaptive => BracketMode::Adaptive,
            HdrMode::Always(stops) => BracketMode::Always(stops.clone()),
        };
        let policy = HdrPolicy {
            mode,
            max_exposures: hdr.max_exposures as usize,
            stop_ratio: hdr.stop_ratio,
            saturated_max_fraction: hdr.saturated_max_fraction,
            dark_max_fraction: hdr.dark_max_fraction,
            meter_quantile: 0.99,
            target_fraction: 0.6,
            exposure_range_s: rig.exposure_range_s,
            levels: MeterLevels::default(),
        };
        HdrControl { policy, rig, reference_s, light_cos, base_by_view: HashMap::new(), steps: VecDeque::new() }
    }

    fn clamp(&self, t: f64) -> f64 {
        let (lo, hi) = self.rig.exposure_range_s;
        t.clamp(lo, hi)
    }

    fn base_for(&self, key: StepKey) -> f64 {
        let cos = self.light_cos.get(&key).copied().unwrap_or(1.0).max(0.05);
        let span = 2f64.powi(BASE_STOPS);
        let predicted = self.base_by_view.get(&key.view).map_or(self.reference_s, |b| b / cos);
        // Never longer than the white reference: the holder plate (registration, the lamp's
        // drift patch) and the markers must not saturate in the base exposure, and the
        // metering sees only the sample. A dim sample gets longer exposures in its bracket.
        self.clamp(predicted.clamp(self.reference_s / span, self.reference_s))
    }
}

/// The footprint and meterings of `step`, made on first use (the oldest kept step dropped).
fn entry<'a>(
    steps: &'a mut VecDeque<InFlight>,
    rig: &HdrRig,
    step: &EngineStep,
    joints: &JointState,
) -> &'a mut InFlight {
    let key = step.key;
    let i = match steps.iter().position(|s| s.key == key) {
        Some(i) => i,
        None => {
            if steps.len() >= STEPS_KEPT {
                steps.pop_front();
            }
            let pose = rig.gonio.scene_pose(joints);
            steps.push_back(InFlight {
                key,
                footprint: sample_footprint(&rig.camera, &pose, rig.region),
                taken: Vec::new(),
            });
            steps.len() - 1
        }
    };
    &mut steps[i]
}

impl ExposureControl for HdrControl {
    fn planned(&mut self, step: &EngineStep) -> Vec<f64> {
        let base = self.base_for(step.key);
        match &self.policy.mode {
            BracketMode::Always(stops) => stops.iter().map(|k| self.clamp(base * k)).collect(),
            _ => vec![base],
        }
    }

    fn inspects(&self) -> bool {
        true
    }

    fn next(&mut self, step: &EngineStep, frames: &[RawFrame]) -> Option<f64> {
        // Brackets are a gonio's (`Engine::spawn_with_exposure` takes gonio devices).
        let joints = step.joints()?;
        let rig = &self.rig;
        let InFlight { footprint: fp, taken, .. } = entry(&mut self.steps, rig, step, &joints);
        for f in &frames[taken.len().min(frames.len())..] {
            // A frame that cannot be metered (size or metadata) ends the bracket: the pipeline
            // reports the frame's own problem.
            let m = meter(f, fp, &rig.nominal, &rig.noise, &self.policy.levels).ok()?;
            taken.push((f.meta.exposure_s, m));
        }
        if let Some((t0, m0)) = taken.first() {
            let cos = self.light_cos.get(&step.key).copied().unwrap_or(1.0).max(0.05);
            self.base_by_view.insert(step.key.view, self.policy.base_exposure(m0, *t0) * cos);
        }
        let next = match self.policy.mode {
            BracketMode::Adaptive => self.policy.next_exposure(taken),
            _ => None,
        };
        if next.is_none() {
            self.steps.retain(|s| s.key != step.key);
        }
        next
    }
}

/// The HDR figures of every journaled capture: counts by exposures, time the brackets took,
/// the time saved against always bracketing, photosites saturated in every exposure.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HdrFigures {
    /// Captures by number of exposures (`exposures_per_capture`).
    pub exposures_per_capture: BTreeMap<usize, u64>,
    /// Rig time the exposures beyond the first took, return trips included, seconds.
    pub bracket_s: f64,
    /// Always bracketing's time minus the policy's, seconds (`hdr_time_saved_s`).
    pub time_saved_s: f64,
    /// Photosites on the sample saturated in every exposure, summed over captures.
    pub saturated_photosites: u64,
    /// Captures with such photosites.
    pub captures_with_saturation: u64,
}

impl HdrFigures {
    /// The figures as report and summary JSON.
    pub fn to_json(&self) -> serde_json::Value {
        json!({
            "exposures_per_capture": self.exposures_per_capture.iter().map(|(k, v)| (k.to_string(), *v)).collect::<BTreeMap<String, u64>>(),
            "hdr_bracket_s": self.bracket_s,
            "hdr_time_saved_s": self.time_saved_s,
            "hdr_saturated_photosites": self.saturated_photosites,
            "hdr_captures_with_saturation": self.captures_with_saturation,
        })
    }
}

/// The figures from the journal; `None` when no capture has an HDR record. Always bracketing
/// would take each of its further exposures at the pose: its own time plus
/// `per_exposure_overhead_s` (command, trigger latency, read-out, transfer); the policy's
/// brackets cost what the engine measured (`bracket_s`).
pub fn journal_hdr(dataset: &Dataset, per_exposure_overhead_s: f64) -> Option<HdrFigures> {
    let mut out = HdrFigures::default();
    let mut any = false;
    for step in dataset.completed() {
        let Some(h) = dataset.step_record(step).and_then(|r| r.hdr) else { continue };
        any = true;
        *out.exposures_per_capture.entry(h.exposures_s.len()).or_default() += 1;
        out.bracket_s += h.bracket_s;
        let always: f64 = h.always_s.iter().skip(1).map(|t| t + per_exposure_overhead_s).sum();
        out.time_saved_s += always - h.bracket_s;
        out.saturated_photosites += h.saturated_photosites;
        out.captures_with_saturation += u64::from(h.saturated_photosites > 0);
    }
    any.then_some(out)
}
