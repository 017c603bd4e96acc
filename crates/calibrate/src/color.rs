//! Colour calibration on a rig: a colour calibration plan ([`ColorPlan`],
//! `rig-configs/plans/calibration-color.toml`) names colour charts mounted in the sample
//! region of the holder plate (which of their patches are held out of the fit), one view and
//! one lamp direction; [`calibrate_color`] has a [`ChartCamera`] photograph each chart (on the
//! simulated rig: `btfrig_sim_calibration::color`, true lens, lamp, seeded sensor noise),
//! registers each frame against the plate's markers, rectifies it and converts it to
//! white-balanced camera RGB radiance factor (the pipeline's radiometry with an identity
//! matrix), averages each patch's interior, screens clipped and dark patches, fits every
//! candidate model with `btfrig-color` on the fitting patches against the patches' reference
//! colours ([`ChartReferences`]), chooses by cross-validated CIEDE2000 and reports every
//! model's CIEDE2000 on the held-out patches.
//! [`ColorCalibrationFile`] is the file it writes (`calibration/*-color.toml`);
//! [`processing_color`] reads the one a rig config names. Format and figures:
//! `docs/color.md`.

use std::path::Path;
use std::time::Instant;

use btfrig_color::chart::{ChartLayout, CHART_NAMES};
use btfrig_color::{
    evaluate, select_model, ColorError, ColorModel, DeltaEStats, FitOptions, ModelKind, PatchStatus, ScreenOptions,
    TargetSpace,
};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::{rectify, to_radiance_factor, vignetting_map, Filter, LinearImage, Radiometry, Region};
use btfrig_markers::GrayImage;
use btfrig_registration::PlateRegistrar;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::RigCalibError;

/// Version of the colour calibration plan format.
pub const COLOR_PLAN_FORMAT_VERSION: u32 = 1;
/// Version of the colour calibration file format.
pub const COLOR_FILE_FORMAT_VERSION: u32 = 1;

/// The default plan, embedded (`rig-configs/plans/calibration-color.toml`).
pub const DEFAULT_COLOR_PLAN: &str = include_str!("../../../rig-configs/plans/calibration-color.toml");

/// Colour calibration files embedded in the binary, for `[camera] color_calibration =
/// "builtin:NAME"`.
pub const BUILTIN_COLOR_CALIBRATIONS: &[(&str, &str)] =
    &[("bonn-gonio-sim-color", include_str!("../../../calibration/bonn-gonio-sim-color.toml"))];

/// One chart of a plan and which of its patches are held out of the fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChartUse {
    /// A built-in chart name ([`CHART_NAMES`]).
    pub name: String,
    /// Every `hold_out_every`-th patch (patches `hold_out_every - 1`, `2 hold_out_every - 1`,
    /// ...) is held out of the fit and evaluated: 1 holds out the whole chart (evaluation
    /// only), 0 holds out none.
    pub hold_out_every: usize,
}

impl ChartUse {
    /// Whether patch `k` is held out.
    pub fn held_out(&self, k: usize) -> bool {
        self.hold_out_every > 0 && k % self.hold_out_every == self.hold_out_every - 1
    }
}

/// A colour calibration plan (format in `docs/color.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorPlan {
    /// Format version ([`COLOR_PLAN_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Name, for reports and the calibration file's source.
    pub name: String,
    /// The charts photographed, one capture each; the first also meters the exposure and
    /// gives the white balance. At least one.
    pub charts: Vec<ChartUse>,
    /// View direction (chart frame): polar angle from the normal, degrees (0..=60).
    pub view_theta_deg: f64,
    /// View azimuth, degrees.
    #[serde(default)]
    pub view_phi_deg: f64,
    /// Lamp polar angle, degrees (0..=70).
    pub light_theta_deg: f64,
    /// Lamp azimuth, degrees; keep it away from the mirror direction of the view.
    pub light_phi_deg: f64,
    /// Exposure: a metering shot is rescaled so that the brightest patch's largest channel
    /// reaches this fraction of full scale (0.05..=0.95).
    pub exposure_fraction: f64,
    /// Texels per side of the rectified sample region (64..=2048).
    pub texels: usize,
    /// Fraction of the patch side left out at each edge before averaging (0..0.45).
    pub patch_margin: f64,
    /// Candidate models (`linear`, `rootpoly2`, `rootpoly3`, `poly2`, `poly3`).
    pub models: Vec<String>,
    /// Cross-validation folds on the fitting patches (2..=fitting patches).
    pub folds: usize,
    /// Ridge parameter of every fit (relative, see `btfrig_color::FitOptions::ridge`).
    #[serde(default)]
    pub ridge: f64,
}

impl ColorPlan {
    /// The embedded default plan.
    pub fn default_plan() -> ColorPlan {
        Self::from_toml(DEFAULT_COLOR_PLAN, "<embedded rig-configs/plans/calibration-color.toml>")
            .expect("the embedded colour calibration plan is valid")
    }

