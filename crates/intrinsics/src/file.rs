//! The stored calibration (`calibration/*.toml`): the `[camera]` table uses exactly the field
//! names of the rig config's `[camera]` section for the geometric parameters, so a rig config
//! can take them over (or point to the file); `[uncertainty]` and `[fit]` record how good
//! they are. Text in, text out: callers read and write the files.

use serde::{Deserialize, Serialize};

use crate::{Calibration, Init, Uncertainty};
use btfrig_core::config::camera::CameraConfig;

/// Version of the file format written by this crate.
pub const FORMAT_VERSION: u32 = 1;

/// Geometric camera parameters, named as in the rig config's `[camera]` section.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraGeometry {
    /// Image width, pixels.
    pub width_px: usize,
    /// Image height, pixels.
    pub height_px: usize,
    /// Focal length along u, pixels.
    pub fx_px: f64,
    /// Focal length along v, pixels.
    pub fy_px: f64,
    /// Principal point u, pixels (integers at pixel centres).
    pub cx_px: f64,
    /// Principal point v, pixels.
    pub cy_px: f64,
    /// OpenCV k1.
    pub k1: f64,
    /// OpenCV k2.
    pub k2: f64,
    /// OpenCV k3.
    pub k3: f64,
    /// OpenCV p1.
    pub p1: f64,
    /// OpenCV p2.
    pub p2: f64,
}

/// How the calibration was obtained and how well it fits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSummary {
    /// RMS reprojection error over the inliers, pixels (both axes together).
    pub rms_px: f64,
    /// A-posteriori standard deviation of unit weight.
    pub sigma0: f64,
    /// Number of views.
    pub views: usize,
    /// Points used.
    pub points: usize,
    /// Points rejected as outliers.
    pub outliers: usize,
    /// RMS reprojection error of each view, pixels.
    pub per_view_rms_px: Vec<f64>,
    /// Initialisation: "zhang" or "held-principal-point".
    pub init: String,
    /// Free text: where the data came from (rig, date, target).
    #[serde(default)]
    pub source: String,
}

/// A stored calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Format version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// The calibrated geometry.
    pub camera: CameraGeometry,
    /// One-standard-deviation uncertainties (same field names; no sizes).
    pub uncertainty: Uncertainty,
    /// Fit statistics.
    pub fit: FitSummary,
}

/// Why a stored calibration cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FileError {
    /// Not valid TOML for this format.
    #[error("{origin}: not a camera calibration file: {message}")]
    Parse {
        /// File name, for the message.
        origin: String,
        /// Parser message.
        message: String,
    },
    /// A format version this crate does not read.
    #[error("{origin}: format_version {found} is not supported (this build reads {FORMAT_VERSION})")]
    Version {
        /// File name.
        origin: String,
        /// Version found.
        found: u32,
    },
}

impl CalibrationFile {
    /// The file content for a calibration result; `source` describes the data.
    pub fn from_calibration(c: &Calibration, source: &str) -> Self {
        let m = &c.camera;
        let d = m.distortion;
        CalibrationFile {
            format_version: FORMAT_VERSION,
            camera: CameraGeometry {
                width_px: m.width,
                height_px: m.height,
                fx_px: m.fx,
                fy_px: m.fy,
                cx_px: m.cx,
                cy_px: m.cy,
                k1: d.k1,
                k2: d.k2,
                k3: d.k3,
                p1: d.p1,
                p2: d.p2,
            },
            uncertainty: c.uncertainty,
            fit: FitSummary {
                rms_px: c.rms_px,
                sigma0: c.sigma0,
                views: c.poses.len(),
                points: c.points_used,
                outliers: c.outliers,
                per_view_rms_px: c.per_view_rms_px.clone(),
                init: match c.init {
                    Init::Zhang => "zhang",
                    Init::HeldPrincipalPoint => "held-principal-point",
                }
                .into(),
                source: source.into(),
            },
        }
    }

    /// TOML text of this file.
    pub fn to_toml(&self) -> String {
        let body = toml::to_string(self).expect("plain numbers and strings always serialise");
        format!("# btfrig geometric camera calibration (docs/camera-calibration.md)\n{body}")
    }

    /// Parses TOML text; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, FileError> {
        let f: CalibrationFile =
            toml::from_str(text).map_err(|e| FileError::Parse { origin: origin.into(), message: e.to_string() })?;
        if f.format_version != FORMAT_VERSION {
            return Err(FileError::Version { origin: origin.into(), found: f.format_version });
        }
        Ok(f)
    }

    /// The rig config's camera section with the geometric fields replaced by this
    /// calibration's (radiometric fields, vignetting and lens, kept from `base`).
    pub fn apply_to(&self, base: &CameraConfig) -> CameraConfig {
        let g = &self.camera;
        CameraConfig {
            width_px: g.width_px,
            height_px: g.height_px,
            fx_px: g.fx_px,
            fy_px: g.fy_px,
            cx_px: g.cx_px,
            cy_px: g.cy_px,
            k1: g.k1,
            k2: g.k2,
            k3: g.k3,
            p1: g.p1,
            p2: g.p2,
            ..base.clone()
        }
    }
}
