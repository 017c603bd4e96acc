//! The `[plate]` section of a rig config. (Skeleton: its owner fills in the fields.)

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// The `[plate]` section.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateConfig {}

impl PlateConfig {
    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let _ = errors;
    }
}
