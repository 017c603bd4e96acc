//! What really happened at the devices, for the error figures of a report only.
//!
//! A simulated rig knows the true state behind every frame (the joints the robot really
//! reached, the lamp's real output, the sample's true appearance); a real rig does not. A
//! backend that knows offers it as a [`TruthProbe`], which a run hands to the processing
//! pipeline next to, never inside, its processing model: processing is a function of frames,
//! the rig config and calibration files, and the probe is consulted only to measure how far
//! its results are from the truth. A real rig's run has no probe and its report no truth
//! figures.

use btfrig_core::camera::CameraModel;
use btfrig_core::kinematics::JointState;
use btfrig_core::pose::ScenePose;

/// The true state at one exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExposureTruth {
    /// The joints the devices really stood at.
    pub joints: JointState,
    /// The lamp's real output relative to its nominal output.
    pub lamp_intensity: f64,
}

/// A rectangle of the sample plane, metres (the texture's region).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleRegion {
    /// Left edge (column 0 lies along it).
    pub x_min: f64,
    /// Right edge.
    pub x_max: f64,
    /// Bottom edge.
    pub y_min: f64,
    /// Top edge (row 0 lies along it).
    pub y_max: f64,
}

/// The truth behind a simulated rig's frames (see the module documentation).
pub trait TruthProbe: Send + Sync {
    /// Takes the true state of the exposure whose frame is stamped `timestamp_s` (each
    /// exposure is answered once; `None` if the probe never saw it).
    fn take_exposure(&self, timestamp_s: f64) -> Option<ExposureTruth>;

    /// The sample's true radiance factor over `region` (`size x size` texels, row-major,
    /// linear sRGB, row 0 along `y_max`), relative to the nominal lamp times
    /// `lamp_intensity`, each texel the mean over its area, as seen from the pose of `joints`.
    fn texture(&self, joints: &JointState, lamp_intensity: f64, region: SampleRegion, size: usize) -> Vec<[f32; 3]>;

    /// The true scene pose at `joints`.
    fn pose(&self, joints: &JointState) -> ScenePose;

    /// The camera's true lens.
    fn camera(&self) -> &CameraModel;
}

/// The truth behind a simulated dome's or camera array's frames (see the module
/// documentation): what a dome run's report measures its textures and its multiplexing gain
/// against. A light is an LED (a camera array's: a flash); a camera is an index into the
/// rig's cameras (`[dome]`), not into the plan's.
pub trait DomeTruthProbe: Send + Sync {
    /// The sample's true texture seen by camera `camera` at turntable angle `turntable_rad`
    /// under light `light` alone at its nominal power: `size x size` texels, row-major,
    /// radiance factor in the pipeline's colour space, as the dome pipeline's textures are.
    fn texture(&self, camera: usize, turntable_rad: f64, light: usize, size: usize) -> Vec<[f32; 3]>;

    /// The noise-free signal of every photosite of camera `camera` (DN above the black and
    /// dark level, before rounding) with the lights at intensities `lights` (1: full power),
    /// exposed `exposure_s` at `gain`: the reference the measured noise is the difference from.
    fn noise_free_dn(&self, camera: usize, turntable_rad: f64, lights: &[f64], exposure_s: f64, gain: f64) -> Vec<f32>;

    /// Lights the rig really held on whatever was asked (stuck on): every frame saw them.
    fn stuck_on(&self) -> Vec<usize>;
    /// The turntable's true angle, radians, at the exposure of camera `camera`'s frame
    /// stamped `timestamp_s` (`None` if the probe never saw that frame).
    fn true_turntable(&self, camera: usize, timestamp_s: f64) -> Option<f64>;
    /// The true scene pose of camera `camera` with the turntable truly at `turntable_rad`.
    fn pose(&self, camera: usize, turntable_rad: f64) -> ScenePose;
    /// The cameras' true lens.
    fn camera(&self) -> &CameraModel;
}
