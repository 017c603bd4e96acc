//! A plan checked against the rig that is to run it: a gonioreflectometer runs gonio plans
//! (`[sampling]`, no `[dome]` table), an LED dome or camera array runs dome plans (a `[dome]`
//! table, `docs/plan-format.md`, "LED dome plans"), and either only plans naming it. The
//! daemon (`btfrig serve`) checks every plan it validates, dry-runs, offers or starts here, so
//! a plan for another kind of rig is refused with both kinds named ([`RunError::WrongRig`]).

use std::path::Path;

use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{DomePlan, ValidatedDomePlan};
use btfrig_core::plan::{Plan, ValidatedPlan, BUILTIN_RIG, BUILTIN_RIGS};

use crate::RunError;

/// Which plan format a plan is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanKind {
    /// A gonioreflectometer plan (`btfrig_core::plan::Plan`): light and view samplings.
    Gonio,
    /// A dome plan (`btfrig_core::plan::dome::DomePlan`): a `[dome]` table; LED domes and
    /// camera arrays.
    Dome,
}

impl PlanKind {
    /// The kind of the plan `text`: a dome plan when it has a `[dome]` table; `None` when it
    /// is not TOML at all.
    pub fn of_toml(text: &str) -> Option<PlanKind> {
        // Too long to parse: the plan parser refuses it, naming the limit.
        if text.len() > btfrig_core::plan::MAX_PLAN_BYTES {
            return None;
        }
        toml::from_str::<toml::Table>(text).ok().map(|t| {
            if t.contains_key("dome") {
                PlanKind::Dome
            } else {
                PlanKind::Gonio
            }
        })
    }

    /// The plans a rig of `rig` runs.
    pub fn for_rig(rig: &RigConfig) -> PlanKind {
        if rig.rig.kind.is_dome() {
            PlanKind::Dome
        } else {
            PlanKind::Gonio
        }
    }

    /// `"gonioreflectometer"` or `"dome"`.
    pub fn as_str(self) -> &'static str {
        match self {
            PlanKind::Gonio => "gonioreflectometer",
            PlanKind::Dome => "dome",
        }
    }

    /// The plan format, for messages.
    pub fn describe(self) -> &'static str {
        match self {
            PlanKind::Gonio => "gonioreflectometer plan (no [dome] table)",
            PlanKind::Dome => "dome plan (a [dome] table)",
        }
    }

    /// What a rig that runs this kind accepts, for messages.
    pub fn allowed(self) -> &'static str {
        match self {
            PlanKind::Gonio => {
                "gonioreflectometer plans (light and view [sampling], no [dome] table; docs/plan-format.md)"
            }
            PlanKind::Dome => "dome plans (a [dome] table; docs/plan-format.md, \"LED dome plans\")",
        }
    }
}

/// A plan that validated and names the rig it was checked against.
#[derive(Debug, Clone)]
pub enum CheckedPlan {
    /// A gonio plan.
    Gonio {
        /// As written.
        plan: Box<Plan>,
        /// Validated against its rig config.
        validated: Box<ValidatedPlan>,
    },
    /// A dome plan.
    Dome {
        /// Validated against its rig config.
        plan: Box<ValidatedDomePlan>,
        /// Its rig config (with the plan's seed).
        rig: Box<RigConfig>,
    },
}

impl CheckedPlan {
    /// Its format.
    pub fn kind(&self) -> PlanKind {
        match self {
            CheckedPlan::Gonio { .. } => PlanKind::Gonio,
            CheckedPlan::Dome { .. } => PlanKind::Dome,
        }
    }

    /// The plan's name.
    pub fn name(&self) -> &str {
        match self {
            CheckedPlan::Gonio { validated, .. } => &validated.name,
            CheckedPlan::Dome { plan, .. } => &plan.plan.name,
        }
    }

