//! Validation of a [`Plan`]: every problem is collected, then either a [`ValidatedPlan`]
//! with everything resolved or [`PlanErrors`] listing them all.
//!
//! One file per plan section (`rig.rs`: `[rig]`, `sampling.rs` and `pairs.rs`: `[sampling]`
//! and `[sparse]`, ...; `resolved.rs`: the result types); this one holds the context, the
//! order of the checks and the checks across sections (reachability, an existing dataset,
//! the shared basis).

mod exposure;
mod outputs;
mod pairs;
mod registration;
mod resolved;
mod rig;
mod run;
mod sampling;
mod texture;

pub use resolved::{
    CaptureList, CompressedModel, ExistingDataset, ExposurePolicy, HdrMode, HdrSettings, MaterialRef,
    OnRegistrationFailure, OutputFormat, Outputs, Region, RegistrationMethod, RegistrationPolicy, ResampleFilter,
    SkipReason, TextureSettings, UnreachablePair, ValidatedPlan, SHARED_BASIS_ALLOWED,
};

use crate::config::RigConfig;
use crate::kinematics::Gonio;

use super::limits::{self, MAX_CAPTURES_CEILING};
use super::{Plan, PlanError, PlanErrors, BUILTIN_FAULT_SCENARIOS, BUILTIN_MATERIAL_NAMES};
use exposure::resolve_exposure;
use outputs::resolve_outputs;
use pairs::{resolve_pairs, resolve_sparse};
use registration::resolve_registration;
use rig::{resolve_material, resolve_rig};
use run::resolve_run;
use sampling::resolve_sampling;
use texture::resolve_texture;

/// How many unreachable pairs an error message lists.
const UNREACHABLE_EXAMPLES: usize = 5;

/// What validation needs from outside the plan text; the caller gathers it (reading files,
/// listing directories) so that validation itself does no I/O.
#[derive(Debug, Clone, Default)]
pub struct PlanContext {
    /// The rig config the plan names, if the caller loaded it. Required when the plan names
    /// a file; for `builtin:...` it may be `None` (the embedded text is parsed) or given.
    pub rig: Option<RigConfig>,
    /// Material names the simulator knows (usually [`BUILTIN_MATERIAL_NAMES`]).
    pub known_materials: Vec<String>,
    /// Fault scenario names (file stems of `sim/faults/*.toml`).
    pub known_faults: Vec<String>,
    /// What the output directory already holds: `None` if it is empty or does not exist.
    pub existing_dataset: Option<ExistingDataset>,
}

impl PlanContext {
    /// No rig loaded, the embedded material and fault scenario names, empty output directory.
    pub fn with_builtin_names() -> Self {
        PlanContext {
            rig: None,
            known_materials: BUILTIN_MATERIAL_NAMES.iter().map(|s| s.to_string()).collect(),
            known_faults: BUILTIN_FAULT_SCENARIOS.iter().map(|s| s.to_string()).collect(),
            existing_dataset: None,
        }
    }
}

