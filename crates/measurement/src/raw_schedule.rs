//! How a dome run captured each view group, recorded in the manifest when its plan keeps raw
//! frames: what `btfrig reprocess` needs to re-demultiplex them. Written by the dome run
//! (`crate::dome`), read by the dome reprocess (`crate::dome_reprocess`).

use btfrig_planner::dome::{DomeMode, DomeSchedule};
use serde::{Deserialize, Serialize};

/// What re-demultiplexing a dome dataset's kept frames needs beyond the frames, the rig config
/// and the calibration files: how the run captured each view group. Recorded in the manifest's
/// `raw_groups` (`docs/dataset-format.md`, "Raw frames of view groups").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSchedule {
    /// The code of every view group.
    pub mode: RawMode,
    /// Lights (LEDs or flashes).
    pub leds: usize,
    /// Pattern frames per view group (`raw/v<view>_p000.exr` up to this minus one).
    pub frames_per_group: usize,
    /// Power every lit light of a pattern fired at (the planner's `pattern_scale`): the
    /// demultiplexers' intensities are the calibrated powers times this.
    pub pattern_scale: f64,
    /// Exposure of every pattern frame, s (also in each frame's metadata).
    pub pattern_exposure_s: f64,
    /// The plan's views in capture order.
    pub views: Vec<RawView>,
}

/// The code of a view group, as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RawMode {
    /// One light per frame: frame `j` is light `j`.
    Single,
    /// One S-matrix of `order` over all lights.
    Multiplexed {
        /// The S-matrix order.
        order: usize,
    },
    /// `groups` consecutive groups of `order` lights, each under its own S-matrix.
    Grouped {
        /// Every group's S-matrix order.
        order: usize,
        /// Number of groups.
        groups: usize,
    },
}

impl From<DomeMode> for RawMode {
    fn from(m: DomeMode) -> Self {
        match m {
            DomeMode::Single => RawMode::Single,
            DomeMode::Multiplexed { order } => RawMode::Multiplexed { order },
            DomeMode::Grouped { order, groups } => RawMode::Grouped { order, groups },
        }
    }
}

impl From<RawMode> for DomeMode {
    fn from(m: RawMode) -> Self {
        match m {
            RawMode::Single => DomeMode::Single,
            RawMode::Multiplexed { order } => DomeMode::Multiplexed { order },
            RawMode::Grouped { order, groups } => DomeMode::Grouped { order, groups },
        }
    }
}

/// One view of the plan.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawView {
    /// Its index in the dataset.
    pub view: u32,
    /// Camera index.
    pub camera: usize,
    /// Rotation index.
    pub rotation: u32,
    /// Commanded turntable angle, radians.
    pub turntable_rad: f64,
}

impl RawSchedule {
    /// Of a run's schedule and views (camera, rotation) with their dataset view indices.
    pub(crate) fn of(schedule: &DomeSchedule, views: &[(usize, u32)], view_id: impl Fn(usize, u32) -> u32) -> Self {
        let turntable = |k: u32| schedule.steps.iter().find(|s| s.rotation == k).map_or(0.0, |s| s.turntable_rad);
        RawSchedule {
            mode: schedule.mode.into(),
            leds: schedule.leds,
            frames_per_group: schedule.patterns.len(),
            pattern_scale: schedule.pattern_scale,
            pattern_exposure_s: schedule.exposure_s,
            views: views
                .iter()
                .map(|&(c, k)| RawView { view: view_id(c, k), camera: c, rotation: k, turntable_rad: turntable(k) })
                .collect(),
        }
    }

    /// As the manifest records it.
    pub(crate) fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("a raw schedule serialises")
    }
}
