//! Looking at a measurement: what the viewer, the coverage plot and `btfrig dataset report`
//! read from a dataset and its compressed models. The CLI uses the same functions
//! (`btfrig dataset render`, `btfrig dataset report`), so the page, the API and the command
//! line show the same numbers.
//!
//! * [`render`]: `btfrig`'s own evaluation of a model at a (light, view) pair
//!   ([`btfrig_compress::Model::query`]: the angular factors interpolated barycentrically over
//!   the samplings' triangulations), and its display as 8-bit sRGB ([`display_scale`]).
//! * [`ViewerData`]: a model as the browser's WebGL2 renderer takes it (a JSON header, then
//!   little-endian f32 blocks, streamed in pieces): the samplings and their triangles (the
//!   page interpolates exactly as [`btfrig_core::sampling::Sampling::interpolate`] does), the
//!   angular factors, and the texel coefficients as RGBA layers of a texture array.
//! * [`coverage`]: every (light, view) pair of a gonio dataset, measured or skipped and why.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use btfrig_compress::{Model, PartRows};
use btfrig_core::Direction;
use serde::Serialize;

/// Magic bytes that open the viewer's binary model data.
pub const VIEWER_MAGIC: &[u8; 8] = b"BTFVIEW1";

/// A model's texture at (light, view), linear RGB, row-major: `btfrig`'s own evaluation.
pub fn render(model: &Model, light: Direction, view: Direction) -> Vec<[f32; 3]> {
    model.query(view, light).texture()
}

/// The scale that maps a model's linear values to the display: 0.9 over the 99th percentile
/// of the brightest channel at normal light and view (1 when that texture is black), so the
/// viewer, the API's render and `btfrig dataset render --png` start from the same exposure.
pub fn display_scale(model: &Model) -> f32 {
    let t = render(model, Direction::new(0.0, 0.0), Direction::new(0.0, 0.0));
    let mut m: Vec<f32> = t.iter().map(|p| p[0].max(p[1]).max(p[2])).filter(|v| v.is_finite()).collect();
    if m.is_empty() {
        return 1.0;
    }
    let k = ((m.len() - 1) as f64 * 0.99).round() as usize;
    let (_, p99, _) = m.select_nth_unstable_by(k, f32::total_cmp);
    if *p99 > 0.0 {
        0.9 / *p99
    } else {
        1.0
    }
}

/// 8-bit sRGB (`RGBRGB...`) of a linear texture times `scale`, values beyond 1 clipped (the
/// viewer's shader applies the same curve).
pub fn srgb8(texture: &[[f32; 3]], scale: f32) -> Vec<u8> {
    btfrig_imageio::linear_to_srgb8(texture, scale)
}

/// The model files of dataset `name` in `dir` (`<name>.<method>.btfm` beside it), by the
/// `<method>` part of their names.
pub fn models_of(dir: &Path, name: &str) -> Vec<String> {
    let ext = format!(".{}", btfrig_compress::file::EXTENSION);
    let prefix = format!("{name}.");
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter_map(|e| {
            let f = e.file_name().to_string_lossy().into_owned();
            let m = f.strip_prefix(&prefix)?.strip_suffix(&ext)?;
            check_model_name(m).is_ok().then(|| m.to_string())
        })
        .collect();
    v.sort();
    v
}

/// A model's name (the `<method>` of `<dataset>.<method>.btfm`): 1 to 40 ASCII letters,
/// digits, `-` and `_`.
pub fn check_model_name(m: &str) -> Result<(), String> {
    if (1..=40).contains(&m.len()) && m.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_') {
        Ok(())
    } else {
        Err(format!(
            "model name {m:?}: use 1 to 40 ASCII letters, digits, '-' and '_' (the <method> of <dataset>.<method>.btfm)"
        ))
    }
}

/// The model file of dataset `name`'s model `method` in `dir`.
pub fn model_file(dir: &Path, name: &str, method: &str) -> PathBuf {
    dir.join(format!("{name}.{method}.{}", btfrig_compress::file::EXTENSION))
}

/// A sampling as the page interpolates over it.
#[derive(Debug, Clone, Serialize)]
pub struct SamplingData {
    /// `[theta, phi]` of each direction, radians.
    pub dirs: Vec<[f64; 2]>,
    /// The interpolation triangles (sample-index triples, in the order
    /// [`btfrig_core::sampling::Sampling::interpolate`] searches them).
    pub tris: Vec<[usize; 3]>,
}