    /// Parses and validates a plan; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<ColorPlan, RigCalibError> {
        let p: ColorPlan =
            toml::from_str(text).map_err(|e| RigCalibError::Plan { origin: origin.into(), message: e.to_string() })?;
        let problems = p.problems();
        if !problems.is_empty() {
            return Err(RigCalibError::Plan { origin: origin.into(), message: problems.join("; ") });
        }
        Ok(p)
    }

    /// Every invalid value, as messages naming the field.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.format_version != COLOR_PLAN_FORMAT_VERSION {
            out.push(format!(
                "format_version = {} is not supported (this build reads {COLOR_PLAN_FORMAT_VERSION})",
                self.format_version
            ));
        }
        if self.charts.is_empty() {
            out.push("charts: at least one chart".into());
        }
        for (i, c) in self.charts.iter().enumerate() {
            if let Err(e) = ChartLayout::by_name(&c.name) {
                out.push(format!("charts[{i}].name: {e}"));
            }
        }
        if !self.charts.iter().any(|c| c.hold_out_every != 1) {
            out.push("charts: every chart is held out (hold_out_every = 1): nothing to fit".into());
        }
        let range = |out: &mut Vec<String>, name: &str, v: f64, lo: f64, hi: f64| {
            if !(v.is_finite() && v >= lo && v <= hi) {
                out.push(format!("{name} = {v}: allowed {lo}..={hi}"));
            }
        };
        range(&mut out, "view_theta_deg", self.view_theta_deg, 0.0, 60.0);
        range(&mut out, "light_theta_deg", self.light_theta_deg, 0.0, 70.0);
        range(&mut out, "exposure_fraction", self.exposure_fraction, 0.05, 0.95);
        range(&mut out, "patch_margin", self.patch_margin, 0.0, 0.45);
        range(&mut out, "ridge", self.ridge, 0.0, 1.0);
        for (n, v) in [("view_phi_deg", self.view_phi_deg), ("light_phi_deg", self.light_phi_deg)] {
            if !v.is_finite() {
                out.push(format!("{n} = {v}: must be finite"));
            }
        }
        if !(64..=2048).contains(&self.texels) {
            out.push(format!("texels = {}: allowed 64..=2048", self.texels));
        }
        if self.models.is_empty() {
            out.push("models: at least one model".into());
        }
        for (i, m) in self.models.iter().enumerate() {
            if let Err(e) = m.parse::<ModelKind>() {
                out.push(format!("models[{i}]: {e}"));
            }
        }
        if self.folds < 2 {
            out.push(format!("folds = {}: at least 2", self.folds));
        }
        out
    }

    /// The candidate models.
    pub fn model_kinds(&self) -> Vec<ModelKind> {
        self.models.iter().filter_map(|m| m.parse().ok()).collect()
    }
}

/// What one patch measured.
#[derive(Debug, Clone, PartialEq)]
pub struct PatchMeasurement {
    /// Chart name.
    pub chart: String,
    /// Patch index in its chart.
    pub index: usize,
    /// Patch name.
    pub name: String,
    /// Mean white-balanced camera RGB (radiance factor units) over the patch interior.
    pub camera: [f64; 3],
    /// Reference colour: the patch's output-space colour (linear sRGB, D65, adapted from
    /// the lamp) times its illumination factor `geometry`.
    pub target: [f64; 3],
    /// The patch's reference colour at full illumination (`target / geometry`).
    pub reference: [f64; 3],
    /// Illumination factor: cosine of the lamp's incidence times the inverse-square falloff
    /// relative to the nominal lamp distance, at the patch centre.
    pub geometry: f64,
    /// Texels averaged.
    pub texels: usize,
    /// Screening verdict (on the demosaiced values, full scale 1).
    pub status: PatchStatus,
    /// Whether the patch is in the fitting set (else held out or test chart).
    pub fit: bool,
}

/// One candidate model's figures.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelResult {
    /// The model family.
    pub kind: ModelKind,
    /// Cross-validated CIEDE2000 on the fitting patches, or why it failed.
    pub cv: Result<DeltaEStats, ColorError>,
    /// CIEDE2000 on the held-out patches, or why there is none.
    pub held_out: Result<DeltaEStats, ColorError>,
    /// Seconds to fit once on the fitting set (median of 5 fits).
    pub fit_s: f64,
    /// Seconds to apply the model to one million pixels (f32, one thread), measured on a
    /// 2^16-pixel buffer.
    pub apply_s_per_mpix: f64,
    /// The model fitted on every fitting patch.
    pub model: Result<ColorModel, ColorError>,
}

/// Result of [`calibrate_color`].
#[derive(Debug, Clone)]
pub struct ColorCalibration {
    /// Every measured patch, fitting chart first.
    pub patches: Vec<PatchMeasurement>,
    /// White balance used (from the first chart's white patch).
    pub white_balance: [f64; 3],
    /// One per candidate, in plan order.
    pub models: Vec<ModelResult>,
    /// Index into `models` of the chosen one (lowest cross-validated mean).
    pub chosen: usize,
    /// Exposure of the captures, seconds.
    pub exposure_s: f64,
    /// Seconds capturing (on the simulated rig: rendering) frames, metering included.
    pub render_s: f64,
    /// Seconds registering, rectifying and averaging.
    pub measure_s: f64,
    /// Per chart: where its reference colours came from ([`ChartReferences::provenance`]).
    pub references: Vec<String>,
}

