//! The sample holder plate: geometry of the plate, the sample region and the markers.
//!
//! Everything lies in the sample frame's `z = 0` plane (metres, origin at the plate centre,
//! `x` right, `y` up seen from above). A marker's image is laid out like a texture: its rows
//! grow along `-y`, its columns along `+x`, so a frontal camera from [`ScenePose::looking_at`]
//! sees it upright and OpenCV's corner order (top-left, top-right, bottom-right, bottom-left)
//! maps to the corners in [`MarkerPlacement::corners_sample_m`].
//!
//! [`ScenePose::looking_at`]: btfrig_core::pose::ScenePose::looking_at

pub use btfrig_core::config::plate::MarkerPlacement;
use btfrig_core::config::plate::PlateConfig;
use btfrig_core::ConfigError;

use crate::markers::MarkerDictionary;
use btfrig_core::config::target::TargetBoard;

/// What the plate surface is at a point of the `z = 0` plane outside the sample region.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlateSurface {
    /// Beyond the plate: black velvet, nothing reflected.
    Outside,
    /// Matte plate surface (also the markers' white modules and quiet zones).
    Plate,
    /// A black marker module.
    Black,
}

/// The plate's layout, made from a validated [`PlateConfig`].
#[derive(Debug, Clone)]
pub struct PlateLayout {
    /// Plate side, metres.
    pub side_m: f64,
    /// Sample region side, metres.
    pub sample_side_m: f64,
    /// Marker side (outer border), metres.
    pub marker_size_m: f64,
    dictionary: MarkerDictionary,
    markers: Vec<MarkerPlacement>,
    /// For a calibration board: its grid (markers found by arithmetic instead of a scan).
    grid: Option<Grid>,
}

/// A square grid of markers: `n x n`, centres `pitch` apart, marker `(r, c)` is
/// `markers[r * n + c]`, row 0 at `+y`.
#[derive(Debug, Clone, Copy)]
struct Grid {
    n: usize,
    pitch: f64,
}

impl PlateLayout {
    /// Builds the layout; fails with every invalid field of `config`.
    pub fn new(config: &PlateConfig) -> Result<PlateLayout, ConfigError> {
        let mut errors = Vec::new();
        config.validate(&mut errors);
        ConfigError::from_list(errors)?;
        let dictionary = MarkerDictionary::by_name(&config.marker_dictionary).ok_or_else(|| ConfigError::Unknown {
            field: "plate.marker_dictionary".into(),
            value: config.marker_dictionary.clone(),
            allowed: "DICT_4X4_50".into(),
        })?;
        let markers = config.marker_placements();
        Ok(PlateLayout {
            side_m: config.side_m,
            sample_side_m: config.sample_side_m,
            marker_size_m: config.marker_size_m,
            dictionary,
            markers,
            grid: None,
        })
    }

    /// The layout of a calibration board ([`TargetBoard`]): the board in place of the plate,
    /// no sample region.
    pub fn target(board: &TargetBoard) -> Result<PlateLayout, ConfigError> {
        board.validate()?;
        let dictionary = MarkerDictionary::by_name(&board.dictionary).ok_or_else(|| ConfigError::Unknown {
            field: "target.dictionary".into(),
            value: board.dictionary.clone(),
            allowed: "DICT_4X4_50".into(),
        })?;
        Ok(PlateLayout {
            side_m: board.side_m(),
            sample_side_m: 0.0,
            marker_size_m: board.marker_size_m,
            dictionary,
            markers: board.markers(),
            grid: Some(Grid { n: board.markers_per_side as usize, pitch: board.pitch_m }),
        })
    }

    /// The markers whose outer square, grown by `margin`, may contain `(x, y)`: all of them
    /// on a plate, at most one on a board (its grid cell).
    fn candidates(&self, x: f64, y: f64) -> &[MarkerPlacement] {
        match self.grid {
            None => &self.markers,
            Some(g) => {
                let h = (g.n as f64 - 1.0) / 2.0;
                let c = (x / g.pitch + h).round();
                let r = (h - y / g.pitch).round();
                if c < 0.0 || r < 0.0 || c >= g.n as f64 || r >= g.n as f64 {
                    return &[];
                }
                let k = r as usize * g.n + c as usize;
                &self.markers[k..k + 1]
            }
        }
    }

    /// The markers with their true corner positions on the plate.
    pub fn markers(&self) -> Vec<MarkerPlacement> {
        self.markers.clone()
    }

