//! Measurement plans: what to measure, as a TOML file (format: `docs/plan-format.md`).
//!
//! Brief overview: [`Plan::from_toml`] parses the text (schema errors carry line and
//! column); [`Plan::validate`] checks every value against a [`PlanContext`] (the loaded rig
//! config, the known material and fault-scenario names, what the output directory already
//! holds) and returns a [`ValidatedPlan`] with resolved samplings and the list of requested
//! (light, view) pairs, or [`PlanErrors`] with **every** problem at once. Nothing here reads
//! files: the caller reads the plan, the rig config it names ([`Plan::rig_config_path`]) and
//! the output directory, and passes what it found as data.
//!
//! ```
//! use btfrig_core::plan::{Plan, PlanContext};
//! let plan = Plan::from_toml(r#"
//!     [sampling]
//!     light = "bonn81"
//!     view = { preset = "bonn81", theta_max_deg = 30 }
//!     [texture]
//!     size = 64
//! "#, "<doc>").unwrap();
//! let ctx = PlanContext::with_builtin_names();
//! let v = plan.validate(&ctx).unwrap();
//! assert_eq!(v.light.len(), 81);
//! assert_eq!(v.view.len(), 19);
//! assert_eq!(v.pairs.len(), 81 * 19);
//! ```

pub mod dome;
mod error;
pub mod limits;
mod validate;

use std::fmt;
use std::path::{Path, PathBuf};

use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::{Deserialize, Serialize};

pub use error::{PlanError, PlanErrors};
pub use limits::{check_plan_size, LimitsSpec, MAX_PLAN_BYTES};

pub use validate::{
    CaptureList, CompressedModel, ExistingDataset, ExposurePolicy, HdrMode, HdrSettings, MaterialRef,
    OnRegistrationFailure, OutputFormat, Outputs, PlanContext, Region, RegistrationMethod, RegistrationPolicy,
    ResampleFilter, SkipReason, TextureSettings, UnreachablePair, ValidatedPlan, SHARED_BASIS_ALLOWED,
};

/// The rig config name that selects the embedded default simulated gonioreflectometer.
pub const BUILTIN_RIG: &str = "builtin:bonn-gonio-sim";

/// The embedded rig configs: (name as written in a plan, TOML text).
pub const BUILTIN_RIGS: &[(&str, &str)] = &[
    (BUILTIN_RIG, include_str!("../../../../rig-configs/bonn-gonio-sim.toml")),
    ("builtin:bonn-gonio-serial", include_str!("../../../../rig-configs/bonn-gonio-serial.toml")),
    ("builtin:bonn-gonio-genicam", include_str!("../../../../rig-configs/bonn-gonio-genicam.toml")),
    ("builtin:bonn-dome-sim", include_str!("../../../../rig-configs/bonn-dome-sim.toml")),
    ("builtin:bonn-dome-serial", include_str!("../../../../rig-configs/bonn-dome-serial.toml")),
    ("builtin:bonn-camera-array-sim", include_str!("../../../../rig-configs/bonn-camera-array-sim.toml")),
];

/// Names of the fault scenarios shipped in `sim/faults/` (file stems). The caller may pass
/// others in [`PlanContext::known_faults`] (e.g. after listing the directory).
pub const BUILTIN_FAULT_SCENARIOS: &[&str] =
    &["none", "flaky", "lamp-drift", "stuck-led", "robot-fault", "hidden-markers"];

/// Names of the materials embedded in the simulator (`sim/materials/`). Kept here as names
/// only because `core` must not depend on `render`; a test in `render` can cross-check.
pub const BUILTIN_MATERIAL_NAMES: &[&str] = &["lacquered-wood", "corduroy", "glazed-tile", "leather"];

