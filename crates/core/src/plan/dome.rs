//! Measurement plans for an LED dome (`docs/plan-format.md`, "LED dome plans"): which views
//! (camera x turntable rotation), how the LEDs are captured (multiplexed or one by one) and
//! the exposure. Lights and views are fixed by the rig, so there is no `[sampling]`.

use serde::{Deserialize, Serialize};

use crate::config::RigConfig;
use crate::ConfigError;

/// A dome plan, as written in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomePlan {
    /// Short name, shown in reports.
    #[serde(default)]
    pub name: String,
    /// Which rig config (`"builtin:bonn-dome-sim"` by default), material and seed.
    #[serde(default = "DomePlan::default_rig")]
    pub rig: super::RigSpec,
    /// The views and the capture mode.
    #[serde(default)]
    pub dome: DomeCapture,
    /// Side of the square rectified textures, texels (8..=1024; default 32).
    #[serde(default = "DomePlan::default_size")]
    pub texture_size: usize,
    /// Fault scenario of the simulated rig (default `"none"`).
    #[serde(default = "DomePlan::default_faults")]
    pub fault_scenario: String,
    /// What the run keeps besides the textures.
    #[serde(default, skip_serializing_if = "DomeOutputs::is_default")]
    pub outputs: DomeOutputs,
}

/// The `[outputs]` table of a dome plan. Textures are always written; the gonio plan's other
/// outputs are not dome outputs, and naming one is a parse error that lists the keys allowed.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomeOutputs {
    /// Keep every pattern frame of every view group (all cameras), lossless, so the dataset
    /// can be demultiplexed again later (`btfrig reprocess`); default false.
    #[serde(default)]
    pub raw_frames: bool,
    /// A compressed BTF model the run builds while it captures, over the per-capture (light,
    /// view) directions in the sample frame (docs/compression.md): the gonio plan's values,
    /// `false` (default) or `"none"`, `"fmf"`, `"pvmf"`, `"pcmf"`, `"pcmf-shared"`, `true`
    /// (= `"fmf"`); written next to the dataset as `<DIR>.<method>.btfm`.
    #[serde(default, skip_serializing_if = "DomeOutputs::no_model")]
    pub compressed_model: super::CompressedModelSpec,
}

impl DomeOutputs {
    fn is_default(&self) -> bool {
        *self == DomeOutputs::default()
    }
    fn no_model(m: &super::CompressedModelSpec) -> bool {
        *m == super::CompressedModelSpec::default()
    }
}

/// How each view group is captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MultiplexPolicy {
    /// Multiplex when the noise model predicts a gain (`btfrig_mux::noise::choose`).
    Auto,
    /// Always one LED per frame.
    Off,
    /// Always multiplex: the full S-matrix, or groups of `group_order` when it is set.
    On,
}

/// The `[dome]` table of a dome plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomeCapture {
    /// Camera indices of the arc to use (default: all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cameras: Option<Vec<usize>>,
    /// Turntable rotation indices (default: all of `[dome] rotations`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotations: Option<Vec<u32>>,
    /// Exposure of a single-light frame, seconds (1e-4..=30); the time budget of a view
    /// group is `LEDs x exposure_s` in every mode.
    #[serde(default = "DomeCapture::default_exposure")]
    pub exposure_s: f64,
    /// Analogue gain (1..=the sensor's maximum).
    #[serde(default = "DomeCapture::default_gain")]
    pub gain: f64,
    /// `"auto"` (default), `"off"` or `"on"`.
    #[serde(default = "DomeCapture::default_policy")]
    pub multiplex: MultiplexPolicy,
    /// With `multiplex = "on"`: capture the LEDs in consecutive groups of this many, each
    /// multiplexed by its own S-matrix of this order, instead of one S-matrix over all of
    /// them (3 or more and below the LED count, so there are at least two groups; the
    /// planner checks that an S-matrix of the order exists). Unset: the full S-matrix.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group_order: Option<usize>,
    /// Typical sample albedo for the noise model (0 < b <= 1; default 0.3).
    #[serde(default = "DomeCapture::default_brightness")]
    pub sample_brightness: f64,
    /// Brightest single-LED response relative to white, for saturation (>= sample_brightness; default 1).
    #[serde(default = "DomeCapture::default_brightness_max")]
    pub brightness_max: f64,
    /// Single-LED reference captures taken in the first view group to measure the
    /// multiplexing gain against (0..=16; default 4; ignored without multiplexing).
    #[serde(default = "DomeCapture::default_reference")]
    pub reference_leds: usize,
    /// Denoise every view group's textures by projection onto their own leading basis of
    /// this many terms over the lights (`btfrig_mux::denoise`; seed 001 §4.2): 1 up to the
    /// lights minus one; unset (default): no denoising.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise_terms: Option<usize>,
}

