//! Our model file format (`.btfm`), byte by byte in `docs/model-format.md`.
//!
//! ```text
//! offset  size  field
//! 0       8     magic "BTFRIGMD"
//! 8       4     u32 LE format version (1; 2 for a PCMF in a shared basis)
//! 12      4     u32 LE header length H
//! 16      H     header: UTF-8 JSON (method, colour model, samplings, sizes, parts, arrays)
//! 16+H    32    SHA-256 of the header bytes
//! ...           for each array listed in header.arrays, in order:
//!               its payload (len values of dtype, little-endian), then SHA-256 of the payload
//! EOF           nothing after the last checksum
//! ```
//!
//! Arrays, per channel `c` and part `p` in order: `c{c}.p{p}.mean` (part rows), `.u` (part
//! rows x k, row-major), `.s` (k, always f32), `.sv` (part columns x k, row-major); then for
//! PCMF `clusters` (u16 per texel, row-major). `mean`, `u`, `sv` are f16 or f32 as the
//! header's `precision` says.
//!
//! Version 2 (written only for a PCMF in a shared basis, header `shared_basis: K`; every
//! other model is still written as version 1, byte for byte as before): per channel first
//! `c{c}.w.mean` (angular rows), `c{c}.w.u` (angular rows x K), `c{c}.w.s` (K, f32), then per
//! part `c{c}.p{p}.a` (K), `.b` (K x k), `.s` (k, f32), `.sv` (part columns x k). The parts'
//! mean and basis are not stored: the reader expands them ([`crate::model::SharedBasis::expand`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::color::ColorModel;
use crate::error::{CompressError, Result};
use crate::model::{Channel, Layout, Method, Model, Part, PartRows, Precision, SharedBasis};

/// First 8 bytes of a model file.
pub const MAGIC: &[u8; 8] = b"BTFRIGMD";
/// Format version of every model without a shared basis (read and written).
pub const VERSION: u32 = 1;
/// Format version of a PCMF in a shared basis (read and written); readers of version 1 only
/// refuse it by its version.
pub const VERSION_SHARED: u32 = 2;

/// The version `model` is written as.
pub fn version_of(model: &Model) -> u32 {
    if model.channels.iter().any(|c| c.shared.is_some()) {
        VERSION_SHARED
    } else {
        VERSION
    }
}
/// File name extension.
pub const EXTENSION: &str = "btfm";

/// Shape of one part in the header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartHeader {
    /// `null` = every angular row; else the view whose lights the part covers.
    pub view: Option<usize>,
    /// Terms.
    pub k: usize,
    /// Part rows.
    pub rows: usize,
    /// Part columns (texels).
    pub cols: usize,
}

/// One array of the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayHeader {
    /// Name (`c0.p3.u`, `clusters`).
    pub name: String,
    /// `f16`, `f32` or `u16`.
    pub dtype: String,
    /// Number of values.
    pub len: usize,
}

/// The per-capture directions of a dome model, in the header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapturesHeader {
    /// The dataset's view id of every view (a dome: `rotation x rig cameras + camera`).
    pub view_ids: Vec<u32>,
    /// Per angular index, `[light theta, light phi, view theta, view phi]`, degrees, in the
    /// sample frame.
    pub directions: Vec<[f64; 4]>,
}

/// The JSON header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// `btfrig-model`.
    pub format: String,
    /// Same as the binary version.
    pub version: u32,
    /// `fmf`, `pvmf`, `pcmf`.
    pub method: String,
    /// PCMF: number of clusters.
    pub clusters: Option<usize>,
    /// PCMF in a shared basis (version 2): terms `K` of the shared angular basis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shared_basis: Option<usize>,
    /// Colour model name.
    pub color: String,
    /// `eps` of the log colour model.
    pub log_eps: f32,
    /// `f16` or `f32`.
    pub precision: String,
    /// Names of the samplings.
    pub sampling_names: [String; 2],
    /// Light directions `[theta_deg, phi_deg]`.
    pub light: Vec<[f64; 2]>,
    /// View directions `[theta_deg, phi_deg]`.
    pub view: Vec<[f64; 2]>,
    /// Texture width.
    pub width: usize,
    /// Texture height.
    pub height: usize,
    /// Angular indices (`view * n_light + light`) that were not measured (rows filled by
    /// interpolation).
    pub unmeasured: Vec<usize>,
    /// A dome or camera array ([`crate::model::CaptureDirections`]): the dataset's view id
    /// of every view and each capture's directions in the sample frame; absent on a gonio
    /// model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub captures: Option<CapturesHeader>,
    /// Per channel, its parts.
    pub channels: Vec<Vec<PartHeader>>,
    /// The arrays that follow, in order.
    pub arrays: Vec<ArrayHeader>,
    /// Free-form provenance (dataset, parameters, build figures).
    #[serde(default)]
    pub source: serde_json::Value,
}

