//! From measurement to material: the numerics that turn a measured BTF into surface geometry
//! and per-texel reflectance models (issue 29). No I/O, no devices, no simulator.
//!
//! Brief overview: the main types and how data moves between them.
//!
//! * [`car`]: seed 002's probabilistic model: the (light, view) pairs clustered into
//!   sub-spaces, each one's texture factorised (colour PCA, Gaussian-Laplacian pyramid) into
//!   2D causal autoregressive models, [`car::fit`] to a [`car::CarBtf`] that synthesises
//!   textures of any size for any pair, bump-mapped by the range map.
//! * [`ps`]: calibrated photometric stereo. A [`ps::PsInput`] (rectified textures on one
//!   texel grid and the light direction of each) goes through [`ps::photometric_stereo`]
//!   with [`ps::PsParams`] (plain least squares or the robust estimator) to a
//!   [`ps::NormalMap`]: unit normal, albedo and the normal's angular uncertainty per texel.
//! * [`integrate`]: the normal map's gradients to a [`integrate::HeightMap`] by weighted
//!   least squares with natural boundaries, and its Monte Carlo uncertainty.
//! * [`lafortune`]: per-texel Lafortune lobes (`K` = 1..3) and a colour albedo by bounded
//!   Levenberg–Marquardt, [`lafortune::fit`] to a [`lafortune::LafortuneMap`].
//! * [`sbrdf`]: seed 003's self-shadowing (per light) and self-occlusion (per view) maps
//!   on top of an SBRDF's predictions, [`sbrdf::fit`] to [`sbrdf::ShadowOcclusionMaps`].
//! * [`scaled_lafortune`]: the lobes times a per-texel, per-view scale `T(v)` (seed 000's
//!   scaled Lafortune lobes), [`scaled_lafortune::fit`] to a
//!   [`scaled_lafortune::ScaledLafortuneMap`].
//! * [`ptm`]: a polynomial texture map per view (biquadratic in the projected light
//!   direction, luminance and chroma), [`ptm::fit`] to a [`ptm::PtmMap`].
//! * [`truth`]: error figures against an injected [`truth::SurfaceTruthProbe`] (the
//!   simulator's), used only after estimation.
//!
//! Formulas: each module's documentation and `docs/material-models.md`.
//!
//! ```
//! use btfrig_model::ps::{photometric_stereo, PsInput, PsMethod, PsParams};
//! // One texel facing +z, albedo 0.5, four lights.
//! let lights = [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]];
//! let imgs: Vec<Vec<[f32; 3]>> = lights.iter().map(|l| vec![[0.5 * l[2] as f32; 3]]).collect();
//! let refs: Vec<&[[f32; 3]]> = imgs.iter().map(|v| v.as_slice()).collect();
//! let input = PsInput { what: "example", width: 1, height: 1, lights: &lights, images: &refs };
//! let map = photometric_stereo(&input, &PsParams::new(PsMethod::LeastSquares)).unwrap();
//! assert!((map.normal[0][2] - 1.0).abs() < 1e-9 && (map.albedo[0][0] - 0.5).abs() < 1e-6);
//! ```

#![warn(missing_docs)]

pub mod car;
pub mod error;
pub mod integrate;
pub mod lafortune;
pub mod ps;
pub mod ptm;
pub mod sbrdf;
pub mod scaled_lafortune;
pub mod truth;

pub use error::{ModelError, Result};