    /// Captures it makes: (light, view) pairs of a gonio plan; textures (lights x views) of a
    /// dome plan.
    pub fn captures(&self) -> u64 {
        match self {
            CheckedPlan::Gonio { validated, .. } => validated.capture_list().captures.len() as u64,
            CheckedPlan::Dome { plan, rig } => {
                let lights = rig.dome.as_ref().map_or(0, |d| d.led_count());
                (lights * plan.cameras.len() * plan.rotations.len()) as u64
            }
        }
    }

    /// The plan's description; a dome plan has none, so its lights and views.
    pub fn description(&self) -> String {
        match self {
            CheckedPlan::Gonio { plan, .. } => plan.description.clone(),
            CheckedPlan::Dome { plan, rig } => {
                let (lights, light) = match &rig.dome {
                    Some(d) => (d.led_count(), if d.is_flash() { "flashes" } else { "LEDs" }),
                    None => (0, "lights"),
                };
                format!(
                    "dome plan: {lights} {light} x {} views (cameras {:?} x rotations {:?})",
                    plan.cameras.len() * plan.rotations.len(),
                    plan.cameras,
                    plan.rotations
                )
            }
        }
    }
}

/// Loads and validates the plan `text` (named `file`, which anchors its relative paths) and
/// checks that `rig` runs it: same kind ([`PlanKind::for_rig`]) and same rig name. A plan of
/// the other kind is refused before it is validated (it cannot run here whatever it says);
/// the refusal names the plan's rig and kind, this rig and its kind, and what is allowed.
/// Text that is not TOML at all is reported by the parser of this rig's plans.
pub fn check_for_rig(text: &str, file: &Path, rig: &RigConfig) -> Result<CheckedPlan, RunError> {
    let parsed = PlanKind::of_toml(text);
    let kind = parsed.unwrap_or(PlanKind::Gonio);
    let here = PlanKind::for_rig(rig);
    let wrong = |plan_rig: String| RunError::WrongRig {
        plan_kind: kind.describe(),
        plan_rig,
        rig: rig.rig.name.clone(),
        rig_kind: rig.rig.kind.as_str(),
        allowed: here.allowed(),
    };
    if kind != here && parsed.is_some() {
        return Err(wrong(plan_rig_label(text, file, kind)));
    }
    let checked = match here {
        PlanKind::Gonio => {
            let (plan, validated) = crate::plan::load_text(text, file)?;
            CheckedPlan::Gonio { plan: Box::new(plan), validated: Box::new(validated) }
        }
        PlanKind::Dome => {
            let (plan, plan_rig, _) = crate::plan::load_dome(text, file)?;
            CheckedPlan::Dome { plan: Box::new(plan), rig: Box::new(plan_rig) }
        }
    };
    let plan_rig = match &checked {
        CheckedPlan::Gonio { validated, .. } => &validated.rig,
        CheckedPlan::Dome { rig, .. } => rig.as_ref(),
    };
    if plan_rig.rig.name != rig.rig.name || plan_rig.rig.kind != rig.rig.kind {
        return Err(wrong(format!("{:?} ({})", plan_rig.rig.name, plan_rig.rig.kind.as_str())));
    }
    Ok(checked)
}

/// The rig a plan names, for a refusal: `"name" (kind)` when its config loads, else the
/// `rig.config` value as written. Only called for text [`PlanKind::of_toml`] parsed (so
/// within the size limit).
fn plan_rig_label(text: &str, file: &Path, kind: PlanKind) -> String {
    let config = toml::from_str::<toml::Table>(text)
        .ok()
        .and_then(|t| t.get("rig")?.get("config")?.as_str().map(String::from))
        .unwrap_or_else(|| match kind {
            PlanKind::Gonio => BUILTIN_RIG.to_string(),
            PlanKind::Dome => DomePlan::DEFAULT_RIG.to_string(),
        });
    let rig_text = match BUILTIN_RIGS.iter().find(|(n, _)| *n == config) {
        Some((_, t)) => Some(t.to_string()),
        None if config.starts_with("builtin:") => None,
        None => std::fs::read_to_string(file.parent().unwrap_or(Path::new(".")).join(&config)).ok(),
    };
    match rig_text.and_then(|t| RigConfig::from_toml(&t, &config).ok()) {
        Some(r) => format!("{:?} ({})", r.rig.name, r.rig.kind.as_str()),
        None => format!("{config:?} (its rig.config, which does not load)"),
    }
}

