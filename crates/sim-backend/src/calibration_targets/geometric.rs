//! The geometric targets on the simulated rig: calibration board, colour chart, bare marker
//! plate. The devices are a run's (robot, rail, lamp, camera on the request's clock, the rig
//! config's positioning error); only the scene in the sample's place differs. The truth
//! probe (true lens, true poses) is for the calibration commands' error figures only.

use std::sync::Arc;

use btfrig_measurement::backend::{CalibrationOpenRequest, MountedTarget, OpenedRig};
use btfrig_measurement::RunError;
use btfrig_render::chart::ColorChart;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::{FaultScenario, RenderedFrameSource, SimRig};

/// Rays per pixel side at marker edges when the board is mounted: a board frame is mostly
/// edges, and the corner positions a calibration fits must not carry the renderer's aliasing.
const BOARD_MARKER_SUPERSAMPLING: u32 = 8;

/// Board, colour chart and bare plate.
pub(super) async fn open_geometric(req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
    let mut rig = req.rig.clone();
    if rig.dome.is_some() {
        return Err(RunError::Rig(format!(
            "the simulated rig mounts a {} on gonioreflectometers only; {} is a dome or camera array",
            req.target.name(),
            rig.rig.name
        )));
    }
    // The request's seed drives the devices' positioning error and the sensor noise.
    rig.rig.seed = req.seed;
    let bad = |e: String| RunError::Input { what: format!("mounting the {}", req.target.name()), message: e };
    let (scene, options) = match req.target {
        MountedTarget::Board(board) => (
            RigScene::with_target(&rig, board).map_err(|e| bad(e.to_string()))?,
            RenderOptions { marker_supersampling: BOARD_MARKER_SUPERSAMPLING, ..RenderOptions::default() },
        ),
        MountedTarget::ColorChart { chart } => {
            let chart = ColorChart::by_name(chart).map_err(bad)?;
            (RigScene::with_chart(&rig, &chart).map_err(|e| bad(e.to_string()))?, RenderOptions::default())
        }
        MountedTarget::Plate => {
            // The holder plate with its markers; the sample on it does not matter to them.
            let material = crate::load_material(Some("lacquered-wood"))?;
            (RigScene::new(&rig, &material).map_err(|e| bad(e.to_string()))?, RenderOptions::default())
        }
        other => return Err(RunError::Rig(format!("not a geometric target: {}", other.name()))),
    };
    let scene = Arc::new(scene);
    let source = Arc::new(RenderedFrameSource::new(scene.clone(), options));
    let truth = Arc::new(SceneTruth::new(scene, source));
    let sim = SimRig::from_rig_config(&rig, &FaultScenario::none(), crate::clock_for(req.time), truth.clone())
        .map_err(|e| RunError::Rig(e.to_string()))?;
    Ok(super::opened_gonio(sim, Some(truth)))
}
