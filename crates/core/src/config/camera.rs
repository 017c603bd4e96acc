//! The `[camera]` section of a rig config: intrinsics, lens distortion, vignetting and the
//! lens's light throughput. The meaning of every parameter is that of
//! [`crate::camera::CameraModel`] (OpenCV's conventions; integer pixel coordinates are pixel
//! centres).
//!
//! Defaults: a 1600 x 1200 frame from an APS-C sensor (23.6 mm wide) behind a ~71 mm lens
//! (`fx = 1600 * 70.8 / 23.6 = 4800 px`). From the rail radius of about 1.2 m a 0.2 m square
//! holder plate then spans 800 px, and its 0.283 m diagonal 1131 px, so the whole plate stays in
//! the 1200 px frame height at any in-plane rotation when viewed head-on (theta 0); the ~0.1 m
//! sample spans about 400 px. The distortion is a mild barrel, as of a short telephoto lens
//! (about 3.4 px inwards at the image corners from k1, k2; tangential terms of a slightly decentred
//! lens); vignetting is cos⁴ plus 10% lens falloff at the corners.

use serde::{Deserialize, Serialize};

use crate::camera::{CameraError, CameraModel, Distortion, Vignetting};
use crate::error::ConfigError;

/// The `[camera]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Image width, pixels (1..=20000).
    pub width_px: usize,
    /// Image height, pixels (1..=20000).
    pub height_px: usize,
    /// Focal length along image x, pixels (> 0).
    pub fx_px: f64,
    /// Focal length along image y, pixels (> 0).
    pub fy_px: f64,
    /// Principal point x, pixels; integer values are pixel centres (centred: (width - 1) / 2).
    pub cx_px: f64,
    /// Principal point y, pixels (centred: (height - 1) / 2).
    pub cy_px: f64,
    /// Radial distortion coefficient of r² (OpenCV k1), dimensionless.
    pub k1: f64,
    /// Radial distortion coefficient of r⁴ (OpenCV k2).
    pub k2: f64,
    /// Radial distortion coefficient of r⁶ (OpenCV k3).
    pub k3: f64,
    /// Tangential distortion coefficient p1 (OpenCV).
    pub p1: f64,
    /// Tangential distortion coefficient p2 (OpenCV).
    pub p2: f64,
    /// Apply the natural cos⁴ falloff of image-plane illumination.
    pub vignetting_cos4: bool,
    /// Lens vignetting polynomial `[a1, a2, a3]` of `1 + a1 ρ² + a2 ρ⁴ + a3 ρ⁶`, ρ = distance
    /// from the principal point over the image half-diagonal (each in -10..=10).
    pub vignetting_poly: [f64; 3],
    /// Aperture f-number N (0.5..=64); image irradiance scales with 1 / (4 N²).
    pub f_number: f64,
    /// Fraction of light the lens transmits (0 < t <= 1).
    pub lens_transmittance: f64,
    /// Optional geometric calibration the pipeline processes frames with instead of the
    /// geometric fields above: a calibration file (`docs/camera-calibration.md`) as a path
    /// relative to the rig config's directory (ending in `.toml`), or `builtin:NAME` for one
    /// embedded in the binary. The fields above stay the camera's truth for a simulated rig
    /// (what the renderer images with).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
    /// Optional colour calibration the pipeline converts textures with (`docs/color.md`):
    /// a file made by `btfrig calibrate color`, as a path relative to the rig config's
    /// directory (ending in `.toml`) or `builtin:NAME`. None: white-balanced camera RGB
    /// through the rig model's matrix.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub color_calibration: Option<String>,
    /// Optional dark and flat-field calibration the pipeline corrects every photosite with
    /// (`docs/dark-flat.md`): the directory `btfrig calibrate radiometric --out` wrote, relative
    /// to the rig config's directory, or `builtin:NAME`. None: the mean dark current is
    /// subtracted and the lens model's vignetting divided out. A run's `--dark-flat` replaces it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dark_flat: Option<String>,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            width_px: 1600,
            height_px: 1200,
            fx_px: 4800.0,
            fy_px: 4800.0,
            cx_px: 799.5,
            cy_px: 599.5,
            k1: -0.08,
            k2: 0.02,
            k3: 0.0,
            p1: 1e-4,
            p2: -1e-4,
            vignetting_cos4: true,
            vignetting_poly: [-0.1, 0.0, 0.0],
            f_number: 8.0,
            lens_transmittance: 0.9,
            calibration: None,
            color_calibration: None,
            dark_flat: None,
        }
    }
}

