//! Turning `--rig` into a validated rig config: a file, or the embedded default.

use std::path::Path;

use anyhow::Context;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::{BUILTIN_RIG, BUILTIN_RIGS};

/// Loads the rig config at `path`, or the embedded default simulated gonioreflectometer
/// (the same text plans name as `builtin:bonn-gonio-sim`), so the binary works from any
/// directory.
/// A GenICam rig in a build without GenICam fails here, saying how to build with it.
pub fn load(path: Option<&Path>) -> anyhow::Result<RigConfig> {
    let rig = load_any(path)?;
    crate::backends::check_genicam(&rig)?;
    Ok(rig)
}

fn load_any(path: Option<&Path>) -> anyhow::Result<RigConfig> {
    if let Some(name) = path.and_then(builtin) {
        let (_, text) = BUILTIN_RIGS.iter().find(|(n, _)| *n == name).expect("builtin() names an embedded rig");
        return Ok(RigConfig::from_toml(text, &format!("<embedded {name}>"))?);
    }
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

/// The embedded rig that `--rig NAME` names when NAME is not a file: `builtin:NAME`,
/// `builtin:bonn-NAME` (`--rig gonio-serial` = `builtin:bonn-gonio-serial`) or
/// `builtin:bonn-NAME-sim` (`--rig dome` = `builtin:bonn-dome-sim`).
pub fn builtin(path: &Path) -> Option<&'static str> {
    if path.exists() {
        return None;
    }
    let name = path.to_str()?.trim_start_matches("builtin:");
    BUILTIN_RIGS.iter().map(|(n, _)| *n).find(|n| {
        *n == format!("builtin:{name}")
            || *n == format!("builtin:bonn-{name}")
            || *n == format!("builtin:bonn-{name}-sim")
    })
}

/// How a command names its `--rig` in output and file headers: the path as given, or the
/// embedded default.
pub fn display_name(path: Option<&Path>) -> String {
    path.map_or("<embedded bonn-gonio-sim>".to_string(), |p| p.display().to_string())
}

/// A calibration plan from `--plan`: the file at `path` read and parsed by `parse` (text,
/// origin), or without one `default()` named `default_name`; with the name headers use.
/// `what` names the plan in the read error.
pub fn plan_or_default<P, E: std::fmt::Display>(
    path: Option<&Path>,
    what: &str,
    default: impl FnOnce() -> P,
    default_name: &str,
    parse: impl FnOnce(&str, &str) -> Result<P, E>,
) -> anyhow::Result<(P, String)> {
    let Some(p) = path else { return Ok((default(), default_name.to_string())) };
    let text = std::fs::read_to_string(p).with_context(|| format!("cannot read {what} {}", p.display()))?;
    let origin = p.display().to_string();
    let plan = parse(&text, &origin).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((plan, origin))
}

/// Whether every device of `cfg` is simulated (`kind = "sim"`): only then may a command
/// print error figures against the simulator's truth.
pub fn all_simulated(cfg: &RigConfig) -> bool {
    cfg.devices.entries().iter().all(|(_, e)| e.kind == "sim")
}