/// A whole measurement plan, as written in the file (nothing resolved yet).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    /// Short name, shown in reports and the dataset manifest (default: empty, then the
    /// caller uses the file name).
    #[serde(default)]
    pub name: String,
    /// One line for people.
    #[serde(default)]
    pub description: String,
    /// Which rig, material and seed.
    #[serde(default)]
    pub rig: RigSpec,
    /// Light and view directions and which pairs of them to capture.
    pub sampling: SamplingPlan,
    /// The rectified textures: size, region, resampling filter.
    #[serde(default)]
    pub texture: TextureSpec,
    /// How exposure time and gain are chosen.
    #[serde(default)]
    pub exposure: ExposureSpec,
    /// Which outputs to write.
    #[serde(default)]
    pub outputs: OutputsSpec,
    /// What may be skipped.
    #[serde(default)]
    pub skip: SkipSpec,
    /// Faults, retries and timeouts of the run.
    #[serde(default)]
    pub run: RunSpec,
    /// How each frame's sample pose is found (marker registration or the nominal pose).
    #[serde(default, skip_serializing_if = "RegistrationSpec::is_default")]
    pub registration: RegistrationSpec,
    /// Sparse acquisition: capture only these pairs of the requested ones (written by
    /// `btfrig sparse select`); the others are skipped with reason `sparse`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sparse: Option<SparseSpec>,
    /// Raised limits of this plan (`[limits] max_captures`); a run policy, not part of
    /// [`Plan::content_hash`].
    #[serde(default, skip_serializing_if = "LimitsSpec::is_default")]
    pub limits: LimitsSpec,
}

/// The `[sparse]` table: the subset of the requested pairs a sparse acquisition captures
/// (chosen so that a linear basis stays well conditioned on it, `btfrig sparse select`).
/// Part of the content hash: it changes what is captured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SparseSpec {
    /// `[light_index, view_index]` pairs into the resolved (filtered) samplings, each once,
    /// each among the requested pairs and reachable by the rig.
    pub pairs: Vec<[usize; 2]>,
}

/// The `[registration]` table: where the pose each frame is rectified with comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegistrationSpec {
    /// `"markers"` (default): register every frame against the holder plate's markers;
    /// `"nominal"`: rectify with the kinematic pose of the commanded joints (no registration).
    #[serde(default = "RegistrationSpec::default_method")]
    pub method: String,
    /// When registration fails: `"nominal"` (default) rectifies with the kinematic pose and
    /// records the step as a fallback; `"fail"` stops the run naming the step and the reason.
    /// A run policy: not part of [`Plan::content_hash`].
    #[serde(default = "RegistrationSpec::default_on_failure")]
    pub on_failure: String,
}

impl RegistrationSpec {
    fn default_method() -> String {
        "markers".into()
    }
    fn default_on_failure() -> String {
        "nominal".into()
    }
    fn is_default(&self) -> bool {
        *self == RegistrationSpec::default()
    }
}

impl Default for RegistrationSpec {
    fn default() -> Self {
        RegistrationSpec { method: Self::default_method(), on_failure: Self::default_on_failure() }
    }
}

/// The `[rig]` table of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigSpec {
    /// A rig config file, relative to the plan file, or `"builtin:bonn-gonio-sim"` (default)
    /// for the embedded simulated gonioreflectometer.
    #[serde(default = "RigSpec::default_config")]
    pub config: String,
    /// Material of the sample on a simulated rig: an embedded name (`lacquered-wood`,
    /// `corduroy`, `glazed-tile`, `leather`) or a material TOML file relative to the plan
    /// (a value ending in `.toml` or containing `/`). Default: the caller's default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<String>,
    /// Overrides the rig config's `[rig] seed` (noise, jitter, faults of a simulated rig).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

impl RigSpec {
    fn default_config() -> String {
        BUILTIN_RIG.to_string()
    }
}

impl Default for RigSpec {
    fn default() -> Self {
        RigSpec { config: Self::default_config(), material: None, seed: None }
    }
}

/// The `[sampling]` table: light and view directions and the pairs to capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingPlan {
    /// Light directions.
    pub light: SamplingSpec,
    /// View directions.
    pub view: SamplingSpec,
    /// Which (light, view) pairs: `"all"` (default, the full cross product) or a list of
    /// `[light_index, view_index]` into the resolved (filtered) samplings.
    #[serde(default)]
    pub pairs: PairsSpec,
}