impl DomeCapture {
    const fn default_exposure() -> f64 {
        0.05
    }
    const fn default_gain() -> f64 {
        1.0
    }
    const fn default_policy() -> MultiplexPolicy {
        MultiplexPolicy::Auto
    }
    const fn default_brightness() -> f64 {
        0.3
    }
    const fn default_brightness_max() -> f64 {
        1.0
    }
    const fn default_reference() -> usize {
        4
    }
}

impl Default for DomeCapture {
    fn default() -> Self {
        DomeCapture {
            cameras: None,
            rotations: None,
            exposure_s: Self::default_exposure(),
            gain: Self::default_gain(),
            multiplex: Self::default_policy(),
            group_order: None,
            sample_brightness: Self::default_brightness(),
            brightness_max: Self::default_brightness_max(),
            reference_leds: Self::default_reference(),
            denoise_terms: None,
        }
    }
}

/// A dome plan checked against its rig: the resolved views.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidatedDomePlan {
    /// The plan.
    pub plan: DomePlan,
    /// Camera indices, in capture order.
    pub cameras: Vec<usize>,
    /// Rotation indices, in capture order.
    pub rotations: Vec<u32>,
    /// The compressed model the run builds while it captures (`outputs.compressed_model`).
    pub compressed_model: Option<super::CompressedModel>,
}

impl DomePlan {
    /// The rig config a dome plan without `[rig] config` runs on.
    pub const DEFAULT_RIG: &'static str = "builtin:bonn-dome-sim";

    fn default_rig() -> super::RigSpec {
        super::RigSpec { config: DomePlan::DEFAULT_RIG.into(), material: None, seed: None }
    }
    const fn default_size() -> usize {
        32
    }
    fn default_faults() -> String {
        "none".into()
    }

