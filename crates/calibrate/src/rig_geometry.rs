//! Rig geometry calibration: the joints' zero offsets from the marker plate registered at a
//! few dozen poses ([`fit_joint_offsets`]), the file it writes ([`RigGeometryFile`],
//! `calibration/*-rig-geometry.toml`) and reading the one a rig config names
//! ([`processing_joint_offsets`], `[geometry] calibration`). Format: `docs/kinematics.md`.
//!
//! What the markers observe is the sample's pose relative to the camera. In it the pan and
//! rail joints appear only as their difference (both rotate about the world vertical), and
//! roll and turntable only as their sum (both rotate about the sample normal): the fit
//! estimates pan, tilt and roll and fixes the rail and turntable offsets at 0, so the pan
//! offset it reports is `pan - rail` and the roll offset `roll + turntable`. The lamp, which
//! the markers do not see, would be needed to separate them.

use std::path::{Path, PathBuf};

use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::{Gonio, JointState};
use nalgebra::{Isometry3, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::RigCalibError;

/// Version of the rig geometry file format.
pub const RIG_GEOMETRY_FORMAT_VERSION: u32 = 1;

/// Rig geometry files embedded in the binary, for `[geometry] calibration = "builtin:NAME"`.
pub const BUILTIN_RIG_GEOMETRY: &[(&str, &str)] =
    &[("bonn-gonio-sim-rig-geometry", include_str!("../../../calibration/bonn-gonio-sim-rig-geometry.toml"))];

/// The fitted offsets, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointOffsetsDeg {
    /// Robot `[pan, tilt, roll]`.
    pub robot_deg: [f64; 3],
    /// Rail (fixed at 0: inseparable from pan).
    pub rail_deg: f64,
    /// Turntable (fixed at 0: inseparable from roll).
    pub turntable_deg: f64,
}

impl JointOffsetsDeg {
    /// As a joint state, radians.
    pub fn to_joints(&self) -> JointState {
        JointState {
            rail: self.rail_deg.to_radians(),
            robot: self.robot_deg.map(f64::to_radians),
            turntable: self.turntable_deg.to_radians(),
        }
    }
}

/// How well the offsets fit, and what they gained.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OffsetFitFigures {
    /// Poses registered and fitted.
    pub poses: usize,
    /// RMS over the poses of the angle between the nominal pose (no offsets) and the
    /// registered one, degrees.
    pub rms_before_deg: f64,
    /// The same with the fitted offsets.
    pub rms_after_deg: f64,
    /// Largest angle before, degrees.
    pub max_before_deg: f64,
    /// Largest angle after, degrees.
    pub max_after_deg: f64,
}

/// A rig geometry calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigGeometryFile {
    /// Format version ([`RIG_GEOMETRY_FORMAT_VERSION`]).
    pub format_version: u32,
    /// The command and rig that made it.
    pub source: String,
    /// The offsets (added to commanded joints).
    pub offsets: JointOffsetsDeg,
    /// Standard deviation of each robot offset (from the fit's covariance scaled by its
    /// residual), degrees.
    pub robot_sigma_deg: [f64; 3],
    /// What the fit cannot separate, and how the file fixes it.
    pub fixed: Vec<String>,
    /// The fit's figures.
    pub fit: OffsetFitFigures,
}

/// What the fit fixes, in the file's words.
pub fn fixed_offsets() -> Vec<String> {
    vec![
        "rail_deg = 0: the markers see pan and rail only as pan - rail (both turn about the vertical); robot_deg[0] \
         is pan - rail"
            .into(),
        "turntable_deg = 0: the markers see roll and turntable only as roll + turntable (both turn about the \
         normal); robot_deg[2] is roll + turntable"
            .into(),
    ]
}

impl RigGeometryFile {
    /// Parses and checks a file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<RigGeometryFile, RigCalibError> {
        let err = |message: String| RigCalibError::Plan { origin: origin.into(), message };
        let f: RigGeometryFile = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if f.format_version != RIG_GEOMETRY_FORMAT_VERSION {
            return Err(err(format!(
                "format_version = {} is not supported (this build reads {RIG_GEOMETRY_FORMAT_VERSION})",
                f.format_version
            )));
        }
        let o = &f.offsets;
        for (name, v) in [
            ("offsets.robot_deg[0]", o.robot_deg[0]),
            ("offsets.robot_deg[1]", o.robot_deg[1]),
            ("offsets.robot_deg[2]", o.robot_deg[2]),
            ("offsets.rail_deg", o.rail_deg),
            ("offsets.turntable_deg", o.turntable_deg),
        ] {
            if !(v.is_finite() && v.abs() <= 10.0) {
                return Err(err(format!("{name} = {v}: allowed -10..=10 degrees")));
            }
        }
        Ok(f)
    }

    /// The TOML text, its header naming the command that made it.
    pub fn to_toml(&self) -> String {
        format!(
            "# Rig geometry calibration (format: docs/kinematics.md): joint zero offsets added to the commanded\n\
             # joints for the nominal pose. Made by: {}\n{}",
            self.source,
            toml::to_string(self).expect("serialisable")
        )
    }
}

