//! Validation of a [`Plan`]: every problem is collected, then either a [`ValidatedPlan`]
//! with everything resolved or [`PlanErrors`] listing them all.

use crate::config::RigConfig;
use crate::direction::{angle_between, Direction};
use crate::kinematics::{Gonio, Unreachable, UnreachableKind};
use crate::sampling::{Sampling, BONN81_RINGS, BONN_DOME1_RINGS, DUPLICATE_TOLERANCE_RAD};

use super::limits::{self, MAX_CAPTURES_CEILING, MAX_DIRECTIONS};
use super::{
    is_path_like, ExposureSpec, FilterSpec, OutputsSpec, PairsSpec, Plan, PlanError, PlanErrors, RegionSpec,
    RegistrationSpec, RunSpec, SamplingSpec, SamplingTable, SkipSpec, BUILTIN_FAULT_SCENARIOS, BUILTIN_MATERIAL_NAMES,
    BUILTIN_RIGS,
};

/// Sampling presets a plan may name, with their directions' source.
const PRESETS: &str = "\"bonn81\", \"dome1-151\"";
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

/// A dataset found in the output directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExistingDataset {
    /// The [`Plan::content_hash`] recorded in its manifest.
    pub plan_hash: u64,
    /// The directory, for the message.
    pub path: String,
}

/// The sample's material on a simulated rig.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MaterialRef {
    /// An embedded material, by name.
    Builtin(String),
    /// A material file as written in the plan (resolve it with [`Plan::material_path`]).
    File(String),
}

/// Texture file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputFormat {
    /// OpenEXR, 16-bit half floats, linear.
    ExrHalf,
    /// OpenEXR, 32-bit floats, linear.
    ExrFloat,
}

impl OutputFormat {
    /// The name as written in plans.
    pub fn name(self) -> &'static str {
        match self {
            OutputFormat::ExrHalf => "exr-half",
            OutputFormat::ExrFloat => "exr-float",
        }
    }
}

/// How a frame is resampled onto the texture grid (the filters of `btfrig_calib::Filter`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResampleFilter {
    /// One bilinear lookup per texel centre.
    Bilinear,
    /// `n x n` lookups on a regular grid over each texel, averaged.
    Supersample {
        /// Sub-samples per texel axis, `1..=16`.
        n: usize,
    },
    /// Lookups over each texel's footprint, their number per axis from the local footprint
    /// length, at most `max`.
    Footprint {
        /// Upper bound of sub-samples per texel axis, `1..=16`.
        max: usize,
    },
    /// Elliptical weighted average over the texel's footprint.
    Ewa,
}

impl ResampleFilter {
    /// Sub-samples per axis of `"supersample"` when the plan gives no `n`.
    pub const DEFAULT_SUPERSAMPLE_N: usize = 4;
    /// Upper bound of `"footprint"` when the plan gives no `max`.
    pub const DEFAULT_FOOTPRINT_MAX: usize = 4;

    /// The filter's name as written in plans.
    pub fn name(self) -> &'static str {
        match self {
            ResampleFilter::Bilinear => "bilinear",
            ResampleFilter::Supersample { .. } => "supersample",
            ResampleFilter::Footprint { .. } => "footprint",
            ResampleFilter::Ewa => "ewa",
        }
    }
}

/// Where the pose each frame is rectified with comes from (`[registration] method`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegistrationMethod {
    /// Registered against the holder plate's markers in the frame.
    Markers,
    /// The nominal pose (kinematics of the commanded joints), no registration.
    Nominal,
}

/// What a failed registration does (`[registration] on_failure`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnRegistrationFailure {
    /// Rectify with the nominal pose; the step is recorded as a fallback and warned about.
    Nominal,
    /// Stop the run, naming the step and the reason (resumable).
    Fail,
}

/// Resolved `[registration]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegistrationPolicy {
    /// Where the pose comes from.
    pub method: RegistrationMethod,
    /// What a failed registration does.
    pub on_failure: OnRegistrationFailure,
}

impl Default for RegistrationPolicy {
    /// Markers, falling back to the nominal pose.
    fn default() -> Self {
        RegistrationPolicy { method: RegistrationMethod::Markers, on_failure: OnRegistrationFailure::Nominal }
    }
}

/// A square region of the sample plane, sample-frame metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Smallest x, metres.
    pub x_min_m: f64,
    /// Largest x, metres.
    pub x_max_m: f64,
    /// Smallest y, metres.
    pub y_min_m: f64,
    /// Largest y, metres.
    pub y_max_m: f64,
}

impl Region {
    /// Side length, metres.
    pub fn side_m(&self) -> f64 {
        self.x_max_m - self.x_min_m
    }

    /// Sample-frame (x, y) of the centre of texel (u, v) of a `size` x `size` texture over
    /// this region (u along +x, v along -y, as in `docs/conventions.md`).
    pub fn texel_centre(&self, u: usize, v: usize, size: usize) -> (f64, f64) {
        let s = size as f64;
        let x = self.x_min_m + (u as f64 + 0.5) * (self.x_max_m - self.x_min_m) / s;
        let y = self.y_max_m - (v as f64 + 0.5) * (self.y_max_m - self.y_min_m) / s;
        (x, y)
    }
}

/// Resolved texture settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureSettings {
    /// Texels per side.
    pub size: usize,
    /// The rectified region of the sample.
    pub region: Region,
    /// Resampling filter.
    pub filter: ResampleFilter,
}

/// Resolved exposure policy.
#[derive(Debug, Clone, PartialEq)]
pub enum ExposurePolicy {
    /// Per capture, so a white reference lands at this fraction of full scale; with HDR on,
    /// metered per capture and bracketed (`docs/hdr.md`).
    Auto {
        /// Target fraction of full scale.
        white_fraction: f64,
        /// Bracketing (`mode = "bracket"` resolves to `Auto` at the default white fraction
        /// with [`HdrMode::Always`]).
        hdr: HdrSettings,
    },
    /// The same exposure and gain for every capture.
    Fixed {
        /// Exposure time, seconds.
        exposure_s: f64,
        /// Analogue gain.
        gain: f64,
    },
}

