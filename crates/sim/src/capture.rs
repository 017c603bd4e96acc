//! One capture of a (light, view) pair on a simulated gonioreflectometer, through the
//! device traits only: the sequence a run engine performs, in its simplest form (no
//! retries, no overlap with the previous transfer; the run engine adds those).

use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState, Unreachable};
use btfrig_core::Direction;
use btfrig_hw::{DeviceError, MoveOptions};

use crate::{SimRig, TrueState};

/// Why a capture did not happen.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The rig cannot realise the pair.
    #[error("light ({:.1}, {:.1}) deg, view ({:.1}, {:.1}) deg: {reason}",
        .light.to_degrees().0, .light.to_degrees().1, .view.to_degrees().0, .view.to_degrees().1)]
    Unreachable {
        /// Requested light direction.
        light: Direction,
        /// Requested view direction.
        view: Direction,
        /// Why.
        reason: Unreachable,
    },
    /// A device failed.
    #[error(transparent)]
    Device(#[from] DeviceError),
}

/// What one capture produced and what really happened.
#[derive(Debug, Clone)]
pub struct Capture {
    /// The joint values the devices were told (from inverse kinematics).
    pub commanded: JointState,
    /// What was physically true during the exposure (positioning error included).
    pub truth: TrueState,
    /// The raw frame as the camera delivered it.
    pub frame: RawFrame,
    /// Rig-clock seconds the capture took: motion, exposure, read-out and transfer.
    pub hardware_s: f64,
}

/// Homes the axes and switches the lamp on, waiting for its warm-up.
pub async fn prepare(rig: &mut SimRig) -> Result<(), DeviceError> {
    let opts = MoveOptions::default();
    let (robot, rail) = tokio::join!(rig.robot.home(opts), rig.rail.home(opts));
    robot?;
    rail?;
    rig.lamp.set_on(true).await?;
    let warm_up = rig.lamp.capabilities().warm_up_s;
    rig.lamp.wait_ready(warm_up + 60.0).await?;
    Ok(())
}

/// Moves robot and rail (at the same time) to the inverse kinematics of `(light, view)`,
/// exposes for `exposure_s` and reads the frame out.
pub async fn capture_pair(
    rig: &mut SimRig,
    gonio: &Gonio,
    light: Direction,
    view: Direction,
    exposure_s: f64,
) -> Result<Capture, CaptureError> {
    let commanded = gonio.ik(light, view).map_err(|reason| CaptureError::Unreachable { light, view, reason })?;
    let clock = rig.world.clock().clone();
    let started = clock.now_s();
    let opts = MoveOptions::default();
    let (robot, rail) =
        tokio::join!(rig.robot.move_to_rad(commanded.robot, opts), rig.rail.move_to_rad(commanded.rail, opts));
    robot?;
    rail?;
    if rig.camera.settings().exposure_s != exposure_s {
        rig.camera.set_exposure_s(exposure_s).await?;
    }
    let frame = rig.camera.capture(60.0 + exposure_s).await?;
    let truth = rig.world.truth();
    Ok(Capture { commanded, truth, frame, hardware_s: clock.now_s() - started })
}