/// One sampling: either a preset name as a plain string (`light = "bonn81"`), or a table with
/// exactly one source (`preset`, `list` or `rings`) and optional filters.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum SamplingSpec {
    /// A preset name: `"bonn81"` or `"dome1-151"`.
    Preset(String),
    /// A table with a source and filters.
    Table(SamplingTable),
}

/// The table form of a [`SamplingSpec`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingTable {
    /// A preset name: `"bonn81"` or `"dome1-151"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// Explicit directions, `[theta, phi]` in degrees (theta in `[0, 90)`, phi in
    /// `[-360, 360]`, wrapped into `[0, 360)`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub list: Option<Vec<[f64; 2]>>,
    /// Rings: `count` directions at `theta_deg`, azimuths `phi_offset_deg + j * 360 / count`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings: Option<Vec<RingSpec>>,
    /// Keep only directions with theta >= this (degrees, `0..=90`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_min_deg: Option<f64>,
    /// Keep only directions with theta <= this (degrees, `0..=90`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_max_deg: Option<f64>,
    /// After the theta filter, keep every k-th direction (indices 0, k, 2k, ...; `1..=1000`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub every: Option<usize>,
}

/// One ring of a `rings` sampling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RingSpec {
    /// Polar angle of the ring, degrees (`[0, 90)`).
    pub theta_deg: f64,
    /// Number of directions on the ring (`1..=360`; 1 for theta = 0).
    pub count: usize,
    /// Azimuth of the first direction, degrees (default 0).
    #[serde(default)]
    pub phi_offset_deg: f64,
}

/// Which (light, view) pairs to capture.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PairsSpec {
    /// A named mode; only `"all"` (the full cross product) exists.
    Mode(String),
    /// Explicit `[light_index, view_index]` pairs, captured in this order.
    List(Vec<[i64; 2]>),
}

impl Default for PairsSpec {
    fn default() -> Self {
        PairsSpec::Mode("all".into())
    }
}

/// The `[texture]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureSpec {
    /// Texels per side of the square texture (`8..=4096`; typical 256, 512, 800; default 256).
    #[serde(default = "TextureSpec::default_size")]
    pub size: u32,
    /// Part of the sample to rectify (default: the whole sample square). Must be square.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<RegionSpec>,
    /// Resampling filter: a name (`"bilinear"`, `"supersample"`, `"footprint"` (default),
    /// `"ewa"`) or a table `{ name = "supersample", n = 4 }` / `{ name = "footprint", max = 4 }`.
    /// The default is the measured best trade (`docs/benchmarks.md`, registration section):
    /// area-correct where a texel covers several pixels, one lookup where it covers less.
    #[serde(default = "TextureSpec::default_filter")]
    pub filter: FilterSpec,
}

/// A resampling filter as written: a name, or a table with the name and its parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum FilterSpec {
    /// A filter name with its default parameter.
    Name(String),
    /// A table.
    Table(FilterTable),
}

/// The table form of a [`FilterSpec`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterTable {
    /// `"bilinear"`, `"supersample"`, `"footprint"` or `"ewa"`.
    pub name: String,
    /// Sub-samples per texel axis of `"supersample"` (`1..=16`, default 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n: Option<u32>,
    /// Upper bound of sub-samples per texel axis of `"footprint"` (`1..=16`, default 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<u32>,
}

impl TextureSpec {
    const fn default_size() -> u32 {
        256
    }
    fn default_filter() -> FilterSpec {
        FilterSpec::Name("footprint".into())
    }
}

impl Default for TextureSpec {
    fn default() -> Self {
        TextureSpec { size: Self::default_size(), region: None, filter: Self::default_filter() }
    }
}

/// A square region of the sample: either in metres in the sample frame (`x_m`, `y_m`, both
/// `[lo, hi]`, origin at the sample centre) or as fractions of the sample square in texture
/// axes (`u` along +x from the left edge, `v` along -y from the top edge, both in `[0, 1]`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// Sample-frame x range, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<[f64; 2]>,
    /// Sample-frame y range, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y_m: Option<[f64; 2]>,
    /// Fraction range along the texture's u axis (+x), `0` = left edge of the sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub u: Option<[f64; 2]>,
    /// Fraction range along the texture's v axis (-y), `0` = top edge (largest y).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v: Option<[f64; 2]>,
}

