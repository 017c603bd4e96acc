//! The simulated rig's side of the calibration procedures.
//!
//! `btfrig-calibrate` holds each procedure's numerics and file format and works on frames,
//! whoever made them; this crate makes those frames on the simulated rig (true lens, lamp,
//! LEDs and sensor, seeded noise) and may read the simulator's truth to report how far a
//! calibration is from it. Processing crates never depend on it.
#![warn(missing_docs)]

// The files, one job each:
// - color, dark_flat, light, leds: each calibration's frames made on the simulated rig
// - perfect: the processing model of a perfect calibration
// - sensor: the true EMVA 1288 figures of the simulated sensor

pub mod color;
pub mod dark_flat;
pub mod light;
pub mod perfect;
pub mod sensor;

use std::time::Instant;

use btfrig_calibrate::{
    calibrate_captures, plan_captures, BoardCaptures, CalibrationPlan, RigCalibError, RigCalibration,
};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

/// A geometric calibration on the simulated rig with the truth it is measured against.
#[derive(Debug, Clone)]
pub struct SimRigCalibration {
    /// What `btfrig_calibrate::calibrate_captures` made of the rendered frames.
    pub result: RigCalibration,
    /// The true camera of the simulated rig (the rig config's own `[camera]` fields, which
    /// the renderer images with).
    pub truth: CameraModel,
}

/// Runs `plan` on the simulated rig `cfg`: renders every capture with the rig's true lens
/// and sensor noise seeded from `seed` and the view index ([`capture_simulated`]), then
/// detects the board and calibrates (`btfrig_calibrate::calibrate_captures`). `progress`
/// receives one line per stage.
pub fn calibrate_simulated(
    cfg: &RigConfig,
    plan: &CalibrationPlan,
    seed: u64,
    mut progress: impl FnMut(&str),
) -> Result<SimRigCalibration, RigCalibError> {
    let shots = capture_simulated(cfg, plan, seed)?;
    progress(&format!("captured {} views in {:.1} s", shots.frames.iter().flatten().count(), shots.render_s));
    let result = calibrate_captures(cfg, plan, &shots, progress)?;
    let truth = RigScene::with_target(cfg, &plan.target)
        .map_err(|e| RigCalibError::Rig(e.to_string()))?
        .camera()
        .model()
        .clone();
    Ok(SimRigCalibration { result, truth })
}

/// Renders the plan's captures on the simulated rig (kept as raw frames: half the memory of a
/// float image): the board lit by the lamp at the plan's exposure, sensor noise seeded from
/// `seed` and the view index.
pub fn capture_simulated(cfg: &RigConfig, plan: &CalibrationPlan, seed: u64) -> Result<BoardCaptures, RigCalibError> {
    let captures = plan_captures(cfg, plan)?;
    let scene = RigScene::with_target(cfg, &plan.target).map_err(|e| RigCalibError::Rig(e.to_string()))?;
    let exposure = scene.exposure_for_white(plan.exposure_fraction, 1e-4, 30.0);
    let opts = RenderOptions { marker_supersampling: plan.marker_supersampling, ..RenderOptions::default() };
    let t = Instant::now();
    let mut frames = Vec::with_capacity(captures.len());
    for (i, cap) in captures.iter().enumerate() {
        if cap.skipped.is_some() {
            frames.push(None);
            continue;
        }
        let s = seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let (raw, _) = scene
            .capture(&cap.joints, 1.0, exposure, 1.0, s, &opts)
            .map_err(|e| RigCalibError::Rig(format!("capture of view {i}: {e}")))?;
        frames.push(Some(raw));
    }
    let render_s = t.elapsed().as_secs_f64();
    Ok(BoardCaptures { frames, captures, render_s })
}
pub mod leds;
