//! Loading a plan and what it names: the rig config, the material and fault scenario (which
//! the device backend checks: they are a simulated rig's options), the exposure; and the
//! dataset manifest of a plan. Shared by `btfrig run`, `btfrig plan` and
//! the daemon.

use std::collections::BTreeMap;
use std::path::Path;

use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{DomePlan, ValidatedDomePlan};
use btfrig_core::plan::{
    CaptureList, ExposurePolicy, MaterialRef, OutputFormat, Plan, PlanContext, SkipReason, ValidatedPlan, BUILTIN_RIGS,
};
use btfrig_store::{
    DirectionDeg, Manifest, RigInfo, Samplings, SkippedStep, StepId, TextureFormat, TextureRegion, TextureSpec,
};

use crate::backend::{BackendRegistry, SceneOptions};
use crate::RunError;

fn read(path: &Path) -> Result<String, RunError> {
    std::fs::read_to_string(path).map_err(|source| RunError::Read { path: path.to_path_buf(), source })
}

/// Reads a plan file, then [`load_text`].
pub fn load(file: &Path) -> Result<(Plan, ValidatedPlan), RunError> {
    load_text(&read(file)?, file)
}

/// Parses and validates plan text with the process's device backends ([`load_text_with`]).
pub fn load_text(text: &str, file: &Path) -> Result<(Plan, ValidatedPlan), RunError> {
    load_text_with(text, file, &crate::backend::installed())
}

/// Parses and validates plan text; `file` names it in errors and anchors its relative paths.
/// The rig config it names is loaded first so the validation can check that the rig
/// realises the plan's samplings; the backend of `backends` that opens the rig checks its
/// device options as opening them would, and a material file the plan names (read and
/// parsed by that backend), so that everything a run would trip over later is refused here,
/// before a dataset directory exists.
pub fn load_text_with(text: &str, file: &Path, backends: &BackendRegistry) -> Result<(Plan, ValidatedPlan), RunError> {
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
    check_rig_with(&validated.rig, &plan.rig.config, backends)?;
    if matches!(validated.material, Some(MaterialRef::File(_))) {
        let backend = backends.for_rig(&validated.rig)?;
        backend
            .check_scene(&SceneOptions { material: material_name(&plan, &validated, file).as_deref(), faults: None })?;
    }
    Ok((plan, validated))
}

/// The rig config's device options, checked by the process's backend for the rig without
/// opening the devices (`btfrig serve --rig` checks its rig with this at start-up, as plans
/// check theirs); `source` names the config in errors.
pub fn check_rig_options(rig: &RigConfig, source: &str) -> Result<(), RunError> {
    check_rig_with(rig, source, &crate::backend::installed())
}

fn check_rig_with(rig: &RigConfig, source: &str, backends: &BackendRegistry) -> Result<(), RunError> {
    backends
        .for_rig(rig)?
        .check_rig(rig)
        .map_err(|message| RunError::Input { what: format!("rig.config {source:?}"), message })
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
        let backend = crate::backend::installed().for_rig(&rig)?;
        let material = dome_material_name(Some(m), file);
        backend.check_scene(&SceneOptions { material: material.as_deref(), faults: None })?;
    }
    Ok((v, rig, rig_text))
}

fn dome_input(what: &str, e: impl std::fmt::Display) -> RunError {
    RunError::Input { what: what.into(), message: e.to_string() }
}

/// The plan's material as the device backend loads it: an embedded name, a material file's
/// path resolved against the plan's directory, or `None` (the backend's default).
pub fn material_name(plan: &Plan, v: &ValidatedPlan, file: &Path) -> Option<String> {
    match &v.material {
        Some(MaterialRef::Builtin(name)) => Some(name.clone()),
        Some(MaterialRef::File(_)) => plan.material_path(file).map(|p| p.display().to_string()),
        None => None,
    }
}

/// A dome plan's `[rig] material` as the device backend loads it: an embedded name, a
/// material file (`.toml`) resolved against the directory of the plan file `plan_path` (as a
/// gonio plan's, [`material_name`]), or `None` (the backend's default).
pub fn dome_material_name(name: Option<&str>, plan_path: &Path) -> Option<String> {
    match name {
        Some(file) if file.ends_with(".toml") => {
            Some(plan_path.parent().unwrap_or(Path::new(".")).join(file).display().to_string())
        }
        n => n.map(String::from),
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
    light: Option<&btfrig_process::light::LightCorrection>,
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
