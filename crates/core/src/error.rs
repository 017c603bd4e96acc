//! Errors of the core model: configuration and input validation.

/// A problem with a configuration file or value. Each names the field, the bad value and
/// what is allowed, so a person can fix the file without reading code.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file is not valid TOML or does not match the schema (unknown field, wrong type).
    #[error("{path}: {message}")]
    Parse {
        /// Where the text came from (file path or `<embedded NAME>`).
        path: String,
        /// The parser's message, which names line, column and field.
        message: String,
    },
    /// A value is outside the range allowed for its field.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Dotted field path, e.g. `camera.width`.
        field: String,
        /// The offending value as written.
        value: String,
        /// What is allowed, e.g. `1..=20000` or `one of RGGB, BGGR, GRBG, GBRG`.
        allowed: String,
    },
    /// A name that refers to nothing known (material, spectrum, device kind).
    #[error("{field} = {value:?} is unknown: allowed {allowed}")]
    Unknown {
        /// Dotted field path.
        field: String,
        /// The offending name.
        value: String,
        /// The names that are known.
        allowed: String,
    },
    /// Several problems found at once: all are reported, not just the first.
    #[error("{} problems:\n{}", .0.len(), .0.iter().map(|e| format!("  - {e}")).collect::<Vec<_>>().join("\n"))]
    Many(Vec<ConfigError>),
}

impl ConfigError {
    /// Collects a list of problems: `Ok(())` when empty, the single error, or `Many`.
    pub fn from_list(mut errors: Vec<ConfigError>) -> Result<(), ConfigError> {
        match errors.len() {
            0 => Ok(()),
            1 => Err(errors.pop().expect("one element")),
            _ => Err(ConfigError::Many(errors)),
        }
    }

    /// Shorthand for [`ConfigError::OutOfRange`].
    pub fn out_of_range(field: &str, value: impl std::fmt::Display, allowed: &str) -> Self {
        ConfigError::OutOfRange { field: field.into(), value: value.to_string(), allowed: allowed.into() }
    }
}
