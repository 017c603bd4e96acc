//! Gonioreflectometer kinematics. (Skeleton: the kinematics owner fills this in.)

use serde::{Deserialize, Serialize};

/// Joint values of a gonioreflectometer, radians. The meaning of each robot joint is
/// documented in `docs/kinematics.md`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Rail angle: the angle between lamp and camera as seen from the sample.
    pub rail: f64,
    /// The robot's three joint angles that orient the sample.
    pub robot: [f64; 3],
    /// Turntable angle (0 when the rig has none).
    pub turntable: f64,
}
