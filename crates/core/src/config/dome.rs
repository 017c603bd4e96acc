//! The `[dome]` section of an LED dome (`kind = "led_dome"`): fixed LEDs on a hemisphere,
//! fixed cameras on an arc, the sample on a turntable (Bonn's Dome II: 198 LEDs, 11 cameras,
//! 12 rotations).
//!
//! World frame: metres, origin at the sample centre, `z` up (the sample normal at every
//! turntable angle). LED `j` of ring `r` sits at polar angle `theta_r` and azimuth
//! `phi_offset_r + 360 k / count_r` on the sphere of `led_radius_m`; LEDs are numbered ring
//! by ring in file order. Camera `c` sits at `camera_theta_deg[c]`, azimuth
//! `camera_azimuth_deg`, `camera_distance_m` from the origin, looking at it. Rotation `k`
//! turns the sample by `360 k / rotations` degrees about `z`. Per-LED power and colour are
//! spread around 1 by seeded log-normal factors (a property of the rig; the pipeline uses
//! them as the LED calibration).

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::direction::Direction;
use crate::pose::ScenePose;
use crate::ConfigError;

/// One ring of LEDs at a fixed polar angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedRing {
    /// Polar angle of the ring from the zenith, degrees (0..=89).
    pub theta_deg: f64,
    /// LEDs on the ring, evenly spaced in azimuth (1..=1000).
    pub count: usize,
    /// Azimuth of the ring's first LED, degrees (default 0).
    #[serde(default)]
    pub phi_offset_deg: f64,
}

/// The `[dome]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomeConfig {
    /// Distance from the sample centre to every LED, metres (0.1..=10).
    pub led_radius_m: f64,
    /// The LED rings, numbered in this order.
    pub led_rings: Vec<LedRing>,
    /// Irradiance one LED at full output gives a surface facing it at 1 m, W/m² over
    /// 380–780 nm, with the `[lamp] spectrum` (0 < E <= 1e5).
    pub led_irradiance_at_1m_w_m2: f64,
    /// Relative RMS spread of the LEDs' power (log-normal, seeded from `[rig] seed`; 0..=0.5).
    #[serde(default)]
    pub led_power_spread: f64,
    /// Relative RMS spread of each LED's R, G, B output (log-normal per channel; 0..=0.2).
    #[serde(default)]
    pub led_colour_spread: f64,
    /// Polar angles of the cameras on the arc, degrees (each 0..=80).
    pub camera_theta_deg: Vec<f64>,
    /// Distance from the sample centre to every camera's centre of projection, metres (0.1..=10).
    pub camera_distance_m: f64,
    /// Azimuth of the camera arc, degrees.
    #[serde(default)]
    pub camera_azimuth_deg: f64,
    /// Turntable positions per measurement, evenly spaced over 360 degrees (1..=360).
    pub rotations: u32,
}