impl SamplingData {
    fn of(s: &btfrig_core::sampling::Sampling) -> Self {
        SamplingData { dirs: s.directions().iter().map(|d| [d.theta, d.phi]).collect(), tris: s.triangles() }
    }
}

/// One block of f32 values in the binary data.
#[derive(Debug, Clone, Serialize)]
pub struct Block {
    /// `coef`, `angular` or `cluster`.
    pub name: &'static str,
    /// Offset from the start of the data (after the header), in f32 values.
    pub offset: usize,
    /// Length in f32 values.
    pub floats: usize,
}

/// The JSON header of the viewer's binary model data (docs/http-api.md, "viewer data").
#[derive(Debug, Clone, Serialize)]
pub struct ViewerHeader {
    /// `fmf`, `pvmf`, `pcmf`.
    pub method: &'static str,
    /// With parameters (`pcmf-32`).
    pub label: String,
    /// Colour model of the channels: `rgb`, `yuv`, `ylog-uv`.
    pub color: &'static str,
    /// `eps` of the log colour model.
    pub log_eps: f32,
    /// Texture width, texels.
    pub width: usize,
    /// Texture height, texels.
    pub height: usize,
    /// Terms per part, the largest over channels and parts (shorter parts are padded with 0).
    pub terms: usize,
    /// RGBA layers per channel and coefficient part: `ceil(terms / 4)`.
    pub quads: usize,
    /// Parts per channel (1 FMF, views for PVMF, clusters for PCMF).
    pub parts: usize,
    /// `all` (a part covers every angular row: FMF, PCMF) or `view` (PVMF: part p covers
    /// the lights of view p, and every part has its own coefficients).
    pub part_rows: &'static str,
    /// Coefficient parts in `coef` (1, or the views of a PVMF).
    pub coef_parts: usize,
    /// Light sampling.
    pub light: SamplingData,
    /// View sampling.
    pub view: SamplingData,
    /// Per angular index `view * n_light + light`: 1 measured, 0 filled by interpolation.
    pub measured: Vec<u8>,
    /// A dome's per-capture (light, view) directions, `[theta, phi]` radians per angular
    /// index: the page then takes the nearest measured capture, as `Model::query` does.
    pub captures: Option<[Vec<[f64; 2]>; 2]>,
    /// [`display_scale`].
    pub display_scale: f32,
    /// The f32 blocks after the header, in order: `angular` (per channel, per part, per part
    /// row: mean then `terms` basis values), `cluster` (per texel its part, PCMF; else 0),
    /// `coef` (layer `(coef_part * 3 + channel) * quads + q`, each `height x width x 4`).
    pub blocks: Vec<Block>,
}

/// A model prepared for the browser.
pub struct ViewerData {
    model: std::sync::Arc<Model>,
    header: ViewerHeader,
}

impl ViewerData {
    /// Prepares `model`'s header (the values follow in [`ViewerData::chunks`]).
    pub fn new(model: std::sync::Arc<Model>) -> Self {
        let m = &*model;
        let lay = &m.layout;
        let terms = m.channels.iter().flat_map(|c| c.parts.iter().map(|p| p.k)).max().unwrap_or(0).max(1);
        let quads = terms.div_ceil(4);
        let parts = m.channels.first().map_or(0, |c| c.parts.len());
        let pvmf = m.channels.iter().flat_map(|c| &c.parts).any(|p| matches!(p.rows, PartRows::View(_)));
        let coef_parts = if pvmf { parts } else { 1 };
        let texels = lay.texels();
        let angular: usize = 3 * m.channels[0].parts.iter().map(|p| p.n_rows()).sum::<usize>() * (1 + terms);
        let blocks = vec![
            Block { name: "angular", offset: 0, floats: angular },
            Block { name: "cluster", offset: angular, floats: texels },
            Block { name: "coef", offset: angular + texels, floats: coef_parts * 3 * quads * texels * 4 },
        ];
        let header = ViewerHeader {
            method: m.method.name(),
            label: m.method.label(),
            color: m.color.name(),
            log_eps: m.log_eps,
            width: lay.width,
            height: lay.height,
            terms,
            quads,
            parts,
            part_rows: if pvmf { "view" } else { "all" },
            coef_parts,
            light: SamplingData::of(&lay.light),
            view: SamplingData::of(&lay.view),
            measured: lay.measured.iter().map(|&b| u8::from(b)).collect(),
            captures: lay.captures.as_ref().map(|c| {
                [c.light.iter().map(|d| [d.theta, d.phi]).collect(), c.view.iter().map(|d| [d.theta, d.phi]).collect()]
            }),
            display_scale: display_scale(m),
            blocks,
        };
        ViewerData { model, header }
    }