/// The joint offsets a rig config's `[geometry] calibration` names (`builtin:NAME` or a path
/// relative to the rig file), with where they came from; `None` when it names none.
pub fn processing_joint_offsets(
    rig: &RigConfig,
    rig_path: Option<&Path>,
) -> Result<Option<(JointState, String)>, RigCalibError> {
    let Some(reference) = rig.geometry.calibration.as_deref() else { return Ok(None) };
    let err = |message: String| RigCalibError::Reference { reference: format!("[geometry] {reference}"), message };
    let (text, origin) = if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, text) = BUILTIN_RIG_GEOMETRY.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_RIG_GEOMETRY.iter().map(|(n, _)| *n).collect();
            err(format!("no built-in rig geometry calibration {name:?} (built in: {})", known.join(", ")))
        })?;
        (text.to_string(), format!("<embedded calibration/{name}.toml>"))
    } else {
        let base: PathBuf = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
        let path = base.join(reference);
        let text = std::fs::read_to_string(&path).map_err(|e| err(format!("cannot read {}: {e}", path.display())))?;
        (text, path.display().to_string())
    };
    let f = RigGeometryFile::from_toml(&text, &origin).map_err(|e| err(e.to_string()))?;
    Ok(Some((f.offsets.to_joints(), origin)))
}

/// One pose: the commanded joints and the registered sample-to-camera transform.
#[derive(Debug, Clone, Copy)]
pub struct PoseObservation {
    /// Commanded joints.
    pub joints: JointState,
    /// The sample-to-camera transform the markers gave.
    pub sample_to_camera: Isometry3<f64>,
}

/// The plate registered in `frame`, taken at commanded `joints` (the nominal pose from
/// `gonio` without offsets seeds the registration).
pub fn observe_pose(
    registrar: &btfrig_registration::PlateRegistrar,
    gonio: &Gonio,
    joints: &JointState,
    frame: &btfrig_core::frame::RawFrame,
) -> Result<PoseObservation, String> {
    let green = crate::green(frame);
    let gray = btfrig_markers::GrayImage::new(frame.width, frame.height, &green).map_err(|e| e.to_string())?;
    let r = registrar.register_image(&gray, &gonio.scene_pose(joints)).map_err(|e| e.to_string())?;
    Ok(PoseObservation { joints: *joints, sample_to_camera: r.registration.sample_to_camera })
}

/// Result of [`fit_joint_offsets`].
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetFit {
    /// The offsets (rail and turntable 0, see the module documentation).
    pub offsets: JointOffsetsDeg,
    /// Standard deviation of each robot offset, degrees.
    pub robot_sigma_deg: [f64; 3],
    /// The figures.
    pub figures: OffsetFitFigures,
    /// Per pose: angle between nominal and registered pose before and after, degrees.
    pub per_pose_deg: Vec<(f64, f64)>,
}

/// The rotation of the sample relative to the camera at `j` plus robot offsets `d`.
fn relative_rotation(gonio: &Gonio, j: &JointState, d: &Vector3<f64>) -> Matrix3<f64> {
    let j = JointState { robot: [j.robot[0] + d[0], j.robot[1] + d[1], j.robot[2] + d[2]], ..*j };
    let p = gonio.scene_pose(&j);
    (p.camera_to_world.inverse() * p.sample_to_world).rotation.to_rotation_matrix().into_inner()
}

/// Rotation vector taking `measured` to `model` (camera frame), radians. From the skew part
/// and the trace with `atan2`: exact near the identity, where an `acos` of the trace is NaN
/// as soon as rounding puts it above 3 (a fit converged on noise-free poses).
fn residual(model: &Matrix3<f64>, measured: &Matrix3<f64>) -> Vector3<f64> {
    let m = model * measured.transpose();
    let v = Vector3::new(m[(2, 1)] - m[(1, 2)], m[(0, 2)] - m[(2, 0)], m[(1, 0)] - m[(0, 1)]) * 0.5;
    let s = v.norm();
    if s < 1e-300 {
        return v;
    }
    let angle = s.atan2((m.trace() - 1.0) * 0.5);
    v * (angle / s)
}

