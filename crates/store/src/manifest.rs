//! The manifest: what a dataset is a measurement of. Schema in `docs/dataset-format.md`.

use std::collections::BTreeSet;

use btfrig_core::Direction;
use serde::{Deserialize, Serialize};

use crate::hash::content_hash;
use crate::StepId;

/// Version of the manifest schema this build writes and reads.
pub const MANIFEST_SCHEMA_VERSION: u32 = 1;

/// The manifest of a dataset (`manifest.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Schema version ([`MANIFEST_SCHEMA_VERSION`]).
    pub schema_version: u32,
    /// The software that wrote the dataset.
    pub software: Software,
    /// The rig: its name and the full config text it ran with.
    pub rig: RigInfo,
    /// The plan: its text and content hash.
    pub plan: PlanInfo,
    /// Light and view directions and which pairs are measured.
    pub samplings: Samplings,
    /// Size, region and pixel format of the rectified textures.
    pub texture: TextureSpec,
    /// True if raw frames are kept under `raw/`.
    pub raw_frames: bool,
    /// True if rectified textures are written under `textures/` (absent in manifests written
    /// before this field existed: true). A plan may keep raw frames only.
    #[serde(default = "Manifest::yes")]
    pub textures: bool,
    /// True if each texture has an 8-bit sRGB preview under `previews/` (absent in manifests
    /// written before this field existed: false). Requires `textures`.
    #[serde(default)]
    pub texture_previews: bool,
    /// Raw frames kept per view group (a dome's pattern frames, `raw/v<view>_p<k>.exr`, one
    /// journal `frames` record per group), and what re-demultiplexing them needs: the capture
    /// schedule as the run recorded it (the runner's `RawSchedule`). Absent: none kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw_groups: Option<serde_json::Value>,
    /// Calibration the run used (`null` until the calibration issue provides one).
    pub calibration: Option<serde_json::Value>,
    /// Seed of every random process of the run (simulated rigs).
    pub seed: u64,
    /// Creation time, seconds since the Unix epoch (UTC).
    pub created_unix_s: f64,
    /// Creation time as RFC 3339 UTC (`2026-11-23T02:19:26Z`).
    pub created_utc: String,
    /// Timing summary, filled by `finish` (`null` while the run is unfinished).
    pub timing: Option<TimingSummary>,
}

/// The software that wrote a dataset.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Software {
    /// Program name (`btfrig`).
    pub name: String,
    /// Its version.
    pub version: String,
}

/// The rig a dataset was measured on.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigInfo {
    /// The rig's name (`[rig] name` of its config).
    pub name: String,
    /// The rig config file's text as loaded.
    pub config_toml: String,
}

/// The plan a dataset measures.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanInfo {
    /// The plan file's text.
    pub text: String,
    /// Its content hash: `sha256:` + hex of the text's UTF-8 bytes ([`plan_hash`]).
    pub hash: String,
}

/// A direction in degrees, as in every file of btfrig.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DirectionDeg {
    /// Polar angle from the sample normal, degrees.
    pub theta_deg: f64,
    /// Azimuth from the sample x axis, degrees.
    pub phi_deg: f64,
}

impl From<Direction> for DirectionDeg {
    fn from(d: Direction) -> Self {
        let (theta_deg, phi_deg) = d.to_degrees();
        DirectionDeg { theta_deg, phi_deg }
    }
}

/// A step the plan does not capture, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkippedStep {
    /// The step.
    pub step: StepId,
    /// Why (e.g. `unreachable: robot joint 2 limit`).
    pub reason: String,
}

/// Light and view samplings and the measured pairs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Samplings {
    /// Light directions; a step's `light` indexes this list.
    pub light: Vec<DirectionDeg>,
    /// View directions; a step's `view` indexes this list.
    pub view: Vec<DirectionDeg>,
    /// The pairs the plan asks for; `null` means every light with every view.
    pub pairs: Option<Vec<StepId>>,
    /// Pairs of the plan that the planner skips, with reasons (not expected in the dataset).
    pub skipped: Vec<SkippedStep>,
}

impl Samplings {
    /// Every light with every view, nothing skipped.
    pub fn full(light: &[Direction], view: &[Direction]) -> Self {
        Samplings {
            light: light.iter().map(|&d| d.into()).collect(),
            view: view.iter().map(|&d| d.into()).collect(),
            pairs: None,
            skipped: Vec::new(),
        }
    }