fn precision_name(p: Precision) -> &'static str {
    match p {
        Precision::F16 => "f16",
        Precision::F32 => "f32",
    }
}

/// The header of `model` (with `source` as provenance).
pub fn header_of(model: &Model, source: serde_json::Value) -> Header {
    let dt = precision_name(model.precision).to_string();
    let mut arrays = Vec::new();
    let mut channels = Vec::new();
    for (c, ch) in model.channels.iter().enumerate() {
        let mut parts = Vec::new();
        if let Some(sh) = &ch.shared {
            for (what, len, dtype) in
                [("mean", sh.mean.len(), &dt), ("u", sh.w.len(), &dt), ("s", sh.s.len(), &"f32".to_string())]
            {
                arrays.push(ArrayHeader { name: format!("c{c}.w.{what}"), dtype: dtype.clone(), len });
            }
        }
        for (p, part) in ch.parts.iter().enumerate() {
            parts.push(PartHeader {
                view: match part.rows {
                    PartRows::All => None,
                    PartRows::View(v) => Some(v),
                },
                k: part.k,
                rows: part.n_rows(),
                cols: part.n_cols(),
            });
            let angular = match &ch.shared {
                None => [("mean", part.mean.len()), ("u", part.u.len())],
                Some(sh) => [("a", sh.cluster_mean[p].len()), ("b", sh.cluster_basis[p].len())],
            };
            for (what, len, dtype) in [
                (angular[0].0, angular[0].1, &dt),
                (angular[1].0, angular[1].1, &dt),
                ("s", part.s.len(), &"f32".to_string()),
                ("sv", part.sv.len(), &dt),
            ] {
                arrays.push(ArrayHeader { name: format!("c{c}.p{p}.{what}"), dtype: dtype.clone(), len });
            }
        }
        channels.push(parts);
    }
    if let Some(cl) = &model.clusters {
        arrays.push(ArrayHeader { name: "clusters".into(), dtype: "u16".into(), len: cl.len() });
    }
    let deg = |s: &Sampling| s.directions().iter().map(|d| [d.theta.to_degrees(), d.phi.to_degrees()]).collect();
    Header {
        format: "btfrig-model".into(),
        version: version_of(model),
        method: model.method.name().into(),
        clusters: match model.method {
            Method::Pcmf { clusters, .. } => Some(clusters),
            _ => None,
        },
        shared_basis: model.method.shared_basis(),
        color: model.color.name().into(),
        log_eps: model.log_eps,
        precision: dt,
        sampling_names: [model.layout.light.name().into(), model.layout.view.name().into()],
        light: deg(&model.layout.light),
        view: deg(&model.layout.view),
        width: model.layout.width,
        height: model.layout.height,
        unmeasured: (0..model.layout.n_angular()).filter(|&a| !model.layout.measured[a]).collect(),
        captures: model.layout.captures.as_ref().map(|c| CapturesHeader {
            view_ids: c.view_ids.clone(),
            directions: c
                .light
                .iter()
                .zip(&c.view)
                .map(|(l, v)| [l.theta.to_degrees(), l.phi.to_degrees(), v.theta.to_degrees(), v.phi.to_degrees()])
                .collect(),
        }),
        channels,
        arrays,
        source,
    }
}

