//! Colour-science numerics for btfrig (no I/O, no clocks): colour spaces ([`space`]),
//! colour differences ([`delta_e`]: CIEDE2000 and CIE76), colour-correction models from
//! camera RGB to a target space ([`model`]: linear 3x3, polynomial, root-polynomial), patch
//! screening and model evaluation and selection by cross-validated CIEDE2000 ([`eval`]).
//!
//! Conventions: XYZ has Y_white = 1; the project's output space is linear sRGB (Rec. 709
//! primaries, D65 white) where a perfect white reflector is (1, 1, 1); colour differences are
//! computed in CIE L*a*b* relative to that space's D65 white. Formulae and references are in
//! `docs/color.md`.
//!
//! ```
//! use btfrig_color::{ColorModel, FitOptions, ModelKind, TargetSpace, evaluate};
//! // Camera RGB that is a known matrix away from the target: the linear model recovers it.
//! let m = [[1.2, -0.1, -0.1], [-0.2, 1.3, -0.1], [0.0, -0.3, 1.3]];
//! let cam: Vec<[f64; 3]> = (0..20).map(|i| {
//!     let t = i as f64;
//!     [0.1 + 0.04 * t, 0.8 - 0.03 * (t * 0.7).sin().abs(), 0.2 + 0.3 * (t * 1.3).cos().abs()]
//! }).collect();
//! let target: Vec<[f64; 3]> = cam.iter().map(|c| btfrig_color::space::mat3_apply(&m, *c)).collect();
//! let model = ColorModel::fit(ModelKind::Linear, &cam, &target, None, &FitOptions::default()).unwrap();
//! let stats = evaluate(&model, &cam, &target, TargetSpace::LinearSrgb).unwrap();
//! assert!(stats.max < 1e-9);
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - space:   colour spaces (XYZ, L*a*b*, linear sRGB, Bradford)
// - delta_e: colour differences (CIEDE2000, CIE76)
// - kind:    the colour-correction model families and their terms
// - model:   colour-correction models, fitted by equilibrated least squares
// - eval:    patch screening, statistics, cross-validated model selection
// - chart:   colour chart layouts and their published references
// - error:   ColorError

pub mod chart;
pub mod delta_e;
pub mod error;
pub mod eval;
pub mod kind;
pub mod model;
pub mod space;

pub use delta_e::{delta_e_2000, delta_e_2000_parts, delta_e_76, Ciede2000Parts};
pub use error::ColorError;
pub use eval::{
    cross_validate, evaluate, screen_patches, screen_weights, select_model, valid_indices, DeltaEStats, ModelReport,
    PatchStatus, ScreenOptions, Selection, TargetSpace,
};
pub use kind::ModelKind;
pub use model::{ColorModel, FitOptions, WhiteConstraint};
