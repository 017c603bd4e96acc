//! `[rig]`: the rig config and the material.

use crate::config::RigConfig;

use super::{MaterialRef, PlanContext};
use crate::plan::{is_path_like, Plan, PlanError, BUILTIN_RIGS};

pub(super) fn resolve_rig(plan: &Plan, ctx: &PlanContext, errors: &mut Vec<PlanError>) -> Option<RigConfig> {
    let name = plan.rig.config.as_str();
    let mut rig = if let Some(r) = &ctx.rig {
        Some(r.clone())
    } else if name.starts_with("builtin:") {
        match BUILTIN_RIGS.iter().find(|(n, _)| *n == name) {
            Some((n, text)) => {
                Some(RigConfig::from_toml(text, &format!("<embedded {n}>")).expect("embedded rig is valid"))
            }
            None => {
                let known: Vec<String> = BUILTIN_RIGS.iter().map(|(n, _)| format!("{n:?}")).collect();
                errors.push(PlanError::unknown(
                    "rig.config",
                    name,
                    format!("{}, or a rig config file relative to the plan", known.join(", ")),
                ));
                None
            }
        }
    } else {
        errors.push(PlanError::invalid(
            "rig.config",
            format!("{name:?}"),
            "this rig config file was not loaded by the caller",
            "a readable rig config file relative to the plan, or \"builtin:bonn-gonio-sim\"",
        ));
        None
    };
    if let (Some(r), Some(seed)) = (rig.as_mut(), plan.rig.seed) {
        r.rig.seed = seed;
    }
    // This plan format drives a gonioreflectometer (directions through inverse kinematics);
    // an LED dome's views and lights are fixed by the rig and run by `btfrig demo --rig dome`.
    if let Some(r) = rig.as_ref().filter(|r| r.rig.kind != crate::config::RigKind::Gonioreflectometer) {
        errors.push(PlanError::invalid(
            "rig.config",
            format!("{name:?} (kind = {:?})", r.rig.kind.as_str()),
            "this plan format drives a gonioreflectometer",
            "a gonioreflectometer rig config; LED domes run dome plans (`btfrig demo --rig dome`, docs/plan-format.md)",
        ));
        return None;
    }
    rig
}

pub(super) fn is_simulated(rig: &RigConfig) -> bool {
    // An emulated camera (PTP firmware in front of the simulator's) renders the material too.
    rig.devices.camera.simulated().is_some()
}

pub(super) fn resolve_material(
    plan: &Plan,
    ctx: &PlanContext,
    rig: Option<&RigConfig>,
    errors: &mut Vec<PlanError>,
) -> Option<MaterialRef> {
    let m = plan.rig.material.as_deref()?;
    // A recorded rig (docs/recorded-camera.md) replays frames of a plan that may name its
    // simulated material: the frames show the sample, the name stays as the plan's record.
    let recorded = rig.is_some_and(|r| r.devices.camera.kind == "recorded");
    if rig.is_some_and(|r| !is_simulated(r)) && !recorded {
        errors.push(PlanError::invalid(
            "rig.material",
            format!("{m:?}"),
            "a material only applies to a simulated rig (devices.camera.kind = \"sim\")",
            "no material for a real rig",
        ));
    }
    if is_path_like(m) {
        if !m.ends_with(".toml") {
            errors.push(PlanError::invalid(
                "rig.material",
                format!("{m:?}"),
                "a material file must be TOML",
                "a path ending in .toml, or a material name",
            ));
        }
        return Some(MaterialRef::File(m.to_string()));
    }
    if !ctx.known_materials.iter().any(|k| k == m) {
        errors.push(PlanError::unknown(
            "rig.material",
            m,
            format!("{}, or a material file ending in .toml", ctx.known_materials.join(", ")),
        ));
    }
    Some(MaterialRef::Builtin(m.to_string()))
}