/// A file that a plan names (rather than an embedded rig, material or fault scenario).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamedFile {
    /// The plan key, e.g. `rig.config`.
    pub field: &'static str,
    /// The value as written.
    pub value: String,
    /// The path it resolves to (relative values against the plan file's directory, as the
    /// loaders resolve them). Pure path arithmetic: nothing is read.
    pub path: std::path::PathBuf,
}

/// Every file the plan `text` (at `file`) would read: a non-embedded `rig.config`, a
/// material file (`rig.material` ending in `.toml` or with a path separator), and a fault
/// scenario that is no embedded name (`run.fault_scenario` of gonio plans, `fault_scenario`
/// of dome plans). Read from the TOML before any validation, so that a caller that must
/// confine what a plan may read (the daemon, for plans sent over its API) can refuse the plan
/// before anything is opened. Text that is not TOML names no files.
pub fn named_files(text: &str, file: &Path) -> Vec<NamedFile> {
    let Ok(t) = toml::from_str::<toml::Table>(text) else { return Vec::new() };
    let dir = file.parent().unwrap_or(Path::new("."));
    let at = |table: Option<&toml::Value>, key: &str| -> Option<String> { table?.get(key)?.as_str().map(String::from) };
    let resolve = |v: &str| -> std::path::PathBuf {
        let p = Path::new(v);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            dir.join(p)
        }
    };
    let mut out = Vec::new();
    if let Some(c) = at(t.get("rig"), "config").filter(|c| !c.starts_with("builtin:")) {
        out.push(NamedFile { field: "rig.config", path: resolve(&c), value: c });
    }
    if let Some(m) =
        at(t.get("rig"), "material").filter(|m| m.ends_with(".toml") || m.contains('/') || m.contains('\\'))
    {
        out.push(NamedFile { field: "rig.material", path: resolve(&m), value: m });
    }
    let embedded_fault = |f: &str| btfrig_core::plan::BUILTIN_FAULT_SCENARIOS.contains(&f);
    if let Some(f) = at(t.get("run"), "fault_scenario").filter(|f| !embedded_fault(f)) {
        out.push(NamedFile { field: "run.fault_scenario", path: resolve(&f), value: f });
    }
    if let Some(f) = t.get("fault_scenario").and_then(|v| v.as_str()).filter(|f| !embedded_fault(f)) {
        out.push(NamedFile { field: "fault_scenario", path: resolve(f), value: f.to_string() });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_files_lists_what_a_plan_would_read_and_nothing_embedded() {
        let plan = Path::new("/plans/p.toml");
        let text = "[rig]\nconfig = \"../etc/rig.toml\"\nmaterial = \"mats/wood.toml\"\n[run]\nfault_scenario = \"/x/f.toml\"\n";
        let got = named_files(text, plan);
        let fields: Vec<_> = got.iter().map(|f| (f.field, f.path.display().to_string())).collect();
        assert_eq!(
            fields,
            [
                ("rig.config", "/plans/../etc/rig.toml".to_string()),
                ("rig.material", "/plans/mats/wood.toml".to_string()),
                ("run.fault_scenario", "/x/f.toml".to_string()),
            ]
        );
        let embedded =
            "fault_scenario = \"flaky\"\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\nmaterial = \"leather\"\n";
        assert!(named_files(embedded, plan).is_empty());
        let dome = "fault_scenario = \"../../proc/self/environ\"\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\n";
        assert_eq!(named_files(dome, plan)[0].field, "fault_scenario");
        assert!(named_files("not toml [", plan).is_empty());
    }
}