/// How a capture's exposures are chosen (`[exposure]` of `mode = "auto"` / `"bracket"`).
#[derive(Debug, Clone, PartialEq)]
pub enum HdrMode {
    /// One exposure per capture (the default).
    Off,
    /// One metered exposure, more where the sample's range needs them.
    Adaptive,
    /// Always the metered base times each of these multipliers (the first is the base's).
    Always(Vec<f64>),
}

/// Resolved HDR settings.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrSettings {
    /// The mode.
    pub mode: HdrMode,
    /// Most exposures per capture (adaptive).
    pub max_exposures: u32,
    /// Ratio between neighbouring exposures of an adaptive bracket.
    pub stop_ratio: f64,
    /// Largest tolerated saturated fraction of the sample's photosites in every exposure.
    pub saturated_max_fraction: f64,
    /// Largest tolerated underexposed fraction in every exposure.
    pub dark_max_fraction: f64,
}

impl HdrSettings {
    /// HDR off, with the plan format's defaults for the other fields.
    pub fn off() -> HdrSettings {
        HdrSettings {
            mode: HdrMode::Off,
            max_exposures: 3,
            stop_ratio: 0.125,
            saturated_max_fraction: 1e-4,
            dark_max_fraction: 0.02,
        }
    }

    /// Whether a capture may take more than one exposure.
    pub fn is_on(&self) -> bool {
        self.mode != HdrMode::Off
    }
}

/// Resolved outputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// Keep raw frames.
    pub raw_frames: bool,
    /// Write rectified textures.
    pub textures: bool,
    /// Write previews.
    pub preview: bool,
    /// Write an 8-bit sRGB preview of every texture.
    pub texture_previews: bool,
    /// Texture file format.
    pub format: OutputFormat,
    /// The compressed model the run builds while it captures, if any.
    pub compressed_model: Option<CompressedModel>,
}

/// A compressed BTF model a run builds while it captures (`outputs.compressed_model`; the
/// models are `btfrig-compress`'s, docs/compression.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompressedModel {
    /// Full-matrix factorization.
    Fmf,
    /// Per-view factorization.
    Pvmf,
    /// Per-cluster factorization (local PCA).
    Pcmf,
    /// Per-cluster factorization with the cluster bases in one shared angular basis of
    /// [`CompressedModel::SHARED_BASIS_TERMS`] terms (`btfrig compress --method pcmf
    /// --shared-basis 32`): the compact form of PCMF 32 x 8.
    PcmfShared,
}

impl CompressedModel {
    /// Terms of the shared angular basis of [`CompressedModel::PcmfShared`]: the storage
    /// point where PCMF 32 x 8 beat the FMF of its size on every material measured
    /// (docs/benchmarks.md). A basis cannot have more terms than the run has captures.
    pub const SHARED_BASIS_TERMS: usize = 32;

    /// The name as written in a plan and on the command line (`btfrig compress --method`).
    pub fn name(self) -> &'static str {
        match self {
            CompressedModel::Fmf => "fmf",
            CompressedModel::Pvmf => "pvmf",
            CompressedModel::Pcmf => "pcmf",
            CompressedModel::PcmfShared => "pcmf-shared",
        }
    }

    /// The model called `name` (`"fmf"`, `"pvmf"`, `"pcmf"`, `"pcmf-shared"`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "fmf" => Some(CompressedModel::Fmf),
            "pvmf" => Some(CompressedModel::Pvmf),
            "pcmf" => Some(CompressedModel::Pcmf),
            "pcmf-shared" => Some(CompressedModel::PcmfShared),
            _ => None,
        }
    }
}

/// A requested pair the rig cannot realise, with the reason from [`Gonio::ik`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnreachablePair {
    /// Index into [`ValidatedPlan::light`].
    pub light: usize,
    /// Index into [`ValidatedPlan::view`].
    pub view: usize,
    /// Why.
    pub reason: Unreachable,
}

/// Why a requested pair is not captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SkipReason {
    /// The rig cannot reach it (`skip.unreachable = true`).
    Unreachable(UnreachableKind),
    /// Its reciprocal is captured earlier (`skip.reciprocal = true`).
    Reciprocal,
    /// Beyond `skip.max_captures`.
    MaxCaptures,
    /// Not in the `[sparse]` subset.
    Sparse,
}

impl SkipReason {
    /// A short stable label for reports, e.g. `unreachable:camera-blocks-lamp`.
    pub fn label(self) -> String {
        match self {
            SkipReason::Unreachable(k) => format!("unreachable:{}", k.label()),
            SkipReason::Reciprocal => "reciprocal".into(),
            SkipReason::MaxCaptures => "max-captures".into(),
            SkipReason::Sparse => "sparse".into(),
        }
    }
}

/// A plan with every reference resolved and every value checked.
#[derive(Debug, Clone)]
pub struct ValidatedPlan {
    /// The plan's name (may be empty; the caller may substitute the file name).
    pub name: String,
    /// [`Plan::content_hash`] of the plan.
    pub plan_hash: u64,
    /// The rig config, with the plan's seed override applied.
    pub rig: RigConfig,
    /// The rig config as named in the plan (`builtin:...` or a path).
    pub rig_source: String,
    /// The material of a simulated rig, if the plan names one.
    pub material: Option<MaterialRef>,
    /// Light directions (after filters), in plan order.
    pub light: Sampling,
    /// View directions (after filters), in plan order.
    pub view: Sampling,
    /// For each light, its index in the unfiltered source (e.g. the Bonn 81 numbering).
    pub light_source_indices: Vec<usize>,
    /// For each view, its index in the unfiltered source.
    pub view_source_indices: Vec<usize>,
    /// Every requested (light, view) pair, in plan order (unreachable ones included).
    pub pairs: Vec<(usize, usize)>,
    /// The requested pairs the rig cannot realise (only when `skip.unreachable = true`;
    /// otherwise they are validation errors).
    pub unreachable: Vec<UnreachablePair>,
    /// Texture settings.
    pub texture: TextureSettings,
    /// Exposure policy.
    pub exposure: ExposurePolicy,
    /// Outputs.
    pub outputs: Outputs,
    /// Skip settings as written.
    pub skip: SkipSpec,
    /// Run settings as written (`fault_scenario` without a `.toml` suffix).
    pub run: RunSpec,
    /// Registration policy.
    pub registration: RegistrationPolicy,
    /// The output directory holds a dataset of this same plan: the run resumes it.
    pub resume: bool,
    /// The `[sparse]` subset, validated (`None`: no sparse acquisition).
    pub sparse: Option<std::collections::BTreeSet<(usize, usize)>>,
}

