//! A geometric calibration target: a square ArUco grid board mounted on the holder in place
//! of the sample plate (no sample), larger than the plate so that it fills the frame.
//!
//! The board lies in the sample frame's `z = 0` plane, centred on the origin, like the plate;
//! `n x n` markers of the plate's dictionary sit on a square grid of pitch `pitch_m`, ids
//! counting row by row from the marker at `(-x, +y)` (top-left seen frontally) starting at
//! `first_id`, the block of `ids_per_side²` ids repeating over larger boards. Marker images
//! are laid out as on the plate ([`super::plate`]): rows along
//! `-y`, columns along `+x`, corners in OpenCV's order. Every corner of every marker is a
//! known target point, so a detector that decodes the ids pairs image points with board
//! points without any search.
//!
//! The layout is what both sides need: the calibration procedure pairs detected corners with
//! it, the simulator's renderer (`btfrig_render::scene::Scene::build_target`) draws it.

use crate::config::plate::{MarkerPlacement, MARKER_DICTIONARIES};
use crate::ConfigError;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

/// A square ArUco grid board (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetBoard {
    /// Markers per row and per column (2..=40).
    #[serde(default = "TargetBoard::default_markers_per_side")]
    pub markers_per_side: u32,
    /// The id pattern repeats every `ids_per_side` markers along rows and columns (a
    /// dictionary of 50 ids holds at most a 7 x 7 block): marker `(r, c)` has id
    /// `first_id + (r mod n) * n + (c mod n)`. Equal ids are then `n` pitches apart, far more
    /// than where the kinematic pose predicts a marker to be, so the calibration pairs each
    /// detection with the instance nearest its prediction.
    #[serde(default = "TargetBoard::default_ids_per_side")]
    pub ids_per_side: u32,
    /// Outer side of one marker (black border included), metres.
    #[serde(default = "TargetBoard::default_marker_size_m")]
    pub marker_size_m: f64,
    /// Distance between neighbouring marker centres, metres (the gap must hold a quiet zone
    /// of at least one module).
    #[serde(default = "TargetBoard::default_pitch_m")]
    pub pitch_m: f64,
    /// Id of the top-left marker.
    #[serde(default)]
    pub first_id: u32,
    /// Marker dictionary (OpenCV name; one of the plate's dictionaries).
    #[serde(default = "TargetBoard::default_dictionary")]
    pub dictionary: String,
    /// Reflectance (spectrum name) of the board and the markers' white modules.
    #[serde(default = "TargetBoard::default_albedo")]
    pub albedo: String,
    /// Reflectance (spectrum name) of the markers' black modules.
    #[serde(default = "TargetBoard::default_marker_black")]
    pub marker_black: String,
}

impl Default for TargetBoard {
    fn default() -> Self {
        TargetBoard {
            markers_per_side: Self::default_markers_per_side(),
            ids_per_side: Self::default_ids_per_side(),
            marker_size_m: Self::default_marker_size_m(),
            pitch_m: Self::default_pitch_m(),
            first_id: 0,
            dictionary: Self::default_dictionary(),
            albedo: Self::default_albedo(),
            marker_black: Self::default_marker_black(),
        }
    }
}

impl TargetBoard {
    const fn default_markers_per_side() -> u32 {
        15
    }
    const fn default_ids_per_side() -> u32 {
        7
    }
    const fn default_marker_size_m() -> f64 {
        0.03
    }
    const fn default_pitch_m() -> f64 {
        0.04
    }
    fn default_dictionary() -> String {
        "DICT_4X4_50".into()
    }
    fn default_albedo() -> String {
        "flat:0.8".into()
    }
    fn default_marker_black() -> String {
        "flat:0.03".into()
    }

    /// Modules across one marker (4x4 data plus the black border).
    pub fn modules(&self) -> u32 {
        6
    }

    /// Side of the square board, metres: the marker grid plus half a pitch of margin beyond
    /// the outer marker centres.
    pub fn side_m(&self) -> f64 {
        self.markers_per_side as f64 * self.pitch_m
    }

    /// Number of markers.
    pub fn marker_count(&self) -> u32 {
        self.markers_per_side * self.markers_per_side
    }

    /// Number of distinct ids (`ids_per_side²`, fewer if the board is smaller).
    pub fn id_count(&self) -> u32 {
        let n = self.ids_per_side.min(self.markers_per_side);
        n * n
    }

    /// Id of the marker in grid row `r`, column `c`.
    pub fn id_at(&self, r: u32, c: u32) -> u32 {
        let n = self.ids_per_side.max(1);
        self.first_id + (r % n) * n + (c % n)
    }

    /// Centre of the marker in grid row `r`, column `c` (row 0 at the top, `+y`).
    pub fn centre(&self, r: u32, c: u32) -> Point2<f64> {
        let h = (self.markers_per_side as f64 - 1.0) / 2.0;
        Point2::new((c as f64 - h) * self.pitch_m, (h - r as f64) * self.pitch_m)
    }

    /// The markers with their true corner positions (sample frame, metres).
    pub fn markers(&self) -> Vec<MarkerPlacement> {
        let h = self.marker_size_m / 2.0;
        let n = self.markers_per_side;
        let mut out = Vec::with_capacity((n * n) as usize);
        for r in 0..n {
            for c in 0..n {
                let p = self.centre(r, c);
                out.push(MarkerPlacement {
                    id: self.id_at(r, c),
                    corners_sample_m: [
                        Point2::new(p.x - h, p.y + h),
                        Point2::new(p.x + h, p.y + h),
                        Point2::new(p.x + h, p.y - h),
                        Point2::new(p.x - h, p.y - h),
                    ],
                });
            }
        }
        out
    }

