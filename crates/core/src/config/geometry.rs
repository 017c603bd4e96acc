//! The `[geometry]` section of a rig config: where lamp, rail and robot are, and their
//! limits. The frames and the arm model are described in `docs/kinematics.md`.

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// The `[geometry]` section of a gonioreflectometer.
///
/// World frame: metres, origin at the nominal sample centre, `z` up. The lamp sits on the
/// world `+x` axis; the camera rail is the horizontal circle around the origin, the camera at
/// rail angle `r` sits at `rail_radius_m * (cos r, sin r, 0)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GonioGeometry {
    /// Distance from the sample centre to the lamp (point source), metres.
    pub lamp_distance_m: f64,
    /// Radius of the camera rail (distance from the sample centre to the camera's centre of
    /// projection), metres.
    pub rail_radius_m: f64,
    /// Smallest rail angle (angle between lamp and camera seen from the sample), degrees.
    pub rail_min_deg: f64,
    /// Largest rail angle, degrees.
    pub rail_max_deg: f64,
    /// Smallest angle between lamp and camera, seen from the sample, at which the camera
    /// body does not block the lamp, degrees.
    pub min_lamp_camera_separation_deg: f64,
    /// Lower limits of the robot joints `[pan, tilt, roll]`, degrees.
    pub joint_min_deg: [f64; 3],
    /// Upper limits of the robot joints `[pan, tilt, roll]`, degrees.
    pub joint_max_deg: [f64; 3],
    /// Whether a turntable sits between the robot flange and the sample (rotating it about
    /// its normal). Inverse kinematics leaves it at 0; forward kinematics honours it.
    #[serde(default)]
    pub has_turntable: bool,
    /// Side of the square holder plate the sample lies on, metres.
    pub holder_plate_size_m: f64,
    /// Thickness of the holder plate (sample surface to the back where the arm attaches), metres.
    pub holder_plate_thickness_m: f64,
    /// Length of the robot flange leaving the back of the plate along the sample's `-z`, metres.
    pub arm_flange_length_m: f64,
    /// Radius of the cylinders that model flange and forearm, metres.
    pub arm_radius_m: f64,
    /// World position of the robot shoulder, where the forearm from the flange ends, metres.
    pub robot_shoulder_m: [f64; 3],
    /// The rig geometry calibration (joint zero offsets, `btfrig calibrate rig-geometry`):
    /// `builtin:NAME` or a file relative to the rig config. Processing adds its offsets to the
    /// commanded joints for the nominal pose; the simulator never reads it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
    /// How far the sample's pose may be from the nominal (kinematic) pose after a move, as
    /// the rig's specification says: degrees of rotation. Registration accepts no pose
    /// farther away, and the first frame's marker search windows are that large.
    /// Absent: [`DEFAULT_POSE_TOLERANCE_DEG`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_tolerance_deg: Option<f64>,
    /// The same for the translation, millimetres. Absent: [`DEFAULT_POSE_TOLERANCE_MM`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_tolerance_mm: Option<f64>,
}

/// The pose tolerance of a rig config without `pose_tolerance_deg`: a real rig's, not the
/// simulator's jitter.
pub const DEFAULT_POSE_TOLERANCE_DEG: f64 = 2.0;
/// The pose tolerance of a rig config without `pose_tolerance_mm`.
pub const DEFAULT_POSE_TOLERANCE_MM: f64 = 10.0;

impl Default for GonioGeometry {
    /// The default simulated Bonn-like rig (the values of `rig-configs/bonn-gonio-sim.toml`).
    fn default() -> Self {
        Self::bonn()
    }
}