/// Which requested pairs are captured and which are skipped, from [`ValidatedPlan::capture_list`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CaptureList {
    /// (light, view) pairs to capture, in plan order.
    pub captures: Vec<(usize, usize)>,
    /// Requested pairs left out, in plan order, with the reason.
    pub skipped: Vec<((usize, usize), SkipReason)>,
}

impl ValidatedPlan {
    /// The pairs to capture, in plan order, and the skipped ones with their reasons.
    /// Unreachable pairs go first, then pairs outside the `[sparse]` subset, then reciprocals
    /// of earlier captures, then everything beyond `max_captures`.
    pub fn capture_list(&self) -> CaptureList {
        let unreachable: std::collections::HashMap<(usize, usize), UnreachableKind> =
            self.unreachable.iter().map(|u| ((u.light, u.view), u.reason.kind())).collect();
        // The reciprocal of (l, v) is the pair (light with v's direction, view with l's
        // direction); each sampling holds a direction at most once, so it is one pair, and a
        // set of the captured pairs answers "captured earlier?" in constant time.
        let (view_as_light, light_as_view) = if self.skip.reciprocal {
            (same_directions(&self.view, &self.light), same_directions(&self.light, &self.view))
        } else {
            (Vec::new(), Vec::new())
        };
        let mut captured: std::collections::HashSet<(usize, usize)> = std::collections::HashSet::new();
        let mut captures = Vec::new();
        let mut skipped = Vec::new();
        for &p in &self.pairs {
            if let Some(k) = unreachable.get(&p) {
                skipped.push((p, SkipReason::Unreachable(*k)));
                continue;
            }
            if self.sparse.as_ref().is_some_and(|s| !s.contains(&p)) {
                skipped.push((p, SkipReason::Sparse));
                continue;
            }
            if self.skip.reciprocal {
                let same_dir = self.light.get(p.0).angle_to(self.view.get(p.1)) < RECIPROCAL_TOLERANCE_RAD;
                let reciprocal = view_as_light[p.1].zip(light_as_view[p.0]);
                if !same_dir && reciprocal.is_some_and(|r| captured.contains(&r)) {
                    skipped.push((p, SkipReason::Reciprocal));
                    continue;
                }
            }
            if self.skip.max_captures.is_some_and(|m| captures.len() >= m) {
                skipped.push((p, SkipReason::MaxCaptures));
                continue;
            }
            if self.skip.reciprocal {
                captured.insert(p);
            }
            captures.push(p);
        }
        CaptureList { captures, skipped }
    }
}

/// Angle below which two directions count as the same for `skip.reciprocal`, radians.
const RECIPROCAL_TOLERANCE_RAD: f64 = 1e-6;

/// For each direction of `from`, the index of the same direction in `to` (within
/// [`RECIPROCAL_TOLERANCE_RAD`]), if any. Sorted by the polar angle's cosine, so each
/// direction is compared only with those of nearly the same height: O(n log n) for the
/// samplings of real plans.
fn same_directions(from: &Sampling, to: &Sampling) -> Vec<Option<usize>> {
    let mut by_z: Vec<(f64, usize)> = to.directions().iter().enumerate().map(|(i, d)| (d.theta.cos(), i)).collect();
    by_z.sort_by(|a, b| a.0.total_cmp(&b.0));
    from.directions()
        .iter()
        .map(|d| {
            let z = d.theta.cos();
            // |cos a - cos b| <= |a - b|: a direction within the tolerance lies in this window.
            let lo = by_z.partition_point(|e| e.0 < z - 2.0 * RECIPROCAL_TOLERANCE_RAD);
            by_z[lo..]
                .iter()
                .take_while(|e| e.0 <= z + 2.0 * RECIPROCAL_TOLERANCE_RAD)
                .filter(|e| d.angle_to(to.get(e.1)) < RECIPROCAL_TOLERANCE_RAD)
                .map(|e| e.1)
                .min()
        })
        .collect()
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

/// What is allowed instead of a shared basis that does not fit (`{k}` = its terms).
pub const SHARED_BASIS_ALLOWED: &str = "\"pcmf\" or \"fmf\", or a plan of at least {k} captures and {k} texels";

impl ValidatedPlan {
    /// Why this plan cannot build [`CompressedModel::PcmfShared`], if it cannot: a shared
    /// basis of K terms needs at least K captures and K texels.
    pub fn shared_basis_problem(&self) -> Option<String> {
        let k = CompressedModel::SHARED_BASIS_TERMS;
        let captures = self.capture_list().captures.len();
        let texels = self.texture.size * self.texture.size;
        if captures < k {
            Some(format!("its shared basis has {k} terms and the plan captures {captures} pairs"))
        } else if texels < k {
            Some(format!("its shared basis has {k} terms and a texture has {texels} texels"))
        } else {
            None
        }
    }
}

/// Checks the `[sparse]` subset: not empty, every pair in range, once, among the requested
/// pairs and reachable.
fn resolve_sparse(
    sp: &super::SparseSpec,
    n_light: usize,
    n_view: usize,
    pairs: &[(usize, usize)],
    unreachable: &[UnreachablePair],
    errors: &mut Vec<PlanError>,
) -> Option<std::collections::BTreeSet<(usize, usize)>> {
    if sp.pairs.is_empty() {
        errors.push(PlanError::invalid("sparse.pairs", "[]", "no pairs", "at least one [light, view] pair"));
        return None;
    }
    let requested: std::collections::HashSet<(usize, usize)> = pairs.iter().copied().collect();
    let blocked: std::collections::HashMap<(usize, usize), &Unreachable> =
        unreachable.iter().map(|u| ((u.light, u.view), &u.reason)).collect();
    let mut first_at: std::collections::HashMap<(usize, usize), usize> = std::collections::HashMap::new();
    let before = errors.len();
    for (i, &[l, v]) in sp.pairs.iter().enumerate() {
        let field = format!("sparse.pairs[{i}]");
        if l >= n_light || v >= n_view {
            errors.push(PlanError::out_of_range(
                field,
                format!("[{l}, {v}]"),
                format!("light 0..={}, view 0..={} (indices into the filtered samplings)", n_light - 1, n_view - 1),
            ));
            continue;
        }
        if let Some(&j) = first_at.get(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                format!("repeats sparse.pairs[{j}]"),
                "each pair once",
            ));
            continue;
        }
        first_at.insert((l, v), i);
        if !requested.contains(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                "is not among the requested pairs (sampling.pairs)",
                "a subset of the requested pairs",
            ));
        } else if let Some(r) = blocked.get(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                format!("the rig cannot reach it ({r})"),
                "pairs the rig can reach",
            ));
        }
    }
    (errors.len() == before).then(|| first_at.into_keys().collect())
}

