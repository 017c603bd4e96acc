//! The `[plate]` section of a rig config: the sample holder plate and its fiducial markers.
//!
//! The plate is a square in the sample frame's `z = 0` plane, centred on the sample origin;
//! the sample region is a centred square inside it; ArUco markers sit on a square ring in the
//! border between the two (`markers_per_side` on each side, corners shared).
//! [`PlateConfig::marker_placements`] gives the marker corner positions that the renderer draws
//! and the registration measures against. Reflectances are spectrum names resolved by the colour system
//! (e.g. `"flat:0.8"` is a spectrally flat 80 % reflector).

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// One marker on the plate.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerPlacement {
    /// Marker id in the plate's dictionary.
    pub id: u32,
    /// Outer corners of the black border in the sample frame (metres), in OpenCV's order:
    /// top-left, top-right, bottom-right, bottom-left of the marker image (its rows grow along
    /// `-y`, its columns along `+x`, so a frontal camera sees it upright).
    pub corners_sample_m: [Point2<f64>; 4],
}

/// Marker dictionaries the renderer knows (bit patterns shipped in `calibration/markers/`).
pub const MARKER_DICTIONARIES: &[(&str, u32)] = &[("DICT_4X4_50", 50)];

/// The `[plate]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateConfig {
    /// Side of the square holder plate, metres.
    #[serde(default = "PlateConfig::default_side_m")]
    pub side_m: f64,
    /// Side of the square sample region in the plate's centre, metres; the material's texel
    /// grid spans exactly this square.
    #[serde(default = "PlateConfig::default_sample_side_m")]
    pub sample_side_m: f64,
    /// Reflectance (spectrum name) of the matte plate surface and of the markers' white modules.
    #[serde(default = "PlateConfig::default_albedo")]
    pub albedo: String,
    /// Reflectance (spectrum name) of the markers' black modules.
    #[serde(default = "PlateConfig::default_marker_black")]
    pub marker_black: String,
    /// Marker dictionary; one of [`MARKER_DICTIONARIES`].
    #[serde(default = "PlateConfig::default_dictionary")]
    pub marker_dictionary: String,
    /// Outer side of one marker (black border included), metres.
    #[serde(default = "PlateConfig::default_marker_size_m")]
    pub marker_size_m: f64,
    /// Markers on each side of the ring, corners counted on both sides: the plate carries
    /// `4 * (markers_per_side - 1)` markers.
    #[serde(default = "PlateConfig::default_markers_per_side")]
    pub markers_per_side: u32,
    /// Distance from the plate centre to the ring of marker centres (half the ring's side), metres.
    #[serde(default = "PlateConfig::default_marker_ring_m")]
    pub marker_ring_m: f64,
    /// Id of the first marker; ids count up clockwise seen from above, starting at the
    /// corner at (-ring, +ring).
    #[serde(default)]
    pub first_marker_id: u32,
}

impl Default for PlateConfig {
    fn default() -> Self {
        PlateConfig {
            side_m: Self::default_side_m(),
            sample_side_m: Self::default_sample_side_m(),
            albedo: Self::default_albedo(),
            marker_black: Self::default_marker_black(),
            marker_dictionary: Self::default_dictionary(),
            marker_size_m: Self::default_marker_size_m(),
            markers_per_side: Self::default_markers_per_side(),
            marker_ring_m: Self::default_marker_ring_m(),
            first_marker_id: 0,
        }
    }
}

impl PlateConfig {
    const fn default_side_m() -> f64 {
        0.20
    }
    const fn default_sample_side_m() -> f64 {
        0.10
    }
    fn default_albedo() -> String {
        "flat:0.8".into()
    }
    fn default_marker_black() -> String {
        "flat:0.03".into()
    }
    fn default_dictionary() -> String {
        "DICT_4X4_50".into()
    }
    const fn default_marker_size_m() -> f64 {
        0.02
    }
    const fn default_markers_per_side() -> u32 {
        4
    }
    const fn default_marker_ring_m() -> f64 {
        0.075
    }

    /// Modules across one marker (data bits plus the one-module black border).
    pub fn marker_modules(&self) -> u32 {
        // Only 4x4 dictionaries are shipped; a 4x4 marker is 6 modules across.
        6
    }

    /// Number of markers on the plate.
    pub fn marker_count(&self) -> u32 {
        4 * self.markers_per_side.saturating_sub(1)
    }

