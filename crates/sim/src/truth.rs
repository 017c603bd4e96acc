//! The simulated gonioreflectometer's truth probe: what the pipeline's error figures are
//! measured against (`btfrig_hw::truth`). It wraps the rig's frame source, records the true
//! state behind every frame it renders (keyed by the frame's time stamp: the simulated camera
//! stamps each frame with the true state's time), and renders the sample's true appearance.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use btfrig_core::camera::CameraModel;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_core::pose::ScenePose;
use btfrig_hw::truth::{ExposureTruth, SampleRegion, TruthProbe};
use btfrig_render::rig_scene::RigScene;

use crate::{FrameSource, SensorFormat, TrueState};

/// Point samples per texel axis of the area-averaged ground truth: 4 while the fine grid
/// stays within 512 x 512, fewer for larger textures (2 at 256 texels, 1 from 512 on), so
/// the truth costs at most about as much as a 512-texel point-sampled one.
pub fn area_truth_subsamples(size: usize) -> usize {
    (512 / size.max(1)).clamp(1, 4)
}

/// A frame source that remembers the truth of each frame, and the scene that knows the rest.
pub struct SceneTruth {
    scene: Arc<RigScene>,
    inner: Arc<dyn FrameSource>,
    log: Mutex<HashMap<u64, ExposureTruth>>,
}

impl SceneTruth {
    /// The truth of `scene`, recording the frames `inner` renders (use the result as the
    /// rig camera's frame source).
    pub fn new(scene: Arc<RigScene>, inner: Arc<dyn FrameSource>) -> Self {
        SceneTruth { scene, inner, log: Mutex::new(HashMap::new()) }
    }

    /// Records the true state of the frame stamped `timestamp_s`.
    pub fn record(&self, timestamp_s: f64, truth: ExposureTruth) {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).insert(timestamp_s.to_bits(), truth);
    }

    /// The scene.
    pub fn scene(&self) -> &Arc<RigScene> {
        &self.scene
    }
}

impl FrameSource for SceneTruth {
    fn format(&self) -> SensorFormat {
        self.inner.format()
    }

    fn render(&self, truth: &TrueState, settings: &btfrig_hw::CaptureSettings, seed: u64) -> RawFrame {
        self.record(truth.time_s, ExposureTruth { joints: truth.joints, lamp_intensity: truth.lamp_intensity });
        self.inner.render(truth, settings, seed)
    }
}

impl TruthProbe for SceneTruth {
    fn take_exposure(&self, timestamp_s: f64) -> Option<ExposureTruth> {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).remove(&timestamp_s.to_bits())
    }

    fn texture(&self, joints: &JointState, lamp_intensity: f64, region: SampleRegion, size: usize) -> Vec<[f32; 3]> {
        let region = btfrig_render::ground_truth::Region {
            x_min: region.x_min,
            x_max: region.x_max,
            y_min: region.y_min,
            y_max: region.y_max,
        };
        let k = area_truth_subsamples(size);
        let scene = &self.scene;
        let truth = scene.renderer().ground_truth(&scene.pose(joints), size * k, size * k, Some(region)).box_average(k);
        let sensor = scene.sensor();
        // The renderer's ground truth is in units of the nominal irradiance's signal rate.
        let scale = (lamp_intensity * sensor.dn_per_electron(1.0) / scene.white_signal_dn(1.0, 1.0)) as f32;
        truth.data.into_iter().map(|p| p.map(|c| c * scale)).collect()
    }

    fn pose(&self, joints: &JointState) -> ScenePose {
        self.scene.pose(joints)
    }

    fn camera(&self) -> &CameraModel {
        self.scene.camera().model()
    }
}
