//! The simulator's own constants as a processing model, for tests that measure the pipeline
//! against the ground truth without calibration error (the runner loads real models from
//! calibration files: `btfrig_measurement::model`).
#![allow(dead_code)]

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::JointState;
use btfrig_hw::truth::{ExposureTruth, TruthProbe};
use btfrig_process::{ProcessSettings, ProcessingModel, Processor};
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::RenderedFrameSource;

pub use btfrig_sim_calibration::perfect::truth_model;

/// The truth probe of `scene`.
pub fn probe(scene: &Arc<RigScene>) -> Arc<SceneTruth> {
    Arc::new(SceneTruth::new(
        scene.clone(),
        Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default())),
    ))
}

/// A processor of `scene` with [`truth_model`] and its probe.
pub fn processor(cfg: &RigConfig, scene: &Arc<RigScene>, settings: ProcessSettings) -> Processor {
    processor_with(truth_model(cfg, scene), scene, settings)
}

/// A processor with `model`, measured against `scene`'s truth.
pub fn processor_with(model: ProcessingModel, scene: &Arc<RigScene>, settings: ProcessSettings) -> Processor {
    Processor::new(model, settings).unwrap().with_truth(Some(probe(scene) as Arc<dyn TruthProbe>))
}

/// Truth of an exposure at `joints` with lamp `lamp`.
pub fn at(joints: JointState, lamp: f64) -> Option<ExposureTruth> {
    Some(ExposureTruth { joints, lamp_intensity: lamp })
}

/// A probe that answers every exposure it was told of (by time stamp), as often as asked,
/// with `scene`'s truth for the rest: for tests that feed the pipeline frames they made.
pub struct KnownExposures {
    scene: Arc<SceneTruth>,
    exposures: std::collections::HashMap<u64, ExposureTruth>,
}

impl KnownExposures {
    /// Each `(time stamp, joints)` at the nominal lamp.
    pub fn new(scene: &Arc<RigScene>, frames: impl IntoIterator<Item = (f64, JointState)>) -> Self {
        let exposures = frames
            .into_iter()
            .map(|(t, joints)| (t.to_bits(), ExposureTruth { joints, lamp_intensity: 1.0 }))
            .collect();
        KnownExposures { scene: probe(scene), exposures }
    }
}

impl TruthProbe for KnownExposures {
    fn take_exposure(&self, timestamp_s: f64) -> Option<ExposureTruth> {
        self.exposures.get(&timestamp_s.to_bits()).copied()
    }

    fn texture(
        &self,
        joints: &JointState,
        lamp_intensity: f64,
        region: btfrig_hw::truth::SampleRegion,
        size: usize,
    ) -> Vec<[f32; 3]> {
        self.scene.texture(joints, lamp_intensity, region, size)
    }

    fn pose(&self, joints: &JointState) -> btfrig_core::pose::ScenePose {
        self.scene.pose(joints)
    }

    fn camera(&self) -> &btfrig_core::camera::CameraModel {
        self.scene.camera()
    }
}