    /// Checks every value; reports all problems, naming fields as `target.<field>`.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut errors = Vec::new();
        if !(2..=40).contains(&self.markers_per_side) {
            errors.push(ConfigError::out_of_range("target.markers_per_side", self.markers_per_side, "2..=40"));
        }
        if !(2..=40).contains(&self.ids_per_side) {
            errors.push(ConfigError::out_of_range("target.ids_per_side", self.ids_per_side, "2..=40"));
        }
        if !(self.marker_size_m.is_finite() && self.marker_size_m > 0.0 && self.marker_size_m <= 1.0) {
            errors.push(ConfigError::out_of_range("target.marker_size_m", self.marker_size_m, "(0, 1] metres"));
        }
        // One module of quiet zone between neighbours.
        let min_pitch = self.marker_size_m * (1.0 + 1.0 / self.modules() as f64);
        if !(self.pitch_m.is_finite() && self.pitch_m >= min_pitch && self.pitch_m <= 1.0) {
            errors.push(ConfigError::out_of_range(
                "target.pitch_m",
                self.pitch_m,
                &format!("[{min_pitch}, 1] metres (marker size plus one module of quiet zone)"),
            ));
        }
        match MARKER_DICTIONARIES.iter().find(|(n, _)| *n == self.dictionary) {
            None => errors.push(ConfigError::Unknown {
                field: "target.dictionary".into(),
                value: self.dictionary.clone(),
                allowed: MARKER_DICTIONARIES.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
            }),
            Some((_, size)) => {
                if self.first_id as u64 + self.id_count() as u64 > *size as u64 {
                    errors.push(ConfigError::out_of_range(
                        "target.first_id",
                        self.first_id,
                        &format!(
                            "0..={} so that all {} ids exist in {}",
                            size.saturating_sub(self.id_count()),
                            self.id_count(),
                            self.dictionary
                        ),
                    ));
                }
            }
        }
        ConfigError::from_list(errors)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_board_is_valid_and_laid_out_row_by_row() {
        let b = TargetBoard { markers_per_side: 7, marker_size_m: 0.06, pitch_m: 0.08, ..TargetBoard::default() };
        b.validate().unwrap();
        let m = b.markers();
        assert_eq!(m.len(), 49);
        assert_eq!(m[0].id, 0);
        assert_eq!(m[48].id, 48);
        // Top-left marker at (-x, +y); id 1 to its right; id 7 below it.
        assert!(m[0].corners_sample_m[0].x < 0.0 && m[0].corners_sample_m[0].y > 0.0);
        assert!((m[1].corners_sample_m[0].x - m[0].corners_sample_m[0].x - b.pitch_m).abs() < 1e-12);
        assert!((m[0].corners_sample_m[0].y - m[7].corners_sample_m[0].y - b.pitch_m).abs() < 1e-12);
        // Inside the board, with the centre marker centred.
        let half = b.side_m() / 2.0;
        assert!(m.iter().flat_map(|k| k.corners_sample_m).all(|c| c.x.abs() < half && c.y.abs() < half));
        let c = m[24].corners_sample_m;
        assert!((c[0].x + c[2].x).abs() < 1e-12 && (c[0].y + c[2].y).abs() < 1e-12);
    }

    #[test]
    fn larger_boards_repeat_the_id_block() {
        let b = TargetBoard::default();
        b.validate().unwrap();
        let m = b.markers();
        assert_eq!(m.len(), 225);
        assert_eq!(b.id_count(), 49);
        // Row 0: ids 0..6, then 0 again; row 7 starts the block again.
        let ids: Vec<u32> = m[..9].iter().map(|k| k.id).collect();
        assert_eq!(ids, vec![0, 1, 2, 3, 4, 5, 6, 0, 1]);
        assert_eq!(m[7 * 15].id, 0);
        assert_eq!(m[15].id, 7);
        // Equal ids are 7 pitches apart at least.
        for a in &m {
            for c in &m {
                if a.id == c.id && a.corners_sample_m != c.corners_sample_m {
                    let d = (a.corners_sample_m[0] - c.corners_sample_m[0]).norm();
                    assert!(d > 6.9 * b.pitch_m, "{d}");
                }
            }
        }
    }

    #[test]
    fn bad_boards_name_every_field() {
        let b = TargetBoard {
            markers_per_side: 41,
            pitch_m: 0.031,
            dictionary: "DICT_5X5_100".into(),
            ..TargetBoard::default()
        };
        let text = b.validate().unwrap_err().to_string();
        for f in ["target.markers_per_side", "target.pitch_m", "target.dictionary"] {
            assert!(text.contains(f), "{text}");
        }
        let b = TargetBoard { first_id: 2, ..TargetBoard::default() };
        assert!(b.validate().unwrap_err().to_string().contains("target.first_id"));
        let b = TargetBoard { ids_per_side: 8, markers_per_side: 8, ..TargetBoard::default() };
        assert!(b.validate().unwrap_err().to_string().contains("target.first_id"));
    }
}