    /// The steps the dataset should hold when complete: the pairs minus the skipped ones.
    pub fn expected_steps(&self) -> BTreeSet<StepId> {
        let skipped: BTreeSet<StepId> = self.skipped.iter().map(|s| s.step).collect();
        let all: Box<dyn Iterator<Item = StepId>> = match &self.pairs {
            Some(p) => Box::new(p.iter().copied()),
            None => Box::new(
                (0..self.light.len() as u32)
                    .flat_map(|light| (0..self.view.len() as u32).map(move |view| StepId { light, view })),
            ),
        };
        all.filter(|s| !skipped.contains(s)).collect()
    }
}

/// Pixel format of the texture files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TextureFormat {
    /// OpenEXR, linear RGB, 16-bit half channels.
    ExrHalf,
    /// OpenEXR, linear RGB, 32-bit float channels.
    ExrFloat,
}

/// Region of the sample plane a texture covers, in sample coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureRegion {
    /// Centre `(x, y)`, metres.
    pub center_m: [f64; 2],
    /// Extent along x and y, metres.
    pub size_m: [f64; 2],
}

/// Size, region and format of the rectified textures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureSpec {
    /// Width, texels.
    pub width: u32,
    /// Height, texels.
    pub height: u32,
    /// The region covered.
    pub region: TextureRegion,
    /// Pixel format.
    pub format: TextureFormat,
}

/// Timing summary written into the manifest by `finish`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingSummary {
    /// Earliest step start among the journaled steps, Unix seconds.
    pub first_step_unix_s: f64,
    /// When `finish` ran, Unix seconds.
    pub finished_unix_s: f64,
    /// Wall time of the run as reported (all sessions of a resumed run), seconds.
    pub wall_s: f64,
    /// Hardware time (simulated rigs: virtual time), seconds, if known.
    pub hardware_s: Option<f64>,
    /// Steps done.
    pub steps_done: u64,
    /// Steps skipped during the run (journal) plus by the plan.
    pub steps_skipped: u64,
    /// Retries: attempts beyond the first, summed over the done steps.
    pub retries: u64,
}

/// Where the manifest's last member, `timing` (the only one `finish` rewrites), starts in
/// `manifest.json` as this crate writes it (pretty JSON, two-space indent; the strings hold
/// no raw newline, so only the top-level key starts a line with this indent).
const TIMING_KEY: &[u8] = b"\n  \"timing\": ";

/// The part of `manifest.json` that never changes after creation: its bytes before the
/// top-level `timing` member (the whole file when there is none).
pub(crate) fn manifest_fixed_part(bytes: &[u8]) -> &[u8] {
    match bytes.windows(TIMING_KEY.len()).rposition(|w| w == TIMING_KEY) {
        Some(at) => &bytes[..at],
        None => bytes,
    }
}

/// The manifest hash journaled when a dataset is created: [`content_hash`] of the bytes of
/// `manifest.json` before its `timing` member. Bytes, not parsed values: any edit of a
/// sampling, the seed, the plan or the rig (even of a float in its last digit) changes it.
pub fn manifest_hash(manifest_json: &[u8]) -> String {
    content_hash(manifest_fixed_part(manifest_json))
}

/// The plan hash of a plan text: [`content_hash`] of its UTF-8 bytes.
pub fn plan_hash(plan_text: &str) -> String {
    content_hash(plan_text.as_bytes())
}

impl Manifest {
    const fn yes() -> bool {
        true
    }

