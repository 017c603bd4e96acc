//! Gonioreflectometer kinematics: a fixed lamp, a camera on a horizontal semicircular rail,
//! and a robot wrist that orients the sample. Inverse kinematics from a (light, view) pair
//! in sample coordinates to joint values, forward kinematics back, the [`ScenePose`] the
//! renderer draws, and reachability with reasons. The maths is in `docs/kinematics.md`.
//!
//! World frame: metres, origin at the nominal sample centre, `z` up. The lamp sits at
//! `lamp_distance_m * (1, 0, 0)`; the camera at rail angle `r` at
//! `rail_radius_m * (cos r, sin r, 0)`, looking at the origin with image `x` along the
//! direction of increasing rail angle and image `y` down (world `-z`).
//!
//! Robot: `R = Rz(pan) * Ry(-tilt) * Rx(roll) * R0 * Rz(turntable)` maps sample to world,
//! where `R0` is the home pose (sample normal along world `+x`, facing the lamp; sample `x`
//! along world `+y`; sample `y` up). So `pan` is the azimuth of the sample normal, `tilt` its
//! elevation above the horizontal plane and `roll` the rotation about the normal.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::config::geometry::GonioGeometry;
use crate::direction::Direction;
use crate::error::ConfigError;
use crate::pose::ScenePose;
use crate::sampling::Sampling;

/// Joint values of a gonioreflectometer, radians. The meaning of each robot joint is
/// documented in `docs/kinematics.md`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Rail angle: the angle between lamp and camera as seen from the sample.
    pub rail: f64,
    /// The robot's three joint angles that orient the sample: `[pan, tilt, roll]`.
    pub robot: [f64; 3],
    /// Turntable angle (0 when the rig has none).
    pub turntable: f64,
}

/// Names of the robot joints, in the order of [`JointState::robot`].
pub const JOINT_NAMES: [&str; 3] = ["pan", "tilt", "roll"];

/// Lamp or camera: the two things that look at the sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Device {
    /// The light source (the requested light direction).
    Lamp,
    /// The camera (the requested view direction).
    Camera,
}

impl fmt::Display for Device {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Device::Lamp => "lamp",
            Device::Camera => "camera",
        })
    }
}

/// Why a (light, view) pair cannot be measured.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Unreachable {
    /// The requested direction is at or below the sample plane.
    #[error("the {which} direction is at or below the sample's horizon (theta = {theta_deg:.3} deg, must be < 90)")]
    BelowHorizon {
        /// Which direction.
        which: Device,
        /// Its polar angle, degrees.
        theta_deg: f64,
    },
    /// Light and view are so close that the camera body would stand in the lamp's light.
    #[error(
        "the camera would block the lamp: light and view are {angle_deg:.3} deg apart, at least {min_deg} deg needed"
    )]
    CameraBlocksLamp {
        /// Angle between light and view, degrees.
        angle_deg: f64,
        /// Configured minimum separation, degrees.
        min_deg: f64,
    },
    /// The rail angle needed is beyond the rail's end stops.
    #[error("the rail cannot reach {angle_deg:.3} deg (end stops at {min_deg} and {max_deg} deg)")]
    RailLimit {
        /// Required rail angle, degrees.
        angle_deg: f64,
        /// Lower end stop, degrees.
        min_deg: f64,
        /// Upper end stop, degrees.
        max_deg: f64,
    },
    /// No branch of the wrist solution keeps every joint within its limits.
    #[error("robot joint {joint} ({}) would need {angle_deg:.3} deg, limits {min_deg} ..= {max_deg} deg", JOINT_NAMES[*joint])]
    JointLimit {
        /// Joint index into [`JointState::robot`] (0 = pan, 1 = tilt, 2 = roll).
        joint: usize,
        /// Required angle, degrees.
        angle_deg: f64,
        /// Lower limit, degrees.
        min_deg: f64,
        /// Upper limit, degrees.
        max_deg: f64,
    },
    /// The robot's forearm would pass through the holder plate (or within its radius of it).
    #[error("the robot forearm would pass through the holder plate ({x_m:.3}, {y_m:.3}) m from the sample centre")]
    ArmHitsHolder {
        /// Sample-frame x where the forearm's axis crosses the sample plane, metres.
        x_m: f64,
        /// Sample-frame y of that crossing, metres.
        y_m: f64,
    },
    /// The robot's forearm lies on the line between the lamp and the sample centre.
    #[error("the robot forearm shadows the sample: it passes {distance_m:.3} m from the lamp's ray to the sample centre (arm radius {radius_m} m)")]
    RobotShadows {
        /// Distance between the forearm axis and the lamp ray, metres.
        distance_m: f64,
        /// Arm radius, metres.
        radius_m: f64,
    },
    /// The robot's forearm lies on the line between the camera and the sample centre.
    #[error("the robot forearm hides the sample from the camera: it passes {distance_m:.3} m from the camera's ray to the sample centre (arm radius {radius_m} m)")]
    RobotHides {
        /// Distance between the forearm axis and the camera ray, metres.
        distance_m: f64,
        /// Arm radius, metres.
        radius_m: f64,
    },
}

