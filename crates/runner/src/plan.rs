//! Loading a plan and what it names: the rig config, the material, the fault scenario, the
//! exposure; and the dataset manifest of a plan. Shared by `btfrig run`, `btfrig plan` and
//! the daemon.

use std::collections::BTreeMap;
use std::path::Path;

use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{DomePlan, ValidatedDomePlan};
use btfrig_core::plan::{
    CaptureList, ExposurePolicy, MaterialRef, OutputFormat, Plan, PlanContext, SkipReason, ValidatedPlan, BUILTIN_RIGS,
};
use btfrig_render::material::{MaterialSpec, BUILTIN_MATERIALS};
use btfrig_sim::FaultScenario;
use btfrig_store::{
    DirectionDeg, Manifest, RigInfo, Samplings, SkippedStep, StepId, TextureFormat, TextureRegion, TextureSpec,
};

use crate::RunError;

/// The material used when a plan names none: deep relief, so that shadowing and masking show.
pub const DEFAULT_MATERIAL: &str = "corduroy";

/// The embedded fault scenarios (`sim/faults/*.toml`), by the names plans and `--faults` use.
pub const FAULT_FILES: &[(&str, &str)] = &[
    ("none", include_str!("../../../sim/faults/none.toml")),
    ("flaky", include_str!("../../../sim/faults/flaky.toml")),
    ("lamp-drift", include_str!("../../../sim/faults/lamp-drift.toml")),
    ("stuck-led", include_str!("../../../sim/faults/stuck-led.toml")),
    ("robot-fault", include_str!("../../../sim/faults/robot-fault.toml")),
    ("hidden-markers", include_str!("../../../sim/faults/hidden-markers.toml")),
];

fn read(path: &Path) -> Result<String, RunError> {
    std::fs::read_to_string(path).map_err(|source| RunError::Read { path: path.to_path_buf(), source })
}

/// Reads a plan file, then [`load_text`].
pub fn load(file: &Path) -> Result<(Plan, ValidatedPlan), RunError> {
    load_text(&read(file)?, file)
}

/// Parses and validates plan text; `file` names it in errors and anchors its relative paths.
/// The rig config it names is loaded first so the validation can check that the rig
/// realises the plan's samplings; its simulated devices' options are checked as building
/// them would ([`btfrig_sim::check_sim_options`]), and a material file the plan names is
/// read and parsed, so that everything a run would trip over later is refused here, before
/// a dataset directory exists.
pub fn load_text(text: &str, file: &Path) -> Result<(Plan, ValidatedPlan), RunError> {
    let plan = Plan::from_toml(text, &file.display().to_string())?;
    let mut ctx = PlanContext::with_builtin_names();
    if let Some(rig) = plan.rig_config_path(file) {
        let cfg = RigConfig::from_toml(&read(&rig)?, &rig.display().to_string())
            .map_err(|e| RunError::Input { what: format!("{}: rig.config", file.display()), message: e.to_string() })?;
        ctx.rig = Some(cfg);
    }
    let validated = plan.validate(&ctx).map_err(|mut e| {
        e.origin = file.display().to_string();
        e
    })?;
    check_rig_options(&validated.rig, &plan.rig.config)?;
    if matches!(validated.material, Some(MaterialRef::File(_))) {
        material(&plan, &validated, file)?;
    }
    Ok((plan, validated))
}

/// The rig config's simulated device options, checked without building the rig (`btfrig
/// serve --rig` checks its rig with this at start-up, as plans check theirs).
pub fn check_rig_options(rig: &RigConfig, source: &str) -> Result<(), RunError> {
    btfrig_sim::check_sim_options(&rig.devices)
        .map_err(|e| RunError::Input { what: format!("rig.config {source:?}"), message: e.to_string() })
}

/// Loads and validates a dome plan (`file` names it in errors and resolves a relative rig
/// config) and its rig config; returns the rig config's text too.
pub fn load_dome(text: &str, file: &Path) -> Result<(ValidatedDomePlan, RigConfig, String), RunError> {
    let origin = file.display().to_string();
    let plan = DomePlan::from_toml(text, &origin).map_err(|e| dome_input(&origin, e))?;
    let name = plan.rig.config.clone();
    let rig_text = match BUILTIN_RIGS.iter().find(|(n, _)| *n == name) {
        Some((_, t)) => t.to_string(),
        None if name.starts_with("builtin:") => {
            let known: Vec<&str> = BUILTIN_RIGS.iter().map(|(n, _)| *n).collect();
            return Err(dome_input("rig.config", format!("{name:?} is unknown: allowed {}", known.join(", "))));
        }
        None => {
            let p = file.parent().unwrap_or(Path::new(".")).join(&name);
            std::fs::read_to_string(&p).map_err(|source| RunError::Read { path: p, source })?
        }
    };
    let mut rig = RigConfig::from_toml(&rig_text, &name).map_err(|e| dome_input("rig.config", e))?;
    if let Some(seed) = plan.rig.seed {
        rig.rig.seed = seed;
    }
    check_rig_options(&rig, &name)?;
    let v = plan.validate(&rig).map_err(|e| dome_input(&origin, e))?;
    if let Some(m) = v.plan.rig.material.as_deref().filter(|m| m.ends_with(".toml")) {
        dome_material(Some(m), file)?;
    }
    Ok((v, rig, rig_text))
}