impl DomeConfig {
    /// Appends every out-of-range value to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let f = "dome";
        if !(self.led_radius_m.is_finite() && (0.1..=10.0).contains(&self.led_radius_m)) {
            errors.push(ConfigError::out_of_range(&format!("{f}.led_radius_m"), self.led_radius_m, "0.1..=10"));
        }
        if self.led_rings.is_empty() {
            errors.push(ConfigError::out_of_range(&format!("{f}.led_rings"), "[]", "at least one ring"));
        }
        for (i, r) in self.led_rings.iter().enumerate() {
            if !(r.theta_deg.is_finite() && (0.0..=89.0).contains(&r.theta_deg)) {
                errors.push(ConfigError::out_of_range(&format!("{f}.led_rings[{i}].theta_deg"), r.theta_deg, "0..=89"));
            }
            if !(1..=1000).contains(&r.count) {
                errors.push(ConfigError::out_of_range(&format!("{f}.led_rings[{i}].count"), r.count, "1..=1000"));
            }
            if !r.phi_offset_deg.is_finite() {
                errors.push(ConfigError::out_of_range(
                    &format!("{f}.led_rings[{i}].phi_offset_deg"),
                    r.phi_offset_deg,
                    "finite",
                ));
            }
        }
        let e = self.led_irradiance_at_1m_w_m2;
        if !(e.is_finite() && e > 0.0 && e <= 1e5) {
            errors.push(ConfigError::out_of_range(&format!("{f}.led_irradiance_at_1m_w_m2"), e, "0 < E <= 1e5"));
        }
        if !(0.0..=0.5).contains(&self.led_power_spread) {
            errors.push(ConfigError::out_of_range(&format!("{f}.led_power_spread"), self.led_power_spread, "0..=0.5"));
        }
        if !(0.0..=0.2).contains(&self.led_colour_spread) {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.led_colour_spread"),
                self.led_colour_spread,
                "0..=0.2",
            ));
        }
        if self.camera_theta_deg.is_empty() || self.camera_theta_deg.len() > 100 {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_theta_deg"),
                format!("{} cameras", self.camera_theta_deg.len()),
                "1..=100 cameras",
            ));
        }
        for (i, t) in self.camera_theta_deg.iter().enumerate() {
            if !(t.is_finite() && (0.0..=80.0).contains(t)) {
                errors.push(ConfigError::out_of_range(&format!("{f}.camera_theta_deg[{i}]"), t, "0..=80"));
            }
        }
        if !(self.camera_distance_m.is_finite() && (0.1..=10.0).contains(&self.camera_distance_m)) {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_distance_m"),
                self.camera_distance_m,
                "0.1..=10",
            ));
        }
        if !self.camera_azimuth_deg.is_finite() {
            errors.push(ConfigError::out_of_range(&format!("{f}.camera_azimuth_deg"), self.camera_azimuth_deg, "finite"));
        }
        if !(1..=360).contains(&self.rotations) {
            errors.push(ConfigError::out_of_range(&format!("{f}.rotations"), self.rotations, "1..=360"));
        }
    }

    /// Number of LEDs.
    pub fn led_count(&self) -> usize {
        self.led_rings.iter().map(|r| r.count).sum()
    }

    /// Number of cameras on the arc.
    pub fn camera_count(&self) -> usize {
        self.camera_theta_deg.len()
    }

    /// World direction of every LED (from the sample centre), in LED index order.
    pub fn led_directions(&self) -> Vec<Direction> {
        self.led_rings
            .iter()
            .flat_map(|r| {
                (0..r.count).map(move |k| Direction::from_degrees(r.theta_deg, r.phi_offset_deg + 360.0 * k as f64 / r.count as f64))
            })
            .collect()
    }

    /// World position of LED `j`, metres.
    pub fn led_position(&self, j: usize) -> Point3<f64> {
        Point3::from(self.led_directions()[j].to_vector() * self.led_radius_m)
    }

    /// World direction towards camera `c`.
    pub fn camera_direction(&self, c: usize) -> Direction {
        Direction::from_degrees(self.camera_theta_deg[c], self.camera_azimuth_deg)
    }

    /// Turntable angle of rotation `k`, radians.
    pub fn rotation_rad(&self, k: u32) -> f64 {
        (360.0 * f64::from(k) / f64::from(self.rotations)).to_radians()
    }

    /// Camera `c`'s pose: at its arc position, optical axis through the origin, image `x`
    /// horizontal (perpendicular to the arc's plane) so the sample's image is upright.
    pub fn camera_to_world(&self, c: usize) -> Isometry3<f64> {
        let v = self.camera_direction(c).to_vector();
        let z_cam = -v;
        // Image x along the horizontal tangent of the arc: the cross product with the zenith,
        // or the world y axis when looking straight down.
        let up = Vector3::z();
        let mut x_cam = z_cam.cross(&up);
        if x_cam.norm() < 1e-6 {
            let phi = self.camera_azimuth_deg.to_radians();
            x_cam = Vector3::new(-phi.sin(), phi.cos(), 0.0);
        }
        let x_cam = x_cam.normalize();
        let y_cam = z_cam.cross(&x_cam);
        let rot = Rotation3::from_basis_unchecked(&[x_cam, y_cam, z_cam]);
        Isometry3::from_parts(
            Translation3::from(v * self.camera_distance_m),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    /// The scene pose of camera `c`, the sample turned by `turntable_rad`, and LED `led`
    /// (the renderer's point light).
    pub fn scene_pose(&self, c: usize, turntable_rad: f64, led: usize) -> ScenePose {
        ScenePose {
            sample_to_world: Isometry3::rotation(Vector3::z() * turntable_rad),
            camera_to_world: self.camera_to_world(c),
            lamp_position: self.led_position(led),
        }
    }

    /// The exact light and view directions in the sample frame of camera `c`, the sample at
    /// `turntable_rad` and LED `led` (what a BTF texel's (light, view) pair is).
    pub fn sample_directions(&self, c: usize, turntable_rad: f64, led: usize) -> (Direction, Direction) {
        let pose = self.scene_pose(c, turntable_rad, led);
        (Direction::from_vector(&pose.lamp_in_sample().coords), Direction::from_vector(&pose.camera_in_sample().coords))
    }

    /// Per-LED power factors around 1 (log-normal with RMS `led_power_spread`), from `seed`.
    pub fn led_power(&self, seed: u64) -> Vec<f64> {
        let mut rng = SplitMix(seed ^ 0x1ed_9043);
        (0..self.led_count()).map(|_| (self.led_power_spread * rng.normal()).exp()).collect()
    }

    /// Per-LED R, G, B output factors around 1 (log-normal with RMS `led_colour_spread`,
    /// normalised to green = 1 so the power factor alone sets the brightness), from `seed`.
    pub fn led_colour(&self, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = SplitMix(seed ^ 0xc0_1003);
        (0..self.led_count())
            .map(|_| {
                let s = self.led_colour_spread;
                [(s * rng.normal()).exp(), 1.0, (s * rng.normal()).exp()]
            })
            .collect()
    }
}

/// A tiny seeded generator (core has no RNG dependency): SplitMix64 with Box–Muller.
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u, v) = (self.next_f64(), self.next_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dome() -> DomeConfig {
        DomeConfig {
            led_radius_m: 0.65,
            led_rings: vec![
                LedRing { theta_deg: 10.0, count: 4, phi_offset_deg: 0.0 },
                LedRing { theta_deg: 50.0, count: 8, phi_offset_deg: 22.5 },
            ],
            led_irradiance_at_1m_w_m2: 0.5,
            led_power_spread: 0.1,
            led_colour_spread: 0.03,
            camera_theta_deg: vec![0.0, 30.0, 60.0],
            camera_distance_m: 0.7,
            camera_azimuth_deg: 0.0,
            rotations: 12,
        }
    }

    #[test]
    fn leds_lie_on_the_sphere_ring_by_ring() {
        let d = dome();
        assert_eq!(d.led_count(), 12);
        let dirs = d.led_directions();
        assert!((dirs[0].to_degrees().0 - 10.0).abs() < 1e-9);
        assert!((dirs[4].to_degrees().0 - 50.0).abs() < 1e-9);
        assert!((d.led_position(7).coords.norm() - 0.65).abs() < 1e-12);
    }

    #[test]
    fn cameras_look_at_the_sample_centre_from_their_arc_position() {
        let d = dome();
        for c in 0..3 {
            let pose = d.scene_pose(c, 0.7, 0);
            let origin_in_cam = pose.camera_to_world.inverse_transform_point(&Point3::origin());
            assert!(origin_in_cam.x.abs() < 1e-12 && origin_in_cam.y.abs() < 1e-12, "camera {c}");
            assert!((origin_in_cam.z - 0.7).abs() < 1e-12);
        }
    }

    #[test]
    fn spreads_are_seeded_and_centred() {
        let d = dome();
        assert_eq!(d.led_power(5), d.led_power(5));
        assert_ne!(d.led_power(5), d.led_power(6));
        let p = d.led_power(1);
        assert!(p.iter().all(|v| (0.5..2.0).contains(v)));
        assert!(d.led_colour(1).iter().all(|c| c[1] == 1.0));
    }

    #[test]
    fn bad_values_name_field_and_range() {
        let mut d = dome();
        d.rotations = 0;
        d.led_rings[1].theta_deg = 95.0;
        let mut e = Vec::new();
        d.validate(&mut e);
        let text: Vec<String> = e.iter().map(|e| e.to_string()).collect();
        assert!(text.contains(&"dome.rotations = 0 is out of range: allowed 1..=360".to_string()), "{text:?}");
        assert!(text.iter().any(|t| t.starts_with("dome.led_rings[1].theta_deg = 95")), "{text:?}");
    }

    fn shipped() -> &'static str {
        crate::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-dome-sim").unwrap().1
    }

    #[test]
    fn the_shipped_dome_is_dome_ii_sized() {
        let cfg = crate::config::RigConfig::from_toml(shipped(), "bonn-dome-sim").unwrap();
        let d = cfg.require_dome("test").unwrap();
        assert_eq!((d.led_count(), d.camera_count(), d.rotations), (198, 11, 12));
        let e = cfg.require_gonio("inverse kinematics").unwrap_err().to_string();
        assert!(e.contains("rig.kind = \"led_dome\"") && e.contains("gonioreflectometer"), "{e}");
    }

    #[test]
    fn kind_and_sections_must_agree() {
        let no_dome = shipped().replace("[dome]", "[unused]");
        let gonio = shipped().replace("kind = \"led_dome\"", "kind = \"gonioreflectometer\"");
        let e = crate::config::RigConfig::from_toml(&gonio, "x").unwrap_err().to_string();
        assert!(e.contains("only with [rig] kind = \"led_dome\""), "{e}");
        assert!(crate::config::RigConfig::from_toml(&no_dome, "x").is_err());
        let wrong_count = shipped().replace("count = 198", "count = 197");
        let e = crate::config::RigConfig::from_toml(&wrong_count, "x").unwrap_err().to_string();
        assert!(e.contains("devices.led_array.count = 197 is out of range: allowed 198"), "{e}");
    }

    #[test]
    fn a_gonio_plan_on_a_dome_is_refused_by_name() {
        let plan = crate::plan::Plan::from_toml(
            "[rig]\nconfig = \"builtin:bonn-dome-sim\"\n[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n",
            "p",
        )
        .unwrap();
        let e = plan.validate(&crate::plan::PlanContext::with_builtin_names()).unwrap_err().to_string();
        assert!(e.contains("rig.config") && e.contains("led_dome"), "{e}");
    }
}