/// The kind of an [`Unreachable`] reason, without its numbers: the key of the report counts.
/// Declared in the order the checks run (the first failing check is the reported reason).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum UnreachableKind {
    /// See [`Unreachable::BelowHorizon`].
    BelowHorizon,
    /// See [`Unreachable::CameraBlocksLamp`].
    CameraBlocksLamp,
    /// See [`Unreachable::RailLimit`].
    RailLimit,
    /// See [`Unreachable::JointLimit`].
    JointLimit,
    /// See [`Unreachable::ArmHitsHolder`].
    ArmHitsHolder,
    /// See [`Unreachable::RobotShadows`].
    RobotShadows,
    /// See [`Unreachable::RobotHides`].
    RobotHides,
}

impl UnreachableKind {
    /// Every kind, in check order.
    pub const ALL: [UnreachableKind; 7] = [
        UnreachableKind::BelowHorizon,
        UnreachableKind::CameraBlocksLamp,
        UnreachableKind::RailLimit,
        UnreachableKind::JointLimit,
        UnreachableKind::ArmHitsHolder,
        UnreachableKind::RobotShadows,
        UnreachableKind::RobotHides,
    ];

    /// A short label for tables.
    pub fn label(self) -> &'static str {
        match self {
            UnreachableKind::BelowHorizon => "below horizon",
            UnreachableKind::CameraBlocksLamp => "camera blocks lamp",
            UnreachableKind::RailLimit => "rail limit",
            UnreachableKind::JointLimit => "joint limit",
            UnreachableKind::ArmHitsHolder => "arm hits holder",
            UnreachableKind::RobotShadows => "robot shadows sample",
            UnreachableKind::RobotHides => "robot hides sample",
        }
    }
}

impl Unreachable {
    /// The kind of this reason.
    pub fn kind(&self) -> UnreachableKind {
        match self {
            Unreachable::BelowHorizon { .. } => UnreachableKind::BelowHorizon,
            Unreachable::CameraBlocksLamp { .. } => UnreachableKind::CameraBlocksLamp,
            Unreachable::RailLimit { .. } => UnreachableKind::RailLimit,
            Unreachable::JointLimit { .. } => UnreachableKind::JointLimit,
            Unreachable::ArmHitsHolder { .. } => UnreachableKind::ArmHitsHolder,
            Unreachable::RobotShadows { .. } => UnreachableKind::RobotShadows,
            Unreachable::RobotHides { .. } => UnreachableKind::RobotHides,
        }
    }
}

/// How many (light, view) pairs of two samplings are reachable, and why the others are not.
#[derive(Debug, Clone, PartialEq)]
pub struct ReachabilityReport {
    /// Name of the light sampling.
    pub lights: String,
    /// Name of the view sampling.
    pub views: String,
    /// Number of pairs classified (`lights.len() * views.len()`).
    pub total: usize,
    /// Pairs with a valid joint state.
    pub reachable: usize,
    /// Count per reason, one entry per [`UnreachableKind::ALL`] in that order (zeros included).
    pub unreachable: Vec<(UnreachableKind, usize)>,
}

