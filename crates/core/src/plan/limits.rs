//! Limits that bound the work and memory of checking, planning and running one plan, so that
//! a short plan text cannot ask for millions of captures (issue 24). Each is checked before
//! anything of its size is built: the text's length before parsing, directions and pairs
//! from their counts before they are expanded.

use serde::{Deserialize, Serialize};

use super::{PlanError, PlanErrors};

/// Largest plan text, bytes, checked before parsing. A fixed limit: the longest useful
/// plan (an explicit list of every Bonn pair) is about 60 KiB.
pub const MAX_PLAN_BYTES: usize = 1 << 20;

/// Most directions per sampling (after expanding rings or a list, before filters). A fixed
/// limit: validation compares every pair of directions once.
pub const MAX_DIRECTIONS: usize = 4096;

/// Default most requested (light, view) pairs per plan (`[limits] max_captures`): the full
/// Bonn 81 x 81 plan (6561) fits fifteen times over.
pub const DEFAULT_MAX_CAPTURES: usize = 100_000;

/// The highest `[limits] max_captures` a plan may set.
pub const MAX_CAPTURES_CEILING: usize = 1_000_000;

/// The `[limits]` table: raises the default limits of a plan, up to a ceiling. A run
/// policy, not part of [`super::Plan::content_hash`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsSpec {
    /// Most requested (light, view) pairs (`1..=1000000`, default 100000); a plan asking
    /// for more is refused before its pairs are expanded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_captures: Option<usize>,
}

impl LimitsSpec {
    /// Whether this is the default (nothing set).
    pub(crate) fn is_default(&self) -> bool {
        *self == LimitsSpec::default()
    }

    /// The pair limit in force: the plan's value within its ceiling, else the default.
    pub fn max_captures(&self) -> usize {
        self.max_captures.filter(|m| (1..=MAX_CAPTURES_CEILING).contains(m)).unwrap_or(DEFAULT_MAX_CAPTURES)
    }
}

/// How to raise the pair limit, for messages.
pub(crate) fn raise_captures() -> String {
    format!(
        "set [limits] max_captures = N in the plan (at most {MAX_CAPTURES_CEILING}), or request fewer pairs \
         (fewer directions, theta_min_deg / theta_max_deg, every = k, or a pairs list)"
    )
}

/// Refuses a plan text longer than [`MAX_PLAN_BYTES`] before it is parsed.
pub fn check_plan_size(text: &str, origin: &str) -> Result<(), PlanErrors> {
    if text.len() <= MAX_PLAN_BYTES {
        return Ok(());
    }
    Err(PlanErrors {
        origin: origin.to_string(),
        errors: vec![PlanError::TooLarge {
            field: "plan text".into(),
            value: format!("{} bytes", text.len()),
            limit: format!("{MAX_PLAN_BYTES} bytes (1 MiB, a fixed limit)"),
            remedy: "describe directions with rings or a preset instead of long lists".into(),
        }],
    })
}