/// The `[exposure]` table, selected by `mode`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum ExposureSpec {
    /// Choose the exposure per capture so a white reference lands at `white_fraction` of
    /// full scale.
    Auto {
        /// Target level of a white reference, fraction of full scale (`0.05..=0.95`, default 0.6).
        #[serde(default = "ExposureSpec::default_white_fraction")]
        white_fraction: f64,
        /// HDR bracketing: `"off"` (default, one exposure per capture) or `"adaptive"` (more
        /// exposures where one cannot hold the sample's range; `docs/hdr.md`).
        #[serde(default = "ExposureSpec::default_hdr", skip_serializing_if = "ExposureSpec::is_default_hdr")]
        hdr: String,
        /// Most exposures per capture with `hdr = "adaptive"` (`1..=8`, default 3).
        #[serde(
            default = "ExposureSpec::default_max_exposures",
            skip_serializing_if = "ExposureSpec::is_default_max_exposures"
        )]
        max_exposures: u32,
        /// Ratio between neighbouring exposures of an adaptive bracket (`1/64 ..= 1/2`,
        /// default 1/8).
        #[serde(
            default = "ExposureSpec::default_stop_ratio",
            skip_serializing_if = "ExposureSpec::is_default_stop_ratio"
        )]
        stop_ratio: f64,
        /// Largest tolerated fraction of the sample's photosites saturated in every exposure
        /// (`0 ..= 0.5`, default 1e-4).
        #[serde(
            default = "ExposureSpec::default_saturated_max_fraction",
            skip_serializing_if = "ExposureSpec::is_default_saturated_max_fraction"
        )]
        saturated_max_fraction: f64,
        /// Largest tolerated fraction underexposed (below 1 % of full scale) in every
        /// exposure (`0 ..= 1`, default 0.02).
        #[serde(
            default = "ExposureSpec::default_dark_max_fraction",
            skip_serializing_if = "ExposureSpec::is_default_dark_max_fraction"
        )]
        dark_max_fraction: f64,
    },
    /// The same exposure for every capture.
    Fixed {
        /// Exposure time, seconds (> 0, within the camera's `exposure_range_s`).
        exposure_s: f64,
        /// Analogue gain (>= 1, within the camera's `gain_range`; default 1).
        #[serde(default = "ExposureSpec::default_gain")]
        gain: f64,
    },
    /// HDR bracketing, always: the metered base exposure times each multiplier (`docs/hdr.md`).
    Bracket {
        /// Exposure multipliers of the bracket relative to the metered base (1 to 8 of
        /// them, each in `1/1024 ..= 64`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stops: Option<Vec<f64>>,
    },
}

impl ExposureSpec {
    const fn default_white_fraction() -> f64 {
        0.6
    }
    const fn default_gain() -> f64 {
        1.0
    }
    // Defaults are left out of the serialisation, so [`Plan::content_hash`] of a plan without
    // HDR settings is what it was before they existed (datasets made then still resume).
    fn is_default_hdr(v: &String) -> bool {
        *v == Self::default_hdr()
    }
    fn is_default_max_exposures(v: &u32) -> bool {
        *v == Self::default_max_exposures()
    }
    fn is_default_stop_ratio(v: &f64) -> bool {
        *v == Self::default_stop_ratio()
    }
    fn is_default_saturated_max_fraction(v: &f64) -> bool {
        *v == Self::default_saturated_max_fraction()
    }
    fn is_default_dark_max_fraction(v: &f64) -> bool {
        *v == Self::default_dark_max_fraction()
    }
    fn default_hdr() -> String {
        "off".into()
    }
    const fn default_max_exposures() -> u32 {
        3
    }
    const fn default_stop_ratio() -> f64 {
        0.125
    }
    const fn default_saturated_max_fraction() -> f64 {
        1e-4
    }
    const fn default_dark_max_fraction() -> f64 {
        0.02
    }
}