    /// Parses a dome plan; `origin` names the text in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<DomePlan, ConfigError> {
        // Refused unparsed, as a gonio plan's ([`super::check_plan_size`]).
        if let Err(e) = super::check_plan_size(text, origin) {
            return Err(ConfigError::Parse { path: origin.into(), message: e.errors[0].to_string() });
        }
        toml::from_str(text).map_err(|e| ConfigError::Parse { path: origin.into(), message: e.to_string() })
    }

    /// The view index of (camera `c`, rotation `k`) in the dataset: `k x cameras + c`, over
    /// the rig's full arc, so datasets of subsets share indices.
    pub fn view_index(rig_cameras: usize, c: usize, k: u32) -> u32 {
        k * rig_cameras as u32 + c as u32
    }

    /// Checks every value against `rig` (an LED dome) and reports all problems at once.
    pub fn validate(self, rig: &RigConfig) -> Result<ValidatedDomePlan, ConfigError> {
        let dome = rig.require_dome("a dome plan")?;
        let d = &self.dome;
        let mut e = Vec::new();
        let cameras: Vec<usize> = d.cameras.clone().unwrap_or_else(|| (0..dome.camera_count()).collect());
        let rotations: Vec<u32> = d.rotations.clone().unwrap_or_else(|| (0..dome.rotations).collect());
        let nc = dome.camera_count();
        // Longer lists must repeat an index; refused before the duplicate scans below.
        if cameras.len() > nc || rotations.len() > dome.rotations as usize {
            let (field, n, max) = if cameras.len() > nc {
                ("dome.cameras", cameras.len(), nc)
            } else {
                ("dome.rotations", rotations.len(), dome.rotations as usize)
            };
            return Err(ConfigError::out_of_range(
                field,
                format!("{n} entries"),
                &format!("at most {max} distinct indices (the rig's count)"),
            ));
        }
        let textures = dome.led_count().saturating_mul(cameras.len()).saturating_mul(rotations.len());
        if textures > super::limits::DEFAULT_MAX_CAPTURES {
            e.push(ConfigError::out_of_range(
                "dome",
                format!("{textures} textures ({} lights x {} cameras x {} rotations)", dome.led_count(), cameras.len(), rotations.len()),
                &format!(
                    "at most {} textures per plan (a fixed limit of dome plans): choose fewer [dome] cameras or rotations",
                    super::limits::DEFAULT_MAX_CAPTURES
                ),
            ));
        }
        if cameras.is_empty() {
            e.push(ConfigError::out_of_range("dome.cameras", "[]", &format!("camera indices in 0..{nc}")));
        }
        for (i, &c) in cameras.iter().enumerate() {
            if c >= nc || cameras[..i].contains(&c) {
                e.push(ConfigError::out_of_range(
                    &format!("dome.cameras[{i}]"),
                    c,
                    &format!("distinct indices in 0..{nc}"),
                ));
            }
        }
        if rotations.is_empty() {
            e.push(ConfigError::out_of_range(
                "dome.rotations",
                "[]",
                &format!("rotation indices in 0..{}", dome.rotations),
            ));
        }
        for (i, &k) in rotations.iter().enumerate() {
            if k >= dome.rotations || rotations[..i].contains(&k) {
                e.push(ConfigError::out_of_range(
                    &format!("dome.rotations[{i}]"),
                    k,
                    &format!("distinct indices in 0..{}", dome.rotations),
                ));
            }
        }
        if !(d.exposure_s.is_finite() && (1e-4..=30.0).contains(&d.exposure_s)) {
            e.push(ConfigError::out_of_range("dome.exposure_s", d.exposure_s, "1e-4..=30"));
        }
        if !(d.gain.is_finite() && d.gain >= 1.0 && d.gain <= rig.sensor.max_analogue_gain) {
            e.push(ConfigError::out_of_range("dome.gain", d.gain, &format!("1..={}", rig.sensor.max_analogue_gain)));
        }
        if !(d.sample_brightness > 0.0 && d.sample_brightness <= 1.0) {
            e.push(ConfigError::out_of_range("dome.sample_brightness", d.sample_brightness, "0 < b <= 1"));
        }
        if !(d.brightness_max.is_finite() && d.brightness_max >= d.sample_brightness) {
            e.push(ConfigError::out_of_range("dome.brightness_max", d.brightness_max, ">= dome.sample_brightness"));
        }
        e.extend(check_group_order(d, dome.led_count()));
        if let Some(k) = d.denoise_terms {
            let n = dome.led_count();
            if !(1..n.saturating_sub(1)).contains(&k) {
                e.push(ConfigError::out_of_range(
                    "dome.denoise_terms",
                    k,
                    &format!("1..{} (fewer terms than the {n} lights, or leave it out for no denoising)", n - 1),
                ));
            }
        }
        if d.reference_leds > 16 {
            e.push(ConfigError::out_of_range("dome.reference_leds", d.reference_leds, "0..=16"));
        }
        if !(8..=1024).contains(&self.texture_size) {
            e.push(ConfigError::out_of_range("texture_size", self.texture_size, "8..=1024"));
        }
        let compressed_model = self.outputs.compressed_model.model().unwrap_or_else(|m| {
            e.push(ConfigError::Unknown {
                field: "outputs.compressed_model".into(),
                value: m.into(),
                allowed: "\"fmf\", \"pvmf\", \"pcmf\", \"pcmf-shared\", \"none\", false, or true (= \"fmf\")".into(),
            });
            None
        });
        if compressed_model == Some(super::CompressedModel::PcmfShared) {
            e.extend(shared_basis_problem(textures));
        }
        if !super::BUILTIN_FAULT_SCENARIOS.contains(&self.fault_scenario.as_str()) {
            e.push(ConfigError::Unknown {
                field: "fault_scenario".into(),
                value: self.fault_scenario.clone(),
                allowed: super::BUILTIN_FAULT_SCENARIOS.join(", "),
            });
        }
        ConfigError::from_list(e)?;
        Ok(ValidatedDomePlan { plan: self, cameras, rotations, compressed_model })
    }
}