impl ColorCalibration {
    /// The chosen model's results.
    pub fn chosen(&self) -> &ModelResult {
        &self.models[self.chosen]
    }

    /// The calibration file of the chosen model.
    pub fn file(&self, rig: &str, plan: &ColorPlan, seed: u64) -> ColorCalibrationFile {
        let m = self.chosen();
        let model = m.model.as_ref().expect("chosen model fitted");
        let stats = m.held_out.as_ref().ok();
        ColorCalibrationFile {
            format_version: COLOR_FILE_FORMAT_VERSION,
            model: m.kind.name().into(),
            input: "white-balanced camera RGB radiance factor".into(),
            output: "linear sRGB (Rec. 709, D65) radiance factor, adapted from the lamp white".into(),
            white_balance: self.white_balance,
            terms: m.kind.term_names().iter().map(|s| s.to_string()).collect(),
            coefficients: model.coefficients().to_vec(),
            source: ColorSource {
                rig: rig.into(),
                plan: plan.name.clone(),
                seed,
                charts: plan.charts.clone(),
                fit_patches: self.patches.iter().filter(|p| p.fit && p.status.is_valid()).count(),
                held_out_patches: self.patches.iter().filter(|p| !p.fit && p.status.is_valid()).count(),
                excluded_patches: self
                    .patches
                    .iter()
                    .filter(|p| !p.status.is_valid())
                    .map(|p| format!("{} {}: {}", p.chart, p.name, describe_status(&p.status)))
                    .collect(),
                references: self.references.clone(),
            },
            statistics: ColorStatistics {
                cv_mean: m.cv.as_ref().map_or(f64::NAN, |s| s.mean),
                held_out_mean: stats.map_or(f64::NAN, |s| s.mean),
                held_out_median: stats.map_or(f64::NAN, |s| s.median),
                held_out_p95: stats.map_or(f64::NAN, |s| s.p95),
                held_out_max: stats.map_or(f64::NAN, |s| s.max),
            },
            candidates: self
                .models
                .iter()
                .map(|r| ColorCandidate {
                    model: r.kind.name().into(),
                    cv_mean: r.cv.as_ref().map_or(f64::NAN, |s| s.mean),
                    held_out_mean: r.held_out.as_ref().map_or(f64::NAN, |s| s.mean),
                    held_out_max: r.held_out.as_ref().map_or(f64::NAN, |s| s.max),
                    fit_ms: r.fit_s * 1e3,
                    error: r.model.as_ref().err().or(r.cv.as_ref().err()).map(|e| e.to_string()).unwrap_or_default(),
                })
                .collect(),
        }
    }
}

/// Words for a patch screening verdict.
pub fn describe_status(s: &PatchStatus) -> String {
    const CH: [&str; 3] = ["red", "green", "blue"];
    match s {
        PatchStatus::Valid => "ok".into(),
        PatchStatus::NonFinite { channel } => format!("{} channel not finite", CH[*channel]),
        PatchStatus::Clipped { channel, value } => {
            format!("{} channel clipped ({value:.3} of full scale): excluded", CH[*channel])
        }
        PatchStatus::Dark { max } => format!("too dark ({max:.4} of full scale): excluded"),
    }
}

/// Where a colour calibration came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorSource {
    /// Rig config name.
    pub rig: String,
    /// Plan name.
    pub plan: String,
    /// Noise seed of the captures.
    pub seed: u64,
    /// The charts and their held-out patches.
    pub charts: Vec<ChartUse>,
    /// Patches fitted.
    pub fit_patches: usize,
    /// Patches evaluated, not fitted.
    pub held_out_patches: usize,
    /// Patches excluded by screening, with the reason.
    #[serde(default)]
    pub excluded_patches: Vec<String>,
    /// Per chart: where its reference colours came from (published or measured values, and
    /// which).
    #[serde(default)]
    pub references: Vec<String>,
}

/// The chosen model's CIEDE2000 figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorStatistics {
    /// Cross-validated mean on the fitting patches.
    pub cv_mean: f64,
    /// Mean on held-out patches.
    pub held_out_mean: f64,
    /// Median on held-out patches.
    pub held_out_median: f64,
    /// 95th percentile on held-out patches.
    pub held_out_p95: f64,
    /// Maximum on held-out patches.
    pub held_out_max: f64,
}

/// One candidate's figures in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorCandidate {
    /// Model name.
    pub model: String,
    /// Cross-validated mean ΔE00 (NaN: failed).
    pub cv_mean: f64,
    /// Held-out mean ΔE00.
    pub held_out_mean: f64,
    /// Held-out max ΔE00.
    pub held_out_max: f64,
    /// Fit time, milliseconds.
    pub fit_ms: f64,
    /// Why it failed, empty if it did not.
    #[serde(default)]
    pub error: String,
}

