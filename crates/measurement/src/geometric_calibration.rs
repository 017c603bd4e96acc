//! Geometric camera calibration through the devices (`btfrig calibrate geometry`): the board
//! mounted in the sample's place, the robot presents it in each view of the plan
//! ([`btfrig_calibrate::plan_captures`]: nominal kinematics), the camera captures, and the
//! frames go to the detection and calibration numerics
//! ([`btfrig_calibrate::calibrate_captures`], `btfrig-intrinsics`), which do no I/O.
//!
//! The exposure is metered on the board itself: a first frame at the camera's present
//! exposure, rescaled so that the board's white (the 90th percentile of the photosites)
//! reaches the plan's `exposure_fraction` of full scale.

use std::time::Instant;

use btfrig_calibrate::{calibrate_captures, plan_captures, BoardCaptures, CalibrationPlan, RigCalibration};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;

use crate::backend::{BackendRegistry, MountedTarget, RigTime};
use crate::calibration_rig::{block_on, level_quantile, CalibrationRig, Role};
use crate::RunError;

/// The devices a geometric calibration needs.
pub const GEOMETRY_DEVICES: &[Role] = &[Role::Robot, Role::Rail, Role::Lamp, Role::Camera];

/// The quantile of the photosites metered as the board's white.
const WHITE_QUANTILE: f64 = 0.9;

/// A geometric calibration's result and how it was taken.
#[derive(Debug, Clone)]
pub struct GeometricCalibration {
    /// What the numerics made of the captured frames.
    pub result: RigCalibration,
    /// The exposure of the captures, seconds.
    pub exposure_s: f64,
    /// The devices used, as `role name (model, port)`.
    pub devices: String,
    /// The true lens, from the backend's truth probe (simulated rigs only): error figures.
    pub truth: Option<CameraModel>,
}

/// Runs `plan` on `rig` through its devices (opened through `backends`, the installed
/// registry when `None`) on `time`; `seed` drives a simulated rig's noise. `progress`
/// receives one line per stage.
pub fn calibrate_geometry(
    rig: &RigConfig,
    backends: Option<&BackendRegistry>,
    plan: &CalibrationPlan,
    seed: u64,
    time: RigTime,
    mut progress: impl FnMut(&str),
) -> Result<GeometricCalibration, RunError> {
    let calib = |e: btfrig_calibrate::RigCalibError| RunError::Rig(e.to_string());
    let captures = plan_captures(rig, plan).map_err(calib)?;
    let t = Instant::now();
    let target = MountedTarget::Board(plan.target.clone());
    let (frames, exposure_s, devices, truth) = block_on(time, async {
        let mut dev = CalibrationRig::open(rig, backends, &target, GEOMETRY_DEVICES, seed, time).await?;
        let devices = dev.describe();
        let first = captures.iter().find(|c| c.skipped.is_none()).ok_or_else(|| {
            RunError::Rig(format!("calibration plan {}: no view is reachable on rig {}", plan.name, rig.rig.name))
        })?;
        dev.move_to(&first.joints).await?;
        let exposure_s = meter(&mut dev, plan.exposure_fraction).await?;
        let mut frames = Vec::with_capacity(captures.len());
        for cap in &captures {
            if cap.skipped.is_some() {
                frames.push(None);
                continue;
            }
            dev.move_to(&cap.joints).await?;
            frames.push(Some(dev.capture(exposure_s).await?));
        }
        let truth = dev.truth.as_ref().map(|t| t.camera().clone());
        dev.finish().await;
        Ok::<_, RunError>((frames, exposure_s, devices, truth))
    })??;
    let capture_s = t.elapsed().as_secs_f64();
    progress(&format!(
        "captured {} views at {exposure_s:.4} s in {capture_s:.1} s ({devices})",
        frames.iter().flatten().count()
    ));
    let shots = BoardCaptures { frames, captures, render_s: capture_s };
    let result = calibrate_captures(rig, plan, &shots, progress).map_err(calib)?;
    Ok(GeometricCalibration { result, exposure_s, devices, truth })
}

/// The exposure that puts the frame's white at `fraction` of full scale: rescaled from a
/// frame at the camera's range's geometric middle, shortened while the frame clips.
async fn meter(dev: &mut CalibrationRig, fraction: f64) -> Result<f64, RunError> {
    let (lo, hi) = dev.exposure_range_s();
    let mut exposure = (lo * hi).sqrt().min(0.1).max(lo);
    for _ in 0..12 {
        let frame = dev.capture(exposure).await?;
        let white = level_quantile(&frame, WHITE_QUANTILE);
        if white >= 0.95 {
            exposure = (exposure / 8.0).max(lo);
            continue;
        }
        if white <= 1e-3 {
            if exposure >= hi {
                break;
            }
            exposure = (exposure * 16.0).min(hi);
            continue;
        }
        return Ok((exposure * fraction / white).clamp(lo, hi));
    }
    Err(dev.device_error(
        Role::Camera,
        format!("cannot meter the board: no exposure in {lo}..{hi} s puts its white between 0.1% and 95% of full scale; is the lamp on?"),
    ))
}
