//! The geometric targets on the simulated rig: calibration board, colour chart.

use btfrig_measurement::backend::{CalibrationOpenRequest, OpenedRig};
use btfrig_measurement::RunError;

/// Board and colour chart.
pub(super) async fn open_geometric(req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
    Err(RunError::Rig(format!("the simulated rig cannot mount a {} yet", req.target.name())))
}
