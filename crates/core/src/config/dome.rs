//! The `[dome]` section of a dome rig: fixed lights on a hemisphere, fixed cameras, the
//! sample (optionally) on a turntable. Two kinds share it:
//!
//! * an LED dome (`kind = "led_dome"`, Bonn's Dome II: 198 LEDs, 11 cameras on an arc, 12
//!   turntable rotations): the lights are `led_rings`;
//! * a camera array (`kind = "camera_array"`, Bonn's first dome: 151 consumer cameras on a
//!   hemisphere): the lights are the cameras' flashes (`[dome.flash]`), flash `j` sits at camera
//!   `j`'s `flash.offset_m` in its camera frame; no turntable (`rotations = 1`).
//!
//! World frame: metres, origin at the sample centre, `z` up (the sample normal at every
//! turntable angle). LED `j` of ring `r` sits at polar angle `theta_r` and azimuth
//! `phi_offset_r + 360 k / count_r` on the sphere of `led_radius_m`; LEDs are numbered ring
//! by ring in file order. Cameras are either an arc (`camera_theta_deg`, at azimuth
//! `camera_azimuth_deg`) or rings (`camera_rings`, numbered like LED rings), each
//! `camera_distance_m` from the origin, looking at it. Rotation `k` turns the sample by
//! `360 k / rotations` degrees about `z`. Per-light power and colour are spread around 1 by
//! seeded log-normal factors (a property of the rig; the pipeline uses them as the light
//! calibration).
//!
//! The code says "LED" for a light of either kind (`led_count`, `led_position`, ...): on a
//! camera array light `j` is the flash of camera `j`.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::config::RigKind;
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

/// The flashes of a camera array (`[dome.flash]`): one per camera, fired during the
/// exposure. A flash is a short pulse, so what a frame collects is its energy, not a rate
/// times the exposure: an exposure of at least `duration_s` catches the whole flash.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlashConfig {
    /// Position of each camera's flash in its own camera frame (x along image columns, y
    /// along image rows, z along the optical axis), metres (each component -0.3..=0.3).
    pub offset_m: [f64; 3],
    /// Radiant exposure one flash at full power gives a surface facing it at 1 m, J/m² over
    /// 380–780 nm, with the `[lamp] spectrum` (0 < H <= 1e3).
    pub energy_at_1m_j_m2: f64,
    /// Length of the flash pulse, s (1e-5..=0.1): an exposure shorter than it catches
    /// `exposure / duration` of the energy.
    pub duration_s: f64,
    /// Relative RMS spread of the flashes' energy (log-normal, seeded from `[rig] seed`; 0..=0.5).
    #[serde(default)]
    pub power_spread: f64,
    /// Relative RMS spread of each flash's R and B output against G (log-normal; 0..=0.2).
    #[serde(default)]
    pub colour_spread: f64,
}

const fn one() -> u32 {
    1
}

