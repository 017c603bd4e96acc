//! Turning `--material` into a validated material: an embedded name or a TOML file.

use anyhow::Context;
use btfrig_render::material::{MaterialSpec, BUILTIN_MATERIALS};

/// The material used when none is named: deep relief, so that shadowing and masking show.
pub const DEFAULT_MATERIAL: &str = "corduroy";

/// Loads an embedded material by name, or a material file if `name` ends in `.toml`.
pub fn load(name: Option<&str>) -> anyhow::Result<MaterialSpec> {
    let name = name.unwrap_or(DEFAULT_MATERIAL);
    if name.ends_with(".toml") {
        let text = std::fs::read_to_string(name).with_context(|| format!("cannot read material file {name}"))?;
        return Ok(MaterialSpec::from_toml(&text, name)?);
    }
    MaterialSpec::builtin(name).map_err(|e| {
        let names: Vec<&str> = BUILTIN_MATERIALS.iter().map(|(n, _)| *n).collect();
        anyhow::anyhow!("--material {name:?}: {e}; allowed: {} or a path ending in .toml", names.join(", "))
    })
}

/// Names of the embedded materials.
pub fn names() -> Vec<&'static str> {
    BUILTIN_MATERIALS.iter().map(|(n, _)| *n).collect()
}
