//! Errors of the modelling numerics: each names what is wrong and what is allowed.

/// What went wrong in a model fit.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum ModelError {
    /// Fewer light directions than the model needs.
    #[error("{what}: {have} distinct light direction(s); photometric stereo needs at least {need} non-coplanar ones")]
    TooFewLights {
        /// Which observations (a view, "all captures").
        what: String,
        /// Distinct light directions given.
        have: usize,
        /// Needed.
        need: usize,
    },
    /// Fewer observations than a model has parameters.
    #[error("{what}: {have} observation(s); it needs at least {need} (light, view) pairs")]
    TooFewObservations {
        /// Which fit.
        what: String,
        /// Observations given.
        have: usize,
        /// Needed.
        need: usize,
    },
    /// The light directions span less than 3 dimensions (all in one plane through the origin).
    #[error("{what}: the {have} light directions are (nearly) coplanar (smallest/largest eigenvalue of L^T L {ratio:.2e}, must exceed {min:.0e}); add a light out of their plane")]
    DegenerateLights {
        /// Which observations.
        what: String,
        /// Directions given.
        have: usize,
        /// Conditioning figure.
        ratio: f64,
        /// Required at least.
        min: f64,
    },
    /// An input array has the wrong length.
    #[error("{what}: {got} values, expected {expected}")]
    WrongSize {
        /// Which array.
        what: String,
        /// Its length.
        got: usize,
        /// The length required.
        expected: usize,
    },
    /// A value outside its allowed range (a light below the horizon, a NaN intensity, a bad parameter).
    #[error("{field} = {value}: {allowed}")]
    OutOfRange {
        /// The field.
        field: String,
        /// Its value, as text.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// Nothing to fit (no texels, no observations).
    #[error("{0}")]
    Empty(String),
}

/// Result of the modelling crate.
pub type Result<T> = std::result::Result<T, ModelError>;
