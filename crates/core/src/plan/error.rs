//! Errors of a measurement plan: each names the field (dotted path), the bad value and what
//! is allowed, so a person can fix the file without reading code.

use std::fmt;

/// One problem with a plan.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// The text is not valid TOML, or does not match the schema (unknown field, wrong type,
    /// unknown `mode`). Serde stops at the first such problem, so this comes alone.
    #[error("line {line}, column {column}: {message}")]
    Syntax {
        /// Where the text came from (file path or `<embedded NAME>`).
        origin: String,
        /// 1-based line of the problem (0 if the parser gave no position).
        line: usize,
        /// 1-based column of the problem (0 if the parser gave no position).
        column: usize,
        /// The parser's message (it names the key and, for enums, the allowed values).
        message: String,
    },
    /// A number outside the range allowed for its field.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Dotted field path, e.g. `sampling.light.list[3].theta`.
        field: String,
        /// The offending value as written.
        value: String,
        /// What is allowed, e.g. `0 <= theta < 90 (degrees)`.
        allowed: String,
    },
    /// A name that refers to nothing known (sampling preset, material, fault scenario, format).
    #[error("{field} = {value:?} is unknown: allowed {allowed}")]
    Unknown {
        /// Dotted field path.
        field: String,
        /// The offending name.
        value: String,
        /// The names that are known.
        allowed: String,
    },
    /// A value that is wrong for a reason other than its range (duplicate, empty, conflict).
    #[error("{field} = {value} is invalid: {problem}; allowed {allowed}")]
    Invalid {
        /// Dotted field path.
        field: String,
        /// The offending value as written.
        value: String,
        /// What is wrong with it.
        problem: String,
        /// What would be accepted instead.
        allowed: String,
    },
    /// With `skip.unreachable = false`, some requested pairs cannot be realised by the rig.
    #[error(
        "{field} = false, but {count} of {total} requested (light, view) pairs cannot be realised by the rig; first: {}; allowed: pairs the rig can reach, or skip.unreachable = true to skip them",
        .first.join("; ")
    )]
    Unreachable {
        /// Always `skip.unreachable`.
        field: String,
        /// How many pairs are unreachable.
        count: usize,
        /// How many pairs were requested.
        total: usize,
        /// The first few, each as `(light i (theta, phi), view j (theta, phi)): reason`.
        first: Vec<String>,
    },
    /// The plan asks for more than a limit allows ([`super::limits`]); checked from counts,
    /// before anything of that size is built.
    #[error("{field} = {value} exceeds the limit of {limit}: allowed at most that; to go beyond, {remedy}")]
    TooLarge {
        /// Dotted field path (or `plan text`).
        field: String,
        /// The plan's value, e.g. `12960000 pairs (3600 light x 3600 view directions)`.
        value: String,
        /// The limit and its name, e.g. `100000 (limits.max_captures)`.
        limit: String,
        /// How to raise the limit, or what to do instead.
        remedy: String,
    },
    /// The output directory already holds a dataset of a different plan.
    #[error(
        "{field} = {path:?} already holds a dataset of another plan (plan hash {found:016x}, this plan {expected:016x}): allowed an empty or new directory, or the same plan to resume"
    )]
    OtherDataset {
        /// Always `output`.
        field: String,
        /// The output directory.
        path: String,
        /// The plan hash recorded in the existing dataset.
        found: u64,
        /// The hash of this plan.
        expected: u64,
    },
}

impl PlanError {
    /// The dotted field path this error is about (`""` for a syntax error without one).
    pub fn field(&self) -> &str {
        match self {
            PlanError::Syntax { .. } => "",
            PlanError::OutOfRange { field, .. }
            | PlanError::Unknown { field, .. }
            | PlanError::Invalid { field, .. }
            | PlanError::Unreachable { field, .. }
            | PlanError::TooLarge { field, .. }
            | PlanError::OtherDataset { field, .. } => field,
        }
    }

    pub(crate) fn out_of_range(field: impl Into<String>, value: impl fmt::Display, allowed: impl Into<String>) -> Self {
        PlanError::OutOfRange { field: field.into(), value: value.to_string(), allowed: allowed.into() }
    }

    pub(crate) fn unknown(field: impl Into<String>, value: impl Into<String>, allowed: impl Into<String>) -> Self {
        PlanError::Unknown { field: field.into(), value: value.into(), allowed: allowed.into() }
    }

    pub(crate) fn invalid(
        field: impl Into<String>,
        value: impl fmt::Display,
        problem: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        PlanError::Invalid {
            field: field.into(),
            value: value.to_string(),
            problem: problem.into(),
            allowed: allowed.into(),
        }
    }
}

/// Every problem found in a plan, in the order of the file's sections. Never empty.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanErrors {
    /// Where the plan came from (file path or `<embedded NAME>`).
    pub origin: String,
    /// The problems, at least one.
    pub errors: Vec<PlanError>,
}

impl PlanErrors {
    /// Does any error name this field (exactly)?
    pub fn has_field(&self, field: &str) -> bool {
        self.errors.iter().any(|e| e.field() == field)
    }
}

impl fmt::Display for PlanErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.origin.is_empty() {
            write!(f, "{}: ", self.origin)?;
        }
        match self.errors.as_slice() {
            [one] => write!(f, "{one}"),
            many => {
                write!(f, "{} problems:", many.len())?;
                for e in many {
                    write!(f, "\n  - {e}")?;
                }
                Ok(())
            }
        }
    }
}

impl std::error::Error for PlanErrors {}
