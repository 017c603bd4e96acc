//! What the pipeline is asked to do: per-frame settings, outputs, preview rate, HDR records.

use btfrig_imaging::{Filter, Region};

use crate::RegistrationPolicy;

/// What the pipeline writes for each frame (the plan's `[outputs]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// Write the rectified texture (`Dataset::write_texture`).
    pub textures: bool,
    /// Write the raw frame (`Dataset::write_raw`); the dataset's manifest must ask for them.
    pub raw_frames: bool,
    /// Write an 8-bit sRGB preview of each texture (`Dataset::write_texture_preview`, in the
    /// `write` stage); needs `textures` and a manifest that asks for them.
    pub texture_previews: bool,
    /// Keep a live preview, rate-limited; `None`: no preview.
    pub preview: Option<PreviewSettings>,
}

impl Default for Outputs {
    /// Textures only, no preview.
    fn default() -> Self {
        Outputs { textures: true, raw_frames: false, texture_previews: false, preview: None }
    }
}

/// How the live preview is made and how often.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewSettings {
    /// Smallest side of the preview, pixels: a smaller texture is enlarged by a whole factor
    /// (nearest neighbour, so texels stay visible as such).
    pub min_side: usize,
    /// Shortest time between two previews, seconds.
    pub min_interval_s: f64,
    /// Largest share of wall time previews may cost: after a preview that cost `c` seconds
    /// the next waits at least `c / max_share`.
    pub max_share: f64,
}

impl Default for PreviewSettings {
    /// 256 px, at most every 0.5 s and at most 2 % of the time.
    fn default() -> Self {
        PreviewSettings { min_side: 256, min_interval_s: 0.5, max_share: 0.02 }
    }
}

/// What to make of each frame.
#[derive(Debug, Clone, Copy)]
pub struct ProcessSettings {
    /// Texture side, texels.
    pub size: usize,
    /// Sample-plane region the texture covers, metres.
    pub region: Region,
    /// Resampling filter.
    pub filter: Filter,
    /// Where the pose comes from and what a failed registration does.
    pub registration: RegistrationPolicy,
}

/// What the journal records of each step's exposures when the plan has HDR on
/// ([`Processor::with_hdr_recording`](crate::Processor::with_hdr_recording), `btfrig_store::StepHdr`).
#[derive(Debug, Clone, PartialEq)]
pub struct HdrRecording {
    /// The bracket always bracketing would take, as multipliers of the step's base exposure
    /// (first 1): the counterfactual of the report's time saved.
    pub always_stops: Vec<f64>,
}