fn resolve_rig(plan: &Plan, ctx: &PlanContext, errors: &mut Vec<PlanError>) -> Option<RigConfig> {
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

fn is_simulated(rig: &RigConfig) -> bool {
    // An emulated camera (PTP firmware in front of the simulator's) renders the material too.
    rig.devices.camera.simulated().is_some()
}

fn resolve_material(
    plan: &Plan,
    ctx: &PlanContext,
    rig: Option<&RigConfig>,
    errors: &mut Vec<PlanError>,
) -> Option<MaterialRef> {
    let m = plan.rig.material.as_deref()?;
    if rig.is_some_and(|r| !is_simulated(r)) {
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

/// One candidate direction with the field path it came from (for duplicate messages).
struct Candidate {
    dir: Direction,
    source_index: usize,
    field: String,
    written: String,
}

/// The directions a sampling keeps after its filters, before the [`Sampling`] (and its
/// triangulation) is built.
struct KeptDirections {
    name: String,
    dirs: Vec<Direction>,
    indices: Vec<usize>,
}

impl KeptDirections {
    fn build(self, prefix: &str, errors: &mut Vec<PlanError>) -> Option<(Sampling, Vec<usize>)> {
        match Sampling::from_list(&self.name, self.dirs) {
            Ok(s) => Some((s, self.indices)),
            Err(e) => {
                // Unreachable after the checks of `resolve_sampling`; reported rather than panicking.
                errors.push(PlanError::invalid(prefix, &self.name, e.to_string(), "a valid sampling"));
                None
            }
        }
    }
}

fn resolve_sampling(spec: &SamplingSpec, prefix: &str, errors: &mut Vec<PlanError>) -> Option<KeptDirections> {
    let table = match spec {
        SamplingSpec::Preset(p) => SamplingTable { preset: Some(p.clone()), ..Default::default() },
        SamplingSpec::Table(t) => t.clone(),
    };
    let n_before = errors.len();
    let sources = [table.preset.is_some(), table.list.is_some(), table.rings.is_some()];
    let n_sources = sources.iter().filter(|s| **s).count();
    let mut candidates: Vec<Candidate> = Vec::new();
    let mut base_name = String::new();
    if n_sources != 1 {
        errors.push(PlanError::invalid(
            prefix,
            format!("{n_sources} sources"),
            "give exactly one source of directions",
            format!("one of preset ({PRESETS}), list = [[theta, phi], ...], rings = [{{ theta_deg, count, phi_offset_deg }}, ...]"),
        ));
    } else if let Some(p) = &table.preset {
        let sampling = match p.as_str() {
            "bonn81" => Some(Sampling::from_rings("bonn81", &BONN81_RINGS)),
            "dome1-151" | "bonn-dome1-151" => Some(Sampling::from_rings("dome1-151", &BONN_DOME1_RINGS)),
            _ => None,
        };
        let field =
            if matches!(spec, SamplingSpec::Preset(_)) { prefix.to_string() } else { format!("{prefix}.preset") };
        match sampling {
            Some(s) => {
                let s = s.expect("presets are valid");
                base_name = s.name().to_string();
                candidates = s
                    .directions()
                    .iter()
                    .enumerate()
                    .map(|(i, d)| Candidate { dir: *d, source_index: i, field: field.clone(), written: String::new() })
                    .collect();
            }
            None => errors.push(PlanError::unknown(field, p, PRESETS)),
        }
    } else if too_many_directions(&table, prefix, errors).is_some() {
        // Counted before expanding (reported): nothing of the refused size is built.
    } else if let Some(list) = &table.list {
        base_name = "list".into();
        if list.is_empty() {
            errors.push(PlanError::invalid(
                format!("{prefix}.list"),
                "[]",
                "no directions",
                "at least one [theta, phi]",
            ));
        }
        for (i, [t, p]) in list.iter().copied().enumerate() {
            let field = format!("{prefix}.list[{i}]");
            let ok_t = check_theta(t, &format!("{field}.theta"), errors);
            let ok_p = check_phi(p, &format!("{field}.phi"), errors);
            if ok_t && ok_p {
                candidates.push(Candidate {
                    dir: Direction::from_degrees(t, p),
                    source_index: i,
                    field,
                    written: format!("[{t}, {p}]"),
                });
            }
        }
    } else if let Some(rings) = &table.rings {
        base_name = "rings".into();
        if rings.is_empty() {
            errors.push(PlanError::invalid(format!("{prefix}.rings"), "[]", "no rings", "at least one ring"));
        }
        let mut k = 0;
        for (r, ring) in rings.iter().enumerate() {
            let field = format!("{prefix}.rings[{r}]");
            let ok_t = check_theta(ring.theta_deg, &format!("{field}.theta_deg"), errors);
            let ok_c = (1..=360).contains(&ring.count);
            if !ok_c {
                errors.push(PlanError::out_of_range(
                    format!("{field}.count"),
                    ring.count,
                    "1..=360 (1 for theta_deg = 0)",
                ));
            }
            let ok_p = ring.phi_offset_deg.is_finite() && ring.phi_offset_deg.abs() <= 360.0;
            if !ok_p {
                errors.push(PlanError::out_of_range(
                    format!("{field}.phi_offset_deg"),
                    ring.phi_offset_deg,
                    "-360..=360 (degrees)",
                ));
            }
            if ok_t && ok_c && ok_p {
                for j in 0..ring.count {
                    let phi = ring.phi_offset_deg + j as f64 * 360.0 / ring.count as f64;
                    candidates.push(Candidate {
                        dir: Direction::from_degrees(ring.theta_deg, phi),
                        source_index: k,
                        field: field.clone(),
                        written: format!("direction {j} ({}, {phi})", ring.theta_deg),
                    });
                    k += 1;
                }
            }
        }
    }
    if errors.len() == n_before {
        check_duplicates(&candidates, errors);
    }

    // Filters.
    let mut name = base_name;
    let mut theta_range = [0.0f64, 90.0];
    for (i, (key, v)) in
        [("theta_min_deg", table.theta_min_deg), ("theta_max_deg", table.theta_max_deg)].into_iter().enumerate()
    {
        if let Some(v) = v {
            if v.is_finite() && (0.0..=90.0).contains(&v) {
                theta_range[i] = v;
                name.push_str(&format!("[{key}={v}]"));
            } else {
                errors.push(PlanError::out_of_range(format!("{prefix}.{key}"), v, "0..=90 (degrees)"));
            }
        }
    }
    if let (Some(lo), Some(hi)) = (table.theta_min_deg, table.theta_max_deg) {
        if lo > hi {
            errors.push(PlanError::invalid(
                format!("{prefix}.theta_max_deg"),
                hi,
                format!("smaller than theta_min_deg = {lo}"),
                "theta_max_deg >= theta_min_deg",
            ));
        }
    }
    let every = table.every.unwrap_or(1);
    if !(1..=1000).contains(&every) {
        errors.push(PlanError::out_of_range(format!("{prefix}.every"), every, "1..=1000"));
    } else if every > 1 {
        name.push_str(&format!("[every={every}]"));
    }
    if errors.len() != n_before || candidates.is_empty() {
        return None;
    }
    // A small tolerance so that `theta_max_deg = 30` keeps a ring written as 30 degrees.
    let tol = 1e-9;
    let kept: Vec<&Candidate> = candidates
        .iter()
        .filter(|c| {
            let t = c.dir.theta.to_degrees();
            t >= theta_range[0] - tol && t <= theta_range[1] + tol
        })
        .collect::<Vec<_>>()
        .into_iter()
        .step_by(every)
        .collect();
    if kept.is_empty() {
        errors.push(PlanError::invalid(
            prefix,
            format!("{} directions", candidates.len()),
            format!("the filters (theta {}..={} deg, every {every}) keep none", theta_range[0], theta_range[1]),
            "filters that keep at least one direction",
        ));
        return None;
    }
    let dirs: Vec<Direction> = kept.iter().map(|c| c.dir).collect();
    let indices: Vec<usize> = kept.iter().map(|c| c.source_index).collect();
    Some(KeptDirections { name, dirs, indices })
}

/// The number of directions a `list` or `rings` source would give, when it exceeds
/// [`MAX_DIRECTIONS`] (reported); counted from the table without expanding it.
fn too_many_directions(table: &SamplingTable, prefix: &str, errors: &mut Vec<PlanError>) -> Option<usize> {
    let (field, n) = if let Some(list) = &table.list {
        (format!("{prefix}.list"), list.len())
    } else if let Some(rings) = &table.rings {
        // Rings with a count out of range are reported by the ring check, not counted here.
        (format!("{prefix}.rings"), rings.iter().map(|r| if r.count <= 360 { r.count } else { 0 }).sum())
    } else {
        return None;
    };
    (n > MAX_DIRECTIONS).then(|| {
        errors.push(PlanError::TooLarge {
            field,
            value: format!("{n} directions"),
            limit: format!("{MAX_DIRECTIONS} directions per sampling (a fixed limit)"),
            remedy: "use fewer or sparser rings, or a shorter list".into(),
        });
        n
    })
}

fn check_theta(t: f64, field: &str, errors: &mut Vec<PlanError>) -> bool {
    let ok = t.is_finite() && (0.0..90.0).contains(&t);
    if !ok {
        errors.push(PlanError::out_of_range(field, t, "0 <= theta < 90 (degrees from the sample normal)"));
    }
    ok
}

fn check_phi(p: f64, field: &str, errors: &mut Vec<PlanError>) -> bool {
    let ok = p.is_finite() && (-360.0..=360.0).contains(&p);
    if !ok {
        errors.push(PlanError::out_of_range(field, p, "-360 <= phi <= 360 (degrees from the sample x axis)"));
    }
    ok
}

fn check_duplicates(candidates: &[Candidate], errors: &mut Vec<PlanError>) {
    let units: Vec<_> = candidates.iter().map(|c| c.dir.to_vector()).collect();
    // For each direction the first earlier one it repeats. Two directions closer than the
    // tolerance differ in z by less than it, so only neighbours in z order are compared:
    // O(n log n) but for many directions of one height (at most a ring's 360, or a list's).
    let mut by_z: Vec<usize> = (0..units.len()).collect();
    by_z.sort_by(|&a, &b| units[a].z.total_cmp(&units[b].z));
    let mut first: Vec<Option<usize>> = vec![None; units.len()];
    for (k, &a) in by_z.iter().enumerate() {
        for &b in by_z[k + 1..].iter().take_while(|&&b| units[b].z - units[a].z <= DUPLICATE_TOLERANCE_RAD) {
            if angle_between(&units[a], &units[b]) < DUPLICATE_TOLERANCE_RAD {
                let (i, j) = (a.min(b), a.max(b));
                first[j] = Some(first[j].map_or(i, |f| f.min(i)));
            }
        }
    }
    for (j, i) in first.iter().enumerate() {
        if let Some(i) = *i {
            let (a, b) = (&candidates[i], &candidates[j]);
            let first = if a.field == b.field { a.written.clone() } else { format!("{} = {}", a.field, a.written) };
            errors.push(PlanError::invalid(
                &b.field,
                &b.written,
                format!("the same direction as {first}"),
                "distinct directions (at theta = 0 every phi is the same direction)",
            ));
        }
    }
}

/// The requested pairs; more than `max_pairs` (`[limits] max_captures`) are refused from
/// their count, before the list is built.
fn resolve_pairs(
    spec: &PairsSpec,
    nl: usize,
    nv: usize,
    max_pairs: usize,
    errors: &mut Vec<PlanError>,
) -> Option<Vec<(usize, usize)>> {
    let allowed_modes = "\"all\", or a list of [light_index, view_index]";
    let count = match spec {
        PairsSpec::List(list) => list.len(),
        PairsSpec::Mode(_) => nl.saturating_mul(nv),
    };
    if count > max_pairs {
        let value = match spec {
            PairsSpec::List(_) => format!("{count} pairs"),
            PairsSpec::Mode(m) => format!("{m:?}: {count} pairs ({nl} light x {nv} view directions)"),
        };
        errors.push(PlanError::TooLarge {
            field: "sampling.pairs".into(),
            value,
            limit: format!("{max_pairs} requested pairs per plan (limits.max_captures)"),
            remedy: limits::raise_captures(),
        });
        return None;
    }
    match spec {
        PairsSpec::Mode(m) if m == "all" => Some((0..nl).flat_map(|l| (0..nv).map(move |v| (l, v))).collect()),
        PairsSpec::Mode(m) => {
            errors.push(PlanError::unknown("sampling.pairs", m, allowed_modes));
            None
        }
        PairsSpec::List(list) => {
            let n_before = errors.len();
            if list.is_empty() {
                errors.push(PlanError::invalid("sampling.pairs", "[]", "no pairs", allowed_modes));
            }
            let mut seen = std::collections::HashMap::new();
            let mut out = Vec::with_capacity(list.len());
            for (k, [l, v]) in list.iter().copied().enumerate() {
                let field = format!("sampling.pairs[{k}]");
                let ok = l >= 0 && (l as u64) < nl as u64 && v >= 0 && (v as u64) < nv as u64;
                if !ok {
                    errors.push(PlanError::out_of_range(
                        field,
                        format!("[{l}, {v}]"),
                        format!(
                            "light index 0..={}, view index 0..={} (indices into the filtered samplings)",
                            nl - 1,
                            nv - 1
                        ),
                    ));
                    continue;
                }
                let p = (l as usize, v as usize);
                if let Some(first) = seen.insert(p, k) {
                    errors.push(PlanError::invalid(
                        field,
                        format!("[{l}, {v}]"),
                        format!("the same pair as sampling.pairs[{first}]"),
                        "each pair once",
                    ));
                }
                out.push(p);
            }
            (errors.len() == n_before).then_some(out)
        }
    }
}

fn resolve_texture(plan: &Plan, rig: Option<&RigConfig>, errors: &mut Vec<PlanError>) -> Option<TextureSettings> {
    let t = &plan.texture;
    let n_before = errors.len();
    if !(8..=4096).contains(&t.size) {
        errors.push(PlanError::out_of_range(
            "texture.size",
            t.size,
            "8..=4096 texels per side (typical 256, 512, 800)",
        ));
    }
    let filter = resolve_filter(&t.filter, errors);
    let side = rig.map(|r| r.plate.sample_side_m);
    let region = match (&t.region, side) {
        (None, Some(a)) => Some(Region { x_min_m: -a / 2.0, x_max_m: a / 2.0, y_min_m: -a / 2.0, y_max_m: a / 2.0 }),
        (None, None) => None,
        (Some(r), side) => resolve_region(r, side, errors),
    };
    // Without a rig (already reported) the region cannot be put in metres.
    match (region, filter) {
        (Some(region), Some(filter)) if errors.len() == n_before => {
            Some(TextureSettings { size: t.size as usize, region, filter })
        }
        _ => None,
    }
}

const FILTER_NAMES: &str = "\"bilinear\", \"supersample\", \"footprint\", \"ewa\"";

fn resolve_filter(f: &FilterSpec, errors: &mut Vec<PlanError>) -> Option<ResampleFilter> {
    let (name, field, n, max) = match f {
        FilterSpec::Name(name) => (name.as_str(), "texture.filter", None, None),
        FilterSpec::Table(t) => (t.name.as_str(), "texture.filter.name", t.n, t.max),
    };
    let n_before = errors.len();
    let param = |key: &str, v: Option<u32>, default: usize, errors: &mut Vec<PlanError>| match v {
        None => default,
        Some(v) if (1..=16).contains(&v) => v as usize,
        Some(v) => {
            errors.push(PlanError::out_of_range(
                format!("texture.filter.{key}"),
                v,
                "1..=16 sub-samples per texel axis",
            ));
            default
        }
    };
    let only = |key: &str, v: Option<u32>, errors: &mut Vec<PlanError>| {
        if let Some(v) = v {
            let allowed = match key {
                "n" => "n only with name = \"supersample\"",
                _ => "max only with name = \"footprint\"",
            };
            errors.push(PlanError::invalid(
                format!("texture.filter.{key}"),
                v,
                format!("filter {name:?} has no parameter {key}"),
                allowed,
            ));
        }
    };
    let filter = match name {
        "bilinear" | "ewa" => {
            only("n", n, errors);
            only("max", max, errors);
            if name == "ewa" {
                ResampleFilter::Ewa
            } else {
                ResampleFilter::Bilinear
            }
        }
        "supersample" => {
            only("max", max, errors);
            ResampleFilter::Supersample { n: param("n", n, ResampleFilter::DEFAULT_SUPERSAMPLE_N, errors) }
        }
        "footprint" => {
            only("n", n, errors);
            ResampleFilter::Footprint { max: param("max", max, ResampleFilter::DEFAULT_FOOTPRINT_MAX, errors) }
        }
        other => {
            errors.push(PlanError::unknown(field, other, FILTER_NAMES));
            return None;
        }
    };
    (errors.len() == n_before).then_some(filter)
}

fn resolve_registration(r: &RegistrationSpec, errors: &mut Vec<PlanError>) -> Option<RegistrationPolicy> {
    let method = match r.method.as_str() {
        "markers" => Some(RegistrationMethod::Markers),
        "nominal" => Some(RegistrationMethod::Nominal),
        other => {
            errors.push(PlanError::unknown("registration.method", other, "\"markers\", \"nominal\""));
            None
        }
    };
    let on_failure = match r.on_failure.as_str() {
        "nominal" => Some(OnRegistrationFailure::Nominal),
        "fail" => Some(OnRegistrationFailure::Fail),
        other => {
            errors.push(PlanError::unknown("registration.on_failure", other, "\"nominal\", \"fail\""));
            None
        }
    };
    Some(RegistrationPolicy { method: method?, on_failure: on_failure? })
}

fn resolve_region(r: &RegionSpec, side: Option<f64>, errors: &mut Vec<PlanError>) -> Option<Region> {
    let allowed_form =
        "either x_m = [lo, hi] and y_m = [lo, hi] (metres), or u = [lo, hi] and v = [lo, hi] (fractions)";
    let metric = (r.x_m, r.y_m);
    let fraction = (r.u, r.v);
    let n_before = errors.len();
    let check = |field: &str, range: [f64; 2], lo: f64, hi: f64, unit: &str, errors: &mut Vec<PlanError>| {
        let ok = range.iter().all(|x| x.is_finite() && *x >= lo - 1e-12 && *x <= hi + 1e-12) && range[0] < range[1];
        if !ok {
            errors.push(PlanError::out_of_range(
                field,
                format!("[{}, {}]", range[0], range[1]),
                format!("[lo, hi] with {lo} <= lo < hi <= {hi} ({unit})"),
            ));
        }
    };
    let region = match (metric, fraction) {
        ((Some(x), Some(y)), (None, None)) => {
            let h = side.map_or(f64::INFINITY, |a| a / 2.0);
            let unit = if side.is_some() { "metres, within the sample square" } else { "metres" };
            check("texture.region.x_m", x, -h, h, unit, errors);
            check("texture.region.y_m", y, -h, h, unit, errors);
            Region { x_min_m: x[0], x_max_m: x[1], y_min_m: y[0], y_max_m: y[1] }
        }
        ((None, None), (Some(u), Some(v))) => {
            check("texture.region.u", u, 0.0, 1.0, "fractions of the sample side", errors);
            check("texture.region.v", v, 0.0, 1.0, "fractions of the sample side", errors);
            let a = side.unwrap_or(1.0);
            // u runs along +x from the left edge, v along -y from the top edge.
            Region {
                x_min_m: -a / 2.0 + u[0] * a,
                x_max_m: -a / 2.0 + u[1] * a,
                y_min_m: a / 2.0 - v[1] * a,
                y_max_m: a / 2.0 - v[0] * a,
            }
        }
        _ => {
            let given: Vec<&str> =
                [("x_m", r.x_m.is_some()), ("y_m", r.y_m.is_some()), ("u", r.u.is_some()), ("v", r.v.is_some())]
                    .iter()
                    .filter(|(_, g)| *g)
                    .map(|(n, _)| *n)
                    .collect();
            errors.push(PlanError::invalid(
                "texture.region",
                format!("{{ {} }}", given.join(", ")),
                "incomplete or mixed region",
                allowed_form,
            ));
            return None;
        }
    };
    if errors.len() != n_before {
        return None;
    }
    let (w, h) = (region.x_max_m - region.x_min_m, region.y_max_m - region.y_min_m);
    if (w - h).abs() > 1e-6 * w.max(h) {
        errors.push(PlanError::invalid(
            "texture.region",
            format!("{w} x {h} m"),
            "the region is not square (textures are square)",
            "equal extents along x and y",
        ));
        return None;
    }
    side.map(|_| region)
}

/// Reads a `[lo, hi]` float pair from a device's options, if present and well formed.
fn option_range(rig: &RigConfig, key: &str) -> Option<[f64; 2]> {
    let arr = rig.devices.camera.options.get(key)?.as_array()?;
    let v: Vec<f64> = arr.iter().filter_map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64))).collect();
    (v.len() == 2).then(|| [v[0], v[1]])
}