    /// The markers with their true corner positions, ids counting up clockwise seen from
    /// above from the corner at `(-ring, +ring)`. Meaningful for a validated section.
    pub fn marker_placements(&self) -> Vec<MarkerPlacement> {
        let r = self.marker_ring_m;
        let n = self.markers_per_side.max(2) as usize;
        let step = 2.0 * r / (n - 1) as f64;
        let mut centres = Vec::with_capacity(4 * (n - 1));
        for k in 0..n - 1 {
            centres.push((-r + k as f64 * step, r));
        }
        for k in 0..n - 1 {
            centres.push((r, r - k as f64 * step));
        }
        for k in 0..n - 1 {
            centres.push((r - k as f64 * step, -r));
        }
        for k in 0..n - 1 {
            centres.push((-r, -r + k as f64 * step));
        }
        let h = self.marker_size_m / 2.0;
        centres
            .iter()
            .enumerate()
            .map(|(k, &(cx, cy))| MarkerPlacement {
                id: self.first_marker_id + k as u32,
                corners_sample_m: [
                    Point2::new(cx - h, cy + h),
                    Point2::new(cx + h, cy + h),
                    Point2::new(cx + h, cy - h),
                    Point2::new(cx - h, cy - h),
                ],
            })
            .collect()
    }

    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        if !(finite_pos(self.side_m) && self.side_m <= 2.0) {
            errors.push(ConfigError::out_of_range("plate.side_m", self.side_m, "(0, 2] metres"));
        }
        if !(finite_pos(self.sample_side_m) && self.sample_side_m < self.side_m) {
            errors.push(ConfigError::out_of_range(
                "plate.sample_side_m",
                self.sample_side_m,
                &format!("(0, plate.side_m = {}) metres", self.side_m),
            ));
        }
        let dict = MARKER_DICTIONARIES.iter().find(|(n, _)| *n == self.marker_dictionary);
        match dict {
            None => errors.push(ConfigError::Unknown {
                field: "plate.marker_dictionary".into(),
                value: self.marker_dictionary.clone(),
                allowed: MARKER_DICTIONARIES.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
            }),
            Some((_, size)) => {
                let last = self.first_marker_id as u64 + self.marker_count() as u64;
                if last > *size as u64 {
                    errors.push(ConfigError::out_of_range(
                        "plate.first_marker_id",
                        self.first_marker_id,
                        &format!(
                            "0..={} so that all {} marker ids exist in {}",
                            size.saturating_sub(self.marker_count()),
                            self.marker_count(),
                            self.marker_dictionary
                        ),
                    ));
                }
            }
        }
        if !(2..=20).contains(&self.markers_per_side) {
            errors.push(ConfigError::out_of_range("plate.markers_per_side", self.markers_per_side, "2..=20"));
        }
        if !finite_pos(self.marker_size_m) {
            errors.push(ConfigError::out_of_range("plate.marker_size_m", self.marker_size_m, "> 0 metres"));
        }
        // Each marker needs a white quiet zone of one module around it, clear of the sample
        // and inside the plate; neighbouring markers must not touch their quiet zones.
        let module = self.marker_size_m / self.marker_modules() as f64;
        let half_outer = self.marker_size_m / 2.0 + module;
        let lo = self.sample_side_m / 2.0 + half_outer;
        let hi = self.side_m / 2.0 - half_outer;
        if !(self.marker_ring_m.is_finite() && self.marker_ring_m >= lo && self.marker_ring_m <= hi) {
            errors.push(ConfigError::out_of_range(
                "plate.marker_ring_m",
                self.marker_ring_m,
                &format!(
                    "[{lo:.4}, {hi:.4}] metres (markers with a one-module quiet zone between sample and plate edge)"
                ),
            ));
        }
        if self.markers_per_side >= 2 && finite_pos(self.marker_size_m) {
            let pitch = 2.0 * self.marker_ring_m / (self.markers_per_side - 1) as f64;
            if pitch < self.marker_size_m + 2.0 * module {
                errors.push(ConfigError::out_of_range(
                    "plate.marker_size_m",
                    self.marker_size_m,
                    &format!(
                        "<= {:.4} metres so that {} markers per side keep their quiet zones",
                        pitch * 6.0 / 8.0,
                        self.markers_per_side
                    ),
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_plate_is_valid_and_has_twelve_markers() {
        let p = PlateConfig::default();
        let mut e = Vec::new();
        p.validate(&mut e);
        assert!(e.is_empty(), "{e:?}");
        assert_eq!(p.marker_count(), 12);
    }

    #[test]
    fn bad_values_are_all_reported() {
        let p = PlateConfig {
            sample_side_m: 0.3,
            marker_dictionary: "DICT_7X7_1".into(),
            markers_per_side: 1,
            marker_ring_m: 0.3,
            ..PlateConfig::default()
        };
        let mut e = Vec::new();
        p.validate(&mut e);
        let text: Vec<String> = e.iter().map(|x| x.to_string()).collect();
        for field in ["plate.sample_side_m", "plate.marker_dictionary", "plate.markers_per_side", "plate.marker_ring_m"]
        {
            assert!(text.iter().any(|t| t.contains(field)), "{field} missing in {text:?}");
        }
    }

    #[test]
    fn unknown_field_is_rejected() {
        let r: Result<PlateConfig, _> = toml::from_str("side_mm = 3");
        assert!(r.unwrap_err().to_string().contains("side_mm"));
    }
}
