//! Raw frame to texture numerics: demosaic, dark/flat, HDR merge, rectification and
//! radiometry, from a camera frame to a texture on the sample plane in the units of the renderer's ground truth.
//!
//! It rectifies with a given pose (the registered one, from `btfrig-registration`, or the
//! nominal one) and camera model ([`rectify`]), converts the result radiometrically to a
//! radiance factor ([`radiometry`]) and measures it against a reference ([`metric`]); before
//! that, the dark/flat correction ([`dark_flat`]) and the HDR merge ([`hdr`], [`exposure`]),
//! and the white-reference measurement of the light ([`light`]).
//!
//! Conventions (`docs/conventions.md`): texture column `u` grows along the sample's `+x`, row
//! `v` along `-y` (row 0 at the `+y` edge); pixel coordinates have integer values at pixel
//! centres (`btfrig_core::camera`). The method and the measured figures are in
//! `docs/rectification.md`.
#![warn(missing_docs)]

// The files, one job each:
// - demosaic:   a raw (Bayer or mono) frame to linear camera RGB, bilinear
// - mosaic:     the same demosaic read in place, only at the pixels a stage reads
// - rectify:    rectification onto the sample plane and its filters
// - radiometry: conversion to radiance factor, the vignetting map
// - dark_flat:  the dark model, master flats, per-photosite correction
// - hdr:        the noise-optimal merge of an exposure bracket
// - exposure:   metering and the exposure policy
// - light:      white-reference measurements of the light
// - metric:     texture error against a reference

pub mod dark_flat;
pub mod demosaic;
pub mod exposure;
pub mod hdr;
pub mod light;
pub mod metric;
pub mod mosaic;
pub mod radiometry;
pub mod rectify;

pub use metric::{compare, rel_rmse, TextureError};
pub use mosaic::Mosaic;
pub use radiometry::{to_radiance_factor, vignetting_map, Radiometry};
pub use rectify::{rectify, rectify_vignetted, Filter, LinearImage, RectifyError, Region, RgbSource, Texture};