/// `outputs.compressed_model = "pcmf-shared"` (or a run's override of it) on a dome plan of
/// fewer textures than the shared basis has terms: refused before the run, as a gonio plan's.
/// (A texture has at least 8 x 8 texels, more than the basis's terms.)
pub fn shared_basis_problem(textures: usize) -> Option<ConfigError> {
    let k = super::CompressedModel::SHARED_BASIS_TERMS;
    (textures < k).then(|| {
        ConfigError::out_of_range(
            "outputs.compressed_model",
            format!("\"pcmf-shared\" (its shared basis has {k} terms and the plan captures {textures} textures)"),
            &super::SHARED_BASIS_ALLOWED.replace("{k}", &k.to_string()),
        )
    })
}

/// `group_order` only refines a forced multiplexed capture (under `"auto"` the noise model
/// picks the groups itself, under `"off"` nothing is multiplexed), and needs at least two
/// groups of at least 3 LEDs' slots (smaller S-matrices do not gain).
fn check_group_order(d: &DomeCapture, leds: usize) -> Option<ConfigError> {
    let m = d.group_order?;
    if d.multiplex != MultiplexPolicy::On {
        let policy = if d.multiplex == MultiplexPolicy::Auto { "auto" } else { "off" };
        return Some(ConfigError::out_of_range(
            "dome.group_order",
            m,
            &format!("only with multiplex = \"on\" (the plan says \"{policy}\"; under \"auto\" the noise model picks the groups)"),
        ));
    }
    if !(3..leds).contains(&m) {
        return Some(ConfigError::out_of_range(
            "dome.group_order",
            m,
            &format!("3..{leds} (at least two groups of the {leds} lights; an order with an S-matrix)"),
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> RigConfig {
        let text = super::super::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-dome-sim").unwrap().1;
        RigConfig::from_toml(text, "dome").unwrap()
    }

    #[test]
    fn defaults_take_every_view() {
        let v = DomePlan::from_toml("", "p").unwrap().validate(&rig()).unwrap();
        assert_eq!((v.cameras.len(), v.rotations.len()), (11, 12));
        assert_eq!(DomePlan::view_index(11, 3, 2), 25);
    }

    #[test]
    fn bad_values_are_all_named() {
        let p = DomePlan::from_toml("[dome]\ncameras = [0, 11]\nrotations = [1, 1]\nexposure_s = 0\n", "p").unwrap();
        let e = p.validate(&rig()).unwrap_err().to_string();
        assert!(e.contains("dome.cameras[1] = 11 is out of range: allowed distinct indices in 0..11"), "{e}");
        assert!(e.contains("dome.rotations[1] = 1"), "{e}");
        assert!(e.contains("dome.exposure_s = 0"), "{e}");
        assert!(DomePlan::from_toml("[dome]\ncamera = [0]\n", "p").unwrap_err().to_string().contains("camera"));
    }

    #[test]
    fn outputs_keep_raw_frames_on_request_and_name_the_allowed_keys() {
        let v = DomePlan::from_toml("", "p").unwrap().validate(&rig()).unwrap();
        assert!(!v.plan.outputs.raw_frames);
        let v = DomePlan::from_toml("[outputs]\nraw_frames = true\n", "p").unwrap().validate(&rig()).unwrap();
        assert!(v.plan.outputs.raw_frames);
        let e = DomePlan::from_toml("[outputs]\ntextures = false\n", "p").unwrap_err().to_string();
        assert!(e.contains("unknown field `textures`, expected `raw_frames` or `compressed_model`"), "{e}");
        let e = DomePlan::from_toml("[outputs]\nraw_frames = \"yes\"\n", "p").unwrap_err().to_string();
        assert!(e.contains("raw_frames") && e.contains("expected a boolean"), "{e}");
    }

    #[test]
    fn a_compressed_model_takes_the_gonio_values_and_pcmf_shared_needs_32_textures() {
        let check = |outputs: &str, dome: &str| {
            DomePlan::from_toml(&format!("[outputs]\n{outputs}[dome]\n{dome}"), "p").unwrap().validate(&rig())
        };
        use super::super::CompressedModel as M;
        for (value, model) in [
            ("false", None),
            ("\"none\"", None),
            ("true", Some(M::Fmf)),
            ("\"fmf\"", Some(M::Fmf)),
            ("\"pvmf\"", Some(M::Pvmf)),
            ("\"pcmf\"", Some(M::Pcmf)),
            ("\"pcmf-shared\"", Some(M::PcmfShared)),
        ] {
            let v = check(&format!("compressed_model = {value}\n"), "").unwrap();
            assert_eq!(v.compressed_model, model, "{value}");
        }
        assert_eq!(DomePlan::from_toml("", "p").unwrap().validate(&rig()).unwrap().compressed_model, None);
        let e = check("compressed_model = \"zip\"\n", "").unwrap_err().to_string();
        assert!(e.contains("outputs.compressed_model = \"zip\" is unknown: allowed \"fmf\", \"pvmf\""), "{e}");
        let e = DomePlan::from_toml("[outputs]\ncompressed_model = 3\n", "p").unwrap_err().to_string();
        assert!(e.contains("compressed_model") && e.contains("\"pcmf-shared\""), "{e}");
        // One view of the dome is 198 textures, more than the basis's 32 terms.
        assert!(check("compressed_model = \"pcmf-shared\"\n", "cameras = [4]\nrotations = [1]\n").is_ok());
        assert!(shared_basis_problem(31).unwrap().to_string().contains("the plan captures 31 textures"));
        assert!(shared_basis_problem(32).is_none());
    }

    #[test]
    fn denoise_terms_are_fewer_than_the_lights() {
        let check = |extra: &str| DomePlan::from_toml(&format!("[dome]\n{extra}"), "p").unwrap().validate(&rig());
        assert_eq!(check("").unwrap().plan.dome.denoise_terms, None);
        assert_eq!(check("denoise_terms = 16\n").unwrap().plan.dome.denoise_terms, Some(16));
        for bad in [0, 197, 500] {
            let e = check(&format!("denoise_terms = {bad}\n")).unwrap_err().to_string();
            assert!(e.contains(&format!("dome.denoise_terms = {bad} is out of range: allowed 1..197")), "{e}");
        }
    }

    #[test]
    fn a_group_order_needs_a_forced_multiplex_and_at_least_two_groups() {
        let check = |extra: &str| DomePlan::from_toml(&format!("[dome]\n{extra}"), "p").unwrap().validate(&rig());
        let v = check("multiplex = \"on\"\ngroup_order = 7\n").unwrap();
        assert_eq!(v.plan.dome.group_order, Some(7));
        let e = check("group_order = 7\n").unwrap_err().to_string();
        assert!(
            e.contains(
                "dome.group_order = 7 is out of range: allowed only with multiplex = \"on\" (the plan says \"auto\""
            ),
            "{e}"
        );
        let e = check("multiplex = \"on\"\ngroup_order = 199\n").unwrap_err().to_string();
        assert!(
            e.contains("dome.group_order = 199 is out of range: allowed 3..198 (at least two groups of the 198 lights"),
            "{e}"
        );
    }
}