fn resolve_exposure(e: &ExposureSpec, rig: Option<&RigConfig>, errors: &mut Vec<PlanError>) -> Option<ExposurePolicy> {
    match e {
        ExposureSpec::Auto {
            white_fraction,
            hdr,
            max_exposures,
            stop_ratio,
            saturated_max_fraction,
            dark_max_fraction,
        } => {
            let white_fraction = *white_fraction;
            let n_before = errors.len();
            if !(white_fraction.is_finite() && (0.05..=0.95).contains(&white_fraction)) {
                errors.push(PlanError::out_of_range(
                    "exposure.white_fraction",
                    white_fraction,
                    "0.05..=0.95 (fraction of full scale)",
                ));
            }
            let hdr =
                resolve_hdr(hdr, *max_exposures, *stop_ratio, *saturated_max_fraction, *dark_max_fraction, errors);
            (errors.len() == n_before).then(|| ExposurePolicy::Auto { white_fraction, hdr: hdr.expect("checked") })
        }
        &ExposureSpec::Fixed { exposure_s, gain } => {
            let t_range = rig.and_then(|r| option_range(r, "exposure_range_s")).unwrap_or([1e-6, 3600.0]);
            let max_gain = rig.map_or(64.0, |r| r.sensor.max_analogue_gain);
            let g_range = rig
                .and_then(|r| option_range(r, "gain_range"))
                .map_or([1.0, max_gain], |[lo, hi]| [lo.max(1.0), hi.min(max_gain)]);
            let mut ok = true;
            if !(exposure_s.is_finite() && exposure_s >= t_range[0] && exposure_s <= t_range[1]) {
                errors.push(PlanError::out_of_range(
                    "exposure.exposure_s",
                    exposure_s,
                    format!("{} ..= {} seconds (the camera's exposure range)", t_range[0], t_range[1]),
                ));
                ok = false;
            }
            if !(gain.is_finite() && gain >= g_range[0] && gain <= g_range[1]) {
                errors.push(PlanError::out_of_range(
                    "exposure.gain",
                    gain,
                    format!("{} ..= {} (the camera's analogue gain range)", g_range[0], g_range[1]),
                ));
                ok = false;
            }
            ok.then_some(ExposurePolicy::Fixed { exposure_s, gain })
        }
        ExposureSpec::Bracket { stops } => {
            let n_before = errors.len();
            match stops.as_deref() {
                None | Some([]) => errors.push(PlanError::invalid(
                    "exposure.stops",
                    "[]",
                    "mode \"bracket\" needs the exposure multipliers",
                    "1 to 8 of them, e.g. stops = [1.0, 0.125]",
                )),
                Some(v) if v.len() > 8 => {
                    errors.push(PlanError::out_of_range("exposure.stops", format!("{} entries", v.len()), "1 ..= 8"))
                }
                Some(v) => {
                    for (i, x) in v.iter().enumerate() {
                        if !(x.is_finite() && (1.0 / 1024.0..=64.0).contains(x)) {
                            errors.push(PlanError::out_of_range(format!("exposure.stops[{i}]"), x, "1/1024 ..= 64"));
                        }
                    }
                }
            }
            (errors.len() == n_before).then(|| ExposurePolicy::Auto {
                white_fraction: 0.6,
                hdr: HdrSettings {
                    mode: HdrMode::Always(stops.clone().unwrap_or_default()),
                    max_exposures: stops.as_ref().map_or(1, |v| v.len() as u32),
                    ..HdrSettings::off()
                },
            })
        }
    }
}