fn dome_input(what: &str, e: impl std::fmt::Display) -> RunError {
    RunError::Input { what: what.into(), message: e.to_string() }
}

/// Loads an embedded material by name, or a material file if `name` ends in `.toml`
/// (default: [`DEFAULT_MATERIAL`]).
pub fn load_material(name: Option<&str>) -> Result<MaterialSpec, RunError> {
    let name = name.unwrap_or(DEFAULT_MATERIAL);
    if name.ends_with(".toml") {
        let text = read(Path::new(name)).map_err(|e| RunError::Input {
            what: format!("rig.material {name:?}"),
            message: format!("{e}; allowed: an existing material file (relative to the plan) or an embedded name"),
        })?;
        return MaterialSpec::from_toml(&text, name)
            .map_err(|e| RunError::Input { what: format!("material {name}"), message: e.to_string() });
    }
    MaterialSpec::builtin(name).map_err(|e| {
        let names: Vec<&str> = BUILTIN_MATERIALS.iter().map(|(n, _)| *n).collect();
        RunError::Input {
            what: format!("material {name:?}"),
            message: format!("{e}; allowed: {} or a path ending in .toml", names.join(", ")),
        }
    })
}

/// The plan's material: an embedded name, a file next to the plan, or the default.
pub fn material(plan: &Plan, v: &ValidatedPlan, file: &Path) -> Result<MaterialSpec, RunError> {
    match &v.material {
        Some(MaterialRef::Builtin(name)) => load_material(Some(name)),
        Some(MaterialRef::File(_)) => {
            let path = plan.material_path(file).expect("a material file reference has a path");
            load_material(Some(&path.display().to_string()))
        }
        None => load_material(None),
    }
}

/// A dome plan's `[rig] material`: an embedded name, a material file resolved against the
/// directory of the plan file `plan_path` (as a gonio plan's, [`material`]), or the default.
pub fn dome_material(name: Option<&str>, plan_path: &Path) -> Result<MaterialSpec, RunError> {
    match name {
        Some(file) if file.ends_with(".toml") => {
            let path = plan_path.parent().unwrap_or(Path::new(".")).join(file);
            load_material(Some(&path.display().to_string()))
        }
        _ => load_material(name),
    }
}

/// The exposure per capture: fixed, or auto: a white Lambertian reflector facing the lamp at
/// the policy's fraction of full scale, from the light calibration's white signal rate
/// (`light`, else the one the rig config names) and the config's `[sensor]` datasheet values.
/// Auto exposure without a light calibration is refused: nothing says how bright the lamp is.
pub fn exposure_s(
    plan: &Plan,
    v: &ValidatedPlan,
    file: &Path,
    light: Option<&btfrig_pipeline::light::LightCorrection>,
) -> Result<f64, RunError> {
    Ok(match v.exposure {
        ExposurePolicy::Fixed { exposure_s, .. } => exposure_s,
        ExposurePolicy::Auto { white_fraction, .. } => {
            let rig_path = plan.rig_config_path(file);
            let config = match light {
                Some(_) => None,
                None => crate::model::config_light(&v.rig, rig_path.as_deref())?,
            };
            let Some(l) = light.or(config.as_ref().map(|(l, _)| l)) else {
                return Err(RunError::Input {
                    what: "[exposure] mode = \"auto\"".into(),
                    message: format!(
                        "the rig {} has no light calibration ([lamp] calibration), so the lamp's brightness is unknown: name one (btfrig calibrate light) or set a fixed exposure_s",
                        v.rig.rig.name
                    ),
                });
            };
            crate::model::exposure_for_white(&v.rig.sensor, l, white_fraction).clamp(1e-6, 3600.0)
        }
    })
}

/// Bytes the camera transfers per frame (the timing model's, or 2 per photosite).
pub fn frame_bytes(v: &ValidatedPlan) -> u64 {
    let cam = &v.rig.camera;
    v.rig.timing.camera.frame_bytes.unwrap_or((cam.width_px * cam.height_px) as u64 * 2)
}