impl ReachabilityReport {
    /// Count of one reason.
    pub fn count(&self, kind: UnreachableKind) -> usize {
        self.unreachable.iter().find(|(k, _)| *k == kind).map_or(0, |(_, n)| *n)
    }
}

impl fmt::Display for ReachabilityReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "light sampling {} x view sampling {}: {} pairs", self.lights, self.views, self.total)?;
        writeln!(f, "  {:<22} {:>7}", "reachable", self.reachable)?;
        for (kind, n) in &self.unreachable {
            writeln!(f, "  {:<22} {:>7}", kind.label(), n)?;
        }
        Ok(())
    }
}

/// A gonioreflectometer built from its `[geometry]` section.
#[derive(Debug, Clone)]
pub struct Gonio {
    geometry: GonioGeometry,
    /// Joint zero offsets added to every joint state before the pose is computed (a rig
    /// geometry calibration; zero unless set with [`Gonio::with_joint_offsets`]).
    offsets: JointState,
    joint_min: [f64; 3],
    joint_max: [f64; 3],
    shoulder: Point3<f64>,
}

/// The home pose: sample `z` (normal) -> world `x`, sample `x` -> world `y`, sample `y` -> world `z`.
fn home_rotation() -> Matrix3<f64> {
    Matrix3::new(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
}

/// The direction of a non-zero sample-frame vector. Unlike an `acos` of `z / |v|`, the
/// `atan2` form keeps full precision near the pole, where `acos` near 1 loses ~1e-8 rad and
/// would break the 1e-9 rad round-trip guarantee.
pub fn direction_of(v: &Vector3<f64>) -> Direction {
    let theta = v.x.hypot(v.y).atan2(v.z);
    let phi = if v.x == 0.0 && v.y == 0.0 { 0.0 } else { v.y.atan2(v.x) };
    Direction::new(theta, phi)
}

/// Wraps an angle into `(-pi, pi]`.
fn wrap_pi(a: f64) -> f64 {
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w <= -PI {
        w + TAU
    } else {
        w
    }
}

/// Distance between segments `p0-p1` and `q0-q1` (closest points by clamped
/// parameters; the segments here are never both degenerate).
fn segment_distance(p0: &Vector3<f64>, p1: &Vector3<f64>, q0: &Vector3<f64>, q1: &Vector3<f64>) -> f64 {
    let d1 = p1 - p0;
    let d2 = q1 - q0;
    let r = p0 - q0;
    let a = d1.dot(&d1);
    let e = d2.dot(&d2);
    let f = d2.dot(&r);
    let (s, t);
    if a <= f64::EPSILON && e <= f64::EPSILON {
        return r.norm();
    }
    if a <= f64::EPSILON {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(&r);
        if e <= f64::EPSILON {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let s0 = if denom > 1e-300 { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
            let t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            } else {
                t = t0;
                s = s0;
            }
        }
    }
    ((p0 + d1 * s) - (q0 + d2 * t)).norm()
}

impl Gonio {
    /// Builds the kinematics of a rig; fails with every bad geometry value.
    pub fn new(geometry: GonioGeometry) -> Result<Self, ConfigError> {
        let mut errors = Vec::new();
        geometry.validate(&mut errors);
        ConfigError::from_list(errors)?;
        let joint_min = geometry.joint_min_deg.map(f64::to_radians);
        let joint_max = geometry.joint_max_deg.map(f64::to_radians);
        let s = geometry.robot_shoulder_m;
        Ok(Gonio {
            geometry,
            offsets: JointState::default(),
            joint_min,
            joint_max,
            shoulder: Point3::new(s[0], s[1], s[2]),
        })
    }

    /// The same kinematics with joint zero offsets (radians): where a joint commanded to `j`
    /// truly stands is `j + offsets`, as a rig geometry calibration measured it. Only
    /// [`Gonio::scene_pose`] honours them (the nominal pose processing starts from); inverse
    /// and forward kinematics stay those of the commanded joints.
    pub fn with_joint_offsets(mut self, offsets: JointState) -> Self {
        self.offsets = offsets;
        self
    }

    /// The joint zero offsets (zero unless calibrated).
    pub fn joint_offsets(&self) -> &JointState {
        &self.offsets
    }

    /// The geometry this was built from.
    pub fn geometry(&self) -> &GonioGeometry {
        &self.geometry
    }

    /// World unit vector from the sample centre to the lamp.
    pub fn lamp_direction_world(&self) -> Vector3<f64> {
        Vector3::x()
    }

    /// World unit vector from the sample centre to the camera at rail angle `rail`.
    pub fn camera_direction_world(&self, rail: f64) -> Vector3<f64> {
        let (s, c) = rail.sin_cos();
        Vector3::new(c, s, 0.0)
    }

    /// The rotation sample -> world for the given joints (robot chain and turntable).
    pub fn sample_rotation(&self, j: &JointState) -> Rotation3<f64> {
        let [pan, tilt, roll] = j.robot;
        Rotation3::from_axis_angle(&Vector3::z_axis(), pan)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), -tilt)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
            * Rotation3::from_matrix_unchecked(home_rotation())
            * Rotation3::from_axis_angle(&Vector3::z_axis(), j.turntable)
    }

    /// Forward kinematics: the (light, view) directions in the sample frame for `j`, i.e. the
    /// directions from the sample centre towards the lamp and the camera.
    pub fn fk(&self, j: &JointState) -> (Direction, Direction) {
        let r = self.sample_rotation(j);
        let light = r.inverse_transform_vector(&self.lamp_direction_world());
        let view = r.inverse_transform_vector(&self.camera_direction_world(j.rail));
        (direction_of(&light), direction_of(&view))
    }

    /// Where sample, camera and lamp are in the world for `j` (plus the joint offsets, if
    /// any): the pose the renderer draws.
    /// The camera (OpenCV frame) sits on the rail looking at the sample centre, image `x`
    /// along increasing rail angle, image `y` down.
    pub fn scene_pose(&self, j: &JointState) -> ScenePose {
        let o = &self.offsets;
        let j = &JointState {
            rail: j.rail + o.rail,
            robot: std::array::from_fn(|k| j.robot[k] + o.robot[k]),
            turntable: j.turntable + o.turntable,
        };
        let rot = self.sample_rotation(j);
        let c = self.camera_direction_world(j.rail);
        let z_cam = -c;
        let y_cam = -Vector3::z();
        let x_cam = y_cam.cross(&z_cam);
        let cam_rot = Rotation3::from_basis_unchecked(&[x_cam, y_cam, z_cam]);
        ScenePose {
            sample_to_world: Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_rotation_matrix(&rot),
            ),
            camera_to_world: Isometry3::from_parts(
                Translation3::from(c * self.geometry.rail_radius_m),
                UnitQuaternion::from_rotation_matrix(&cam_rot),
            ),
            lamp_position: Point3::from(self.lamp_direction_world() * self.geometry.lamp_distance_m),
        }
    }

    /// Inverse kinematics: joints that put the lamp along `light` and the camera along `view`
    /// (both in the sample frame), or the first reason why that is impossible. Checks run in
    /// the order of [`UnreachableKind::ALL`]. The turntable stays at 0.
    pub fn ik(&self, light: Direction, view: Direction) -> Result<JointState, Unreachable> {
        let g = &self.geometry;
        let l = light.to_vector();
        let v = view.to_vector();
        for (which, d) in [(Device::Lamp, &l), (Device::Camera, &v)] {
            // `!(>)` also rejects NaN.
            if !(d.z > 0.0 && direction_of(d).theta < FRAC_PI_2) {
                return Err(Unreachable::BelowHorizon { which, theta_deg: direction_of(d).theta.to_degrees() });
            }
        }
        let cross = l.cross(&v);
        let rail = cross.norm().atan2(l.dot(&v));
        let rail_deg = rail.to_degrees();
        if rail_deg < g.min_lamp_camera_separation_deg {
            return Err(Unreachable::CameraBlocksLamp {
                angle_deg: rail_deg,
                min_deg: g.min_lamp_camera_separation_deg,
            });
        }
        if !(g.rail_min_deg..=g.rail_max_deg).contains(&rail_deg) {
            return Err(Unreachable::RailLimit {
                angle_deg: rail_deg,
                min_deg: g.rail_min_deg,
                max_deg: g.rail_max_deg,
            });
        }
        // Orthonormal triads built the same way from (l, v) in the sample frame and from
        // (lamp, camera) in the world: R maps one onto the other. The world triad is
        // (x, y, z) because the lamp is on x and the rail in the xy-plane at positive y
        // (rail in (0, pi)), so R's rows are the sample triad.
        let e1 = l;
        let e3 = cross / cross.norm();
        let e2 = e3.cross(&e1);
        let r = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
        let m = r * home_rotation().transpose();
        // m = Rz(pan) Ry(-tilt) Rx(roll); its first column is the world normal.
        let pan = m[(1, 0)].atan2(m[(0, 0)]);
        let tilt = m[(2, 0)].atan2(m[(0, 0)].hypot(m[(1, 0)]));
        let roll = m[(2, 1)].atan2(m[(2, 2)]);
        let branches = [[pan, tilt, roll], [wrap_pi(pan + PI), wrap_pi(PI - tilt), wrap_pi(roll + PI)]];
        let mut robot = None;
        let mut first_violation = None;
        for b in branches {
            match self.fit_limits(b) {
                Ok(q) => {
                    robot = Some(q);
                    break;
                }
                Err(e) => {
                    first_violation.get_or_insert(e);
                }
            }
        }
        let robot = match robot {
            Some(q) => q,
            None => return Err(first_violation.expect("a branch failed")),
        };
        let joints = JointState { rail, robot, turntable: 0.0 };
        self.check_arm(&joints)?;
        Ok(joints)
    }

    /// Picks for each joint the representative `a`, `a + 2 pi` or `a - 2 pi` within limits.
    fn fit_limits(&self, q: [f64; 3]) -> Result<[f64; 3], Unreachable> {
        let mut out = q;
        for k in 0..3 {
            let fit = [q[k], q[k] + TAU, q[k] - TAU]
                .into_iter()
                .find(|a| (self.joint_min[k]..=self.joint_max[k]).contains(a));
            match fit {
                Some(a) => out[k] = a,
                None => {
                    return Err(Unreachable::JointLimit {
                        joint: k,
                        angle_deg: q[k].to_degrees(),
                        min_deg: self.geometry.joint_min_deg[k],
                        max_deg: self.geometry.joint_max_deg[k],
                    })
                }
            }
        }
        Ok(out)
    }

    /// The world end points of the forearm: from the end of the flange to the shoulder.
    pub fn forearm(&self, j: &JointState) -> (Point3<f64>, Point3<f64>) {
        let g = &self.geometry;
        let rot = self.sample_rotation(j);
        let flange_end = rot * Point3::new(0.0, 0.0, -(g.holder_plate_thickness_m + g.arm_flange_length_m));
        (flange_end, self.shoulder)
    }

    /// The arm model of `docs/kinematics.md`: the flange stays behind the plate; the forearm
    /// may cross the plate or the lamp and camera rays to the sample centre.
    fn check_arm(&self, j: &JointState) -> Result<(), Unreachable> {
        let g = &self.geometry;
        let rot = self.sample_rotation(j);
        let (a_w, b_w) = self.forearm(j);
        // In sample coordinates the plate is the slab z in [-thickness, 0].
        let a = rot.inverse_transform_point(&a_w).coords;
        let b = rot.inverse_transform_point(&b_w).coords;
        let half = g.holder_plate_size_m / 2.0 + g.arm_radius_m;
        if b.z > 0.0 {
            // The forearm comes out in front of the sample plane: where does it cross?
            let t = -a.z / (b.z - a.z);
            let p = a + (b - a) * t;
            if p.x.abs() < half && p.y.abs() < half {
                return Err(Unreachable::ArmHitsHolder { x_m: p.x, y_m: p.y });
            }
        }
        // Parts more than one radius behind the sample plane cannot reach the rays to the
        // centre, which lie in front of it; the flange is entirely hidden behind the plate.
        let origin = Vector3::zeros();
        let lamp = rot.inverse_transform_vector(&self.lamp_direction_world()) * g.lamp_distance_m;
        let cam = rot.inverse_transform_vector(&self.camera_direction_world(j.rail)) * g.rail_radius_m;
        let dl = segment_distance(&a, &b, &lamp, &origin);
        if dl < g.arm_radius_m {
            return Err(Unreachable::RobotShadows { distance_m: dl, radius_m: g.arm_radius_m });
        }
        let dc = segment_distance(&a, &b, &cam, &origin);
        if dc < g.arm_radius_m {
            return Err(Unreachable::RobotHides { distance_m: dc, radius_m: g.arm_radius_m });
        }
        Ok(())
    }

    /// Classifies every (light, view) pair of two samplings.
    pub fn report(&self, lights: &Sampling, views: &Sampling) -> ReachabilityReport {
        let mut counts = [0usize; UnreachableKind::ALL.len()];
        let mut reachable = 0;
        for &l in lights.directions() {
            for &v in views.directions() {
                match self.ik(l, v) {
                    Ok(_) => reachable += 1,
                    Err(e) => counts[e.kind() as usize] += 1,
                }
            }
        }
        ReachabilityReport {
            lights: lights.name().to_string(),
            views: views.name().to_string(),
            total: lights.len() * views.len(),
            reachable,
            unreachable: UnreachableKind::ALL.iter().copied().zip(counts).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::direction::angle_between;

    /// Angular distance between two sample-frame directions, radians: well defined at the
    /// pole, where comparing phi would be meaningless.
    fn angular_error(a: Direction, b: Direction) -> f64 {
        angle_between(&a.to_vector(), &b.to_vector())
    }
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn bonn() -> Gonio {
        Gonio::new(GonioGeometry::bonn()).expect("default geometry is valid")
    }

    #[test]
    fn acceptance_every_bonn_pair_round_trips_or_has_a_reason() {
        let gonio = bonn();
        let s = Sampling::bonn81();
        let mut reachable = 0;
        let mut worst: f64 = 0.0;
        for (il, &l) in s.directions().iter().enumerate() {
            for (iv, &v) in s.directions().iter().enumerate() {
                match gonio.ik(l, v) {
                    Ok(j) => {
                        let (l2, v2) = gonio.fk(&j);
                        let err = angular_error(l, l2).max(angular_error(v, v2));
                        worst = worst.max(err);
                        assert!(err < 1e-9, "pair ({il}, {iv}): error {err:e} rad");
                        reachable += 1;
                    }
                    Err(reason) => {
                        // A reason a person can read, and the light == view pairs are blocked.
                        assert!(!reason.to_string().is_empty());
                        if il == iv {
                            assert_eq!(reason.kind(), UnreachableKind::CameraBlocksLamp);
                        }
                    }
                }
            }
        }
        let report = gonio.report(&s, &s);
        println!("{report}");
        assert_eq!(report.total, 6561);
        assert_eq!(report.reachable, reachable);
        assert_eq!(report.reachable + report.unreachable.iter().map(|(_, n)| n).sum::<usize>(), 6561);
        assert_eq!(report.count(UnreachableKind::CameraBlocksLamp), 81);
        assert!(report.reachable > 6000, "{report}");
        assert!(worst < 1e-12, "worst round-trip error {worst:e}");
    }

    #[test]
    fn random_pairs_round_trip() {
        let gonio = bonn();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut ok = 0;
        for _ in 0..50_000 {
            let mut d = || Direction::new(rng.gen_range(0.0..89.9f64).to_radians(), rng.gen_range(0.0..TAU));
            let (l, v) = (d(), d());
            if let Ok(j) = gonio.ik(l, v) {
                let (l2, v2) = gonio.fk(&j);
                assert!(angular_error(l, l2) < 1e-9 && angular_error(v, v2) < 1e-9, "{l:?} {v:?} -> {j:?}");
                assert!((j.rail - l.angle_to(v)).abs() < 1e-12);
                ok += 1;
            }
        }
        assert!(ok > 40_000, "{ok}");
    }

    #[test]
    fn round_trip_near_the_pole_and_the_rail_ends() {
        // The pole has no azimuth: comparisons are by angle only. Pairs just beyond the
        // separation limit and near the largest rail angle stress the triad construction.
        let g = GonioGeometry {
            rail_max_deg: 180.0,
            rail_min_deg: 0.0,
            min_lamp_camera_separation_deg: 0.0,
            joint_min_deg: [-180.0, -90.0, -360.0],
            joint_max_deg: [180.0, 90.0, 360.0],
            ..GonioGeometry::bonn()
        };
        let gonio = Gonio::new(g).expect("valid");
        let cases = [
            (Direction::new(0.0, 0.0), Direction::new(1e-7, 1.0)),
            (Direction::new(1e-9, 2.0), Direction::new(0.3, 4.0)),
            (Direction::new(0.0, 5.0), Direction::new(89.0f64.to_radians(), 0.3)),
            (Direction::from_degrees(89.0, 0.0), Direction::from_degrees(89.0, 180.0 - 1e-6)),
            (Direction::from_degrees(45.0, 10.0), Direction::from_degrees(45.0 + 1e-6, 10.0)),
        ];
        for (l, v) in cases {
            let j = gonio.ik(l, v).unwrap_or_else(|e| panic!("{l:?} {v:?}: {e}"));
            let (l2, v2) = gonio.fk(&j);
            assert!(
                angular_error(l, l2) < 1e-9 && angular_error(v, v2) < 1e-9,
                "{l:?} {v:?}: {:e} {:e}",
                angular_error(l, l2),
                angular_error(v, v2)
            );
        }
    }

    #[test]
    fn scene_pose_agrees_with_fk_also_for_jittered_joints() {
        let gonio = bonn();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..2000 {
            let j = JointState {
                rail: rng.gen_range(0.1..3.0),
                robot: [rng.gen_range(-2.0..2.0), rng.gen_range(-1.4..1.4), rng.gen_range(-3.0..3.0)],
                turntable: rng.gen_range(-0.5..0.5),
            };
            let (l, v) = gonio.fk(&j);
            let pose = gonio.scene_pose(&j);
            let l_pose = direction_of(&pose.lamp_in_sample().coords);
            let v_pose = direction_of(&pose.camera_in_sample().coords);
            assert!(angular_error(l, l_pose) < 1e-12 && angular_error(v, v_pose) < 1e-12);
            // Distances from the config, camera looking at the sample centre, image y down.
            assert!((pose.camera_in_sample().coords.norm() - 1.2).abs() < 1e-12);
            assert!((pose.lamp_in_sample().coords.norm() - 2.0).abs() < 1e-12);
            let centre = pose.camera_to_world.inverse_transform_point(&Point3::origin());
            assert!(centre.x.abs() < 1e-12 && centre.y.abs() < 1e-12 && (centre.z - 1.2).abs() < 1e-12);
            let down = pose.camera_to_world.transform_vector(&Vector3::y());
            assert!((down - (-Vector3::z())).norm() < 1e-12);
        }
    }

    #[test]
    fn analytic_home_pose() {
        // All joints 0: the normal faces the lamp, sample x along world y. Rail 90 deg puts
        // the camera on world +y, i.e. on the sample's +x axis at grazing.
        let gonio = bonn();
        let j = JointState { rail: FRAC_PI_2, robot: [0.0; 3], turntable: 0.0 };
        let (l, v) = gonio.fk(&j);
        assert!(l.theta.abs() < 1e-15);
        assert!(v.angle_to(Direction::from_degrees(90.0, 0.0)) < 1e-15);
        // Tilt 30 deg raises the normal: the lamp (horizontal) is then 30 deg from the normal,
        // below it, i.e. towards sample -y.
        let j = JointState { rail: FRAC_PI_2, robot: [0.0, 30f64.to_radians(), 0.0], turntable: 0.0 };
        let (l, _) = gonio.fk(&j);
        assert!(l.angle_to(Direction::from_degrees(30.0, 270.0)) < 1e-12);
        // IK of a symmetric pair in the plane of the normal and x: the normal bisects the
        // lamp and camera, so pan = rail / 2 and tilt = 0.
        let j = gonio.ik(Direction::from_degrees(40.0, 180.0), Direction::from_degrees(40.0, 0.0)).expect("reachable");
        assert!((j.rail - 80f64.to_radians()).abs() < 1e-12);
        assert!((j.robot[0] - 40f64.to_radians()).abs() < 1e-12 && j.robot[1].abs() < 1e-12, "{j:?}");
    }

    #[test]
    fn reasons_are_reported() {
        let gonio = bonn();
        let e = gonio.ik(Direction::from_degrees(90.0, 0.0), Direction::from_degrees(10.0, 0.0)).unwrap_err();
        assert!(matches!(e, Unreachable::BelowHorizon { which: Device::Lamp, .. }), "{e}");
        let e = gonio.ik(Direction::from_degrees(10.0, 0.0), Direction::from_degrees(91.0, 0.0)).unwrap_err();
        assert!(matches!(e, Unreachable::BelowHorizon { which: Device::Camera, .. }), "{e}");
        let e = gonio.ik(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(35.0, 0.0)).unwrap_err();
        assert!(matches!(e, Unreachable::CameraBlocksLamp { .. }), "{e}");
        assert!(e.to_string().contains("5.000 deg apart, at least 8 deg"), "{e}");
        let e = gonio.ik(Direction::from_degrees(88.0, 0.0), Direction::from_degrees(88.0, 177.0)).unwrap_err();
        assert!(matches!(e, Unreachable::RailLimit { .. }), "{e}");
        // Tight tilt limits: a pair that needs the normal well above the horizontal plane.
        let tight = Gonio::new(GonioGeometry {
            joint_min_deg: [-120.0, -20.0, -185.0],
            joint_max_deg: [120.0, 20.0, 185.0],
            ..GonioGeometry::bonn()
        })
        .expect("valid");
        let e = tight.ik(Direction::from_degrees(60.0, 0.0), Direction::from_degrees(60.0, 90.0)).unwrap_err();
        assert!(matches!(e, Unreachable::JointLimit { joint: 1, .. }), "{e}");
        assert!(e.to_string().contains("tilt"), "{e}");
    }

    #[test]
    fn a_shoulder_in_front_of_the_sample_shadows_or_collides() {
        // Shoulder between sample and lamp, in the rail plane: lamp rays must be blocked
        // for a sample facing the lamp, and the forearm crosses the plate for frontal pairs.
        let g = GonioGeometry { robot_shoulder_m: [1.0, 0.0, 0.0], ..GonioGeometry::bonn() };
        let gonio = Gonio::new(g).expect("valid");
        let e = gonio.ik(Direction::from_degrees(0.0, 0.0), Direction::from_degrees(45.0, 0.0)).unwrap_err();
        assert_eq!(e.kind(), UnreachableKind::ArmHitsHolder, "{e}");
        // Lamp at grazing: the forearm leaves the plate's back, swings past the plate edge
        // and runs to (1, 0, 0), right along the lamp ray.
        let mut shadowed = 0;
        let s = Sampling::bonn81();
        let report = gonio.report(&s, &s);
        shadowed += report.count(UnreachableKind::RobotShadows);
        assert!(shadowed > 0, "{report}");
        // The default rig has its shoulder behind and below: no shadowing at all for the
        // pairs checked above.
        assert!(bonn().ik(Direction::from_degrees(0.0, 0.0), Direction::from_degrees(45.0, 0.0)).is_ok());
    }

    #[test]
    fn segment_distance_cases() {
        let z = Vector3::zeros();
        let d = segment_distance(&z, &Vector3::x(), &Vector3::new(0.5, 1.0, -1.0), &Vector3::new(0.5, 1.0, 1.0));
        assert!((d - 1.0).abs() < 1e-15);
        let d = segment_distance(&z, &Vector3::x(), &Vector3::new(2.0, 0.0, 0.0), &Vector3::new(3.0, 0.0, 0.0));
        assert!((d - 1.0).abs() < 1e-15);
        let d = segment_distance(&z, &Vector3::x(), &Vector3::new(0.2, 0.0, 0.0), &Vector3::new(0.8, 0.0, 0.0));
        assert!(d.abs() < 1e-15);
    }
}
