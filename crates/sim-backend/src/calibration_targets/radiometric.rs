//! The radiometric targets on the simulated rig: white tile, uniform field, lens cap.

use btfrig_measurement::backend::{CalibrationOpenRequest, OpenedRig};
use btfrig_measurement::RunError;

/// White tile, uniform field, lens cap.
pub(super) async fn open_radiometric(req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
    Err(RunError::Rig(format!("the simulated rig cannot mount a {} yet", req.target.name())))
}