/// A colour calibration file (`calibration/*-color.toml`, format in `docs/color.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorCalibrationFile {
    /// Format version ([`COLOR_FILE_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Model name (`linear`, `rootpoly2`, ...).
    pub model: String,
    /// What the model takes (documentation).
    pub input: String,
    /// What the model gives (documentation).
    pub output: String,
    /// Per-channel multipliers applied to camera RGB before the model.
    pub white_balance: [f64; 3],
    /// Term names, in coefficient order (documentation; checked against the model).
    pub terms: Vec<String>,
    /// One row per term, one column per output channel.
    pub coefficients: Vec<[f64; 3]>,
    /// Provenance.
    pub source: ColorSource,
    /// The chosen model's figures.
    pub statistics: ColorStatistics,
    /// Every candidate's figures.
    #[serde(default)]
    pub candidates: Vec<ColorCandidate>,
}

impl ColorCalibrationFile {
    /// Parses and checks a file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<ColorCalibrationFile, RigCalibError> {
        let err = |message: String| RigCalibError::Plan { origin: origin.into(), message };
        let f: ColorCalibrationFile = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if f.format_version != COLOR_FILE_FORMAT_VERSION {
            return Err(err(format!(
                "format_version = {} is not supported (this build reads {COLOR_FILE_FORMAT_VERSION})",
                f.format_version
            )));
        }
        if let Some((i, v)) = f.white_balance.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
            return Err(err(format!("white_balance[{i}] = {v}: must be finite and > 0")));
        }
        f.to_model().map_err(|e| err(e.to_string()))?;
        Ok(f)
    }

    /// The TOML text (with a comment header).
    pub fn to_toml(&self) -> String {
        format!(
            "# Colour calibration (format: docs/color.md), written by `btfrig calibrate color`.\n\
             # output = model(white_balance * camera RGB radiance factor), model terms below.\n{}",
            toml::to_string(self).expect("serialisable")
        )
    }

    /// The model.
    pub fn to_model(&self) -> Result<ColorModel, ColorError> {
        let kind: ModelKind = self.model.parse()?;
        let names: Vec<&str> = kind.term_names().to_vec();
        if self.terms.iter().map(String::as_str).ne(names.iter().copied()) {
            return Err(ColorError::WrongTermCount { model: kind, expected: names.len(), got: self.terms.len() });
        }
        ColorModel::from_coefficients(kind, self.coefficients.clone())
    }
}

/// The colour correction a run processes textures with: the file the rig config's `[camera]
/// color_calibration` names (`builtin:NAME` or a path relative to the rig file), or `None`.
pub fn processing_color(
    rig: &RigConfig,
    rig_path: Option<&Path>,
) -> Result<Option<ColorCalibrationFile>, RigCalibError> {
    let Some(reference) = rig.camera.color_calibration.as_deref() else { return Ok(None) };
    let err = |message: String| RigCalibError::Reference { reference: reference.into(), message };
    let (text, origin) = if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, text) = BUILTIN_COLOR_CALIBRATIONS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_COLOR_CALIBRATIONS.iter().map(|(n, _)| *n).collect();
            err(format!("no built-in colour calibration {name:?} (built in: {})", known.join(", ")))
        })?;
        (text.to_string(), format!("<embedded calibration/{name}.toml>"))
    } else {
        let base = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
        let path = base.join(reference);
        let text = std::fs::read_to_string(&path).map_err(|e| err(format!("cannot read {}: {e}", path.display())))?;
        (text, path.display().to_string())
    };
    ColorCalibrationFile::from_toml(&text, &origin).map(Some).map_err(|e| err(e.to_string()))
}

/// A captured chart frame with the pose it was taken at.
struct ChartShot {
    chart: ChartLayout,
    raw: RawFrame,
    nominal: ScenePose,
}

/// Which frame [`calibrate_color`] asks a [`ChartCamera`] for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChartFrame {
    /// The metering shot of the plan's first chart, at [`ChartCamera::metering_exposure_s`].
    Metering,
    /// The capture of the plan's chart of this index, at the metered exposure.
    Chart(usize),
}

