//! Turning `--rig` into a validated rig config: a file, or the embedded default.

use std::path::Path;

use anyhow::Context;
use btfrig_core::config::RigConfig;

/// The default simulated gonioreflectometer, embedded so the binary works from any directory.
pub const DEFAULT_RIG_TOML: &str = include_str!("../../../rig-configs/bonn-gonio-sim.toml");

/// Loads the rig config at `path`, or the embedded default.
pub fn load(path: Option<&Path>) -> anyhow::Result<RigConfig> {
    match path {
        None => Ok(RigConfig::from_toml(DEFAULT_RIG_TOML, "<embedded rig-configs/bonn-gonio-sim.toml>")?),
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("cannot read rig config {}", p.display()))?;
            Ok(RigConfig::from_toml(&text, &p.display().to_string())?)
        }
    }
}
