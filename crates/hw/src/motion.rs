//! Moving devices: the robot that orients the sample, the camera rail, the turntable.
//!
//! Every move returns once the axis has *settled* at its target (not when the command was
//! accepted), or fails after [`MoveOptions::timeout_s`]. Angles are radians throughout; the
//! method and field names say so.

use async_trait::async_trait;

use crate::{Device, DeviceError};

/// Options of one move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveOptions {
    /// Longest time the call may take, from command to settled, seconds. If the device has
    /// not settled by then the call fails with [`crate::ErrorKind::Timeout`]; the axis may
    /// still be moving and report [`crate::ErrorKind::Busy`] until it stops.
    pub timeout_s: f64,
}

impl MoveOptions {
    /// Options with the given timeout, seconds.
    pub const fn with_timeout_s(timeout_s: f64) -> Self {
        MoveOptions { timeout_s }
    }
}

impl Default for MoveOptions {
    /// 60 s: longer than any full-range move of the Bonn-like rig (about 15 s).
    fn default() -> Self {
        MoveOptions { timeout_s: 60.0 }
    }
}

/// Travel limits and speed of one rotary axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisLimits {
    /// Lowest reachable angle, radians.
    pub min_rad: f64,
    /// Highest reachable angle, radians.
    pub max_rad: f64,
    /// Top speed, radians per second.
    pub max_speed_rad_per_s: f64,
}

impl AxisLimits {
    /// Whether `angle_rad` lies within `[min_rad, max_rad]`.
    pub fn contains(&self, angle_rad: f64) -> bool {
        angle_rad >= self.min_rad && angle_rad <= self.max_rad
    }
}

/// The robot that holds and orients the sample: three rotary joints.
/// The meaning of each joint is documented in `docs/kinematics.md`.
#[async_trait]
pub trait Robot: Device {
    /// Limits of the three joints.
    fn joint_limits(&self) -> [AxisLimits; 3];

    /// Finds the reference position of every joint; needed once after power-up before any
    /// move (otherwise moves fail with [`crate::ErrorKind::NotHomed`]).
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError>;

    /// Moves all joints to `joints_rad` and returns when settled, with the position the
    /// controller then reports.
    async fn move_to_rad(&mut self, joints_rad: [f64; 3], opts: MoveOptions) -> Result<[f64; 3], DeviceError>;

    /// The joint position the controller reports (its encoders), radians.
    async fn position_rad(&mut self) -> Result<[f64; 3], DeviceError>;

    /// Whether the robot has been homed. Default: asks for the position and treats
    /// [`crate::ErrorKind::NotHomed`] as `false`.
    async fn is_homed(&mut self) -> Result<bool, DeviceError> {
        match self.position_rad().await {
            Ok(_) => Ok(true),
            Err(e) if e.kind() == crate::ErrorKind::NotHomed => Ok(false),
            Err(e) => Err(e),
        }
    }

    /// Stops any motion at once. Default: nothing to stop (moves are complete when they return).
    async fn stop(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }
}

/// The rail that carries the camera around the sample. Its angle is the angle between lamp
/// and camera as seen from the sample.
#[async_trait]
pub trait Rail: Device {
    /// Travel limits and speed.
    fn limits(&self) -> AxisLimits;

    /// Finds the reference position; needed once before any move.
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError>;

    /// Moves to `angle_rad` and returns when settled, with the reported angle.
    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError>;

    /// The angle the controller reports, radians.
    async fn position_rad(&mut self) -> Result<f64, DeviceError>;

    /// Stops any motion at once. Default: nothing to stop.
    async fn stop(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }
}

/// A turntable that rotates the sample about its normal.
#[async_trait]
pub trait Turntable: Device {
    /// Travel limits and speed (a table without end stops reports a wide range).
    fn limits(&self) -> AxisLimits;

    /// Finds the reference position; needed once before any move.
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError>;

    /// Turns to `angle_rad` and returns when settled, with the reported angle.
    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError>;

    /// The angle the controller reports, radians.
    async fn position_rad(&mut self) -> Result<f64, DeviceError>;

    /// Stops any motion at once. Default: nothing to stop.
    async fn stop(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }
}