impl Default for ExposureSpec {
    fn default() -> Self {
        ExposureSpec::Auto {
            white_fraction: Self::default_white_fraction(),
            hdr: Self::default_hdr(),
            max_exposures: Self::default_max_exposures(),
            stop_ratio: Self::default_stop_ratio(),
            saturated_max_fraction: Self::default_saturated_max_fraction(),
            dark_max_fraction: Self::default_dark_max_fraction(),
        }
    }
}

/// The `[outputs]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputsSpec {
    /// Keep the raw sensor frames (default false).
    #[serde(default)]
    pub raw_frames: bool,
    /// Write the rectified textures (default true).
    #[serde(default = "OutputsSpec::yes")]
    pub textures: bool,
    /// Write small preview images (default false).
    #[serde(default)]
    pub preview: bool,
    /// Write an 8-bit sRGB PNG preview of every texture under `previews/` (default false;
    /// needs `textures`).
    #[serde(default)]
    pub texture_previews: bool,
    /// A compressed BTF model the run builds while it captures (docs/compression.md):
    /// `false` (default) or `"none"`: no model; `"fmf"`, `"pvmf"`, `"pcmf"`, `"pcmf-shared"`
    /// (PCMF 32 x 8 in a shared basis of 32 terms): that model, written next to the dataset
    /// as `<DIR>.<method>.btfm`; `true`: the default model,
    /// `"fmf"`. A derived output, not part of [`Plan::content_hash`].
    #[serde(default)]
    pub compressed_model: CompressedModelSpec,
    /// Texture file format: `"exr-half"` (default) or `"exr-float"`.
    #[serde(default = "OutputsSpec::default_format")]
    pub format: String,
}

/// The value of `outputs.compressed_model` as written: a bool or a model name (resolved and
/// checked by validation into [`CompressedModel`](crate::plan::CompressedModel)).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum CompressedModelSpec {
    /// `false`: none; `true`: the default model (FMF).
    Flag(bool),
    /// `"none"`, `"fmf"`, `"pvmf"`, `"pcmf"` or `"pcmf-shared"`.
    Method(String),
}

impl<'de> Deserialize<'de> for CompressedModelSpec {
    // By hand rather than `untagged`, so a wrong type gets a message naming what is allowed.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = CompressedModelSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("false, true, or one of \"fmf\", \"pvmf\", \"pcmf\", \"pcmf-shared\", \"none\"")
            }
            fn visit_bool<E: serde::de::Error>(self, v: bool) -> Result<Self::Value, E> {
                Ok(CompressedModelSpec::Flag(v))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Self::Value, E> {
                Ok(CompressedModelSpec::Method(v.to_string()))
            }
        }
        d.deserialize_any(V)
    }
}

impl CompressedModelSpec {
    /// The model asked for: `Ok(None)` for none, `Err(name)` for a name that is no model
    /// (validation reports it, naming the allowed values).
    pub fn model(&self) -> Result<Option<validate::CompressedModel>, &str> {
        match self {
            CompressedModelSpec::Flag(false) => Ok(None),
            CompressedModelSpec::Flag(true) => Ok(Some(validate::CompressedModel::Fmf)),
            CompressedModelSpec::Method(m) if m == "none" => Ok(None),
            CompressedModelSpec::Method(m) => validate::CompressedModel::from_name(m).map(Some).ok_or(m.as_str()),
        }
    }

    /// The value as written in TOML, for messages.
    pub fn display(&self) -> String {
        match self {
            CompressedModelSpec::Flag(b) => b.to_string(),
            CompressedModelSpec::Method(m) => format!("{m:?}"),
        }
    }
}

impl Default for CompressedModelSpec {
    fn default() -> Self {
        CompressedModelSpec::Flag(false)
    }
}

impl OutputsSpec {
    const fn yes() -> bool {
        true
    }
    fn default_format() -> String {
        "exr-half".into()
    }
}

impl Default for OutputsSpec {
    fn default() -> Self {
        OutputsSpec {
            raw_frames: false,
            textures: true,
            preview: false,
            texture_previews: false,
            compressed_model: CompressedModelSpec::default(),
            format: Self::default_format(),
        }
    }
}

