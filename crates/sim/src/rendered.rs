//! The frame source of a simulated rig that renders what its camera sees: the true joint
//! state through the rig's kinematics into a scene pose, the physically based renderer,
//! and the sensor model (`btfrig-render`).

use std::sync::Mutex;

use btfrig_core::frame::RawFrame;
use btfrig_hw::CaptureSettings;
use btfrig_render::renderer::{RenderOptions, RenderStats};
use btfrig_render::rig_scene::RigScene;
use btfrig_render::sensor::SensorModel;

use crate::{FrameSource, SensorFormat, TrueState};

/// Renders frames of a [`RigScene`] and keeps running totals of the renderer's work, so a
/// run can report what the renderer skipped.
pub struct RenderedFrameSource {
    scene: std::sync::Arc<RigScene>,
    options: RenderOptions,
    totals: Mutex<(u64, RenderStats)>,
}

impl RenderedFrameSource {
    /// A source for `scene`, rendering with `options` (skips on by default).
    pub fn new(scene: std::sync::Arc<RigScene>, options: RenderOptions) -> Self {
        RenderedFrameSource { scene, options, totals: Mutex::new((0, RenderStats::default())) }
    }

    /// The scene (for ground truth of the same true state).
    pub fn scene(&self) -> &RigScene {
        &self.scene
    }

    /// Frames rendered so far and the renderer's summed statistics.
    pub fn totals(&self) -> (u64, RenderStats) {
        *self.totals.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The frame layout of a rendered camera: its lens's image size and its sensor's format.
pub(crate) fn sensor_format(cam: &btfrig_core::camera::CameraModel, sensor: &SensorModel) -> SensorFormat {
    SensorFormat {
        width: cam.width,
        height: cam.height,
        bit_depth: sensor.bit_depth,
        bayer: sensor.bayer,
        black_level: sensor.black_level_dn,
        white_level: sensor.white_level(1.0),
    }
}

/// Exposure and gain clamped into the sensor model's ranges. The camera device has already
/// checked the settings against its own ranges; a device range wider than the sensor's
/// must not make rendering fail half-way through a run.
pub(crate) fn sensor_settings(sensor: &SensorModel, settings: &CaptureSettings) -> (f64, f64) {
    (settings.exposure_s.clamp(0.0, 3600.0), settings.gain.clamp(1.0, sensor.max_analogue_gain))
}

impl FrameSource for RenderedFrameSource {
    fn format(&self) -> SensorFormat {
        sensor_format(self.scene.camera().model(), self.scene.sensor())
    }

    fn render(&self, truth: &TrueState, settings: &CaptureSettings, seed: u64) -> RawFrame {
        let (exposure_s, gain) = sensor_settings(self.scene.sensor(), settings);
        let (frame, stats) = self
            .scene
            .capture(&truth.joints, truth.lamp_intensity, exposure_s, gain, seed, &self.options)
            .expect("exposure and gain were clamped into the sensor's ranges");
        let mut totals = self.totals.lock().unwrap_or_else(|e| e.into_inner());
        totals.0 += 1;
        totals.1 += stats;
        frame
    }
}
