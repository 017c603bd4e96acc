//! A simulated gonioreflectometer ready to capture: the rig's physics, its devices on a
//! virtual clock, and the runtime that drives them.

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_hw::TokioClock;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::{FaultScenario, RenderedFrameSource, SimRig};

/// A current-thread tokio runtime on paused (virtual) time: simulated hardware time passes
/// instantly, and rendering parallelises inside rayon.
pub fn virtual_time_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread().enable_time().start_paused(true).build()?)
}

/// The physics and the devices of one simulated rig.
pub struct Session {
    /// The rig's physics (for ground truth and previews).
    pub scene: Arc<RigScene>,
    /// The camera's frame source (for the renderer's statistics).
    pub source: Arc<RenderedFrameSource>,
    /// The devices.
    pub rig: SimRig,
}

/// Builds a session; call inside the runtime that will drive it (the clock belongs to it).
pub fn build(cfg: &RigConfig, material: &MaterialSpec, faults: &FaultScenario) -> anyhow::Result<Session> {
    let scene = Arc::new(RigScene::new(cfg, material)?);
    let source = Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default()));
    let rig = SimRig::from_rig_config(cfg, faults, TokioClock::shared(), source.clone())?;
    Ok(Session { scene, source, rig })
}
