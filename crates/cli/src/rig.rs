//! Turning `--rig` into a validated rig config: a file, or the embedded default.

use std::path::Path;

use anyhow::Context;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::{BUILTIN_RIG, BUILTIN_RIGS};

/// Loads the rig config at `path`, or the embedded default simulated gonioreflectometer
/// (the same text plans name as `builtin:bonn-gonio-sim`), so the binary works from any
/// directory.
pub fn load(path: Option<&Path>) -> anyhow::Result<RigConfig> {
    match path {
        None => {
            let (_, text) = BUILTIN_RIGS
                .iter()
                .find(|(name, _)| *name == BUILTIN_RIG)
                .expect("the default rig is among the embedded rigs");
            Ok(RigConfig::from_toml(text, "<embedded rig-configs/bonn-gonio-sim.toml>")?)
        }
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("cannot read rig config {}", p.display()))?;
            Ok(RigConfig::from_toml(&text, &p.display().to_string())?)
        }
    }
}