/// Plan skips counted by reason, in order of first appearance.
pub fn skip_counts(skipped: &[((usize, usize), SkipReason)]) -> Vec<(String, usize)> {
    let mut counts: Vec<(String, usize)> = Vec::new();
    for (_, r) in skipped {
        let label = r.label();
        match counts.iter_mut().find(|(l, _)| *l == label) {
            Some((_, n)) => *n += 1,
            None => counts.push((label, 1)),
        }
    }
    counts
}

/// [`skip_counts`] as a map.
pub fn skip_map(skipped: &[((usize, usize), SkipReason)]) -> BTreeMap<String, u64> {
    skip_counts(skipped).into_iter().map(|(k, n)| (k, n as u64)).collect()
}

/// A fault scenario by name: an embedded one ([`FAULT_FILES`]) or a TOML file, relative to
/// `base` (the plan's directory for the plan's own field, the working directory for an
/// override). `field` names the setting in errors.
pub fn fault_scenario(name: &str, base: &Path, field: &str) -> Result<FaultScenario, RunError> {
    let bad = |message: String| RunError::Input { what: format!("{field} {name:?}"), message };
    if let Some((_, text)) = FAULT_FILES.iter().find(|(n, _)| *n == name) {
        return FaultScenario::from_toml(text, &format!("<embedded sim/faults/{name}.toml>"))
            .map_err(|e| bad(e.to_string()));
    }
    let path = base.join(name);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        let names: Vec<&str> = FAULT_FILES.iter().map(|(n, _)| *n).collect();
        bad(format!("cannot read {}: {e}; allowed: {} or a scenario file", path.display(), names.join(", ")))
    })?;
    FaultScenario::from_toml(&text, &path.display().to_string()).map_err(|e| bad(e.to_string()))
}

/// The manifest of a new dataset of this plan.
pub fn manifest(
    plan: &Plan,
    v: &ValidatedPlan,
    text: &str,
    file: &Path,
    list: &CaptureList,
) -> Result<Manifest, RunError> {
    // BUILTIN_RIGS names keep their `builtin:` prefix.
    let config_toml = match plan.rig.config.starts_with("builtin:") {
        true => BUILTIN_RIGS
            .iter()
            .find(|(n, _)| *n == plan.rig.config)
            .map(|(_, t)| t.to_string())
            .ok_or_else(|| RunError::Rig(format!("rig.config = {:?} is not an embedded rig", plan.rig.config)))?,
        false => {
            let p = plan.rig_config_path(file).unwrap_or_else(|| plan.rig.config.clone().into());
            read(&p)?
        }
    };
    let id = |(l, v): (usize, usize)| StepId { light: l as u32, view: v as u32 };
    let samplings = Samplings {
        light: v.light.directions().iter().map(|&d| DirectionDeg::from(d)).collect(),
        view: v.view.directions().iter().map(|&d| DirectionDeg::from(d)).collect(),
        pairs: Some(list.captures.iter().chain(list.skipped.iter().map(|(p, _)| p)).map(|&p| id(p)).collect()),
        skipped: list.skipped.iter().map(|&(p, r)| SkippedStep { step: id(p), reason: r.label() }).collect(),
    };
    let r = &v.texture.region;
    let texture = TextureSpec {
        width: v.texture.size as u32,
        height: v.texture.size as u32,
        region: TextureRegion {
            center_m: [(r.x_min_m + r.x_max_m) / 2.0, (r.y_min_m + r.y_max_m) / 2.0],
            size_m: [r.x_max_m - r.x_min_m, r.y_max_m - r.y_min_m],
        },
        format: match v.outputs.format {
            OutputFormat::ExrHalf => TextureFormat::ExrHalf,
            OutputFormat::ExrFloat => TextureFormat::ExrFloat,
        },
    };
    let rig = RigInfo { name: v.rig.rig.name.clone(), config_toml };
    let mut m = Manifest::new(rig, text, samplings, texture, v.outputs.raw_frames, v.rig.rig.seed);
    m.textures = v.outputs.textures;
    m.texture_previews = v.outputs.texture_previews;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_fault_files_are_the_names_plans_may_use_and_all_parse() {
        let mut ours: Vec<&str> = FAULT_FILES.iter().map(|(n, _)| *n).collect();
        let mut core: Vec<&str> = btfrig_core::plan::BUILTIN_FAULT_SCENARIOS.to_vec();
        ours.sort_unstable();
        core.sort_unstable();
        assert_eq!(ours, core);
        for (name, _) in FAULT_FILES {
            fault_scenario(name, Path::new("/nonexistent"), "--faults").unwrap();
        }
        let e = fault_scenario("nosuch", Path::new("/nonexistent"), "--faults").unwrap_err().to_string();
        assert!(
            e.contains("--faults \"nosuch\"") && e.contains("robot-fault") && e.contains("/nonexistent/nosuch"),
            "{e}"
        );
    }
}