/// The rig side of a colour calibration: photographs the plan's charts, each mounted in the
/// sample region of the holder plate, with the lamp on.
pub trait ChartCamera {
    /// Exposure of the metering shot, seconds: a first guess that keeps the chart's white
    /// below full scale (the procedure rescales from what it measures).
    fn metering_exposure_s(&self) -> f64;
    /// A raw frame of `frame` with the goniometer at `joints`, exposure `exposure_s` at gain 1.
    fn capture(&mut self, frame: ChartFrame, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String>;
}

/// What a colour calibration knows besides its frames: the charts' reference colours and the
/// lamp's level (from the light calibration on a real rig).
#[derive(Debug, Clone, PartialEq)]
pub struct ChartReferences {
    /// Per chart of the plan, per patch: the reference colour at full illumination (linear
    /// sRGB, D65, adapted from the lamp white; a real rig computes it from the chart maker's
    /// data and the lamp's white).
    pub patches: Vec<Vec<[f64; 3]>>,
    /// Signal rate of a white Lambertian reflector facing the lamp along its normal at the
    /// nominal lamp distance, e-/s per photosite at gain 1 (the light calibration's green
    /// `white_rate_e_per_s`): the radiance factor's unit.
    pub white_rate_e_per_s: f64,
    /// Per chart: where its reference colours came from (written into the calibration file).
    pub provenance: Vec<String>,
}

/// Where a chart's reference colours come from: the chart maker's published values
/// (`btfrig_color::chart`, from `shared/data/colorchecker*_lab_d50.csv`: X-Rite's 2016 CIE
/// L*a*b* under ICC D50) or a file of the chart measured with a spectrophotometer.
#[derive(Debug, Clone, PartialEq)]
pub enum ReferenceValues {
    /// The published values of the chart's edition.
    Published,
    /// Measured values: the file's name and, per patch in chart order, CIE L*a*b* (D50).
    Measured {
        /// The file, for the calibration file's provenance.
        origin: String,
        /// One per patch.
        lab_d50: Vec<[f64; 3]>,
    },
}

impl ReferenceValues {
    /// Reads a measured reference file for `chart`: CSV, `#` comment lines, a header line
    /// naming the columns, of which `L`, `a` and `b` (CIE L*a*b*, D50 white) are used; one
    /// row per patch in the chart's order (as `shared/data/colorcheckersg140_lab_d50.csv`).
    pub fn measured_from_csv(text: &str, origin: &str, chart: &str) -> Result<ReferenceValues, RigCalibError> {
        let err = |message: String| RigCalibError::Plan { origin: origin.into(), message };
        let layout = ChartLayout::by_name(chart).map_err(|e| err(e.to_string()))?;
        let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'));
        let (_, header) = lines.next().ok_or_else(|| err("no header line (columns L, a, b needed)".into()))?;
        let cols: Vec<&str> = header.split(',').map(str::trim).collect();
        let col = |n: &str| {
            cols.iter().position(|c| *c == n).ok_or_else(|| {
                err(format!("header {header:?} has no column {n:?} (needed: L, a, b: CIE L*a*b* under D50)"))
            })
        };
        let (cl, ca, cb) = (col("L")?, col("a")?, col("b")?);
        let mut lab_d50 = Vec::new();
        for (i, line) in lines {
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            let mut v = [0.0; 3];
            for (k, c) in [cl, ca, cb].into_iter().enumerate() {
                v[k] = f.get(c).and_then(|x| x.parse::<f64>().ok()).filter(|x| x.is_finite()).ok_or_else(|| {
                    err(format!("line {}: column {} is not a number: {line:?}", i + 1, ["L", "a", "b"][k]))
                })?;
            }
            if !(0.0..=100.0).contains(&v[0]) {
                return Err(err(format!("line {}: L = {}: allowed 0..=100", i + 1, v[0])));
            }
            lab_d50.push(v);
        }
        if lab_d50.len() != layout.patches.len() {
            return Err(err(format!(
                "{} patch rows, chart {chart} has {} patches (one row per patch, in chart order)",
                lab_d50.len(),
                layout.patches.len()
            )));
        }
        Ok(ReferenceValues::Measured { origin: origin.into(), lab_d50 })
    }

    /// The values' provenance, for the calibration file.
    pub fn describe(&self, chart: &str) -> String {
        match self {
            ReferenceValues::Published => {
                let edition = ChartLayout::by_name(chart).map(|l| l.edition).unwrap_or_default();
                format!("{chart}: published CIE L*a*b* (D50) of {edition} (shared/data/*_lab_d50.csv)")
            }
            ReferenceValues::Measured { origin, .. } => format!("{chart}: measured CIE L*a*b* (D50) from {origin}"),
        }
    }

