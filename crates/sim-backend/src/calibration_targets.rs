//! The simulated rig with a calibration target mounted (`RigBackend::open_calibration`):
//! the devices of a run, whose camera sees the target instead of a sample.
//!
//! Two halves, one per kind of target: the geometric ones (board, colour chart, bare marker plate) and the
//! radiometric ones (white tile, uniform field, lens cap).

use std::sync::Arc;

use btfrig_hw::truth::TruthProbe;
use btfrig_measurement::backend::{CalibrationOpenRequest, InProcess, MountedTarget, OpenedGonio, OpenedRig};
use btfrig_measurement::RunError;
use btfrig_sim::SimRig;

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

/// A simulated gonioreflectometer's devices as a calibration's opened rig.
fn opened_gonio(sim: SimRig, truth: Option<Arc<dyn TruthProbe>>) -> OpenedRig {
    let clock = sim.world.clock().clone();
    let SimRig { robot, rail, lamp, camera, .. } = sim;
    OpenedRig::Gonio(OpenedGonio { robot, rail, lamp, camera, clock, truth, links: Box::new(InProcess) })
}