    /// The header.
    pub fn header(&self) -> &ViewerHeader {
        &self.header
    }

    /// Bytes in all: magic, header length (u32 LE), header, padding to 4 bytes, values.
    pub fn len(&self) -> u64 {
        let h = self.header_bytes().len() as u64;
        let floats: usize = self.header.blocks.iter().map(|b| b.floats).sum();
        h + 4 * floats as u64
    }

    /// Never empty (the header is there).
    pub fn is_empty(&self) -> bool {
        false
    }

    fn header_bytes(&self) -> Vec<u8> {
        let mut json = serde_json::to_vec(&self.header).expect("the header serialises");
        while (VIEWER_MAGIC.len() + 4 + json.len()) % 4 != 0 {
            json.push(b' ');
        }
        let mut out = Vec::with_capacity(12 + json.len());
        out.extend_from_slice(VIEWER_MAGIC);
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(&json);
        out
    }

    /// The data in pieces of at most one texture layer each, made as they are asked for
    /// (so a large model is streamed, not copied whole into a response buffer).
    pub fn chunks(self) -> impl Iterator<Item = Vec<u8>> + Send + 'static {
        let head = self.header_bytes();
        let h = self.header;
        let model = self.model;
        let layers = h.coef_parts * 3 * h.quads;
        let pieces = 3 + layers;
        (0..pieces).map(move |i| match i {
            0 => head.clone(),
            1 => angular_block(&model, h.terms),
            2 => cluster_block(&model),
            _ => coef_layer(&model, &h, i - 3),
        })
    }
}

fn le(values: impl Iterator<Item = f32>) -> Vec<u8> {
    values.flat_map(f32::to_le_bytes).collect()
}

fn angular_block(m: &Model, terms: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for ch in &m.channels {
        for p in &ch.parts {
            for r in 0..p.n_rows() {
                out.push(p.mean[r]);
                out.extend_from_slice(&p.u[r * p.k..(r + 1) * p.k]);
                out.extend(std::iter::repeat_n(0.0, terms - p.k));
            }
        }
    }
    le(out.into_iter())
}

fn cluster_block(m: &Model) -> Vec<u8> {
    let n = m.layout.texels();
    match &m.clusters {
        Some(c) => le(c.iter().map(|&k| f32::from(k))),
        None => le(std::iter::repeat_n(0.0, n)),
    }
}

/// Layer `(coef_part * 3 + channel) * quads + q`: per texel the coefficients `4q..4q+4` of
/// its part (PCMF: its cluster's column; PVMF: part `coef_part`).
fn coef_layer(m: &Model, h: &ViewerHeader, layer: usize) -> Vec<u8> {
    let q = layer % h.quads;
    let c = (layer / h.quads) % 3;
    let cp = layer / h.quads / 3;
    let ch = &m.channels[c];
    let n = m.layout.texels();
    let mut out = Vec::with_capacity(n * 16);
    for x in 0..n {
        let (part, col) = match &m.clusters {
            Some(cl) => (&ch.parts[cl[x] as usize], m.cluster_col[x] as usize),
            None => (&ch.parts[cp], x),
        };
        let k = part.k;
        let row = &part.sv[col * k..(col + 1) * k];
        for j in 4 * q..4 * q + 4 {
            out.extend_from_slice(&row.get(j).copied().unwrap_or(0.0).to_le_bytes());
        }
    }
    out
}

/// One (light, view) pair of a dataset and what became of it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct PairState {
    /// Light index (into the manifest's `samplings.light`).
    pub light: u32,
    /// View index.
    pub view: u32,
    /// `measured`, `skipped` or `pending` (planned, not captured yet).
    pub state: String,
    /// Why it was skipped (the report's label: `unreachable:camera blocks lamp`,
    /// `max-captures`, `sparse`, `reciprocal`).
    pub reason: Option<String>,
}