/// Checks the HDR fields of `mode = "auto"`; `None` after an error.
fn resolve_hdr(
    hdr: &str,
    max_exposures: u32,
    stop_ratio: f64,
    saturated_max_fraction: f64,
    dark_max_fraction: f64,
    errors: &mut Vec<PlanError>,
) -> Option<HdrSettings> {
    let n_before = errors.len();
    if !(1..=8).contains(&max_exposures) {
        errors.push(PlanError::out_of_range("exposure.max_exposures", max_exposures, "1 ..= 8"));
    }
    if !(stop_ratio.is_finite() && (1.0 / 64.0..=0.5).contains(&stop_ratio)) {
        errors.push(PlanError::out_of_range("exposure.stop_ratio", stop_ratio, "1/64 ..= 1/2"));
    }
    if !(saturated_max_fraction.is_finite() && (0.0..=0.5).contains(&saturated_max_fraction)) {
        errors.push(PlanError::out_of_range("exposure.saturated_max_fraction", saturated_max_fraction, "0 ..= 0.5"));
    }
    if !(dark_max_fraction.is_finite() && (0.0..=1.0).contains(&dark_max_fraction)) {
        errors.push(PlanError::out_of_range("exposure.dark_max_fraction", dark_max_fraction, "0 ..= 1"));
    }
    let mode = match hdr {
        "off" => HdrMode::Off,
        "adaptive" => HdrMode::Adaptive,
        other => {
            errors.push(PlanError::unknown("exposure.hdr", other, "\"off\", \"adaptive\""));
            HdrMode::Off
        }
    };
    (errors.len() == n_before).then_some(HdrSettings {
        mode,
        max_exposures,
        stop_ratio,
        saturated_max_fraction,
        dark_max_fraction,
    })
}