/// Fits the robot's zero offsets so that the nominal relative pose matches the registered one
/// at every observation (Gauss-Newton on the rotation residuals; `gonio` must carry no
/// offsets). Needs at least 3 observations.
pub fn fit_joint_offsets(gonio: &Gonio, obs: &[PoseObservation]) -> Result<OffsetFit, RigCalibError> {
    if obs.len() < 3 {
        return Err(RigCalibError::Rig(format!("{} registered poses: the offset fit needs at least 3", obs.len())));
    }
    let measured: Vec<Matrix3<f64>> =
        obs.iter().map(|o| o.sample_to_camera.rotation.to_rotation_matrix().into_inner()).collect();
    let residuals = |d: &Vector3<f64>| -> Vec<Vector3<f64>> {
        obs.iter().zip(&measured).map(|(o, m)| residual(&relative_rotation(gonio, &o.joints, d), m)).collect()
    };
    let mut d = Vector3::zeros();
    let h = 1e-7;
    let mut jtj = nalgebra::Matrix3::zeros();
    for _ in 0..20 {
        let r0 = residuals(&d);
        let cols: Vec<Vec<Vector3<f64>>> = (0..3)
            .map(|k| {
                let mut dk = d;
                dk[k] += h;
                residuals(&dk).iter().zip(&r0).map(|(a, b)| (a - b) / h).collect()
            })
            .collect();
        jtj = nalgebra::Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        for i in 0..obs.len() {
            for a in 0..3 {
                jtr[a] += cols[a][i].dot(&r0[i]);
                for b in 0..3 {
                    jtj[(a, b)] += cols[a][i].dot(&cols[b][i]);
                }
            }
        }
        let step = jtj.try_inverse().ok_or_else(|| {
            RigCalibError::Rig("the poses do not determine the offsets (singular normal matrix)".into())
        })? * jtr;
        d -= step;
        if step.norm() < 1e-12 {
            break;
        }
    }
    let before: Vec<f64> = residuals(&Vector3::zeros()).iter().map(|r| r.norm().to_degrees()).collect();
    let after_r = residuals(&d);
    let after: Vec<f64> = after_r.iter().map(|r| r.norm().to_degrees()).collect();
    let rss: f64 = after_r.iter().map(|r| r.norm_squared()).sum();
    let dof = (3 * obs.len()).saturating_sub(3).max(1) as f64;
    let cov = jtj.try_inverse().unwrap_or_else(nalgebra::Matrix3::zeros) * (rss / dof);
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    Ok(OffsetFit {
        offsets: JointOffsetsDeg {
            robot_deg: [d[0].to_degrees(), d[1].to_degrees(), d[2].to_degrees()],
            rail_deg: 0.0,
            turntable_deg: 0.0,
        },
        robot_sigma_deg: [0, 1, 2].map(|k| cov[(k, k)].max(0.0).sqrt().to_degrees()),
        figures: OffsetFitFigures {
            poses: obs.len(),
            rms_before_deg: rms(&before),
            rms_after_deg: rms(&after),
            max_before_deg: max(&before),
            max_after_deg: max(&after),
        },
        per_pose_deg: before.into_iter().zip(after).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::config::geometry::GonioGeometry;

    /// Offsets put into the "true" joints are found again from noise-free relative poses,
    /// pan as pan - rail; the nominal pose error drops to ~0.
    #[test]
    fn offsets_are_recovered_from_relative_poses() {
        let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
        let truth =
            JointState { rail: 0.1f64.to_radians(), robot: [0.3, -0.2, 0.25].map(f64::to_radians), turntable: 0.0 };
        let mut obs = Vec::new();
        for k in 0..12 {
            let j = JointState {
                rail: (40.0 + 9.0 * k as f64).to_radians(),
                robot: [
                    (-30.0 + 5.0 * k as f64).to_radians(),
                    (20.0 - 4.0 * k as f64).to_radians(),
                    (30.0 * k as f64).to_radians(),
                ],
                turntable: 0.0,
            };
            let t = JointState {
                rail: j.rail + truth.rail,
                robot: std::array::from_fn(|i| j.robot[i] + truth.robot[i]),
                turntable: 0.0,
            };
            let p = gonio.scene_pose(&t);
            // The camera where the nominal rail puts it: the registration's frame.
            let nominal_cam = gonio.scene_pose(&j).camera_to_world;
            let true_rel = p.camera_to_world.inverse() * p.sample_to_world;
            // Registration measures sample relative to the true camera.
            let _ = nominal_cam;
            obs.push(PoseObservation { joints: j, sample_to_camera: true_rel });
        }
        let fit = fit_joint_offsets(&gonio, &obs).unwrap();
        let o = fit.offsets.robot_deg;
        assert!((o[0] - (0.3 - 0.1)).abs() < 1e-6, "pan - rail: {o:?}");
        assert!((o[1] + 0.2).abs() < 1e-6 && (o[2] - 0.25).abs() < 1e-6, "{o:?}");
        assert!(fit.figures.rms_after_deg < 1e-6 && fit.figures.rms_before_deg > 0.2, "{:?}", fit.figures);
    }
}
