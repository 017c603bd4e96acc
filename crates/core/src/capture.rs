//! A capture as the run engine delivers it: which step it is, its raw frames, the commanded
//! joints and when each part happened. Plain data, so the stage pipeline reads captures
//! without depending on the device-owning engine (and a reprocess builds them from a dataset).

use std::fmt;

use crate::frame::RawFrame;
use crate::kinematics::JointState;

/// Identifies a capture: its light and view indices (as `btfrig_store::StepId`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StepKey {
    /// Index into the light sampling.
    pub light: u32,
    /// Index into the view sampling.
    pub view: u32,
}

impl fmt::Display for StepKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "light {}, view {}", self.light, self.view)
    }
}

/// When the parts of one step happened, seconds on the rig clock.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepTimes {
    /// Move to this step's pose started (last attempt).
    pub move_start_s: f64,
    /// Both devices settled.
    pub move_end_s: f64,
    /// Trigger sent (last attempt).
    pub trigger_start_s: f64,
    /// Exposure and sensor read-out done.
    pub trigger_end_s: f64,
    /// Frame on the host.
    pub transfer_end_s: f64,
    /// Rig time the step's exposures beyond the first took: their triggers and read-outs, and
    /// the return trips to the step's pose for exposures asked for after inspection, seconds
    /// (0 for one exposure).
    pub bracket_s: f64,
}

/// A frame the run engine (`btfrig_acquire::Engine::spawn`) delivers, exactly once per step.
#[derive(Debug, Clone)]
pub struct CapturedFrame {
    /// Position of the step in the schedule given to the engine.
    pub index: usize,
    /// Which capture.
    pub key: StepKey,
    /// The raw frame with its metadata: the step's first (base) exposure.
    pub frame: RawFrame,
    /// The step's further exposures, in the order taken (empty for one exposure): an HDR
    /// bracket of the same pose (`btfrig_acquire::ExposureControl`).
    pub bracket: Vec<RawFrame>,
    /// 1 + retries spent on this step (any operation).
    pub attempts: u32,
    /// The joint state the devices were commanded to.
    pub joints: JointState,
    /// Hardware time stamps.
    pub times: StepTimes,
}