/// The `[dome]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomeConfig {
    /// Distance from the sample centre to every LED, metres (0.1..=10; LED dome only).
    #[serde(default)]
    pub led_radius_m: f64,
    /// The LED rings, numbered in this order (LED dome only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub led_rings: Vec<LedRing>,
    /// Irradiance one LED at full output gives a surface facing it at 1 m, W/m² over
    /// 380–780 nm, with the `[lamp] spectrum` (0 < E <= 1e5; LED dome only).
    #[serde(default)]
    pub led_irradiance_at_1m_w_m2: f64,
    /// Relative RMS spread of the LEDs' power (log-normal, seeded from `[rig] seed`; 0..=0.5).
    #[serde(default)]
    pub led_power_spread: f64,
    /// Relative RMS spread of each LED's R, G, B output (log-normal per channel; 0..=0.2).
    #[serde(default)]
    pub led_colour_spread: f64,
    /// The cameras' flashes, which are the lights of a camera array (camera array only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flash: Option<FlashConfig>,
    /// Polar angles of the cameras on an arc at `camera_azimuth_deg`, degrees (each 0..=80);
    /// give this or `camera_rings`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera_theta_deg: Vec<f64>,
    /// Rings of cameras on the hemisphere (polar angle 0..=80), numbered ring by ring; give
    /// this or `camera_theta_deg`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera_rings: Vec<LedRing>,
    /// Distance from the sample centre to every camera's centre of projection, metres (0.1..=10).
    pub camera_distance_m: f64,
    /// Azimuth of the camera arc, degrees.
    #[serde(default)]
    pub camera_azimuth_deg: f64,
    /// Turntable positions per measurement, evenly spaced over 360 degrees (1..=360; a
    /// camera array has no turntable: 1, the default).
    #[serde(default = "one")]
    pub rotations: u32,
    /// The lights' power and colour calibration the pipeline demultiplexes and converts with:
    /// `builtin:NAME` or a path relative to the rig file (made by `btfrig calibrate leds`,
    /// `docs/rig-config.md`, "LED calibration"). Without one, every light counts as equal and
    /// textures are in relative units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub led_calibration: Option<String>,
    /// The brightness the planner assumes for a light of nominal power when the rig names no
    /// `led_calibration` (whose `reference_rate` it takes otherwise): e-/s per photosite
    /// (green, gain 1; e- per flash on a camera array) of a white Lambertian reflector lit
    /// along its normal from the nominal light distance. A datasheet figure; it only chooses
    /// the capture mode and exposure, never converts a texture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_signal_e_per_s: Option<f64>,
}

