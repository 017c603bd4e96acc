//! Errors of the colour numerics.

use crate::kind::ModelKind;

/// What went wrong in a fit or an evaluation; each variant names the offending input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ColorError {
    /// Fewer usable samples (weight > 0) than the model has free coefficients per output.
    #[error("{model}: {samples} usable samples, the model needs at least {needed}")]
    TooFewSamples {
        /// The model being fitted.
        model: ModelKind,
        /// Samples with positive weight.
        samples: usize,
        /// Minimum number of samples.
        needed: usize,
    },
    /// Two inputs that must have one entry per sample differ in length.
    #[error("{what} has {got} entries, expected {expected} (one per sample)")]
    LengthMismatch {
        /// Which input.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// A NaN or infinite value in an input.
    #[error("{what}[{index}] is not finite ({value})")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// Sample index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A negative or non-finite weight.
    #[error("weight[{index}] = {value} must be finite and >= 0")]
    InvalidWeight {
        /// Sample index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// An option out of its range.
    #[error("option {what} = {value} out of range ({allowed})")]
    InvalidOption {
        /// Option name.
        what: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range, in words.
        allowed: &'static str,
    },
    /// The fit's design matrix is (nearly) rank deficient: the samples do not hold enough
    /// distinct colours for this model (e.g. every patch grey). `condition` is the condition
    /// number of the column-equilibrated design matrix (infinite when exactly singular).
    #[error("{model}: design matrix condition number {condition:.3e} exceeds the limit {limit:.1e}: the samples cannot determine this model's terms (use fewer terms, more distinct patches or a ridge)")]
    IllConditioned {
        /// The model being fitted.
        model: ModelKind,
        /// Its condition number.
        condition: f64,
        /// The limit ([`crate::FitOptions::max_condition`]).
        limit: f64,
    },
    /// The samples do not span the three colour dimensions: the condition number of their
    /// (column-equilibrated) camera r, g, b exceeds [`crate::FitOptions::max_colour_condition`]
    /// (e.g. every patch grey, or a few hues only). Infinite when exactly degenerate.
    #[error("{model}: the patches' camera colours have condition number {condition:.3e} over the limit {limit:.1e}: too few distinct colours (all grey or few hues) to determine a colour map")]
    FewColours {
        /// The model being fitted.
        model: ModelKind,
        /// Condition number of the samples' r, g, b.
        condition: f64,
        /// The limit.
        limit: f64,
    },
    /// A model's coefficient table has the wrong number of terms.
    #[error("{model}: {got} coefficient rows, the model has {expected} terms")]
    WrongTermCount {
        /// The model.
        model: ModelKind,
        /// Its number of terms.
        expected: usize,
        /// Rows given.
        got: usize,
    },
    /// An unknown model name.
    #[error("unknown colour model {0:?} (known: linear, poly2, poly3, rootpoly2, rootpoly3)")]
    UnknownModel(String),
    /// No candidate model could be fitted and cross-validated.
    #[error("no colour model could be fitted: {first_error}")]
    NoUsableModel {
        /// The first candidate's error, as text.
        first_error: String,
    },
    /// Nothing to compute statistics over.
    #[error("no samples to evaluate")]
    Empty,
}