impl Plan {
    /// Checks every value of the plan against `ctx` and reports **all** problems at once,
    /// each naming the field, the bad value and what is allowed.
    pub fn validate(&self, ctx: &PlanContext) -> Result<ValidatedPlan, PlanErrors> {
        let mut errors: Vec<PlanError> = Vec::new();
        let rig = resolve_rig(self, ctx, &mut errors);
        let material = resolve_material(self, ctx, rig.as_ref(), &mut errors);
        if let Some(m) = self.limits.max_captures.filter(|m| !(1..=MAX_CAPTURES_CEILING).contains(m)) {
            errors.push(PlanError::out_of_range(
                "limits.max_captures",
                m,
                format!("1..={MAX_CAPTURES_CEILING} (a fixed ceiling; default {})", limits::DEFAULT_MAX_CAPTURES),
            ));
        }
        let light = resolve_sampling(&self.sampling.light, "sampling.light", &mut errors);
        let view = resolve_sampling(&self.sampling.view, "sampling.view", &mut errors);
        let max_pairs = self.limits.max_captures();
        let pairs = match (&light, &view) {
            (Some(l), Some(v)) => {
                resolve_pairs(&self.sampling.pairs, l.dirs.len(), v.dirs.len(), max_pairs, &mut errors)
            }
            _ => None,
        };
        // The samplings (with their triangulations) are built only for pairs within the limit.
        let (light, view) = match pairs {
            Some(_) => (
                light.and_then(|k| k.build("sampling.light", &mut errors)),
                view.and_then(|k| k.build("sampling.view", &mut errors)),
            ),
            None => (None, None),
        };
        let texture = resolve_texture(self, rig.as_ref(), &mut errors);
        let exposure = resolve_exposure(&self.exposure, rig.as_ref(), &mut errors);
        let outputs = resolve_outputs(&self.outputs, &mut errors);
        if self.skip.max_captures == Some(0) {
            errors.push(PlanError::out_of_range("skip.max_captures", 0, ">= 1 (or leave it out for no cap)"));
        }
        let run = resolve_run(&self.run, ctx, rig.as_ref(), &mut errors);
        let registration = resolve_registration(&self.registration, &mut errors);
        let plan_hash = self.content_hash();
        let mut resume = false;
        if let Some(existing) = &ctx.existing_dataset {
            if existing.plan_hash == plan_hash {
                resume = true;
            } else {
                errors.push(PlanError::OtherDataset {
                    field: "output".into(),
                    path: existing.path.clone(),
                    found: existing.plan_hash,
                    expected: plan_hash,
                });
            }
        }

        let mut unreachable = Vec::new();
        if let (Some(rig), Some((l, _)), Some((v, _)), Some(pairs)) = (&rig, &light, &view, &pairs) {
            match Gonio::new(rig.geometry.clone()) {
                Ok(gonio) => {
                    for &(i, j) in pairs {
                        if let Err(reason) = gonio.ik(l.get(i), v.get(j)) {
                            unreachable.push(UnreachablePair { light: i, view: j, reason });
                        }
                    }
                }
                Err(e) => errors.push(PlanError::invalid("rig.config", &self.rig.config, e.to_string(), "a valid rig")),
            }
            if !unreachable.is_empty() && !self.skip.unreachable {
                errors.push(PlanError::Unreachable {
                    field: "skip.unreachable".into(),
                    count: unreachable.len(),
                    total: pairs.len(),
                    first: unreachable
                        .iter()
                        .take(UNREACHABLE_EXAMPLES)
                        .map(|u| {
                            let (lt, lp) = l.get(u.light).to_degrees();
                            let (vt, vp) = v.get(u.view).to_degrees();
                            format!(
                                "(light {} ({lt:.1}, {lp:.1}), view {} ({vt:.1}, {vp:.1})): {}",
                                u.light, u.view, u.reason
                            )
                        })
                        .collect(),
                });
            } else if !pairs.is_empty() && unreachable.len() == pairs.len() {
                errors.push(PlanError::invalid(
                    "sampling",
                    format!("{} pairs", pairs.len()),
                    format!("the rig can reach none of them (first: {})", unreachable[0].reason),
                    "at least one pair the rig can reach",
                ));
            }
        }

        let sparse = match (&self.sparse, &light, &view, &pairs) {
            (Some(sp), Some((l, _)), Some((v, _)), Some(pairs)) => {
                resolve_sparse(sp, l.len(), v.len(), pairs, &unreachable, &mut errors)
            }
            _ => None,
        };
        if !errors.is_empty() {
            return Err(PlanErrors { origin: String::new(), errors });
        }
        let (rig, (light, light_source_indices), (view, view_source_indices)) =
            (rig.expect("no errors"), light.expect("no errors"), view.expect("no errors"));
        let plan = ValidatedPlan {
            name: self.name.clone(),
            plan_hash,
            rig,
            rig_source: self.rig.config.clone(),
            material,
            light,
            view,
            light_source_indices,
            view_source_indices,
            pairs: pairs.expect("no errors"),
            unreachable,
            texture: texture.expect("no errors"),
            exposure: exposure.expect("no errors"),
            outputs: outputs.expect("no errors"),
            skip: self.skip.clone(),
            run,
            registration: registration.expect("no errors"),
            resume,
            sparse,
        };
        check_shared_basis(&plan)?;
        Ok(plan)
    }

    /// [`Plan::from_toml`] then [`Plan::validate`], with `origin` in every error.
    pub fn load_and_validate(text: &str, origin: &str, ctx: &PlanContext) -> Result<ValidatedPlan, PlanErrors> {
        let plan = Plan::from_toml(text, origin)?;
        plan.validate(ctx).map_err(|mut e| {
            e.origin = origin.to_string();
            e
        })
    }
}

/// `outputs.compressed_model = "pcmf-shared"` on a plan too small for it: refused before the
/// run rather than when the model is built after it.
fn check_shared_basis(plan: &ValidatedPlan) -> Result<(), PlanErrors> {
    if plan.outputs.compressed_model != Some(CompressedModel::PcmfShared) {
        return Ok(());
    }
    match plan.shared_basis_problem() {
        None => Ok(()),
        Some(why) => Err(PlanErrors {
            origin: String::new(),
            errors: vec![PlanError::invalid(
                "outputs.compressed_model",
                "\"pcmf-shared\"",
                why,
                SHARED_BASIS_ALLOWED.replace("{k}", &CompressedModel::SHARED_BASIS_TERMS.to_string()),
            )],
        }),
    }
}
