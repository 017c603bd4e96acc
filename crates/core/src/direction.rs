//! Directions on the hemisphere above the sample, in the one convention used everywhere.
//!
//! The **sample frame** is right-handed: `z` is the sample's outward normal, `x` is the
//! sample's x axis (the texture's `u` axis, pointing from texel column 0 towards larger
//! columns), `y = z × x` (texture rows grow along `-y`, see `docs/conventions.md`).
//!
//! A direction points **from the sample towards** the light or the camera. `theta` is the
//! angle from the normal (`0` = straight above, `pi/2` = grazing), `phi` the azimuth from the
//! `x` axis towards `y`. Unit vector: `(sin θ cos φ, sin θ sin φ, cos θ)`.
//! Angles are radians in code; files and the command line use degrees.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// A direction in spherical sample coordinates (radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Direction {
    /// Angle from the sample normal, radians, in `[0, pi]` (`<= pi/2` above the sample).
    pub theta: f64,
    /// Azimuth from the sample's x axis towards y, radians, normalised to `[0, 2 pi)`.
    pub phi: f64,
}

impl Direction {
    /// A direction from angles in radians; `phi` is wrapped into `[0, 2 pi)`.
    pub fn new(theta: f64, phi: f64) -> Self {
        Self { theta, phi: wrap_2pi(phi) }
    }

    /// A direction from angles in degrees.
    pub fn from_degrees(theta_deg: f64, phi_deg: f64) -> Self {
        Self::new(theta_deg.to_radians(), phi_deg.to_radians())
    }

    /// `(theta, phi)` in degrees.
    pub fn to_degrees(self) -> (f64, f64) {
        (self.theta.to_degrees(), self.phi.to_degrees())
    }

    /// The unit vector in the sample frame.
    pub fn to_vector(self) -> Vector3<f64> {
        let (st, ct) = self.theta.sin_cos();
        let (sp, cp) = self.phi.sin_cos();
        Vector3::new(st * cp, st * sp, ct)
    }

    /// The direction of a (not necessarily unit, non-zero) vector in the sample frame.
    /// At the poles (`x = y = 0`) `phi` is 0 by definition.
    pub fn from_vector(v: &Vector3<f64>) -> Self {
        // atan2 of (horizontal length, height): full precision near the pole, where
        // acos(z / r) loses about half the digits.
        let theta = v.x.hypot(v.y).atan2(v.z);
        let phi = if v.x == 0.0 && v.y == 0.0 { 0.0 } else { v.y.atan2(v.x) };
        Self::new(theta, phi)
    }

    /// Angle between two directions, radians, accurate also for nearly equal directions.
    pub fn angle_to(self, other: Direction) -> f64 {
        angle_between(&self.to_vector(), &other.to_vector())
    }

    /// True if the direction lies strictly above the sample plane.
    pub fn is_above(self) -> bool {
        self.theta < std::f64::consts::FRAC_PI_2
    }
}

/// Angle between two vectors, radians. Uses `atan2(|a×b|, a·b)`, which keeps full precision
/// near 0 and pi, where `acos` of the dot product loses half the digits.
pub fn angle_between(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b))
}

/// Wraps an angle into `[0, 2 pi)`.
pub fn wrap_2pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a.rem_euclid(t);
    if w >= t {
        0.0
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vector_round_trip_over_the_hemisphere() {
        for it in 0..=18 {
            for ip in 0..36 {
                let d = Direction::from_degrees(it as f64 * 5.0, ip as f64 * 10.0);
                let back = Direction::from_vector(&d.to_vector());
                assert!(d.angle_to(back) < 1e-12, "{d:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn convention_axes() {
        let x = Direction::from_degrees(90.0, 0.0).to_vector();
        let y = Direction::from_degrees(90.0, 90.0).to_vector();
        let z = Direction::from_degrees(0.0, 123.0).to_vector();
        assert!((x - Vector3::x()).norm() < 1e-15);
        assert!((y - Vector3::y()).norm() < 1e-15);
        assert!((z - Vector3::z()).norm() < 1e-15);
    }

    #[test]
    fn phi_is_wrapped() {
        let d = Direction::from_degrees(30.0, -30.0);
        assert!((d.phi.to_degrees() - 330.0).abs() < 1e-12);
        assert!(wrap_2pi(std::f64::consts::TAU) == 0.0);
    }

    #[test]
    fn from_vector_is_precise_near_the_pole() {
        let d = Direction::new(1e-9, 0.7);
        let back = Direction::from_vector(&d.to_vector());
        assert!((back.theta - 1e-9).abs() < 1e-20, "{back:?}");
    }

    #[test]
    fn small_angles_keep_precision() {
        let a = Direction::from_degrees(45.0, 10.0);
        let b = Direction::new(a.theta + 1e-10, a.phi);
        assert!((a.angle_to(b) - 1e-10).abs() < 1e-16);
    }
}