fn put_f(out: &mut Vec<u8>, v: &[f32], dtype: &str) {
    match dtype {
        "f16" => {
            for x in v {
                out.extend_from_slice(&half::f16::from_f32(*x).to_le_bytes());
            }
        }
        _ => {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
}

/// The file's bytes.
pub fn encode(model: &Model, source: serde_json::Value) -> Vec<u8> {
    let header = header_of(model, source);
    let json = serde_json::to_vec(&header).expect("header serialises");
    let mut out = Vec::with_capacity(model.payload_bytes() + json.len() + 4096);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&header.version.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&Sha256::digest(&json));
    let mut arr = header.arrays.iter();
    let emit = |out: &mut Vec<u8>, payload: Vec<u8>| {
        out.extend_from_slice(&payload);
        out.extend_from_slice(&Sha256::digest(&payload));
    };
    for ch in &model.channels {
        if let Some(sh) = &ch.shared {
            for v in [&sh.mean, &sh.w, &sh.s] {
                let a = arr.next().expect("header lists every array");
                let mut p = Vec::with_capacity(v.len() * 4);
                put_f(&mut p, v, &a.dtype);
                emit(&mut out, p);
            }
        }
        for (j, part) in ch.parts.iter().enumerate() {
            let angular = match &ch.shared {
                None => [&part.mean, &part.u],
                Some(sh) => [&sh.cluster_mean[j], &sh.cluster_basis[j]],
            };
            for v in [angular[0], angular[1], &part.s, &part.sv] {
                let a = arr.next().expect("header lists every array");
                let mut p = Vec::with_capacity(v.len() * 4);
                put_f(&mut p, v, &a.dtype);
                emit(&mut out, p);
            }
        }
    }
    if let Some(cl) = &model.clusters {
        let mut p = Vec::with_capacity(cl.len() * 2);
        for x in cl {
            p.extend_from_slice(&x.to_le_bytes());
        }
        emit(&mut out, p);
    }
    out
}

/// Writes `model` to `path`. Refuses to replace an existing file unless `overwrite`; writes
/// a temporary file next to it and renames it, so a crash never leaves half a model under
/// the name. Returns the bytes written.
pub fn write(path: &Path, model: &Model, source: serde_json::Value, overwrite: bool) -> Result<u64> {
    if path.exists() && !overwrite {
        return Err(CompressError::Exists { path: path.into() });
    }
    let bytes = encode(model, source);
    let tmp = path.with_extension(format!("{EXTENSION}.tmp"));
    let io = |source| CompressError::Io { path: path.into(), source };
    let mut f = std::fs::File::create(&tmp).map_err(io)?;
    f.write_all(&bytes).map_err(io)?;
    f.sync_all().map_err(io)?;
    drop(f);
    std::fs::rename(&tmp, path).map_err(io)?;
    Ok(bytes.len() as u64)
}

struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn fail(&self, what: String) -> CompressError {
        CompressError::Format { path: self.path.into(), what }
    }
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8]> {
        if self.bytes.len() - self.pos < n {
            return Err(self.fail(format!(
                "truncated: {what} needs {n} bytes at offset {}, the file has {} left",
                self.pos,
                self.bytes.len() - self.pos
            )));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn checked(&mut self, n: usize, section: &str) -> Result<&[u8]> {
        let start = self.pos;
        self.take(n, section)?;
        let sum = self.take(32, &format!("checksum of {section}"))?.to_vec();
        let data = &self.bytes[start..start + n];
        if Sha256::digest(data).as_slice() != sum.as_slice() {
            return Err(CompressError::Checksum { path: self.path.into(), section: section.into() });
        }
        Ok(data)
    }
}

/// Reads only the header (cheap: for `dataset info`), checking magic, version and header
/// checksum. Returns the header and the file size.
pub fn read_header(path: &Path) -> Result<(Header, u64)> {
    let bytes = std::fs::read(path).map_err(|source| CompressError::Io { path: path.into(), source })?;
    let (h, _) = parse_header(path, &bytes)?;
    Ok((h, bytes.len() as u64))
}

fn parse_header<'a>(path: &'a Path, bytes: &'a [u8]) -> Result<(Header, Reader<'a>)> {
    let mut r = Reader { path, bytes, pos: 0 };
    let magic = r.take(8, "magic")?.to_vec();
    if magic != MAGIC {
        return Err(r.fail(format!("not a btfrig model file: magic {magic:?}, expected {MAGIC:?}")));
    }
    let version = r.u32("version")?;
    if version != VERSION && version != VERSION_SHARED {
        return Err(r.fail(format!(
            "format version {version} is not supported: this build reads versions {VERSION} and {VERSION_SHARED}"
        )));
    }
    let hl = r.u32("header length")? as usize;
    let json = r.checked(hl, "header")?;
    let header: Header = serde_json::from_slice(json).map_err(|e| r.fail(format!("header JSON: {e}")))?;
    if header.version != version {
        return Err(r.fail(format!("header says version {}, the binary field {version}", header.version)));
    }
    if (version == VERSION_SHARED) != header.shared_basis.is_some() {
        return Err(r.fail(format!(
            "version {version} with shared_basis {:?}: a shared basis is version {VERSION_SHARED} exactly",
            header.shared_basis
        )));
    }
    Ok((header, r))
}