/// The coverage of a dataset's (light, view) pairs.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Coverage {
    /// Light directions, `[theta_deg, phi_deg]`.
    pub light: Vec<[f64; 2]>,
    /// View directions, `[theta_deg, phi_deg]`.
    pub view: Vec<[f64; 2]>,
    /// Every pair, light fastest.
    pub pairs: Vec<PairState>,
    /// Measured pairs (journaled steps).
    pub measured: u64,
    /// Skipped pairs by reason (as `report.json`'s `skipped`).
    pub skipped: BTreeMap<String, u64>,
    /// Pairs planned but not captured yet.
    pub pending: u64,
    /// Where the skip reasons came from, or why they are unknown.
    pub note: String,
}

/// Every (light, view) pair of the gonio dataset in `dir`: measured (journaled), skipped by
/// the plan (reasons from the plan in the manifest, as the run decided them), or pending.
pub fn coverage(dir: &Path) -> Result<Coverage, String> {
    let man_path = dir.join(btfrig_store::MANIFEST_FILE);
    let man: serde_json::Value = std::fs::read(&man_path)
        .map_err(|e| format!("{}: {e}", man_path.display()))
        .and_then(|b| serde_json::from_slice(&b).map_err(|e| format!("{}: {e}", man_path.display())))?;
    let dirs = |k: &str| -> Vec<[f64; 2]> {
        man["samplings"][k]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|d| [d["theta_deg"].as_f64().unwrap_or(f64::NAN), d["phi_deg"].as_f64().unwrap_or(f64::NAN)])
                    .collect()
            })
            .unwrap_or_default()
    };
    let (light, view) = (dirs("light"), dirs("view"));
    if light.is_empty() || view.is_empty() {
        return Err(format!("{}: no samplings.light / samplings.view", man_path.display()));
    }
    let jpath = dir.join(btfrig_store::JOURNAL_FILE);
    let bytes = std::fs::read(&jpath).unwrap_or_default();
    let replay = btfrig_store::journal::replay(&jpath.display().to_string(), &bytes).map_err(|e| e.to_string())?;
    let mut skipped_by: BTreeMap<(u32, u32), String> =
        replay.skipped.iter().map(|(s, r)| ((s.light, s.view), r.clone())).collect();
    let text = man["plan"]["text"].as_str().unwrap_or_default();
    let note = match btfrig_measurement::plan::load_text(text, &dir.join("plan.toml")) {
        Ok((_, v)) if v.light.len() == light.len() && v.view.len() == view.len() => {
            for ((l, vw), r) in v.capture_list().skipped {
                skipped_by.entry((l as u32, vw as u32)).or_insert_with(|| r.label());
            }
            "skip reasons from the plan in the manifest".to_string()
        }
        Ok(_) => "the plan in the manifest gives other samplings: skip reasons unknown".to_string(),
        Err(e) => format!("the plan in the manifest does not load here ({e}): skip reasons unknown"),
    };
    let mut pairs = Vec::with_capacity(light.len() * view.len());
    let (mut measured, mut pending) = (0, 0);
    let mut skipped: BTreeMap<String, u64> = BTreeMap::new();
    for v in 0..view.len() as u32 {
        for l in 0..light.len() as u32 {
            let step = btfrig_store::StepId { light: l, view: v };
            let (state, reason) = if replay.done.contains_key(&step) {
                measured += 1;
                ("measured", None)
            } else if let Some(r) = skipped_by.get(&(l, v)) {
                *skipped.entry(r.clone()).or_default() += 1;
                ("skipped", Some(r.clone()))
            } else {
                pending += 1;
                ("pending", None)
            };
            pairs.push(PairState { light: l, view: v, state: state.into(), reason });
        }
    }
    Ok(Coverage { light, view, pairs, measured, skipped, pending, note })
}

/// A (light, view) pair from `[theta, phi]` in degrees, theta 0 to 90, or why not.
pub fn pair_from_degrees(light: [f64; 2], view: [f64; 2]) -> Result<(Direction, Direction), String> {
    let one = |what: &str, [t, p]: [f64; 2]| {
        if !(t.is_finite() && (0.0..=90.0).contains(&t)) {
            return Err(format!("{what} theta {t}: allowed 0 to 90 degrees"));
        }
        if !p.is_finite() {
            return Err(format!("{what} phi {p}: allowed any finite number of degrees"));
        }
        Ok(Direction::from_degrees(t, p))
    };
    Ok((one("light", light)?, one("view", view)?))
}