fn resolve_outputs(o: &OutputsSpec, errors: &mut Vec<PlanError>) -> Option<Outputs> {
    let n_before = errors.len();
    let format = match o.format.as_str() {
        "exr-half" => Some(OutputFormat::ExrHalf),
        "exr-float" => Some(OutputFormat::ExrFloat),
        other => {
            errors.push(PlanError::unknown("outputs.format", other, "\"exr-half\", \"exr-float\""));
            None
        }
    };
    let compressed_model = o.compressed_model.model().unwrap_or_else(|m| {
        errors.push(PlanError::unknown(
            "outputs.compressed_model",
            m,
            "\"fmf\", \"pvmf\", \"pcmf\", \"pcmf-shared\", \"none\", false, or true (= \"fmf\")",
        ));
        None
    });
    if compressed_model.is_some() && !o.textures {
        errors.push(PlanError::invalid(
            "outputs.compressed_model",
            o.compressed_model.display(),
            "the model is built from the textures, and textures = false writes none",
            "compressed_model = false, or textures = true",
        ));
    }
    if !o.textures && !o.raw_frames {
        errors.push(PlanError::invalid(
            "outputs.textures",
            false,
            "with raw_frames = false as well, the run would write nothing",
            "textures = true or raw_frames = true",
        ));
    }
    if o.texture_previews && !o.textures {
        errors.push(PlanError::invalid(
            "outputs.texture_previews",
            true,
            "with textures = false there is no texture to preview",
            "texture_previews = false, or textures = true",
        ));
    }
    (errors.len() == n_before).then(|| Outputs {
        raw_frames: o.raw_frames,
        textures: o.textures,
        preview: o.preview,
        texture_previews: o.texture_previews,
        format: format.expect("no errors"),
        compressed_model,
    })
}