/// Reads a whole model, checking every checksum, every size, and that nothing follows.
pub fn read(path: &Path) -> Result<Model> {
    let bytes = std::fs::read(path).map_err(|source| CompressError::Io { path: path.into(), source })?;
    decode(path, &bytes)
}

/// [`read`] from bytes (`path` names them in errors).
pub fn decode(path: &Path, bytes: &[u8]) -> Result<Model> {
    let (h, mut r) = parse_header(path, bytes)?;
    let fail = |what: String| CompressError::Format { path: PathBuf::from(path), what };
    let precision = match h.precision.as_str() {
        "f16" => Precision::F16,
        "f32" => Precision::F32,
        p => return Err(fail(format!("precision {p:?}: allowed f16, f32"))),
    };
    let color = ColorModel::from_name(&h.color).ok_or_else(|| fail(format!("colour model {:?} unknown", h.color)))?;
    let method = match (h.method.as_str(), h.clusters, h.shared_basis) {
        ("fmf", _, None) => Method::Fmf,
        ("pvmf", _, None) => Method::Pvmf,
        ("pcmf", Some(c), shared_basis) => Method::Pcmf { clusters: c, shared_basis },
        (m, c, k) => {
            return Err(fail(format!(
                "method {m:?} (clusters {c:?}, shared basis {k:?}): allowed fmf, pvmf, pcmf with clusters \
                 (a shared basis only for pcmf)"
            )))
        }
    };
    let sampling = |name: &str, d: &[[f64; 2]]| {
        Sampling::from_list(name, d.iter().map(|x| Direction::from_degrees(x[0], x[1])).collect())
            .map_err(|e| fail(format!("sampling: {e}")))
    };
    let light = sampling(&h.sampling_names[0], &h.light)?;
    let view = sampling(&h.sampling_names[1], &h.view)?;
    let mut layout = Layout::full(light, view, h.width, h.height);
    for &a in &h.unmeasured {
        if a >= layout.n_angular() {
            return Err(fail(format!("unmeasured index {a} >= {} angular rows", layout.n_angular())));
        }
        layout.measured[a] = false;
    }
    if let Some(c) = &h.captures {
        if c.view_ids.len() != layout.n_view() || c.directions.len() != layout.n_angular() {
            return Err(fail(format!(
                "captures: {} view ids and {} directions for {} views and {} angular rows",
                c.view_ids.len(),
                c.directions.len(),
                layout.n_view(),
                layout.n_angular()
            )));
        }
        layout.captures = Some(crate::model::CaptureDirections {
            view_ids: c.view_ids.clone(),
            light: c.directions.iter().map(|d| Direction::from_degrees(d[0], d[1])).collect(),
            view: c.directions.iter().map(|d| Direction::from_degrees(d[2], d[3])).collect(),
        });
    }
    let mut arrays = h.arrays.iter();
    let mut next = |r: &mut Reader, want_len: usize, want_name: &str| -> Result<Vec<f32>> {
        let a = arrays.next().ok_or_else(|| fail(format!("array {want_name} missing from the header")))?;
        if a.name != want_name || a.len != want_len {
            return Err(fail(format!(
                "array {} of {} values where {want_name} of {want_len} is expected",
                a.name, a.len
            )));
        }
        let size = match a.dtype.as_str() {
            "f16" => 2,
            "f32" => 4,
            d => return Err(fail(format!("array {}: dtype {d:?}, allowed f16, f32", a.name))),
        };
        let data = r.checked(a.len * size, &a.name)?;
        Ok(if size == 2 {
            data.chunks_exact(2).map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32()).collect()
        } else {
            data.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().expect("4"))).collect()
        })
    };
    if h.channels.len() != 3 {
        return Err(fail(format!("{} channels, expected 3", h.channels.len())));
    }
    let mut channels = Vec::new();
    for (c, parts_h) in h.channels.iter().enumerate() {
        let mut parts = Vec::new();
        let mut shared = match h.shared_basis {
            None => None,
            Some(k) => {
                let m = layout.n_angular();
                let n = |w: &str| format!("c{c}.w.{w}");
                let mean = next(&mut r, m, &n("mean"))?;
                let w = next(&mut r, m * k, &n("u"))?;
                let s = next(&mut r, k, &n("s"))?;
                Some(SharedBasis { k, mean, w, s, cluster_mean: Vec::new(), cluster_basis: Vec::new() })
            }
        };
        for (p, ph) in parts_h.iter().enumerate() {
            let n = |w: &str| format!("c{c}.p{p}.{w}");
            let rows = match ph.view {
                None => PartRows::All,
                Some(v) => PartRows::View(v),
            };
            let (mean, u) = match &mut shared {
                None => (next(&mut r, ph.rows, &n("mean"))?, next(&mut r, ph.rows * ph.k, &n("u"))?),
                Some(sh) => {
                    if ph.view.is_some() || ph.rows != sh.n_rows() || ph.k > sh.k {
                        return Err(fail(format!(
                            "channel {c} part {p}: view {:?}, {} rows, {} terms in a shared basis of {} rows x {} \
                             terms (expected every row, at most {} terms)",
                            ph.view,
                            ph.rows,
                            ph.k,
                            sh.n_rows(),
                            sh.k,
                            sh.k
                        )));
                    }
                    sh.cluster_mean.push(next(&mut r, sh.k, &n("a"))?);
                    sh.cluster_basis.push(next(&mut r, sh.k * ph.k, &n("b"))?);
                    sh.expand(p)
                }
            };
            let s = next(&mut r, ph.k, &n("s"))?;
            let sv = next(&mut r, ph.cols * ph.k, &n("sv"))?;
            parts.push(Part { rows, k: ph.k, mean, u, s, sv });
        }
        channels.push(Channel { parts, shared });
    }
    let clusters = if matches!(method, Method::Pcmf { .. }) {
        let a = arrays.next().ok_or_else(|| fail("array clusters missing".into()))?;
        if a.name != "clusters" || a.dtype != "u16" || a.len != layout.texels() {
            return Err(fail(format!(
                "array {} ({}, {}) where clusters (u16, {}) is expected",
                a.name,
                a.dtype,
                a.len,
                layout.texels()
            )));
        }
        let data = r.checked(a.len * 2, "clusters")?;
        Some(data.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect::<Vec<u16>>())
    } else {
        None
    };
    if let Some(a) = arrays.next() {
        return Err(fail(format!("header lists an unexpected array {}", a.name)));
    }
    if r.pos != bytes.len() {
        return Err(fail(format!("{} trailing bytes after the last array (offset {})", bytes.len() - r.pos, r.pos)));
    }
    let mut model =
        Model { method, color, log_eps: h.log_eps, precision, layout, channels, clusters, cluster_col: Vec::new() };
    model.index_clusters();
    validate_shapes(&model).map_err(fail)?;
    Ok(model)
}

fn validate_shapes(m: &Model) -> std::result::Result<(), String> {
    let nl = m.layout.n_light();
    for (c, ch) in m.channels.iter().enumerate() {
        for (p, part) in ch.parts.iter().enumerate() {
            let rows = match part.rows {
                PartRows::All => m.layout.n_angular(),
                PartRows::View(v) if v < m.layout.n_view() => nl,
                PartRows::View(v) => return Err(format!("channel {c} part {p}: view {v} out of range")),
            };
            if part.n_rows() != rows {
                return Err(format!("channel {c} part {p}: {} rows, expected {rows}", part.n_rows()));
            }
        }
        let cols_ok = match &m.clusters {
            Some(cl) => {
                let kc = ch.parts.len();
                if cl.iter().any(|&x| x as usize >= kc) {
                    return Err(format!("cluster index >= {kc} parts"));
                }
                (0..kc).all(|j| ch.parts[j].n_cols() == cl.iter().filter(|&&x| x as usize == j).count())
            }
            None => ch.parts.iter().all(|p| p.n_cols() == m.layout.texels()),
        };
        if !cols_ok {
            return Err(format!("channel {c}: part columns do not match the texels"));
        }
    }
    Ok(())
}