    /// Per patch of `chart`: the reference colour as linear sRGB (D65) radiance factor,
    /// Bradford-adapted from D50, the output space of the colour models.
    pub fn linear_srgb(&self, chart: &str) -> Result<Vec<[f64; 3]>, RigCalibError> {
        use btfrig_color::space::{bradford, d65_white, lab_to_xyz, mat3_apply, mat3_mul, xyz_to_srgb_matrix};
        let labs: Vec<[f64; 3]> = match self {
            ReferenceValues::Published => {
                ChartLayout::by_name(chart).map_err(RigCalibError::Rig)?.patches.iter().map(|p| p.lab_d50).collect()
            }
            ReferenceValues::Measured { lab_d50, .. } => lab_d50.clone(),
        };
        // ICC D50, as the published data.
        let d50 = [0.9642, 1.0, 0.8249];
        let m = mat3_mul(&xyz_to_srgb_matrix(), &bradford(d50, d65_white()));
        Ok(labs.iter().map(|lab| mat3_apply(&m, lab_to_xyz(*lab, d50))).collect())
    }
}

/// Runs `plan` on a rig: `rig` photographs a metering shot of the first chart, then every
/// chart at the exposure that puts the brightest patch at `plan.exposure_fraction` of full
/// scale (times `exposure_scale`, 1 normally; stress tests over- or under-expose); each frame
/// is registered and rectified with `camera` (the processing camera, e.g.
/// [`crate::processing_camera`]) at the pose of the rig config's nominal kinematics, its patches
/// measured against `references`, and every candidate model fitted and evaluated.
/// `progress` receives one line per stage.
#[allow(clippy::too_many_arguments)]
pub fn calibrate_color(
    cfg: &RigConfig,
    camera: &CameraModel,
    plan: &ColorPlan,
    references: &ChartReferences,
    exposure_scale: f64,
    rig: &mut dyn ChartCamera,
    mut progress: impl FnMut(&str),
) -> Result<ColorCalibration, RigCalibError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(RigCalibError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let rig_err = |e: String| RigCalibError::Rig(e);
    let charts: Vec<ChartLayout> =
        plan.charts.iter().map(|c| ChartLayout::by_name(&c.name)).collect::<Result<_, _>>().map_err(rig_err)?;
    let counts: Vec<usize> = references.patches.iter().map(Vec::len).collect();
    let want: Vec<usize> = charts.iter().map(|c| c.patches.len()).collect();
    if counts != want {
        return Err(rig_err(format!(
            "chart references: patches per chart {counts:?}, the plan's charts have {want:?}"
        )));
    }
    if !(references.white_rate_e_per_s.is_finite() && references.white_rate_e_per_s > 0.0) {
        return Err(rig_err(format!(
            "chart references: white_rate_e_per_s = {}: allowed finite and > 0",
            references.white_rate_e_per_s
        )));
    }
    let gonio = Gonio::new(cfg.geometry.clone()).map_err(|e| rig_err(e.to_string()))?;
    let view = Direction::from_degrees(plan.view_theta_deg, plan.view_phi_deg);
    let light = Direction::from_degrees(plan.light_theta_deg, plan.light_phi_deg);

    // 1. Capture: a metering shot of the fitting chart, then every chart at the exposure that
    // puts the brightest patch at `exposure_fraction` of full scale.
    let t = Instant::now();
    let joints = gonio.ik(light, view).map_err(|e| rig_err(format!("chart view unreachable: {e}")))?;
    let nominal = gonio.scene_pose(&joints);
    let meter_exposure = rig.metering_exposure_s();
    let meter = rig
        .capture(ChartFrame::Metering, &joints, meter_exposure)
        .map_err(|e| rig_err(format!("metering capture: {e}")))?;
    let registrar = PlateRegistrar::new(camera.clone(), &cfg.plate, Default::default())
        .map_err(|e| rig_err(format!("registrar: {e}")))?;
    let irradiance = references.white_rate_e_per_s;
    let m = measure(irradiance, &charts[0], &meter, &nominal, camera, &registrar, cfg, plan, [1.0; 3])?;
    let brightest = m.iter().map(|p| p.peak_raw_mean).fold(0.0, f64::max);
    if !(brightest > 1e-4) {
        return Err(rig_err(format!(
            "metering shot: brightest patch at {brightest:.2e} of full scale; is the lamp on?"
        )));
    }
    let exposure_s = (meter_exposure * plan.exposure_fraction / brightest * exposure_scale).clamp(1e-4, 30.0);
    progress(&format!(
        "metering: brightest patch at {:.3} of full scale in {:.4} s; exposure {:.4} s",
        brightest, meter_exposure, exposure_s
    ));
    let mut shots = Vec::new();
    for (i, chart) in charts.into_iter().enumerate() {
        let raw =
            rig.capture(ChartFrame::Chart(i), &joints, exposure_s).map_err(|e| rig_err(format!("capture: {e}")))?;
        shots.push(ChartShot { chart, raw, nominal });
    }
    let render_s = t.elapsed().as_secs_f64();
    progress(&format!("captured {} chart(s) in {render_s:.1} s", shots.len()));

    // 2. Measure: the fitting chart first without white balance, to find it.
    let t = Instant::now();
    let fit_raw = measure(
        irradiance,
        &shots[0].chart,
        &shots[0].raw,
        &shots[0].nominal,
        camera,
        &registrar,
        cfg,
        plan,
        [1.0; 3],
    )?;
    let white_balance = white_balance_from(&fit_raw, &references.patches[0])?;
    let mut patches = Vec::new();
    for (ci, shot) in shots.iter().enumerate() {
        let raw =
            measure(irradiance, &shot.chart, &shot.raw, &shot.nominal, camera, &registrar, cfg, plan, white_balance)?;
        for (k, r) in raw.into_iter().enumerate() {
            let reference = references.patches[ci][k];
            patches.push(PatchMeasurement {
                chart: shot.chart.name.clone(),
                index: k,
                name: shot.chart.patches[k].name.clone(),
                camera: r.camera,
                target: reference.map(|v| v * r.geometry),
                reference,
                geometry: r.geometry,
                texels: r.texels,
                status: r.status,
                fit: !plan.charts[ci].held_out(k),
            });
        }
    }
    let measure_s = t.elapsed().as_secs_f64();
    for p in patches.iter().filter(|p| !p.status.is_valid()) {
        progress(&format!("{} patch {} ({}): {}", p.chart, p.index + 1, p.name, describe_status(&p.status)));
    }

    // 3. Fit and evaluate.
    let fit: Vec<&PatchMeasurement> = patches.iter().filter(|p| p.fit && p.status.is_valid()).collect();
    let held: Vec<&PatchMeasurement> = patches.iter().filter(|p| !p.fit && p.status.is_valid()).collect();
    progress(&format!("{} fitting patches, {} held-out patches", fit.len(), held.len()));
    let cam: Vec<[f64; 3]> = fit.iter().map(|p| p.camera).collect();
    let tgt: Vec<[f64; 3]> = fit.iter().map(|p| p.target).collect();
    let options = FitOptions { ridge: plan.ridge, ..FitOptions::default() };
    let kinds = plan.model_kinds();
    let folds = plan.folds.min(cam.len().max(2));
    let selection = select_model(&kinds, &cam, &tgt, None, &options, TargetSpace::LinearSrgb, folds);
    let mut models = Vec::new();
    for r in selection.reports {
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let t = Instant::now();
                let _ = ColorModel::fit(r.kind, &cam, &tgt, None, &options);
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let held_out = r.model.as_ref().map_err(Clone::clone).and_then(|m| held_out_stats(m, &held));
        let apply_s_per_mpix = r.model.as_ref().map_or(f64::NAN, apply_time_per_mpix);
        models.push(ModelResult {
            kind: r.kind,
            cv: r.cv,
            held_out,
            fit_s: times[2],
            apply_s_per_mpix,
            model: r.model,
        });
    }
    let chosen = selection.chosen.ok_or_else(|| {
        let first = models
            .iter()
            .find_map(|m| m.model.as_ref().err().or(m.cv.as_ref().err()))
            .map_or_else(|| "no candidate".to_string(), |e| e.to_string());
        rig_err(format!("no colour model could be fitted on {} patches: {first}", fit.len()))
    })?;
    Ok(ColorCalibration {
        patches,
        white_balance,
        models,
        chosen,
        exposure_s,
        render_s,
        measure_s,
        references: references.provenance.clone(),
    })
}

/// CIEDE2000 of held-out patches, each compared at full illumination (model output and
/// target divided by the patch's illumination factor), so the figure is the chart's colour
/// error whatever the light's angle.
fn held_out_stats(model: &ColorModel, held: &[&PatchMeasurement]) -> Result<DeltaEStats, ColorError> {
    if held.is_empty() {
        return Err(ColorError::Empty);
    }
    let cam: Vec<[f64; 3]> = held.iter().map(|p| p.camera.map(|v| v / p.geometry)).collect();
    let tgt: Vec<[f64; 3]> = held.iter().map(|p| p.reference).collect();
    // Homogeneous models are unaffected by the division; polynomial ones are evaluated at the
    // scale they were fitted at, then divided.
    if model.kind().exposure_invariant() {
        evaluate(model, &cam, &tgt, TargetSpace::LinearSrgb)
    } else {
        let per: Vec<f64> = held
            .iter()
            .map(|p| {
                let o = model.apply(p.camera).map(|v| v / p.geometry);
                TargetSpace::LinearSrgb.delta_e_2000(o, p.reference)
            })
            .collect();
        DeltaEStats::from_values(per)
    }
}

fn apply_time_per_mpix(model: &ColorModel) -> f64 {
    let mut buf: Vec<[f32; 3]> =
        (0..1 << 16).map(|i| [(i % 251) as f32 / 251.0, 0.5, (i % 13) as f32 / 13.0]).collect();
    let t = Instant::now();
    model.apply_f32(&mut buf);
    t.elapsed().as_secs_f64() * 1e6 / buf.len() as f64
}

/// White balance from the first chart's measured patches: the brightest unclipped patch
/// whose reference colour is neutral (channels within 10%: the chart's white) is made grey,
/// green unchanged.
fn white_balance_from(m: &[RawPatch], references: &[[f64; 3]]) -> Result<[f64; 3], RigCalibError> {
    let neutral = m
        .iter()
        .zip(references)
        .filter(|(p, r)| {
            let lo = r.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = r.iter().cloned().fold(0.0, f64::max);
            p.status.is_valid() && p.camera.iter().all(|v| *v > 0.0) && lo > 0.0 && hi / lo < 1.1
        })
        .max_by(|a, b| a.1[1].total_cmp(&b.1[1]))
        .map(|(p, _)| p)
        .ok_or_else(|| {
            RigCalibError::Rig("no unclipped, measurable neutral patch on the first chart for the white balance".into())
        })?;
    Ok([neutral.camera[1] / neutral.camera[0], 1.0, neutral.camera[1] / neutral.camera[2]])
}

struct RawPatch {
    camera: [f64; 3],
    geometry: f64,
    texels: usize,
    status: PatchStatus,
    /// Largest channel of the patch's mean demosaiced value (full scale 1).
    peak_raw_mean: f64,
}

/// Registers, rectifies and converts one chart frame; per patch the interior mean of the
/// camera RGB radiance factor (white balance `wb`, identity matrix, `white_rate_e_per_s` the
/// unit, see [`ChartReferences`]), screening verdict and illumination factor.
#[allow(clippy::too_many_arguments)]
fn measure(
    white_rate_e_per_s: f64,
    chart: &ChartLayout,
    raw: &RawFrame,
    nominal: &ScenePose,
    camera: &CameraModel,
    registrar: &PlateRegistrar,
    cfg: &RigConfig,
    plan: &ColorPlan,
    wb: [f64; 3],
) -> Result<Vec<RawPatch>, RigCalibError> {
    let rig = |e: String| RigCalibError::Rig(e);
    let dm = demosaic_bilinear(raw);
    let image = LinearImage { width: dm.width, height: dm.height, data: dm.data };
    let green: Vec<f32> = image.data.iter().map(|p| p[1]).collect();
    let gray = GrayImage::new(image.width, image.height, &green).map_err(|e| rig(e.to_string()))?;
    let pose = registrar
        .register_image(&gray, nominal)
        .map_err(|e| rig(format!("chart {}: registration failed: {e}", chart.name)))?
        .registration
        .pose;
    let region = Region::centred_square(cfg.plate.sample_side_m);
    let n = plan.texels;
    let tex =
        rectify(&image, camera, &pose, region, n, Filter::Supersample { n: 2 }).map_err(|e| rig(e.to_string()))?;
    let vig = vignetting_map(camera, &pose, region, n).map_err(|e| rig(e.to_string()))?;
    // The same parameters as the pipeline's `Processor::radiometry` (the rig config's sensor
    // constants, the lamp's nominal irradiance), with a white balance measured here and no matrix.
    let sensor = &cfg.sensor;
    let radiometry = Radiometry {
        dn_range: (f64::from(raw.meta.white_level) - f64::from(raw.meta.black_level)).max(1.0),
        exposure_s: raw.meta.exposure_s,
        dn_per_electron: raw.meta.gain.max(1.0) / sensor.electrons_per_dn,
        dark_e_per_s: sensor.dark_current_e_per_s,
        nominal_irradiance: white_rate_e_per_s,
        white_balance: wb,
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    let rf = to_radiance_factor(&tex, &vig, &radiometry).map_err(|e| rig(e.to_string()))?;
    let texel = cfg.plate.sample_side_m / n as f64;
    let half_in = chart.patch_side_m() / 2.0 * (1.0 - 2.0 * plan.patch_margin);
    let lamp = Vector3::from(pose.lamp_position.coords);
    let normal = pose.sample_to_world.rotation * Vector3::z();
    let d0 = cfg.geometry.lamp_distance_m;
    let options = ScreenOptions::default();
    let mut out = Vec::with_capacity(chart.patches.len());
    for k in 0..chart.patches.len() {
        let [cx, cy] = chart.patch_centre_m(k);
        let (mut sum, mut sum_raw, mut peak, mut count) = ([0.0f64; 3], [0.0f64; 3], [f64::NEG_INFINITY; 3], 0usize);
        let c0 = (((cx - half_in - region.x_min) / texel).ceil().max(0.0)) as usize;
        let c1 = (((cx + half_in - region.x_min) / texel).floor().max(0.0) as usize).min(n);
        let r0 = (((region.y_max - (cy + half_in)) / texel).ceil().max(0.0)) as usize;
        let r1 = (((region.y_max - (cy - half_in)) / texel).floor().max(0.0) as usize).min(n);
        for row in r0..r1 {
            for col in c0..c1 {
                let i = row * n + col;
                if vig[i] <= 0.0 {
                    continue;
                }
                for ch in 0..3 {
                    sum[ch] += f64::from(rf.data[i][ch]);
                    sum_raw[ch] += f64::from(tex.data[i][ch]);
                    peak[ch] = peak[ch].max(f64::from(tex.data[i][ch]));
                }
                count += 1;
            }
        }
        if count == 0 {
            return Err(rig(format!(
                "chart {} patch {} ({}): no texels inside the image (chart not in view?)",
                chart.name,
                k + 1,
                chart.patches[k].name
            )));
        }
        let mean = sum.map(|s| s / count as f64);
        let mean_raw = sum_raw.map(|s| s / count as f64);
        let status = btfrig_color::screen_patches(&[mean_raw], Some(&[peak]), &options)[0];
        // Illumination factor at the patch centre (registered pose, lamp of the kinematics).
        let p = pose.sample_to_world * Point3::new(cx, cy, 0.0);
        let to_lamp = lamp - p.coords;
        let d = to_lamp.norm();
        let geometry = (normal.dot(&to_lamp) / d).max(0.0) * (d0 / d).powi(2);
        out.push(RawPatch {
            camera: mean,
            geometry,
            texels: count,
            status,
            peak_raw_mean: mean_raw.iter().cloned().fold(0.0, f64::max),
        });
    }
    Ok(out)
}

/// Names of the built-in charts (for messages).
pub fn chart_names() -> &'static [&'static str] {
    &CHART_NAMES
}