    /// A manifest for a new run, created now, by this software version, without calibration
    /// or timing, with textures (set [`Manifest::textures`] to false for raw frames only).
    pub fn new(
        rig: RigInfo,
        plan_text: &str,
        samplings: Samplings,
        texture: TextureSpec,
        raw_frames: bool,
        seed: u64,
    ) -> Self {
        let now =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0);
        Manifest {
            schema_version: MANIFEST_SCHEMA_VERSION,
            software: Software { name: "btfrig".into(), version: env!("CARGO_PKG_VERSION").into() },
            rig,
            plan: PlanInfo { text: plan_text.into(), hash: plan_hash(plan_text) },
            samplings,
            texture,
            raw_frames,
            textures: true,
            texture_previews: false,
            raw_groups: None,
            calibration: None,
            seed,
            created_unix_s: now,
            created_utc: rfc3339_utc(now as i64),
            timing: None,
        }
    }

    /// Every inconsistency of the manifest (empty when it is sound).
    pub fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if !self.textures && !self.raw_frames {
            p.push("textures and raw_frames are both false: the dataset would hold no data".into());
        }
        if self.texture_previews && !self.textures {
            p.push("texture_previews is true but textures is false: a preview shows a texture".into());
        }
        if self.schema_version != MANIFEST_SCHEMA_VERSION {
            p.push(format!("schema_version {} (this build reads {MANIFEST_SCHEMA_VERSION})", self.schema_version));
        }
        if plan_hash(&self.plan.text) != self.plan.hash {
            p.push(format!(
                "plan.hash {} is not the hash of plan.text ({})",
                self.plan.hash,
                plan_hash(&self.plan.text)
            ));
        }
        let (nl, nv) = (self.samplings.light.len() as u32, self.samplings.view.len() as u32);
        if nl == 0 || nv == 0 {
            p.push(format!("samplings: {nl} light and {nv} view directions; both must be non-empty"));
        }
        for (name, list) in [("light", &self.samplings.light), ("view", &self.samplings.view)] {
            for (i, d) in list.iter().enumerate() {
                if !(0.0..=90.0).contains(&d.theta_deg) || !d.phi_deg.is_finite() {
                    p.push(format!(
                        "samplings.{name}[{i}]: theta {} deg, phi {} deg (theta in 0..=90)",
                        d.theta_deg, d.phi_deg
                    ));
                }
            }
        }
        let out_of_range = |s: &StepId| s.light >= nl || s.view >= nv;
        for s in self.samplings.pairs.iter().flatten().chain(self.samplings.skipped.iter().map(|s| &s.step)) {
            if out_of_range(s) {
                p.push(format!("samplings: step {s} outside lights 0..{nl}, views 0..{nv}"));
            }
        }
        if self.texture.width == 0 || self.texture.height == 0 {
            p.push(format!("texture: {}x{} texels (both must be > 0)", self.texture.width, self.texture.height));
        }
        if !self.texture.region.size_m.iter().all(|&s| s > 0.0 && s.is_finite()) {
            p.push(format!("texture.region.size_m {:?} (both must be > 0)", self.texture.region.size_m));
        }
        p
    }
}

/// `YYYY-MM-DDTHH:MM:SSZ` for Unix seconds (proleptic Gregorian, UTC).
pub fn rfc3339_utc(unix_s: i64) -> String {
    let (days, secs) = (unix_s.div_euclid(86_400), unix_s.rem_euclid(86_400));
    // Civil-from-days (Howard Hinnant's algorithm), era-based.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", secs / 3600, secs % 3600 / 60, secs % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manifest_hash_ignores_timing_only() {
        let d = [Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 90.0)];
        let texture = TextureSpec {
            width: 4,
            height: 4,
            region: TextureRegion { center_m: [0.0, 0.0], size_m: [0.1, 0.1] },
            format: TextureFormat::ExrHalf,
        };
        let rig = RigInfo { name: "r".into(), config_toml: "[rig]\nname = \"r\"\n".into() };
        let mut m = Manifest::new(rig, "[plan]\n", Samplings::full(&d, &d), texture, false, 7);
        let created = serde_json::to_vec_pretty(&m).unwrap();
        let h = manifest_hash(&created);
        m.timing = Some(TimingSummary {
            first_step_unix_s: 1.0,
            finished_unix_s: 2.0,
            wall_s: 1.0,
            hardware_s: None,
            steps_done: 4,
            steps_skipped: 0,
            retries: 0,
        });
        assert_eq!(manifest_hash(&serde_json::to_vec_pretty(&m).unwrap()), h, "timing is not protected");
        m.seed = 8;
        assert_ne!(manifest_hash(&serde_json::to_vec_pretty(&m).unwrap()), h, "the seed is protected");
        m.seed = 7;
        m.samplings.view[1].theta_deg = 30.000000000000004;
        assert_ne!(manifest_hash(&serde_json::to_vec_pretty(&m).unwrap()), h, "an angle is protected");
    }

    #[test]
    fn rfc3339_matches_known_dates() {
        assert_eq!(rfc3339_utc(0), "1970-01-01T00:00:00Z");
        // `date -u -d @951782400` = 2000-02-29 00:00:00 (leap day of a century leap year).
        assert_eq!(rfc3339_utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(rfc3339_utc(1_795_400_366), "2026-11-23T02:19:26Z");
        assert_eq!(rfc3339_utc(-1), "1969-12-31T23:59:59Z");
    }

    #[test]
    fn expected_steps_are_pairs_minus_skips() {
        let d = [Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 90.0)];
        let mut s = Samplings::full(&d, &d[..1]);
        assert_eq!(s.expected_steps().len(), 2);
        s.skipped.push(SkippedStep { step: StepId { light: 1, view: 0 }, reason: "unreachable".into() });
        assert_eq!(s.expected_steps().into_iter().collect::<Vec<_>>(), vec![StepId { light: 0, view: 0 }]);
        s.pairs = Some(vec![StepId { light: 1, view: 0 }]);
        assert!(s.expected_steps().is_empty());
    }
}