fn resolve_run(r: &RunSpec, ctx: &PlanContext, rig: Option<&RigConfig>, errors: &mut Vec<PlanError>) -> RunSpec {
    let mut out = r.clone();
    if let Some(f) = &r.fault_scenario {
        let stem = f.strip_suffix(".toml").unwrap_or(f);
        if !ctx.known_faults.iter().any(|k| k == stem) {
            errors.push(PlanError::unknown(
                "run.fault_scenario",
                f,
                format!("{} (files in sim/faults/), or leave it out", ctx.known_faults.join(", ")),
            ));
        }
        if rig.is_some_and(|r| !is_simulated(r)) && stem != "none" {
            errors.push(PlanError::invalid(
                "run.fault_scenario",
                format!("{f:?}"),
                "fault injection only applies to a simulated rig",
                "no fault scenario for a real rig",
            ));
        }
        out.fault_scenario = Some(stem.to_string());
    }
    if r.max_retries > 100 {
        errors.push(PlanError::out_of_range("run.max_retries", r.max_retries, "0..=100"));
    }
    if !(r.backoff_s.is_finite() && (0.0..=600.0).contains(&r.backoff_s)) {
        errors.push(PlanError::out_of_range("run.backoff_s", r.backoff_s, "0 ..= 600 seconds"));
    }
    for (key, v) in [("move_timeout_s", r.move_timeout_s), ("capture_timeout_s", r.capture_timeout_s)] {
        if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
            errors.push(PlanError::out_of_range(format!("run.{key}"), v, "> 0 and <= 3600 seconds"));
        }
    }
    out
}
