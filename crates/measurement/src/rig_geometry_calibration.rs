//! Rig geometry calibration through the devices (`btfrig calibrate rig-geometry`): the bare
//! marker plate mounted, the robot and rail driven to a few dozen poses spread over the joint
//! space, the plate registered in each frame with the processing camera
//! (`btfrig_registration::PlateRegistrar`), and the joints' zero offsets fitted to the
//! registered poses (`btfrig_calibrate::rig_geometry::fit_joint_offsets`, pure numerics).

use btfrig_calibrate::rig_geometry::{fit_joint_offsets, observe_pose, OffsetFit};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::Direction;
use btfrig_registration::PlateRegistrar;

use crate::backend::{BackendRegistry, MountedTarget, RigTime};
use crate::calibration_rig::{block_on, level_quantile, CalibrationRig, Role};
use crate::RunError;

/// The devices a rig geometry calibration needs.
pub const RIG_GEOMETRY_DEVICES: &[Role] = &[Role::Robot, Role::Rail, Role::Lamp, Role::Camera];

/// The result, with what the truth probe says (simulated rigs only: error figures).
#[derive(Debug, Clone)]
pub struct RigGeometryCalibration {
    /// The fit.
    pub fit: OffsetFit,
    /// Poses asked for, and those whose plate was registered.
    pub poses_planned: usize,
    /// Why each unregistered pose was skipped.
    pub skipped: Vec<String>,
    /// Devices used.
    pub devices: String,
    /// The exposure, seconds.
    pub exposure_s: f64,
    /// Per registered pose: true minus commanded joints, radians (from the truth probe).
    pub true_offsets: Vec<JointState>,
}

/// `count` (light, view) pairs spread over the hemisphere (a fixed golden-angle sequence:
/// the same poses every run), each reachable on `gonio`, as commanded joints.
pub fn poses(gonio: &Gonio, count: usize) -> Vec<JointState> {
    let golden = 137.507_764_f64;
    let mut out = Vec::new();
    let mut k = 0usize;
    while out.len() < count && k < 20 * count {
        let f = (k as f64 + 0.5) / count as f64;
        let view = Direction::from_degrees(10.0 + 45.0 * (f % 1.0), golden * k as f64);
        let light = Direction::from_degrees(15.0 + 40.0 * ((0.37 + 0.61 * k as f64) % 1.0), golden * k as f64 + 150.0);
        k += 1;
        if let Ok(j) = gonio.ik(light, view) {
            out.push(j);
        }
    }
    out
}

/// Runs the calibration on `rig` over `count` poses, registering with `camera` (the
/// processing camera). `seed` drives a simulated rig's noise; `progress` gets one line per stage.
#[allow(clippy::too_many_arguments)]
pub fn calibrate_rig_geometry(
    rig: &RigConfig,
    backends: Option<&BackendRegistry>,
    camera: &CameraModel,
    count: usize,
    seed: u64,
    time: RigTime,
    mut progress: impl FnMut(&str),
) -> Result<RigGeometryCalibration, RunError> {
    let gonio = Gonio::new(rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    let joints = poses(&gonio, count);
    let registrar = PlateRegistrar::new(camera.clone(), &rig.plate, Default::default())
        .map_err(|e| RunError::Rig(format!("registrar: {e}")))?;
    let (frames, exposure_s, devices, truth) = block_on(time, async {
        let mut dev =
            CalibrationRig::open(rig, backends, &MountedTarget::Plate, RIG_GEOMETRY_DEVICES, seed, time).await?;
        let devices = dev.describe();
        let first = joints.first().ok_or_else(|| RunError::Rig("no reachable pose".into()))?;
        dev.move_to(first).await?;
        let (lo, hi) = dev.exposure_range_s();
        let mut exposure = (lo * hi).sqrt().min(0.1).max(lo);
        for _ in 0..12 {
            let level = level_quantile(&dev.capture(exposure).await?, 0.9);
            if level >= 0.95 {
                exposure = (exposure / 8.0).max(lo);
            } else if level <= 1e-3 {
                exposure = (exposure * 16.0).min(hi);
            } else {
                exposure = (exposure * 0.5 / level).clamp(lo, hi);
                break;
            }
        }
        let mut frames = Vec::new();
        for j in &joints {
            dev.move_to(j).await?;
            frames.push(dev.capture(exposure).await?);
        }
        let truth = dev.truth.clone();
        dev.finish().await;
        Ok::<_, RunError>((frames, exposure, devices, truth))
    })??;
    progress(&format!("captured {} poses at {exposure_s:.4} s ({devices})", frames.len()));
    let mut obs = Vec::new();
    let mut skipped = Vec::new();
    let mut true_offsets = Vec::new();
    for (i, (frame, j)) in frames.iter().zip(&joints).enumerate() {
        match observe_pose(&registrar, &gonio, j, frame) {
            Ok(o) => {
                obs.push(o);
                if let Some(t) = truth.as_ref().and_then(|t| t.take_exposure(frame.meta.timestamp_s)) {
                    true_offsets.push(JointState {
                        rail: t.joints.rail - j.rail,
                        robot: std::array::from_fn(|k| t.joints.robot[k] - j.robot[k]),
                        turntable: t.joints.turntable - j.turntable,
                    });
                }
            }
            Err(e) => skipped.push(format!("pose {i}: {e}")),
        }
    }
    progress(&format!("registered {} of {} poses", obs.len(), joints.len()));
    let fit = fit_joint_offsets(&gonio, &obs).map_err(|e| RunError::Rig(e.to_string()))?;
    Ok(RigGeometryCalibration { fit, poses_planned: joints.len(), skipped, devices, exposure_s, true_offsets })
}