/// The `[skip]` table: what may be left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkipSpec {
    /// Skip (and report) pairs the rig cannot reach (default true); `false` makes any
    /// unreachable pair a validation error.
    #[serde(default = "SkipSpec::yes")]
    pub unreachable: bool,
    /// Skip a pair whose reciprocal (light and view swapped) is captured earlier in the
    /// plan (default false).
    #[serde(default)]
    pub reciprocal: bool,
    /// Capture at most this many pairs (the first ones in plan order; `>= 1`), for quick runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_captures: Option<usize>,
}

impl SkipSpec {
    const fn yes() -> bool {
        true
    }
}

impl Default for SkipSpec {
    fn default() -> Self {
        SkipSpec { unreachable: true, reciprocal: false, max_captures: None }
    }
}

/// The `[run]` table: how the run engine behaves. Not part of [`Plan::content_hash`]: a run
/// may be resumed with other retry or timeout settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    /// Fault scenario of a simulated rig: a file stem in `sim/faults/` (e.g. `"flaky"`), or
    /// absent for none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fault_scenario: Option<String>,
    /// How often a retryable failure of one step is retried (`0..=100`, default 3).
    #[serde(default = "RunSpec::default_max_retries")]
    pub max_retries: u32,
    /// Wait before the first retry, seconds, doubling each time (`0..=600`, default 1.0).
    #[serde(default = "RunSpec::default_backoff_s")]
    pub backoff_s: f64,
    /// Time limit of one device move, seconds (`(0, 3600]`, default 120).
    #[serde(default = "RunSpec::default_move_timeout_s")]
    pub move_timeout_s: f64,
    /// Time limit of one capture beyond its exposure time, seconds (`(0, 3600]`, default 60).
    #[serde(default = "RunSpec::default_capture_timeout_s")]
    pub capture_timeout_s: f64,
    /// The time the rig's devices run on (default `"rig"`: the wall clock when any device is
    /// real, the simulator's virtual time otherwise; `"wall"`: the wall clock, also for a
    /// simulated rig, whose devices then wait in real time).
    #[serde(default, skip_serializing_if = "RunClock::is_rig")]
    pub clock: RunClock,
}

/// `[run] clock`: the time a run's devices run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RunClock {
    /// As the rig needs: the wall clock when any device is real hardware, virtual time for a
    /// rig of simulated and emulated devices only.
    #[default]
    Rig,
    /// The wall clock, whatever the rig.
    Wall,
}

impl RunClock {
    /// Whether this is the default.
    pub fn is_rig(&self) -> bool {
        *self == RunClock::Rig
    }
}

impl RunSpec {
    const fn default_max_retries() -> u32 {
        3
    }
    const fn default_backoff_s() -> f64 {
        1.0
    }
    const fn default_move_timeout_s() -> f64 {
        120.0
    }
    const fn default_capture_timeout_s() -> f64 {
        60.0
    }
}

impl Default for RunSpec {
    fn default() -> Self {
        RunSpec {
            fault_scenario: None,
            max_retries: Self::default_max_retries(),
            backoff_s: Self::default_backoff_s(),
            move_timeout_s: Self::default_move_timeout_s(),
            capture_timeout_s: Self::default_capture_timeout_s(),
            clock: RunClock::Rig,
        }
    }
}

impl Plan {
    /// Parses a plan from TOML text; `origin` names the file in error messages. Text longer
    /// than [`MAX_PLAN_BYTES`] is refused unparsed ([`PlanError::TooLarge`]). Only syntax
    /// and schema are checked here (a wrong key or type stops parsing at the first); ranges,
    /// names and reachability are checked by [`Plan::validate`], which reports all at once.
    pub fn from_toml(text: &str, origin: &str) -> Result<Plan, PlanErrors> {
        check_plan_size(text, origin)?;
        toml::from_str(text).map_err(|e: toml::de::Error| {
            let (line, column) = e.span().map(|s| line_column(text, s.start)).unwrap_or((0, 0));
            PlanErrors {
                origin: origin.to_string(),
                errors: vec![PlanError::Syntax {
                    origin: origin.to_string(),
                    line,
                    column,
                    message: e.message().trim().to_string(),
                }],
            }
        })
    }

