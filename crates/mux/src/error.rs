//! The one error type of the crate: every variant names the offending value and what is
//! allowed, so a caller can print it as is.

/// Errors of S-matrix construction, demultiplexing, least squares and noise prediction.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MuxError {
    /// No S-matrix construction of this order is implemented.
    #[error(
        "no S-matrix construction of order {order}: available are Sylvester 2^k-1, Paley primes p = 3 mod 4 \
         and twin primes p(p+2); nearest available orders: below {}, above {} \
         (or use SMatrix::for_sources to pad with always-off slots)",
        order_or_none(.below),
        order_or_none(.above)
    )]
    NoConstruction {
        /// The requested order.
        order: usize,
        /// The largest available order below it.
        below: Option<usize>,
        /// The smallest available order above it.
        above: Option<usize>,
    },
    /// A construction's parameter is out of range.
    #[error("{construction}: {what} = {value} is not allowed: {allowed}")]
    BadParameter {
        /// The construction or routine.
        construction: &'static str,
        /// The parameter.
        what: &'static str,
        /// The offending value.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// A buffer has the wrong length for the declared shape.
    #[error("{what}: buffer holds {len} values, expected {expected} ({shape})")]
    Shape {
        /// Which buffer.
        what: &'static str,
        /// Its length.
        len: usize,
        /// The expected length.
        expected: usize,
        /// The shape that implies it.
        shape: String,
    },
    /// A demultiplexing method cannot handle this S-matrix.
    #[error("method {method} cannot demultiplex a {construction} S-matrix of order {order}: {allowed}")]
    MethodUnsupported {
        /// The method.
        method: &'static str,
        /// The construction of the matrix.
        construction: &'static str,
        /// Its order.
        order: usize,
        /// Which constructions the method handles.
        allowed: &'static str,
    },
    /// A calibrated LED intensity is not a finite, non-negative number.
    #[error("LED {index}: calibrated intensity {value} is not allowed: must be finite and >= 0")]
    BadIntensity {
        /// The LED (column of the pattern matrix).
        index: usize,
        /// The value.
        value: f64,
    },
    /// A pattern-matrix entry is not finite.
    #[error("pattern matrix entry (frame {frame}, source {source_index}) = {value} is not finite")]
    BadPattern {
        /// Row (frame).
        frame: usize,
        /// Column (source).
        source_index: usize,
        /// The value.
        value: f64,
    },
    /// The least-squares system has fewer usable frames than unknowns.
    #[error(
        "least squares needs at least as many frames as unknown sources: {frames} frames, {unknowns} unknowns \
         ({excluded} sources excluded as dead, stuck, always-off or too dim)"
    )]
    Underdetermined {
        /// Frames (rows).
        frames: usize,
        /// Unknown sources left.
        unknowns: usize,
        /// Sources excluded.
        excluded: usize,
    },
    /// The pattern matrix is too ill-conditioned for the requested tolerance.
    #[error(
        "pattern matrix is ill-conditioned: condition number {condition:.3e} exceeds the allowed {max_condition:.1e} \
         (weakest direction mostly source {weakest_source}); recalibrate, or exclude dim sources \
         (LsParams::min_relative_intensity)"
    )]
    IllConditioned {
        /// Ratio of the largest to the smallest singular value.
        condition: f64,
        /// The limit (`LsParams::max_condition`).
        max_condition: f64,
        /// The source with the largest weight in the right singular vector of the smallest singular value.
        weakest_source: usize,
    },
    /// A noise-model or scene parameter is out of range.
    #[error("{what} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// The parameter.
        what: &'static str,
        /// The offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
}

fn order_or_none(o: &Option<usize>) -> String {
    o.map_or_else(|| "none".to_string(), |v| v.to_string())
}
