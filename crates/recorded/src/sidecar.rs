//! The sidecar (`recording.toml`): what the camera of a recording is, and for each frame its
//! file, the commanded pose (joint states, or light and view directions) and its exposure and
//! gain. The format is `docs/recorded-camera.md`; these structs are its schema (unknown
//! fields are errors, as in every btfrig file).

use std::path::Path;

use btfrig_core::frame::BayerPattern;
use serde::{Deserialize, Serialize};

use crate::RecordingError;

/// The sidecar's file name in a recording directory.
pub const SIDECAR_FILE: &str = "recording.toml";

/// The format version this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// The whole sidecar.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sidecar {
    /// What the recording is.
    pub recording: RecordingInfo,
    /// The camera every frame was taken with (once for the recording).
    pub camera: CameraInfo,
    /// One entry per frame file.
    #[serde(default, rename = "frame")]
    pub frames: Vec<FrameEntry>,
}

/// `[recording]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingInfo {
    /// Format version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// Free text: where the frames come from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
}

/// `[camera]`: the sensor layout and what the camera allowed, once for the recording.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraInfo {
    /// Frame width, photosites.
    pub width: usize,
    /// Frame height, photosites.
    pub height: usize,
    /// Bits per sample of the raw data (1..=16).
    pub bit_depth: u8,
    /// Black level, DN.
    pub black_level: u16,
    /// Saturation level, DN.
    pub white_level: u16,
    /// Colour filter array of the top-left 2x2 block: `"RGGB"`, `"BGGR"`, `"GRBG"`, `"GBRG"`,
    /// or `"mono"`.
    pub bayer: String,
    /// Shortest and longest exposure the camera allowed, seconds (the HDR control's range).
    pub exposure_range_s: [f64; 2],
    /// Lowest and highest gain the camera allowed.
    pub gain_range: [f64; 2],
    /// The aperture's f-number, if the camera reported one (a frame may give its own).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_number: Option<f64>,
    /// Make and model, for `btfrig hw probe` and messages.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
}

/// A direction in the sample frame, degrees (the convention of docs/conventions.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DirectionDeg {
    /// From the sample normal, degrees.
    pub theta_deg: f64,
    /// Azimuth, degrees.
    pub phi_deg: f64,
}

/// `[[frame]]`: one frame file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameEntry {
    /// The frame's file, relative to the recording directory.
    pub file: String,
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Analogue gain (1 = base).
    pub gain: f64,
    /// The robot's commanded joints `[pan, tilt, roll]`, degrees (with `rail_deg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot_deg: Option<[f64; 3]>,
    /// The rail's commanded angle, degrees (with `robot_deg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rail_deg: Option<f64>,
    /// The light direction in the sample frame (with `view`; joints follow from the rig's
    /// inverse kinematics when `robot_deg`/`rail_deg` are absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<DirectionDeg>,
    /// The view direction in the sample frame (with `light`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<DirectionDeg>,
    /// The aperture's f-number, if not the camera's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_number: Option<f64>,
    /// Sensor temperature, degrees Celsius, where the camera reported it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature_c: Option<f64>,
    /// The step the frame was captured for (`l003_v017`), informational.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step: Option<String>,
}

/// The allowed `[camera] bayer` values.
pub const BAYER_VALUES: &str = "\"RGGB\", \"BGGR\", \"GRBG\", \"GBRG\" or \"mono\"";

impl CameraInfo {
    /// The colour filter array (`None`: mono), or a message naming the bad value.
    pub fn bayer_pattern(&self) -> Result<Option<BayerPattern>, String> {
        match self.bayer.as_str() {
            "RGGB" => Ok(Some(BayerPattern::Rggb)),
            "BGGR" => Ok(Some(BayerPattern::Bggr)),
            "GRBG" => Ok(Some(BayerPattern::Grbg)),
            "GBRG" => Ok(Some(BayerPattern::Gbrg)),
            "mono" => Ok(None),
            other => Err(format!("{other:?} is not a colour filter layout: allowed {BAYER_VALUES}")),
        }
    }

    /// The `bayer` value of a pattern.
    pub fn bayer_name(pattern: Option<BayerPattern>) -> String {
        match pattern {
            Some(BayerPattern::Rggb) => "RGGB",
            Some(BayerPattern::Bggr) => "BGGR",
            Some(BayerPattern::Grbg) => "GRBG",
            Some(BayerPattern::Gbrg) => "GBRG",
            None => "mono",
        }
        .to_string()
    }
}

impl Sidecar {
    /// Parses the sidecar text of `path` (named in errors, with the line and the field toml
    /// reports).
    pub fn from_toml(text: &str, path: &Path) -> Result<Sidecar, RecordingError> {
        let sidecar: Sidecar = toml::from_str(text).map_err(|e| RecordingError::Sidecar {
            path: path.into(),
            message: e.to_string().trim_end().replace('\n', "\n  "),
        })?;
        if sidecar.recording.format_version != FORMAT_VERSION {
            return Err(RecordingError::Sidecar {
                path: path.into(),
                message: format!(
                    "recording.format_version = {} is not readable by this build: allowed {FORMAT_VERSION}",
                    sidecar.recording.format_version
                ),
            });
        }
        Ok(sidecar)
    }

    /// As TOML text, with a header naming the format.
    pub fn to_toml(&self) -> String {
        let body = toml::to_string(self).expect("a sidecar serialises");
        format!("# A btfrig recording: frames and what they were taken with (docs/recorded-camera.md).\n{body}")
    }
}