    /// A stable 64-bit FNV-1a hash of the canonical serialisation of everything that decides
    /// the dataset's content (all but `name`, `description` and `[run]`). Comments, key order
    /// and spelling of defaults do not change it; it recognises "the same plan" on resume.
    pub fn content_hash(&self) -> u64 {
        // `registration.on_failure` is a run policy like `[run]`: a run that stopped on a
        // failed registration may be resumed with a fallback.
        let registration =
            RegistrationSpec { on_failure: RegistrationSpec::default_on_failure(), ..self.registration.clone() };
        // `outputs.compressed_model` is a derived output: a run may be resumed with or
        // without the model, and plans written before the key existed keep their hash.
        let outputs = OutputsSpec { compressed_model: CompressedModelSpec::default(), ..self.outputs.clone() };
        let canonical = Plan {
            name: String::new(),
            description: String::new(),
            run: RunSpec::default(),
            limits: LimitsSpec::default(),
            registration,
            outputs,
            ..self.clone()
        };
        let text = toml::to_string(&canonical).expect("a plan always serialises");
        fnv1a64(text.as_bytes())
    }

    /// The rig config file this plan names, resolved against the plan file's path, or
    /// `None` for an embedded config (`builtin:...`). Pure path arithmetic, no I/O.
    pub fn rig_config_path(&self, plan_path: &Path) -> Option<PathBuf> {
        if self.rig.config.starts_with("builtin:") {
            return None;
        }
        Some(resolve_relative(plan_path, &self.rig.config))
    }

    /// The material file this plan names, resolved against the plan file's path, or `None`
    /// for an embedded material name (or no material). Pure path arithmetic, no I/O.
    pub fn material_path(&self, plan_path: &Path) -> Option<PathBuf> {
        let m = self.rig.material.as_deref()?;
        is_path_like(m).then(|| resolve_relative(plan_path, m))
    }
}

/// Does a material or rig reference look like a file path rather than a name?
pub(crate) fn is_path_like(s: &str) -> bool {
    s.ends_with(".toml") || s.contains('/') || s.contains('\\')
}

fn resolve_relative(plan_path: &Path, target: &str) -> PathBuf {
    let t = Path::new(target);
    if t.is_absolute() {
        return t.to_path_buf();
    }
    plan_path.parent().map(|d| d.join(t)).unwrap_or_else(|| t.to_path_buf())
}

/// 1-based line and column (in characters) of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// FNV-1a, 64 bit: tiny, stable across platforms and versions (unlike `DefaultHasher`).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

// A string or a table: hand-written so that errors inside the table keep serde's message
// naming the bad key (an untagged enum would say only "did not match any variant").
impl<'de> Deserialize<'de> for SamplingSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = SamplingSpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a preset name (\"bonn81\", \"dome1-151\") or a table with preset, list or rings")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Self::Value, E> {
                Ok(SamplingSpec::Preset(s.to_string()))
            }
            fn visit_map<A: MapAccess<'de>>(self, m: A) -> Result<Self::Value, A::Error> {
                SamplingTable::deserialize(de::value::MapAccessDeserializer::new(m)).map(SamplingSpec::Table)
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for FilterSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = FilterSpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a filter name (\"bilinear\", \"supersample\", \"footprint\", \"ewa\") or a table with name and n or max")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Self::Value, E> {
                Ok(FilterSpec::Name(s.to_string()))
            }
            fn visit_map<A: MapAccess<'de>>(self, m: A) -> Result<Self::Value, A::Error> {
                FilterTable::deserialize(de::value::MapAccessDeserializer::new(m)).map(FilterSpec::Table)
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for PairsSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = PairsSpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("\"all\" or a list of [light_index, view_index] pairs")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Self::Value, E> {
                Ok(PairsSpec::Mode(s.to_string()))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, s: A) -> Result<Self::Value, A::Error> {
                Vec::<[i64; 2]>::deserialize(de::value::SeqAccessDeserializer::new(s)).map(PairsSpec::List)
            }
        }
        d.deserialize_any(V)
    }
}

#[cfg(test)]
mod tests;
