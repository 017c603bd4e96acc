//! The simulated rig with a calibration target mounted (`RigBackend::open_calibration`):
//! the devices of a run, whose camera sees the target instead of a sample.
//!
//! Two halves, one per kind of target: the geometric ones (board, colour chart, bare marker plate) and the
//! radiometric ones (white tile, uniform field, lens cap).

use btfrig_measurement::backend::{CalibrationOpenRequest, MountedTarget, OpenedRig};
use btfrig_measurement::RunError;

mod geometric;
mod radiometric;

use geometric::open_geometric;
use radiometric::open_radiometric;

/// Opens the simulated rig of `req` with its target mounted.
pub(crate) async fn open(req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
    match req.target {
        MountedTarget::Board(_) | MountedTarget::ColorChart { .. } | MountedTarget::Plate => open_geometric(req).await,
        MountedTarget::WhiteTile { .. } | MountedTarget::UniformField | MountedTarget::Capped => {
            open_radiometric(req).await
        }
        other => Err(RunError::Rig(format!("the simulated rig cannot mount a {}", other.name()))),
    }
}