/// The model's texture at (light, view) as a file's bytes: 8-bit sRGB PNG at `scale`
/// (default [`display_scale`]), or linear float OpenEXR.
pub fn render_file(
    model: &Model,
    light: Direction,
    view: Direction,
    scale: Option<f32>,
    exr: bool,
) -> Result<Vec<u8>, String> {
    let t = render(model, light, view);
    let (w, h) = (model.layout.width, model.layout.height);
    let name = Path::new("render");
    if exr {
        btfrig_imageio::encode_rgb_exr(name, w, h, &t, btfrig_imageio::ExrPrecision::Float).map_err(|e| e.to_string())
    } else {
        let scale = scale.unwrap_or_else(|| display_scale(model));
        btfrig_imageio::encode_srgb8_png(name, w, h, &srgb8(&t, scale)).map_err(|e| e.to_string())
    }
}

/// The last model read, kept while its file is unchanged (the viewer asks for its data and
/// then renders of the same model).
#[derive(Default)]
pub struct ModelCache {
    last: std::sync::Mutex<Option<CachedModel>>,
}

/// A model with its file, the file's modification time and size.
type CachedModel = (PathBuf, std::time::SystemTime, u64, std::sync::Arc<Model>);

impl ModelCache {
    /// The model in `file`, read unless the cached one has the same path, time and size.
    pub fn get(&self, file: &Path) -> Result<std::sync::Arc<Model>, String> {
        let meta = std::fs::metadata(file).map_err(|e| format!("{}: {e}", file.display()))?;
        let stamp = (meta.modified().unwrap_or(std::time::UNIX_EPOCH), meta.len());
        if let Some((p, t, n, m)) = self.last.lock().map_err(|_| "model cache poisoned".to_string())?.as_ref() {
            if p == file && (*t, *n) == stamp {
                return Ok(m.clone());
            }
        }
        let m = std::sync::Arc::new(btfrig_compress::file::read(file).map_err(|e| e.to_string())?);
        *self.last.lock().map_err(|_| "model cache poisoned".to_string())? =
            Some((file.into(), stamp.0, stamp.1, m.clone()));
        Ok(m)
    }
}

/// Per capture, in journal order: what the report's series plot.
#[derive(Debug, Clone, Serialize)]
pub struct CaptureRow {
    /// Light index.
    pub light: u32,
    /// View index.
    pub view: u32,
    /// Wall time from start to commit, seconds.
    pub wall_s: f64,
    /// Hardware (rig) time, seconds.
    pub hardware_s: Option<f64>,
    /// Seconds per pipeline stage.
    pub stage_s: BTreeMap<String, f64>,
    /// How the pose was found (`markers`, `nominal-fallback`, `nominal-by-plan`).
    pub pose: Option<String>,
    /// RMS reprojection error of the plate's markers, pixels.
    pub rms_px: Option<f64>,
    /// Predicted texel position error (1 sigma), texels.
    pub texel_sigma: Option<f64>,
    /// Exposures of an HDR bracket, seconds.
    pub exposures_s: Option<Vec<f64>>,
}

/// What the report page shows: coverage, the per-capture series and the run's report.
#[derive(Debug, Clone, Serialize)]
pub struct ReportData {
    /// The dataset's directory name.
    pub name: String,
    /// [`coverage`].
    pub coverage: Coverage,
    /// Per capture, in journal order.
    pub captures: Vec<CaptureRow>,
    /// `report.json` as written by the run (null before the run's first report).
    pub report: serde_json::Value,
    /// The compression error per capture of the dataset's model (`fmf` when there is one,
    /// else the first): `(model, errors in capture order)`, or why there is none.
    pub model_errors: Result<(String, Vec<CaptureError>), String>,
}

/// The report page's data for the dataset in `dir`.
pub fn report_data(dir: &Path) -> Result<ReportData, String> {
    let coverage = coverage(dir)?;
    let jpath = dir.join(btfrig_store::JOURNAL_FILE);
    let bytes = std::fs::read(&jpath).unwrap_or_default();
    let replay = btfrig_store::journal::replay(&jpath.display().to_string(), &bytes).map_err(|e| e.to_string())?;
    let mut steps: Vec<_> = replay.done.values().collect();
    steps.sort_by(|a, b| a.timing.started_unix_s.total_cmp(&b.timing.started_unix_s));
    let captures = steps
        .into_iter()
        .map(|s| CaptureRow {
            light: s.step.light,
            view: s.step.view,
            wall_s: s.timing.wall_s,
            hardware_s: s.timing.hardware_s,
            stage_s: s.timing.stage_s.clone(),
            pose: s.registration.as_ref().map(|r| r.pose.as_str().to_string()),
            rms_px: s.registration.as_ref().and_then(|r| r.rms_px),
            texel_sigma: s.registration.as_ref().and_then(|r| r.texel_sigma),
            exposures_s: s.hdr.as_ref().map(|h| h.exposures_s.clone()),
        })
        .collect();
    let report = std::fs::read(dir.join(btfrig_store::REPORT_FILE))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or(serde_json::Value::Null);
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let models = models_of(parent, &name);
    let model_errors = match models.iter().find(|m| *m == "fmf").or(models.first()) {
        None => Err("no compressed model beside the dataset".to_string()),
        Some(m) => btfrig_compress::file::read(&model_file(parent, &name, m))
            .map_err(|e| e.to_string())
            .and_then(|model| capture_errors(dir, &model))
            .map(|e| (m.clone(), e)),
    };
    Ok(ReportData { name, coverage, captures, report, model_errors })
}