impl CameraConfig {
    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let mut push = |field: &str, value: String, allowed: &str| {
            errors.push(ConfigError::OutOfRange { field: format!("camera.{field}"), value, allowed: allowed.into() })
        };
        for (field, v) in [("width_px", self.width_px), ("height_px", self.height_px)] {
            if !(1..=20000).contains(&v) {
                push(field, v.to_string(), "1..=20000");
            }
        }
        for (field, v) in [("fx_px", self.fx_px), ("fy_px", self.fy_px)] {
            if !(v.is_finite() && v > 0.0 && v <= 1e6) {
                push(field, v.to_string(), "0 < f <= 1e6");
            }
        }
        for (field, v, size) in [("cx_px", self.cx_px, self.width_px), ("cy_px", self.cy_px, self.height_px)] {
            if !(v.is_finite() && v >= -0.5 && v <= size as f64 - 0.5) {
                push(field, v.to_string(), "inside the image: -0.5..=size-0.5");
            }
        }
        for (field, v) in [("k1", self.k1), ("k2", self.k2), ("k3", self.k3)] {
            if !(v.is_finite() && v.abs() <= 10.0) {
                push(field, v.to_string(), "-10..=10");
            }
        }
        for (field, v) in [("p1", self.p1), ("p2", self.p2)] {
            if !(v.is_finite() && v.abs() <= 0.1) {
                push(field, v.to_string(), "-0.1..=0.1");
            }
        }
        for (i, v) in self.vignetting_poly.iter().enumerate() {
            if !(v.is_finite() && v.abs() <= 10.0) {
                push(&format!("vignetting_poly[{i}]"), v.to_string(), "-10..=10");
            }
        }
        if !(self.f_number.is_finite() && (0.5..=64.0).contains(&self.f_number)) {
            push("f_number", self.f_number.to_string(), "0.5..=64");
        }
        if !(self.lens_transmittance > 0.0 && self.lens_transmittance <= 1.0) {
            push("lens_transmittance", self.lens_transmittance.to_string(), "0 < t <= 1");
        }
        if let Some(c) = &self.calibration {
            let ok = match c.strip_prefix("builtin:") {
                Some(name) => !name.trim().is_empty(),
                None => c.trim().ends_with(".toml") && c.trim().len() > 5,
            };
            if !ok {
                push("calibration", format!("{c:?}"), "a calibration file path ending in .toml, or builtin:NAME");
            }
        }
        if let Some(c) = &self.color_calibration {
            let ok = match c.strip_prefix("builtin:") {
                Some(name) => !name.trim().is_empty(),
                None => c.trim().ends_with(".toml") && c.trim().len() > 5,
            };
            if !ok {
                push(
                    "color_calibration",
                    format!("{c:?}"),
                    "a colour calibration file path ending in .toml, or builtin:NAME",
                );
            }
        }
        if let Some(c) = &self.dark_flat {
            if c.strip_prefix("builtin:").unwrap_or(c).trim().is_empty() {
                push("dark_flat", format!("{c:?}"), "a dark/flat calibration directory, or builtin:NAME");
            }
        }
        // Only when the numbers are individually sane: does the distortion fold inside the image?
        if errors.is_empty() {
            if let Err(e @ CameraError::FoldInsideImage { .. }) = self.to_model() {
                errors.push(ConfigError::OutOfRange {
                    field: "camera.k1/k2/k3".into(),
                    value: format!("({}, {}, {})", self.k1, self.k2, self.k3),
                    allowed: format!("a distortion that does not fold over inside the image ({e})"),
                });
            }
        }
    }

    /// Builds the camera model described by this section.
    pub fn to_model(&self) -> Result<CameraModel, CameraError> {
        CameraModel::new(
            self.width_px,
            self.height_px,
            self.fx_px,
            self.fy_px,
            self.cx_px,
            self.cy_px,
            Distortion { k1: self.k1, k2: self.k2, k3: self.k3, p1: self.p1, p2: self.p2 },
            Vignetting { cos4: self.vignetting_cos4, poly: self.vignetting_poly },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Rotation3, Vector3};

    #[test]
    fn default_is_valid_and_builds() {
        let cfg = CameraConfig::default();
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        assert!(errors.is_empty(), "{errors:?}");
        let cam = cfg.to_model().unwrap();
        assert_eq!((cam.width, cam.height), (1600, 1200));
    }

    #[test]
    fn default_plate_fits_head_on_at_any_rotation() {
        // 0.2 m square plate at the ~1.2 m rail radius, head-on, rotated in plane.
        let cam = CameraConfig::default().to_model().unwrap();
        let margin = 30.0;
        for deg in (0..90).step_by(5) {
            let rot = Rotation3::from_axis_angle(&Vector3::z_axis(), (deg as f64).to_radians());
            for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                let p = rot * Vector3::new(0.1 * sx, 0.1 * sy, 0.0) + Vector3::new(0.0, 0.0, 1.2);
                let px = cam.project(&Point3::from(p)).unwrap();
                assert!(
                    px.x > margin && px.y > margin && px.x < 1600.0 - margin && px.y < 1200.0 - margin,
                    "corner at {deg} deg projects to {px:?}"
                );
            }
        }
        // And the plate fills a good part of the frame: more than half the height head-on.
        let a = cam.project(&Point3::new(0.0, -0.1, 1.2)).unwrap();
        let b = cam.project(&Point3::new(0.0, 0.1, 1.2)).unwrap();
        assert!(b.y - a.y > 600.0);
    }

    #[test]
    fn all_bad_values_are_reported() {
        let cfg = CameraConfig { width_px: 0, fx_px: -1.0, k1: f64::NAN, f_number: 100.0, ..Default::default() };
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        let text: Vec<String> = errors.iter().map(|e| e.to_string()).collect();
        assert!(text.iter().any(|t| t.contains("camera.width_px")), "{text:?}");
        assert!(text.iter().any(|t| t.contains("camera.fx_px")), "{text:?}");
        assert!(text.iter().any(|t| t.contains("camera.k1")), "{text:?}");
        assert!(text.iter().any(|t| t.contains("camera.f_number")), "{text:?}");
    }

    #[test]
    fn folding_distortion_is_a_config_error() {
        let cfg = CameraConfig { fx_px: 500.0, fy_px: 500.0, k1: -0.5, k2: 0.0, ..Default::default() };
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].to_string().contains("fold"));
    }

    #[test]
    fn calibration_reference_is_checked() {
        for good in ["calibration/x.toml", "builtin:bonn-gonio-sim-geometry"] {
            let cfg = CameraConfig { calibration: Some(good.into()), ..Default::default() };
            let mut errors = Vec::new();
            cfg.validate(&mut errors);
            assert!(errors.is_empty(), "{good}: {errors:?}");
        }
        for bad in ["", "builtin:", "calibration/x.json"] {
            let cfg = CameraConfig { calibration: Some(bad.into()), ..Default::default() };
            let mut errors = Vec::new();
            cfg.validate(&mut errors);
            assert_eq!(errors.len(), 1, "{bad}: {errors:?}");
            assert!(errors[0].to_string().contains("camera.calibration"), "{}", errors[0]);
        }
        let cfg: CameraConfig = toml::from_str("calibration = \"calibration/a.toml\"").unwrap();
        assert_eq!(cfg.calibration.as_deref(), Some("calibration/a.toml"));
        assert_eq!(CameraConfig::default().calibration, None);
    }

    #[test]
    fn partial_section_takes_defaults() {
        let cfg: CameraConfig = toml::from_str("fx_px = 5000.0\nfy_px = 5000.0").unwrap();
        assert_eq!(cfg.width_px, 1600);
        assert_eq!(cfg.fx_px, 5000.0);
        assert!(toml::from_str::<CameraConfig>("focal = 3").is_err());
    }
}