impl GonioGeometry {
    /// The default simulated Bonn-like rig (the values of `rig-configs/bonn-gonio-sim.toml`).
    pub const fn bonn() -> Self {
        GonioGeometry {
            lamp_distance_m: 2.0,
            rail_radius_m: 1.2,
            rail_min_deg: 5.0,
            rail_max_deg: 175.0,
            min_lamp_camera_separation_deg: 8.0,
            joint_min_deg: [-120.0, -85.0, -185.0],
            joint_max_deg: [120.0, 85.0, 185.0],
            has_turntable: false,
            holder_plate_size_m: 0.2,
            holder_plate_thickness_m: 0.01,
            arm_flange_length_m: 0.25,
            arm_radius_m: 0.05,
            robot_shoulder_m: [-0.6, -0.6, -0.8],
            calibration: None,
            pose_tolerance_deg: None,
            pose_tolerance_mm: None,
        }
    }

    /// The pose tolerance in force: (degrees, metres), the defaults where a key is absent.
    pub fn pose_tolerance(&self) -> (f64, f64) {
        (
            self.pose_tolerance_deg.unwrap_or(DEFAULT_POSE_TOLERANCE_DEG),
            self.pose_tolerance_mm.unwrap_or(DEFAULT_POSE_TOLERANCE_MM) / 1000.0,
        )
    }

    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let mut range = |field: &str, value: f64, lo: f64, hi: f64, allowed: &str| {
            if !(value >= lo && value <= hi) {
                errors.push(ConfigError::out_of_range(&format!("geometry.{field}"), value, allowed));
            }
        };
        range("lamp_distance_m", self.lamp_distance_m, 0.1, 100.0, "0.1 ..= 100");
        range("rail_radius_m", self.rail_radius_m, 0.1, 100.0, "0.1 ..= 100");
        range("rail_min_deg", self.rail_min_deg, 0.0, 180.0, "0 ..= 180");
        range("rail_max_deg", self.rail_max_deg, 0.0, 180.0, "0 ..= 180");
        range("min_lamp_camera_separation_deg", self.min_lamp_camera_separation_deg, 0.0, 90.0, "0 ..= 90");
        for k in 0..3 {
            range(&format!("joint_min_deg[{k}]"), self.joint_min_deg[k], -360.0, 360.0, "-360 ..= 360");
            range(&format!("joint_max_deg[{k}]"), self.joint_max_deg[k], -360.0, 360.0, "-360 ..= 360");
        }
        range("holder_plate_size_m", self.holder_plate_size_m, 0.005, 1.0, "0.005 ..= 1");
        range("holder_plate_thickness_m", self.holder_plate_thickness_m, 0.0, 0.1, "0 ..= 0.1");
        range("arm_flange_length_m", self.arm_flange_length_m, 0.0, 2.0, "0 ..= 2");
        range("arm_radius_m", self.arm_radius_m, 0.001, 0.5, "0.001 ..= 0.5");
        if let Some(v) = self.pose_tolerance_deg {
            range("pose_tolerance_deg", v, 0.05, 10.0, "0.05 ..= 10 degrees");
        }
        if let Some(v) = self.pose_tolerance_mm {
            range("pose_tolerance_mm", v, 0.1, 100.0, "0.1 ..= 100 mm");
        }
        for k in 0..3 {
            range(&format!("robot_shoulder_m[{k}]"), self.robot_shoulder_m[k], -10.0, 10.0, "-10 ..= 10");
        }
        // Relations between fields, reported with the field that would have to change.
        if self.rail_min_deg >= self.rail_max_deg {
            errors.push(ConfigError::out_of_range(
                "geometry.rail_max_deg",
                self.rail_max_deg,
                &format!("> rail_min_deg = {}", self.rail_min_deg),
            ));
        }
        for k in 0..3 {
            if self.joint_min_deg[k] >= self.joint_max_deg[k] {
                errors.push(ConfigError::out_of_range(
                    &format!("geometry.joint_max_deg[{k}]"),
                    self.joint_max_deg[k],
                    &format!("> joint_min_deg[{k}] = {}", self.joint_min_deg[k]),
                ));
            }
        }
        let s = self.robot_shoulder_m;
        let reach = self.holder_plate_thickness_m + self.arm_flange_length_m;
        let shoulder_distance = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
        if shoulder_distance <= reach {
            errors.push(ConfigError::out_of_range(
                "geometry.robot_shoulder_m",
                format!("{s:?} (distance {shoulder_distance:.3} m)"),
                &format!("farther from the sample centre than plate thickness + flange length = {reach} m"),
            ));
        }
        if self.arm_radius_m >= self.holder_plate_size_m / 2.0 {
            errors.push(ConfigError::out_of_range(
                "geometry.arm_radius_m",
                self.arm_radius_m,
                &format!(
                    "< holder_plate_size_m / 2 = {} (the flange hides behind the plate)",
                    self.holder_plate_size_m / 2.0
                ),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEFAULT_RIG: &str = include_str!("../../../../rig-configs/bonn-gonio-sim.toml");

    /// Parses only the `[geometry]` table: the other sections belong to other owners.
    fn geometry_of(text: &str) -> GonioGeometry {
        let table: toml::Table = toml::from_str(text).expect("valid TOML");
        table["geometry"].clone().try_into().expect("a valid [geometry] section")
    }

    #[test]
    fn default_rig_file_has_the_default_geometry_and_it_validates() {
        let g = geometry_of(DEFAULT_RIG);
        // The shipped rig names its rig-geometry calibration; the nominal geometry is Bonn's.
        assert_eq!(g.calibration.as_deref(), Some("builtin:bonn-gonio-sim-rig-geometry"));
        assert_eq!(
            GonioGeometry { calibration: None, pose_tolerance_deg: None, pose_tolerance_mm: None, ..g.clone() },
            GonioGeometry::bonn()
        );
        // It states its pose tolerance (docs/rig-config.md); without the keys, the defaults.
        assert_eq!(g.pose_tolerance(), (1.5, 0.005));
        assert_eq!(
            GonioGeometry::bonn().pose_tolerance(),
            (DEFAULT_POSE_TOLERANCE_DEG, DEFAULT_POSE_TOLERANCE_MM / 1e3)
        );
        let mut errors = Vec::new();
        g.validate(&mut errors);
        assert!(errors.is_empty(), "{errors:?}");
    }

    #[test]
    fn every_bad_value_is_reported_with_its_range() {
        let g = GonioGeometry {
            lamp_distance_m: -1.0,
            rail_min_deg: 120.0,
            rail_max_deg: 100.0,
            joint_min_deg: [-120.0, f64::NAN, 10.0],
            joint_max_deg: [120.0, 85.0, 0.0],
            robot_shoulder_m: [0.1, 0.0, 0.0],
            pose_tolerance_deg: Some(0.0),
            pose_tolerance_mm: Some(f64::INFINITY),
            ..GonioGeometry::bonn()
        };
        let mut errors = Vec::new();
        g.validate(&mut errors);
        let text: Vec<String> = errors.iter().map(|e| e.to_string()).collect();
        let has = |needle: &str| text.iter().any(|t| t.contains(needle));
        assert!(has("geometry.lamp_distance_m = -1 is out of range: allowed 0.1 ..= 100"), "{text:#?}");
        assert!(has("geometry.rail_max_deg = 100"), "{text:#?}");
        assert!(has("geometry.joint_min_deg[1] = NaN"), "{text:#?}");
        assert!(has("geometry.joint_max_deg[2] = 0"), "{text:#?}");
        assert!(has("geometry.robot_shoulder_m"), "{text:#?}");
        assert!(has("geometry.pose_tolerance_deg = 0 is out of range: allowed 0.05 ..= 10 degrees"), "{text:#?}");
        assert!(has("geometry.pose_tolerance_mm = inf"), "{text:#?}");
        assert_eq!(errors.len(), 7, "{text:#?}");
    }

    #[test]
    fn unknown_fields_are_rejected() {
        let text = DEFAULT_RIG.replace("rail_radius_m", "rail_radius");
        let table: toml::Table = toml::from_str(&text).expect("valid TOML");
        let r: Result<GonioGeometry, _> = table["geometry"].clone().try_into();
        let msg = r.unwrap_err().to_string();
        assert!(msg.contains("rail_radius"), "{msg}");
    }
}