/// The plots' script, shared by the operator page (`/ui/plots.js`) and the report file.
pub const PLOTS_JS: &str = include_str!("../ui/plots.js");
/// uPlot 1.6.32 (MIT), vendored unchanged (`ui/vendor/README.md`).
pub const UPLOT_JS: &str = include_str!("../ui/vendor/uPlot.iife.min.js");
/// uPlot's style sheet.
pub const UPLOT_CSS: &str = include_str!("../ui/vendor/uPlot.min.css");

/// The report of the dataset in `dir` as one self-contained HTML file (no network: the
/// script and the data are inline).
pub fn report_html(dir: &Path) -> Result<String, String> {
    let data = report_data(dir)?;
    // `</` may not appear inside a script element.
    let json = serde_json::to_string(&data).map_err(|e| e.to_string())?.replace("</", "<\\/");
    let title = html_escape(&data.name);
    Ok(format!(
        r#"<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>btfrig report: {title}</title>
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; img-src data:">
<style>
body {{ font: 14px system-ui, sans-serif; margin: 1.5em; color: #222; }}
h1 {{ font-size: 1.4em; }} h2 {{ font-size: 1.1em; margin-top: 1.6em; }}
table {{ border-collapse: collapse; }} td, th {{ padding: 2px 8px; text-align: left; border-bottom: 1px solid #ddd; }}
.plot {{ margin: 0.5em 0; }} .legend span {{ display: inline-block; margin-right: 1.2em; }}
.swatch {{ display: inline-block; width: 0.9em; height: 0.9em; vertical-align: middle; margin-right: 0.3em; }}
</style>
<style>{uplot_css}</style></head>
<body>
<h1>btfrig report: {title}</h1>
<table id="summary"></table>
<h2>Coverage: (light, view) pairs</h2>
<div id="coverage" class="plot"></div>
<h2>Registration error per capture</h2>
<div id="registration" class="plot"></div>
<h2>Exposure per capture</h2>
<div id="exposure" class="plot"></div>
<h2>Stage times per capture</h2>
<div id="stages" class="plot"></div>
<h2>Multiplex gain per view group (domes, camera arrays)</h2>
<div id="multiplex-gain" class="plot"></div>
<h2>Compression error per capture</h2>
<div id="compression" class="plot"></div>
<script id="report-data" type="application/json">{json}</script>
<script>{uplot}</script>
<script>{plots}</script>
<script>
const data = JSON.parse(document.getElementById("report-data").textContent);
BtfPlots.report(document, data);
</script>
</body></html>
"#,
        plots = PLOTS_JS.replace("</script", "<\\/script"),
        uplot = UPLOT_JS.replace("</script", "<\\/script"),
        uplot_css = UPLOT_CSS,
    ))
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_compress::{Channel, ColorModel, Layout, Method, Part, Precision};
    use btfrig_core::sampling::{Ring, Sampling};

    /// A 3 x 2 texel FMF over 7 x 7 directions whose values say where they come from.
    fn small_model() -> Model {
        let s = || Sampling::from_rings("s", &[Ring::new(0.0, 1, 0.0), Ring::new(30.0, 6, 0.0)]).unwrap();
        let layout = Layout::full(s(), s(), 3, 2);
        let (rows, texels) = (layout.n_angular(), layout.texels());
        let channels = (0..3)
            .map(|c| {
                let k = 5 - c; // 5, 4, 3 terms: padding to 5
                let mean = (0..rows).map(|a| a as f32 * 0.01).collect();
                let u = (0..rows * k).map(|i| (i % 7) as f32 * 0.1).collect();
                let sv = (0..texels * k).map(|i| (c * 100 + i) as f32).collect();
                Channel::new(vec![Part { rows: PartRows::All, k, mean, u, s: vec![1.0; k], sv }])
            })
            .collect();
        Model {
            method: Method::Fmf,
            color: ColorModel::Rgb,
            log_eps: 1e-3,
            precision: Precision::F32,
            layout,
            channels,
            clusters: None,
            cluster_col: Vec::new(),
        }
    }

    #[test]
    fn viewer_data_is_as_long_as_it_says_and_holds_the_factors_where_the_header_says() {
        let m = std::sync::Arc::new(small_model());
        let d = ViewerData::new(m.clone());
        let h = d.header().clone();
        assert_eq!((h.terms, h.quads, h.parts, h.coef_parts), (5, 2, 1, 1));
        assert_eq!(h.light.tris.len(), m.layout.light.triangles().len());
        let len = d.len();
        let bytes: Vec<u8> = d.chunks().flatten().collect();
        assert_eq!(bytes.len() as u64, len);
        assert_eq!(&bytes[..8], VIEWER_MAGIC);
        let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        assert_eq!((12 + hlen) % 4, 0);
        let f: Vec<f32> =
            bytes[12 + hlen..].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        let block = |n: &str| h.blocks.iter().find(|b| b.name == n).unwrap().clone();
        // Channel 1 (4 terms), angular row 3: mean, 4 basis values, one padding zero.
        let ang = block("angular");
        let rows = m.layout.n_angular();
        let at = ang.offset + rows * 6 + 3 * 6;
        let p = &m.channels[1].parts[0];
        assert_eq!(&f[at..at + 6], &[p.mean[3], p.u[12], p.u[13], p.u[14], p.u[15], 0.0]);
        // Texel 4 of channel 2 (3 terms): layer (0 * 3 + 2) * 2 + 0 holds its terms 0..3, then 0.
        let coef = block("coef");
        let texels = m.layout.texels();
        let at = coef.offset + 4 * texels * 4 + 4 * 4;
        let p = &m.channels[2].parts[0];
        assert_eq!(&f[at..at + 4], &[p.sv[12], p.sv[13], p.sv[14], 0.0]);
        assert_eq!(f.len(), coef.offset + coef.floats);
    }

    #[test]
    fn render_is_the_models_query_and_pairs_out_of_range_are_refused() {
        let m = small_model();
        let (l, v) = pair_from_degrees([20.0, 40.0], [10.0, 300.0]).unwrap();
        assert_eq!(render(&m, l, v), m.query(v, l).texture());
        for (light, view, word) in [
            ([91.0, 0.0], [0.0, 0.0], "light theta"),
            ([0.0, 0.0], [-1.0, 0.0], "view theta"),
            ([0.0, f64::NAN], [0.0, 0.0], "light phi"),
        ] {
            let e = pair_from_degrees(light, view).unwrap_err();
            assert!(e.contains(word) && e.contains("allowed"), "{e}");
        }
        assert!(check_model_name("fmf").is_ok() && check_model_name("pcmf-shared").is_ok());
        assert!(check_model_name("../x").is_err() && check_model_name("").is_err());
    }
}

/// The model beside the measurement at the measured pair nearest to (light, view).
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The dataset's light index of the nearest measured pair.
    pub light: u32,
    /// Its view id.
    pub view: u32,
    /// Its light direction (degrees `[theta, phi]`).
    pub light_deg: [f64; 2],
    /// Its view direction.
    pub view_deg: [f64; 2],
    /// `sqrt(sum (model - measured)^2 / sum measured^2)` over the texture's texels and channels.
    pub rel_rmse: f64,
    /// Three panels side by side, 8-bit sRGB PNG: the model, the measured texture (both at
    /// `scale`), and `|model - measured|` at 4 x `scale`.
    pub png: Vec<u8>,
}

/// Gain of the difference panel over the display scale.
pub const DIFFERENCE_GAIN: f32 = 4.0;

/// [`Comparison`] of `model` with the dataset in `dir` at the measured pair nearest to
/// (light, view) (least sum of the light's and the view's angles).
pub fn compare(
    dir: &Path,
    model: &Model,
    light: Direction,
    view: Direction,
    scale: Option<f32>,
) -> Result<Comparison, String> {
    let src = btfrig_compress::dataset::DatasetSource::open(dir).map_err(|e| e.to_string())?;
    let lay = src.layout();
    let dirs_of = |s: btfrig_store::StepId| {
        let (l, v) = src.layout_pair(s);
        lay.directions(lay.index(l as usize, v as usize))
    };
    let step = *src
        .steps()
        .iter()
        .min_by(|a, b| {
            let d = |s: btfrig_store::StepId| {
                let (l, v) = dirs_of(s);
                light.angle_to(l) + view.angle_to(v)
            };
            d(**a).total_cmp(&d(**b))
        })
        .ok_or("the dataset has no measured texture")?;
    let measured = src.read(step).map_err(|e| e.to_string())?;
    let (ld, vd) = dirs_of(step);
    let (w, h) = (model.layout.width, model.layout.height);
    if (w, h) != (lay.width, lay.height) {
        return Err(format!("the model's textures are {w} x {h}, the dataset's {} x {}", lay.width, lay.height));
    }
    let modelled = render(model, ld, vd);
    let mut e = btfrig_compress::eval::ErrorSums::default();
    e.add(&modelled, &measured);
    let diff: Vec<[f32; 3]> =
        modelled.iter().zip(&measured).map(|(p, q)| std::array::from_fn(|c| (p[c] - q[c]).abs())).collect();
    let scale = scale.unwrap_or_else(|| display_scale(model));
    let panels = [srgb8(&modelled, scale), srgb8(&measured, scale), srgb8(&diff, scale * DIFFERENCE_GAIN)];
    const GAP: usize = 4;
    let width = 3 * w + 2 * GAP;
    let mut rgb = vec![255u8; width * h * 3];
    for (k, p) in panels.iter().enumerate() {
        for y in 0..h {
            let at = (y * width + k * (w + GAP)) * 3;
            rgb[at..at + 3 * w].copy_from_slice(&p[y * w * 3..(y + 1) * w * 3]);
        }
    }
    let png = btfrig_imageio::encode_srgb8_png(Path::new("comparison"), width, h, &rgb).map_err(|e| e.to_string())?;
    let deg = |d: Direction| {
        let (t, p) = d.to_degrees();
        [t, p]
    };
    Ok(Comparison {
        light: step.light,
        view: step.view,
        light_deg: deg(ld),
        view_deg: deg(vd),
        rel_rmse: e.rel_rmse(),
        png,
    })
}

/// The model's error at one measured capture.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct CaptureError {
    /// Light index.
    pub light: u32,
    /// View id.
    pub view: u32,
    /// `sqrt(sum (model - measured)^2 / sum measured^2)` over the texture.
    pub rel_rmse: f64,
}

/// The model's relative RMSE at every measured capture of the dataset in `dir`, in journal
/// (capture) order: the model evaluated at the capture's directions against its texture.
pub fn capture_errors(dir: &Path, model: &Model) -> Result<Vec<CaptureError>, String> {
    use rayon::prelude::*;
    let src = btfrig_compress::dataset::DatasetSource::open(dir).map_err(|e| e.to_string())?;
    let lay = src.layout();
    if (model.layout.width, model.layout.height) != (lay.width, lay.height) {
        return Err(format!(
            "the model's textures are {} x {}, the dataset's {} x {}",
            model.layout.width, model.layout.height, lay.width, lay.height
        ));
    }
    let jpath = dir.join(btfrig_store::JOURNAL_FILE);
    let bytes = std::fs::read(&jpath).map_err(|e| format!("{}: {e}", jpath.display()))?;
    let replay = btfrig_store::journal::replay(&jpath.display().to_string(), &bytes).map_err(|e| e.to_string())?;
    let mut steps: Vec<_> = src.steps().to_vec();
    let started = |s: &btfrig_store::StepId| replay.done.get(s).map_or(0.0, |r| r.timing.started_unix_s);
    steps.sort_by(|a, b| started(a).total_cmp(&started(b)));
    steps
        .par_iter()
        .map(|&s| {
            let (l, v) = src.layout_pair(s);
            let (ld, vd) = lay.directions(lay.index(l as usize, v as usize));
            let measured = src.read(s).map_err(|e| e.to_string())?;
            let mut e = btfrig_compress::eval::ErrorSums::default();
            e.add(&model.query(vd, ld).texture(), &measured);
            Ok(CaptureError { light: s.light, view: s.view, rel_rmse: e.rel_rmse() })
        })
        .collect()
}
