//! The resolved plan ([`ValidatedPlan`]) and its parts, and what is derived from it
//! (the capture list, the shared basis check).

use crate::config::RigConfig;
use crate::kinematics::{Unreachable, UnreachableKind};
use crate::sampling::Sampling;

use crate::plan::{RunSpec, SkipSpec};

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

/// How a frame is resampled onto the texture grid (the filters of `btfrig_imaging::Filter`).
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