    /// Name of the marker dictionary (OpenCV's name).
    pub fn dictionary_name(&self) -> &str {
        &self.dictionary.name
    }

    /// True if `(x, y)` lies in the sample region (closed square).
    pub fn in_sample(&self, x: f64, y: f64) -> bool {
        if self.sample_side_m <= 0.0 {
            // A calibration board has no sample.
            return false;
        }
        let h = self.sample_side_m / 2.0;
        x.abs() <= h && y.abs() <= h
    }

    /// True if `(x, y)` lies within `margin` metres of a marker's outer square (where a
    /// pixel may straddle a black/white edge).
    pub fn near_marker(&self, x: f64, y: f64, margin: f64) -> bool {
        self.candidates(x, y).iter().any(|mk| {
            let (tl, br) = (mk.corners_sample_m[0], mk.corners_sample_m[2]);
            x >= tl.x - margin && x <= br.x + margin && y <= tl.y + margin && y >= br.y - margin
        })
    }

    /// Distance (metres, along x or y) from `(x, y)` to the nearest module grid line of a
    /// marker, or infinity when the point is more than `margin` away from every marker. A
    /// pixel whose footprint radius is below this distance sees one module colour only.
    pub fn marker_edge_distance(&self, x: f64, y: f64, margin: f64) -> f64 {
        let m = self.dictionary.modules();
        let module = self.marker_size_m / m as f64;
        let mut best = f64::INFINITY;
        for mk in self.candidates(x, y) {
            let (tl, br) = (mk.corners_sample_m[0], mk.corners_sample_m[2]);
            if x >= tl.x - margin && x <= br.x + margin && y <= tl.y + margin && y >= br.y - margin {
                let gx = ((x - tl.x) / module).round().clamp(0.0, m as f64);
                let gy = ((tl.y - y) / module).round().clamp(0.0, m as f64);
                let dx = (x - (tl.x + gx * module)).abs();
                let dy = (y - (tl.y - gy * module)).abs();
                best = best.min(dx.min(dy));
            }
        }
        best
    }

    /// The surface of the plate at `(x, y)` (the sample region is not checked here).
    pub fn surface_at(&self, x: f64, y: f64) -> PlateSurface {
        let half = self.side_m / 2.0;
        if !(x.abs() <= half && y.abs() <= half) {
            return PlateSurface::Outside;
        }
        let m = self.dictionary.modules();
        let module = self.marker_size_m / m as f64;
        for mk in self.candidates(x, y) {
            let tl = mk.corners_sample_m[0];
            let (dx, dy) = (x - tl.x, tl.y - y);
            if dx >= 0.0 && dy >= 0.0 && dx < self.marker_size_m && dy < self.marker_size_m {
                let col = ((dx / module) as usize).min(m - 1);
                let row = ((dy / module) as usize).min(m - 1);
                let id = mk.id as usize;
                return if self.dictionary.is_white(id, row, col) { PlateSurface::Plate } else { PlateSurface::Black };
            }
        }
        PlateSurface::Plate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_layout_rings_the_sample_with_twelve_markers() {
        let l = PlateLayout::new(&PlateConfig::default()).unwrap();
        let m = l.markers();
        assert_eq!(m.len(), 12);
        let ids: Vec<u32> = m.iter().map(|x| x.id).collect();
        assert_eq!(ids, (0..12).collect::<Vec<_>>());
        for mk in &m {
            for c in &mk.corners_sample_m {
                assert!(c.x.abs() <= 0.1 && c.y.abs() <= 0.1);
                assert!(c.x.abs() > 0.05 || c.y.abs() > 0.05, "marker corner inside the sample");
            }
            // Top-left is up-left of bottom-right.
            assert!(mk.corners_sample_m[0].x < mk.corners_sample_m[2].x);
            assert!(mk.corners_sample_m[0].y > mk.corners_sample_m[2].y);
        }
        // The border module of a marker is black; the quiet zone outside it is plate.
        let tl = m[0].corners_sample_m[0];
        assert_eq!(l.surface_at(tl.x + 1e-4, tl.y - 1e-4), PlateSurface::Black);
        assert_eq!(l.surface_at(tl.x - 1e-4, tl.y + 1e-4), PlateSurface::Plate);
        assert_eq!(l.surface_at(0.11, 0.0), PlateSurface::Outside);
    }
}