impl DomeConfig {
    /// Appends every out-of-range value to `errors`; `kind` is the rig's (an LED dome needs
    /// `led_rings`, a camera array `[dome.flash]` and no LED fields).
    pub fn validate(&self, kind: RigKind, errors: &mut Vec<ConfigError>) {
        let f = "dome";
        if let Some(n) = self.nominal_signal_e_per_s.filter(|n| !(n.is_finite() && *n > 0.0 && *n <= 1e12)) {
            errors.push(ConfigError::out_of_range(&format!("{f}.nominal_signal_e_per_s"), n, "0 < rate <= 1e12"));
        }
        let flashes = kind == RigKind::CameraArray;
        if flashes {
            // The lights are the flashes: every LED field must stay unset.
            let none = "absent on a camera array (its lights are the cameras' flashes, [dome.flash])";
            for (field, set) in [
                ("led_radius_m", self.led_radius_m != 0.0),
                ("led_rings", !self.led_rings.is_empty()),
                ("led_irradiance_at_1m_w_m2", self.led_irradiance_at_1m_w_m2 != 0.0),
                ("led_power_spread", self.led_power_spread != 0.0),
                ("led_colour_spread", self.led_colour_spread != 0.0),
            ] {
                if set {
                    errors.push(ConfigError::out_of_range(&format!("{f}.{field}"), "set", none));
                }
            }
            match &self.flash {
                None => errors.push(ConfigError::out_of_range(
                    &format!("{f}.flash"),
                    "missing",
                    "a [dome.flash] section on a camera array",
                )),
                Some(fl) => fl.validate(errors),
            }
            if self.rotations != 1 {
                errors.push(ConfigError::out_of_range(
                    &format!("{f}.rotations"),
                    self.rotations,
                    "1 (a camera array has no turntable)",
                ));
            }
        } else {
            if self.flash.is_some() {
                errors.push(ConfigError::out_of_range(
                    &format!("{f}.flash"),
                    "a [dome.flash] section",
                    "only with [rig] kind = \"camera_array\"",
                ));
            }
            if !(self.led_radius_m.is_finite() && (0.1..=10.0).contains(&self.led_radius_m)) {
                errors.push(ConfigError::out_of_range(&format!("{f}.led_radius_m"), self.led_radius_m, "0.1..=10"));
            }
            if self.led_rings.is_empty() {
                errors.push(ConfigError::out_of_range(&format!("{f}.led_rings"), "[]", "at least one ring"));
            }
            validate_rings(&format!("{f}.led_rings"), &self.led_rings, 89.0, errors);
            let e = self.led_irradiance_at_1m_w_m2;
            if !(e.is_finite() && e > 0.0 && e <= 1e5) {
                errors.push(ConfigError::out_of_range(&format!("{f}.led_irradiance_at_1m_w_m2"), e, "0 < E <= 1e5"));
            }
            if !(0.0..=0.5).contains(&self.led_power_spread) {
                errors.push(ConfigError::out_of_range(
                    &format!("{f}.led_power_spread"),
                    self.led_power_spread,
                    "0..=0.5",
                ));
            }
            if !(0.0..=0.2).contains(&self.led_colour_spread) {
                errors.push(ConfigError::out_of_range(
                    &format!("{f}.led_colour_spread"),
                    self.led_colour_spread,
                    "0..=0.2",
                ));
            }
            if !(1..=360).contains(&self.rotations) {
                errors.push(ConfigError::out_of_range(&format!("{f}.rotations"), self.rotations, "1..=360"));
            }
        }
        match (self.camera_theta_deg.is_empty(), self.camera_rings.is_empty()) {
            (true, true) => errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_theta_deg"),
                "missing",
                "cameras as camera_theta_deg (an arc) or camera_rings",
            )),
            (false, false) => errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_rings"),
                "set together with camera_theta_deg",
                "one of camera_theta_deg (an arc) or camera_rings",
            )),
            _ => {}
        }
        if self.camera_theta_deg.len() > 100 {
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
        validate_rings(&format!("{f}.camera_rings"), &self.camera_rings, 80.0, errors);
        let ring_cameras: usize = self.camera_rings.iter().map(|r| r.count).sum();
        if ring_cameras > 1000 {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_rings"),
                format!("{ring_cameras} cameras"),
                "1..=1000 cameras",
            ));
        }
        if !(self.camera_distance_m.is_finite() && (0.1..=10.0).contains(&self.camera_distance_m)) {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_distance_m"),
                self.camera_distance_m,
                "0.1..=10",
            ));
        }
        if !self.camera_azimuth_deg.is_finite() {
            errors.push(ConfigError::out_of_range(
                &format!("{f}.camera_azimuth_deg"),
                self.camera_azimuth_deg,
                "finite",
            ));
        }
    }

    /// Whether the lights are the cameras' flashes (a camera array).
    pub fn is_flash(&self) -> bool {
        self.flash.is_some()
    }

    /// Number of lights: LEDs, or flashes (one per camera).
    pub fn led_count(&self) -> usize {
        match self.flash {
            Some(_) => self.camera_count(),
            None => self.led_rings.iter().map(|r| r.count).sum(),
        }
    }

    /// Number of cameras.
    pub fn camera_count(&self) -> usize {
        if self.camera_rings.is_empty() {
            self.camera_theta_deg.len()
        } else {
            self.camera_rings.iter().map(|r| r.count).sum()
        }
    }

    /// World direction of every light (from the sample centre), in light index order.
    pub fn led_directions(&self) -> Vec<Direction> {
        if self.is_flash() {
            return (0..self.led_count()).map(|j| Direction::from_vector(&self.led_position(j).coords)).collect();
        }
        ring_directions(&self.led_rings)
    }

    /// World position of light `j` (LED `j`, or camera `j`'s flash), metres.
    pub fn led_position(&self, j: usize) -> Point3<f64> {
        match &self.flash {
            Some(fl) => self.camera_to_world(j) * Point3::from(Vector3::from(fl.offset_m)),
            None => {
                let (ring, k) = ring_index(&self.led_rings, j);
                let dir =
                    Direction::from_degrees(ring.theta_deg, ring.phi_offset_deg + 360.0 * k as f64 / ring.count as f64);
                Point3::from(dir.to_vector() * self.led_radius_m)
            }
        }
    }

    /// What one light at full output gives a surface facing it at 1 m: an LED's irradiance,
    /// W/m², or a flash's radiant exposure, J/m² (the renderer's light scale).
    pub fn light_at_1m(&self) -> f64 {
        self.flash.as_ref().map_or(self.led_irradiance_at_1m_w_m2, |f| f.energy_at_1m_j_m2)
    }

    /// The nominal distance of the lights from the sample centre, metres (the LED radius, or
    /// the camera distance for flashes): the light calibration's reference.
    pub fn light_distance_m(&self) -> f64 {
        if self.is_flash() {
            self.camera_distance_m
        } else {
            self.led_radius_m
        }
    }

    /// How much of one light a frame of `exposure_s` collects, in the unit of
    /// [`DomeConfig::light_at_1m`]: the exposure in seconds for an LED, the fraction of the
    /// flash pulse for a flash (1 for exposures at least `flash.duration_s` long). A
    /// simulated frame's signal is the light's rate times this.
    pub fn light_units(&self, exposure_s: f64) -> f64 {
        match &self.flash {
            Some(f) => (exposure_s / f.duration_s).min(1.0),
            None => exposure_s,
        }
    }

    /// World direction towards camera `c`.
    pub fn camera_direction(&self, c: usize) -> Direction {
        if self.camera_rings.is_empty() {
            Direction::from_degrees(self.camera_theta_deg[c], self.camera_azimuth_deg)
        } else {
            let (ring, k) = ring_index(&self.camera_rings, c);
            Direction::from_degrees(ring.theta_deg, ring.phi_offset_deg + 360.0 * k as f64 / ring.count as f64)
        }
    }

    /// Turntable angle of rotation `k`, radians.
    pub fn rotation_rad(&self, k: u32) -> f64 {
        (360.0 * f64::from(k) / f64::from(self.rotations)).to_radians()
    }

    /// Camera `c`'s pose: at its position, optical axis through the origin, image `x`
    /// horizontal (perpendicular to the camera's meridian) so the sample's image is upright.
    pub fn camera_to_world(&self, c: usize) -> Isometry3<f64> {
        let dir = self.camera_direction(c);
        let v = dir.to_vector();
        let z_cam = -v;
        // Image x along the horizontal tangent of the meridian: the cross product with the
        // zenith, or (looking straight down) perpendicular to the camera's azimuth.
        let up = Vector3::z();
        let mut x_cam = z_cam.cross(&up);
        if x_cam.norm() < 1e-6 {
            let phi = if self.camera_rings.is_empty() { self.camera_azimuth_deg.to_radians() } else { dir.phi };
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

    /// The scene pose of camera `c`, the sample turned by `turntable_rad`, and light `led`
    /// (the renderer's point light).
    pub fn scene_pose(&self, c: usize, turntable_rad: f64, led: usize) -> ScenePose {
        ScenePose {
            sample_to_world: Isometry3::rotation(Vector3::z() * turntable_rad),
            camera_to_world: self.camera_to_world(c),
            lamp_position: self.led_position(led),
        }
    }

    /// The exact light and view directions in the sample frame of camera `c`, the sample at
    /// `turntable_rad` and light `led` (what a BTF texel's (light, view) pair is).
    pub fn sample_directions(&self, c: usize, turntable_rad: f64, led: usize) -> (Direction, Direction) {
        let pose = self.scene_pose(c, turntable_rad, led);
        (Direction::from_vector(&pose.lamp_in_sample().coords), Direction::from_vector(&pose.camera_in_sample().coords))
    }

    fn spreads(&self) -> (f64, f64) {
        self.flash
            .as_ref()
            .map_or((self.led_power_spread, self.led_colour_spread), |f| (f.power_spread, f.colour_spread))
    }

    /// Per-light power factors around 1 (log-normal with RMS `led_power_spread`, or
    /// `flash.power_spread`), from `seed`.
    pub fn led_power(&self, seed: u64) -> Vec<f64> {
        let mut rng = SplitMix(seed ^ 0x1ed_9043);
        let spread = self.spreads().0;
        (0..self.led_count()).map(|_| (spread * rng.normal()).exp()).collect()
    }

    /// Per-light R, G, B output factors around 1 (log-normal with RMS `led_colour_spread`, or
    /// `flash.colour_spread`, normalised to green = 1 so the power factor alone sets the
    /// brightness), from `seed`.
    pub fn led_colour(&self, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = SplitMix(seed ^ 0xc0_1003);
        let s = self.spreads().1;
        (0..self.led_count()).map(|_| [(s * rng.normal()).exp(), 1.0, (s * rng.normal()).exp()]).collect()
    }
}

impl FlashConfig {
    fn validate(&self, errors: &mut Vec<ConfigError>) {
        let f = "dome.flash";
        for (i, v) in self.offset_m.iter().enumerate() {
            if !(v.is_finite() && (-0.3..=0.3).contains(v)) {
                errors.push(ConfigError::out_of_range(&format!("{f}.offset_m[{i}]"), v, "-0.3..=0.3"));
            }
        }
        let h = self.energy_at_1m_j_m2;
        if !(h.is_finite() && h > 0.0 && h <= 1e3) {
            errors.push(ConfigError::out_of_range(&format!("{f}.energy_at_1m_j_m2"), h, "0 < H <= 1e3"));
        }
        if !(self.duration_s.is_finite() && (1e-5..=0.1).contains(&self.duration_s)) {
            errors.push(ConfigError::out_of_range(&format!("{f}.duration_s"), self.duration_s, "1e-5..=0.1"));
        }
        if !(0.0..=0.5).contains(&self.power_spread) {
            errors.push(ConfigError::out_of_range(&format!("{f}.power_spread"), self.power_spread, "0..=0.5"));
        }
        if !(0.0..=0.2).contains(&self.colour_spread) {
            errors.push(ConfigError::out_of_range(&format!("{f}.colour_spread"), self.colour_spread, "0..=0.2"));
        }
    }
}

/// Every out-of-range value of `rings` (polar angle 0..=`max_theta`, count 1..=1000, finite offset).
fn validate_rings(field: &str, rings: &[LedRing], max_theta: f64, errors: &mut Vec<ConfigError>) {
    for (i, r) in rings.iter().enumerate() {
        if !(r.theta_deg.is_finite() && (0.0..=max_theta).contains(&r.theta_deg)) {
            errors.push(ConfigError::out_of_range(
                &format!("{field}[{i}].theta_deg"),
                r.theta_deg,
                &format!("0..={max_theta}"),
            ));
        }
        if !(1..=1000).contains(&r.count) {
            errors.push(ConfigError::out_of_range(&format!("{field}[{i}].count"), r.count, "1..=1000"));
        }
        if !r.phi_offset_deg.is_finite() {
            errors.push(ConfigError::out_of_range(&format!("{field}[{i}].phi_offset_deg"), r.phi_offset_deg, "finite"));
        }
    }
}

/// Directions of every entry of `rings`, ring by ring.
fn ring_directions(rings: &[LedRing]) -> Vec<Direction> {
    rings
        .iter()
        .flat_map(|r| {
            (0..r.count).map(move |k| {
                Direction::from_degrees(r.theta_deg, r.phi_offset_deg + 360.0 * k as f64 / r.count as f64)
            })
        })
        .collect()
}

/// The ring of entry `j` and its position on the ring.
fn ring_index(rings: &[LedRing], mut j: usize) -> (&LedRing, usize) {
    for r in rings {
        if j < r.count {
            return (r, j);
        }
        j -= r.count;
    }
    panic!("index beyond the rings' {} entries", rings.iter().map(|r| r.count).sum::<usize>())
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
            flash: None,
            camera_theta_deg: vec![0.0, 30.0, 60.0],
            camera_rings: Vec::new(),
            camera_distance_m: 0.7,
            camera_azimuth_deg: 0.0,
            rotations: 12,
            led_calibration: None,
            nominal_signal_e_per_s: None,
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
        d.validate(RigKind::LedDome, &mut e);
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

    fn shipped_array() -> &'static str {
        crate::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-camera-array-sim").unwrap().1
    }

    #[test]
    fn the_shipped_camera_array_has_151_cameras_whose_flashes_are_the_lights() {
        let cfg = crate::config::RigConfig::from_toml(shipped_array(), "bonn-camera-array-sim").unwrap();
        let d = cfg.require_dome("test").unwrap();
        assert_eq!((d.led_count(), d.camera_count(), d.rotations), (151, 151, 1));
        assert!(cfg.devices.turntable.is_none());
        // The cameras are the Dome-1 layout, ring by ring.
        let layout = crate::sampling::Sampling::bonn_dome1();
        for c in [0, 1, 30, 31, 150] {
            let (t, p) = d.camera_direction(c).to_degrees();
            let (lt, lp) = layout.directions()[c].to_degrees();
            assert!((t - lt).abs() < 1e-9 && ((p - lp + 540.0) % 360.0 - 180.0).abs() < 1e-9, "camera {c}");
        }
        // Flash j is 4 cm from camera j's centre of projection, close to its line of sight.
        for j in [0, 7, 100] {
            let cam = d.camera_to_world(j).translation.vector;
            let flash = d.led_position(j).coords;
            assert!(((flash - cam).norm() - 0.04).abs() < 1e-12, "flash {j}");
            let angle = cam.angle(&flash).to_degrees();
            assert!((3.0..3.6).contains(&angle), "flash {j}: {angle} deg from retro-reflection");
        }
        // A flash pulse: every exposure of at least its duration collects it once.
        assert_eq!((d.light_units(0.01), d.light_units(0.0005)), (1.0, 0.5));
        assert_eq!(d.led_power(3).len(), 151);
        let e = cfg.require_gonio("inverse kinematics").unwrap_err().to_string();
        assert!(e.contains("camera_array"), "{e}");
    }

    #[test]
    fn bad_camera_array_values_name_field_and_range() {
        let text = shipped_array()
            .replace("rotations = 1", "rotations = 4\nled_radius_m = 0.65")
            .replace("duration_s = 0.001", "duration_s = 0.5")
            .replace("offset_m = [0.0, -0.04, 0.0]", "offset_m = [0.0, -0.04, 1.0]")
            .replace("energy_at_1m_j_m2 = 1.2e-4", "energy_at_1m_j_m2 = 0.0")
            .replace("count = 151", "count = 150")
            .replace("[devices.led_array]", "[devices.turntable]\nkind = \"sim\"\n\n[devices.led_array]");
        let e = crate::config::RigConfig::from_toml(&text, "x").unwrap_err().to_string();
        for want in [
            "dome.rotations = 4 is out of range: allowed 1 (a camera array has no turntable)",
            "dome.led_radius_m = set is out of range: allowed absent on a camera array",
            "dome.flash.duration_s = 0.5 is out of range: allowed 1e-5..=0.1",
            "dome.flash.offset_m[2] = 1 is out of range: allowed -0.3..=0.3",
            "dome.flash.energy_at_1m_j_m2 = 0 is out of range: allowed 0 < H <= 1e3",
            "devices.led_array.count = 150 is out of range: allowed 151 (the flashes: one per camera)",
            "devices.turntable = an entry is out of range: allowed absent on a camera array",
        ] {
            assert!(e.contains(want), "missing {want:?} in\n{e}");
        }
        let no_flash = shipped_array().replace("[dome.flash]", "[unused]");
        assert!(crate::config::RigConfig::from_toml(&no_flash, "x").is_err());
        let rings_and_arc =
            shipped_array().replace("camera_distance_m = 0.7", "camera_distance_m = 0.7\ncamera_theta_deg = [0.0]");
        let e = crate::config::RigConfig::from_toml(&rings_and_arc, "x").unwrap_err().to_string();
        assert!(e.contains("dome.camera_rings = set together with camera_theta_deg"), "{e}");
        let flash_on_led_dome = shipped().replace(
            "rotations = 12",
            "rotations = 12\n[dome.flash]\noffset_m = [0.0, 0.0, 0.0]\nenergy_at_1m_j_m2 = 1.0\nduration_s = 0.001",
        );
        let e = crate::config::RigConfig::from_toml(&flash_on_led_dome, "x").unwrap_err().to_string();
        assert!(
            e.contains(
                "dome.flash = a [dome.flash] section is out of range: allowed only with [rig] kind = \"camera_array\""
            ),
            "{e}"
        );
    }
}
