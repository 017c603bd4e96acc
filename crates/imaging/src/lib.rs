//! Calibration and rectification: from a demosaiced camera frame to a texture on the sample
//! plane, in the units of the renderer's ground truth.
//!
//! This first part rectifies with the **nominal pose** (from kinematics) and the rig's known
//! camera model ([`rectify`]), converts the result radiometrically to a radiance factor
//! ([`radiometry`]), and measures it against a reference ([`metric`]). Marker-based
//! registration will replace the nominal pose later; the resampling filters stay.
//!
//! Conventions (`docs/conventions.md`): texture column `u` grows along the sample's `+x`, row
//! `v` along `-y` (row 0 at the `+y` edge); pixel coordinates have integer values at pixel
//! centres (`btfrig_core::camera`). The method and the measured figures are in
//! `docs/rectification.md`.
#![warn(missing_docs)]

pub mod dark_flat;
pub mod exposure;
pub mod hdr;
pub mod light;
pub mod metric;
pub mod radiometry;
pub mod rectify;

pub use metric::{compare, rel_rmse, TextureError};
pub use radiometry::{to_radiance_factor, vignetting_map, Radiometry};
pub use rectify::{rectify, Filter, LinearImage, RectifyError, Region, Texture};
