//! Export to the Bonn `.btf` containers, and a reader of what we write.
//!
//! Byte layouts from `shared/reference/ubo-btf-formats.md` (§3.4–3.6, checklist §3.9):
//! little-endian; signature; meta block version 4 (`Size` = 276 + xml + Σ(4 + name)), three
//! channels `R`, `G`, `B`; the sampling block repeating the light list for every view;
//! `W`, `H`; zero rotations; then
//!
//! * **DFMF** (`!DFMF08FCR`): `num_components_max`, colour model 0 (linear RGB: models 11
//!   and up are clamped to [0, 1] by `btf.hh`), mean 0, identity matrix; per channel
//!   `scalar_size`, `k_c`, rows $n_L n_V$, cols $W H$, $S$, $U$ (row $v n_L + l$), $SV$
//!   (row $y W + x$). Value $= \sum_k U[lv][k]\,SV[xy][k]$.
//! * **FMF1** (`!FMF12FCER`): header version 2, dynamic-range reduction 1, no height map;
//!   one $U$ with rows $(v n_L + l) n_C + c$ and ONE $SV$ shared by the channels. Value
//!   $= \exp(\sum_k U\,SV) - 10^{-5}$ (log-domain HDR, no clamp).
//!
//! Texel rows are stored bottom to top (file row $y$ = texture row $H-1-y$): `btf.hh` flips
//! them on load, so `btf-extractor` returns our textures upright. The Bonn readers need
//! $n_L = n_V$ and no trailing bytes; [`Ubo::validate`] refuses anything else.
//!
//! From a model: a linear-colour model becomes DFMF exactly up to the chosen rank — every
//! RGB channel is $\sum_d M_{cd}(\mu_d 1^\top + U_d SV_d^\top)$, a product $A C^\top$ whose
//! optimal rank-$K$ truncation [`crate::linalg::factored_svd`] computes from the factors (per
//! view and per cluster parts become block columns). FMF1, and DFMF of the log-colour model,
//! re-encode by decoding every (light, view) texture of the model and fitting the target
//! form with the streaming randomized SVD. Neither touches the measured data.

use std::io::Write;
use std::path::Path;

use nalgebra::DMatrix;

use crate::error::{CompressError, Result};
use crate::linalg::factored_svd;
use crate::model::Model;
use crate::rsvd::{RsvdParams, StreamingRsvd};

/// `!DFMF08FCR`.
pub const DFMF_SIGNATURE: &[u8; 10] = b"!DFMF08FCR";
/// `!FMF12FCER`.
pub const FMF1_SIGNATURE: &[u8; 10] = b"!FMF12FCER";
/// The `eps` of FMF1's dynamic-range reduction (hard-coded in the readers).
pub const FMF1_EPS: f32 = 1e-5;

/// Which container.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UboFormat {
    /// `!DFMF08FCR`, per-channel factors, colour model 0.
    Dfmf,
    /// `!FMF12FCER`, shared spatial factor, log domain.
    Fmf1,
}

/// One factor pair: `U` (rows x k, row-major), `S`, `SV` (cols x k, row-major, texel order
/// of OUR textures: row 0 at the top; the writer flips).
#[derive(Debug, Clone, PartialEq)]
pub struct Factors {
    /// Terms.
    pub k: usize,
    /// Singular values.
    pub s: Vec<f32>,
    /// Angular factor.
    pub u: Vec<f32>,
    /// Spatial factor.
    pub sv: Vec<f32>,
}

/// A Bonn container's content.
#[derive(Debug, Clone, PartialEq)]
pub struct Ubo {
    /// Which container.
    pub format: UboFormat,
    /// Light directions `(theta, phi)`, radians.
    pub light: Vec<(f32, f32)>,
    /// View directions `(theta, phi)`, radians.
    pub view: Vec<(f32, f32)>,
    /// Texture width.
    pub width: usize,
    /// Texture height.
    pub height: usize,
    /// 2 (f16) or 4 (f32).
    pub scalar_size: u8,
    /// DFMF: three channels; FMF1: one (rows `(v nL + l) 3 + c`).
    pub factors: Vec<Factors>,
    /// Free text in the meta block's XML field.
    pub xml: String,
}

impl Ubo {
    /// The checklist of the reference (§3.9).
    pub fn validate(&self) -> Result<()> {
        let e = |s: String| Err(CompressError::Export(s));
        if self.light.len() != self.view.len() {
            return e(format!(
                "the Bonn readers need as many lights as views (btf.hh sizes U as lights^2): {} lights, {} views",
                self.light.len(),
                self.view.len()
            ));
        }
        if self.scalar_size != 2 && self.scalar_size != 4 {
            return e(format!("scalar size {}: allowed 2 (f16) or 4 (f32)", self.scalar_size));
        }
        let m = self.light.len() * self.view.len();
        let n = self.width * self.height;
        let (want, rows) = match self.format {
            UboFormat::Dfmf => (3, m),
            UboFormat::Fmf1 => (1, 3 * m),
        };
        if self.factors.len() != want {
            return e(format!("{} factor sets, expected {want}", self.factors.len()));
        }
        let mut plane_u = 0u64;
        let mut plane_sv = 0u64;
        for f in &self.factors {
            if f.u.len() != rows * f.k || f.sv.len() != n * f.k || f.s.len() != f.k {
                return e(format!(
                    "factor sizes: U {} (want {}), SV {} (want {})",
                    f.u.len(),
                    rows * f.k,
                    f.sv.len(),
                    n * f.k
                ));
            }
            plane_u += (rows * f.k) as u64 * u64::from(self.scalar_size);
            plane_sv += (n * f.k) as u64 * u64::from(self.scalar_size);
        }
        if plane_u >= 1 << 32 || plane_sv >= 1 << 32 {
            return e("a factor plane exceeds btf.hh's 32-bit offsets (4 GiB)".into());
        }
        Ok(())
    }

    /// The file's bytes.
    pub fn encode(&self) -> Result<Vec<u8>> {
        self.validate()?;
        let mut o = Vec::new();
        o.extend_from_slice(match self.format {
            UboFormat::Dfmf => DFMF_SIGNATURE,
            UboFormat::Fmf1 => FMF1_SIGNATURE,
        });
        // Meta block, version 4.
        let xml = self.xml.as_bytes();
        let names: [&[u8]; 3] = [b"R", b"G", b"B"];
        let size = 276 + xml.len() + names.iter().map(|n| 4 + n.len()).sum::<usize>();
        let start = o.len();
        put_u32(&mut o, size as u32);
        put_u32(&mut o, 4);
        for text in ["btfrig simulated gonioreflectometer", "btfrig", "btfrig"] {
            let mut field = [0u8; 80];
            field[..text.len()].copy_from_slice(text.as_bytes());
            o.extend_from_slice(&field);
        }
        put_f32(&mut o, 0.0); // ppmm: unknown
        for _ in 0..3 {
            put_f32(&mut o, 1.0); // rgb scale
        }
        put_u32(&mut o, 0); // cosine flag: cos(theta_l) not in the data
        put_u32(&mut o, xml.len() as u32);
        o.extend_from_slice(xml);
        put_u32(&mut o, 3);
        for n in names {
            put_u32(&mut o, n.len() as u32);
            o.extend_from_slice(n);
        }
        debug_assert_eq!(o.len() - start, size);
        // Sampling block.
        put_u32(&mut o, self.view.len() as u32);
        for &(tv, pv) in &self.view {
            put_f32(&mut o, tv);
            put_f32(&mut o, pv);
            put_u32(&mut o, self.light.len() as u32);
            for &(tl, pl) in &self.light {
                put_f32(&mut o, tl);
                put_f32(&mut o, pl);
            }
        }
        put_u32(&mut o, self.width as u32);
        put_u32(&mut o, self.height as u32);
        put_u32(&mut o, 0); // rotations
        let m = self.light.len() * self.view.len();
        match self.format {
            UboFormat::Dfmf => {
                put_u32(&mut o, self.factors.iter().map(|f| f.k).max().unwrap_or(0) as u32);
                put_u32(&mut o, 0); // colour model 0: RGB
                for _ in 0..3 {
                    put_f32(&mut o, 0.0);
                }
                for r in 0..3 {
                    for c in 0..3 {
                        put_f32(&mut o, if r == c { 1.0 } else { 0.0 });
                    }
                }
                for f in &self.factors {
                    self.put_factors(&mut o, f, m);
                }
            }
            UboFormat::Fmf1 => {
                o.push(2); // header version
                put_u32(&mut o, 1); // dynamic range reduction: log(value + 1e-5)
                put_u32(&mut o, 0); // no height map
                put_u32(&mut o, 0);
                let f = &self.factors[0];
                put_u32(&mut o, f.k as u32);
                o.push(self.scalar_size);
                put_u32(&mut o, f.k as u32);
                put_u32(&mut o, (3 * m) as u32);
                put_u32(&mut o, (self.width * self.height) as u32);
                self.put_values(&mut o, &f.s);
                self.put_values(&mut o, &f.u);
                self.put_sv(&mut o, f);
            }
        }
        Ok(o)
    }

    fn put_factors(&self, o: &mut Vec<u8>, f: &Factors, rows: usize) {
        o.push(self.scalar_size);
        put_u32(o, f.k as u32);
        put_u32(o, rows as u32);
        put_u32(o, (self.width * self.height) as u32);
        self.put_values(o, &f.s);
        self.put_values(o, &f.u);
        self.put_sv(o, f);
    }

    fn put_sv(&self, o: &mut Vec<u8>, f: &Factors) {
        let (w, h, k) = (self.width, self.height, f.k);
        for y in 0..h {
            let row = h - 1 - y; // bottom to top
            self.put_values(o, &f.sv[row * w * k..(row + 1) * w * k]);
        }
    }

    fn put_values(&self, o: &mut Vec<u8>, v: &[f32]) {
        if self.scalar_size == 2 {
            for x in v {
                o.extend_from_slice(&half::f16::from_f32(*x).to_le_bytes());
            }
        } else {
            for x in v {
                put_f32(o, *x);
            }
        }
    }

    /// Writes the file (refusing to replace one unless `overwrite`).
    pub fn write(&self, path: &Path, overwrite: bool) -> Result<u64> {
        if path.exists() && !overwrite {
            return Err(CompressError::Exists { path: path.into() });
        }
        let bytes = self.encode()?;
        let io = |source| CompressError::Io { path: path.into(), source };
        let mut f = std::fs::File::create(path).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
        Ok(bytes.len() as u64)
    }

    /// Parses a file we wrote (version-4 meta block, rotations, DFMF or FMF1 as above).
    pub fn decode(path: &Path, b: &[u8]) -> Result<Ubo> {
        let mut r = Cur { b, pos: 0, path };
        let sig = r.take(10)?.to_vec();
        let format = if sig == DFMF_SIGNATURE {
            UboFormat::Dfmf
        } else if sig == FMF1_SIGNATURE {
            UboFormat::Fmf1
        } else {
            return Err(
                r.fail(format!("signature {:?}: expected !DFMF08FCR or !FMF12FCER", String::from_utf8_lossy(&sig)))
            );
        };
        let meta_start = r.pos;
        let size = r.u32()? as usize;
        let version = r.u32()?;
        if version != 4 {
            return Err(r.fail(format!("meta version {version}: this reader reads version 4 (what we write)")));
        }
        r.take(240 + 4 + 12 + 4)?;
        let xl = r.u32()? as usize;
        let xml = String::from_utf8_lossy(r.take(xl)?).into_owned();
        let nc = r.u32()?;
        for _ in 0..nc {
            let l = r.u32()? as usize;
            r.take(l)?;
        }
        if r.pos - meta_start != size {
            return Err(r.fail(format!("meta block Size {size} but {} bytes read", r.pos - meta_start)));
        }
        let nv = r.u32()? as usize;
        let mut view = Vec::new();
        let mut light = Vec::new();
        for v in 0..nv {
            let (t, p) = (r.f32()?, r.f32()?);
            view.push((t, p));
            let nl = r.u32()? as usize;
            for _ in 0..nl {
                let d = (r.f32()?, r.f32()?);
                if v == 0 {
                    light.push(d);
                }
            }
        }
        let width = r.u32()? as usize;
        let height = r.u32()? as usize;
        let nrot = r.u32()? as usize;
        r.take(nrot * 36)?;
        let n = width * height;
        let m = light.len() * view.len();
        let mut factors = Vec::new();
        let mut scalar_size = 0;
        match format {
            UboFormat::Dfmf => {
                let _kmax = r.u32()?;
                let model = r.u32()?;
                if model != 0 {
                    return Err(r.fail(format!("colour model {model}: this reader reads 0 (RGB)")));
                }
                r.take(48)?;
                for _ in 0..3 {
                    scalar_size = r.take(1)?[0];
                    let k = r.u32()? as usize;
                    let (rows, cols) = (r.u32()? as usize, r.u32()? as usize);
                    if rows != m || cols != n {
                        return Err(r.fail(format!("channel of {rows} x {cols}, expected {m} x {n}")));
                    }
                    factors.push(r.factors(scalar_size, k, rows, width, height)?);
                }
            }
            UboFormat::Fmf1 => {
                let hv = r.take(1)?[0];
                let drr = r.u32()?;
                let (ha, hb) = (r.u32()? as usize, r.u32()? as usize);
                r.take(ha * hb * 2)?;
                if hv != 2 || drr != 1 {
                    return Err(r.fail(format!("FMF1 header version {hv}, DRR {drr}: expected 2 and 1")));
                }
                let k1 = r.u32()? as usize;
                scalar_size = r.take(1)?[0];
                let k2 = r.u32()? as usize;
                let (rows, cols) = (r.u32()? as usize, r.u32()? as usize);
                if k1 != k2 || rows != 3 * m || cols != n {
                    return Err(r.fail(format!("FMF1 k {k1}/{k2}, {rows} x {cols}: expected equal k, {} x {n}", 3 * m)));
                }
                factors.push(r.factors(scalar_size, k1, rows, width, height)?);
            }
        }
        if r.pos != b.len() {
            return Err(r.fail(format!("{} trailing bytes", b.len() - r.pos)));
        }
        Ok(Ubo { format, light, view, width, height, scalar_size, factors, xml })
    }

    /// Reads a file.
    pub fn read(path: &Path) -> Result<Ubo> {
        let b = std::fs::read(path).map_err(|source| CompressError::Io { path: path.into(), source })?;
        Self::decode(path, &b)
    }

    /// Decoded linear RGB of texel `(col, row)` (our orientation: row 0 at the top) at light
    /// `l`, view `v`, as the Bonn readers compute it (in f32).
    pub fn texel(&self, l: usize, v: usize, col: usize, row: usize) -> [f32; 3] {
        let nl = self.light.len();
        let x = row * self.width + col;
        let lv = v * nl + l;
        match self.format {
            UboFormat::Dfmf => std::array::from_fn(|c| {
                let f = &self.factors[c];
                (0..f.k).map(|j| f.u[lv * f.k + j] * f.sv[x * f.k + j]).sum()
            }),
            UboFormat::Fmf1 => std::array::from_fn(|c| {
                let f = &self.factors[0];
                let r = lv * 3 + c;
                let s: f32 = (0..f.k).map(|j| f.u[r * f.k + j] * f.sv[x * f.k + j]).sum();
                s.exp() - FMF1_EPS
            }),
        }
    }
}

struct Cur<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl Cur<'_> {
    fn fail(&self, what: String) -> CompressError {
        CompressError::Format { path: self.path.into(), what: format!("{what} (offset {})", self.pos) }
    }
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.b.len() - self.pos < n {
            return Err(self.fail(format!("truncated: {n} bytes needed")));
        }
        self.pos += n;
        Ok(&self.b[self.pos - n..self.pos])
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn f32(&mut self) -> Result<f32> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn values(&mut self, size: u8, n: usize) -> Result<Vec<f32>> {
        let raw = self.take(n * size as usize)?;
        Ok(match size {
            2 => raw.chunks_exact(2).map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32()).collect(),
            4 => raw.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4"))).collect(),
            s => return Err(self.fail(format!("scalar size {s}: allowed 2, 4"))),
        })
    }
    fn factors(&mut self, size: u8, k: usize, rows: usize, w: usize, h: usize) -> Result<Factors> {
        let s = self.values(size, k)?;
        let u = self.values(size, rows * k)?;
        let file_sv = self.values(size, w * h * k)?;
        let mut sv = vec![0.0f32; w * h * k];
        for y in 0..h {
            let row = h - 1 - y;
            sv[row * w * k..(row + 1) * w * k].copy_from_slice(&file_sv[y * w * k..(y + 1) * w * k]);
        }
        Ok(Factors { k, s, u, sv })
    }
}

fn put_u32(o: &mut Vec<u8>, v: u32) {
    o.extend_from_slice(&v.to_le_bytes());
}

fn put_f32(o: &mut Vec<u8>, v: f32) {
    o.extend_from_slice(&v.to_le_bytes());
}

/// Light directions shared by every view within this angle count as one light list.
pub const SAME_LIGHT_TOLERANCE_DEG: f64 = 0.01;

/// Whether a layout's sampling fits a Bonn container, checked before any work: the readers
/// take one light list (the first view's) for every view, and need as many lights as views.
/// A dome whose turntable turns between views moves its lights in the sample frame, which
/// no `.btf` reader can express; the error says which field cannot hold what.
pub fn check_exportable(layout: &crate::model::Layout) -> Result<()> {
    if let Some(c) = &layout.captures {
        let (nl, nv) = (layout.n_light(), layout.n_view());
        let mut worst = (0.0f64, 0usize, 0usize);
        for v in 1..nv {
            for l in 0..nl {
                let d = c.light[layout.index(l, v)].angle_to(c.light[layout.index(l, 0)]).to_degrees();
                if d > worst.0 {
                    worst = (d, l, v);
                }
            }
        }
        if worst.0 > SAME_LIGHT_TOLERANCE_DEG {
            let (d, l, v) = worst;
            return Err(CompressError::Export(format!(
                "the .btf sampling block stores one light list per view, but btf.hh and btf-extractor read the \
                 first view's list for every view; in this dataset the lights move in the sample frame from view to \
                 view (the turntable turns: light {l} is {d:.1} deg away from its direction at view id {} when \
                 seen from view id {}), so no Bonn container can hold its sampling. Export one turntable rotation \
                 of a dome, or a camera array",
                c.view_ids[0], c.view_ids[v]
            )));
        }
    }
    if layout.n_light() != layout.n_view() {
        return Err(CompressError::Export(format!(
            "the Bonn readers need as many lights as views (btf.hh sizes U as lights^2): {} lights, {} views{}",
            layout.n_light(),
            layout.n_view(),
            if layout.captures.is_some() { " measured by the plan (a full-hemisphere plan has as many)" } else { "" }
        )));
    }
    Ok(())
}

/// The light list of the container (a dome or camera array: the sample-frame directions of
/// the first view's captures, the same at every view once [`check_exportable`] passed).
fn light_dirs(layout: &crate::model::Layout) -> Vec<(f32, f32)> {
    match &layout.captures {
        Some(c) => to_pairs((0..layout.n_light()).map(|l| c.light[layout.index(l, 0)])),
        None => to_pairs(layout.light.directions().iter().copied()),
    }
}

/// The view list of the container (a dome or camera array: each view's sample-frame direction).
fn view_dirs(layout: &crate::model::Layout) -> Vec<(f32, f32)> {
    match &layout.captures {
        Some(c) => to_pairs((0..layout.n_view()).map(|v| c.view[layout.index(0, v)])),
        None => to_pairs(layout.view.directions().iter().copied()),
    }
}

fn to_pairs(d: impl Iterator<Item = btfrig_core::Direction>) -> Vec<(f32, f32)> {
    d.map(|d| {
        let phi = if d.phi > std::f64::consts::PI { d.phi - std::f64::consts::TAU } else { d.phi };
        (d.theta as f32, phi as f32)
    })
    .collect()
}

/// What an export cost in accuracy: relative RMS of the exported BTF against the model's,
/// over every (light, view) pair and texel (in the channels the format stores), of the values
/// as written: truncation to the file's terms and rounding to its precision (f16) included.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExportFit {
    /// Terms per factor set.
    pub terms: usize,
    /// `||model - exported|| / ||model||`.
    pub rel_rmse: f64,
}

/// The model as a DFMF container with `rank` terms per channel (`None`: every term the
/// factors have, i.e. exact up to rounding).
pub fn to_dfmf(model: &Model, rank: Option<usize>, scalar_size: u8) -> Result<(Ubo, ExportFit)> {
    check_exportable(&model.layout)?;
    let (m, n) = (model.layout.n_angular(), model.layout.texels());
    let mut factors = Vec::new();
    let (mut err2, mut tot2) = (0.0f64, 0.0f64);
    let mut terms = 0;
    if let Some(mix) = model.color.inverse_matrix() {
        // Factored form of every RGB channel: columns [mean | U] against [1 | SV] per part.
        let blocks: Vec<(DMatrix<f64>, DMatrix<f64>)> = (0..3).map(|d| part_factors(model, d)).collect();
        let r: usize = blocks.iter().map(|b| b.0.ncols()).sum();
        for row in mix.iter() {
            let mut a = DMatrix::<f64>::zeros(m, r);
            let mut c = DMatrix::<f64>::zeros(n, r);
            let mut off = 0;
            for (d, (ad, cd)) in blocks.iter().enumerate() {
                let w = ad.ncols();
                a.columns_mut(off, w).copy_from(&(ad * row[d]));
                c.columns_mut(off, w).copy_from(cd);
                off += w;
            }
            let keep = rank.unwrap_or(r).min(r);
            let (u, s, v) = factored_svd(&a, &c, keep);
            let k = s.len();
            terms = terms.max(k);
            let sv = &v * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(s.clone()));
            let f = Factors { k, s: s.iter().map(|&x| x as f32).collect(), u: row_major(&u), sv: row_major(&sv) }
                .rounded(scalar_size);
            // Of the factors as stored: the dropped terms and the rounding (f16: ~1e-4
            // relative, far above the truncation of an exact conversion).
            let (e2, total) = factored_err2(&a, &c, &f);
            err2 += e2;
            tot2 += total;
            factors.push(f);
        }
    } else {
        // Log colour: decode and refit per RGB channel.
        let keep = rank.unwrap_or(64);
        let mut rs: Vec<StreamingRsvd<f32>> = (0..3)
            .map(|c| StreamingRsvd::new(m, n, &RsvdParams { seed: 11 + c as u64, ..RsvdParams::rank(keep) }))
            .collect::<Result<_>>()?;
        loop {
            let mut more = false;
            for a in 0..m {
                let t = model.texture(a);
                for (c, r) in rs.iter_mut().enumerate() {
                    let row: Vec<f32> = t.iter().map(|p| p[c]).collect();
                    r.push(a, &row);
                }
            }
            for r in rs.iter_mut() {
                more |= r.end_pass()?;
            }
            if !more {
                break;
            }
        }
        for r in rs {
            let svd = r.finish()?;
            terms = terms.max(svd.s.len());
            factors.push(
                Factors {
                    k: svd.s.len(),
                    s: svd.s.iter().map(|&x| x as f32).collect(),
                    u: row_major(&svd.u),
                    sv: row_major(&svd.sv),
                }
                .rounded(scalar_size),
            );
        }
        let ubo = Ubo {
            format: UboFormat::Dfmf,
            light: light_dirs(&model.layout),
            view: view_dirs(&model.layout),
            width: model.layout.width,
            height: model.layout.height,
            scalar_size,
            factors,
            xml: String::new(),
        };
        let fit = compare(model, &ubo);
        return Ok((ubo, fit));
    }
    let ubo = Ubo {
        format: UboFormat::Dfmf,
        light: light_dirs(&model.layout),
        view: view_dirs(&model.layout),
        width: model.layout.width,
        height: model.layout.height,
        scalar_size,
        factors,
        xml: String::new(),
    };
    Ok((ubo, ExportFit { terms, rel_rmse: (err2 / tot2.max(f64::MIN_POSITIVE)).sqrt() }))
}

/// The model as an FMF1 container (log domain, `rank` terms shared by the channels): the
/// model is decoded at every (light, view) pair and refitted.
pub fn to_fmf1(model: &Model, rank: usize, scalar_size: u8) -> Result<(Ubo, ExportFit)> {
    check_exportable(&model.layout)?;
    let (m, n) = (model.layout.n_angular(), model.layout.texels());
    let mut r = StreamingRsvd::<f32>::new(3 * m, n, &RsvdParams { seed: 17, ..RsvdParams::rank(rank) })?;
    loop {
        for a in 0..m {
            let t = model.texture(a);
            for c in 0..3 {
                let row: Vec<f32> = t.iter().map(|p| (p[c].max(0.0) + FMF1_EPS).ln()).collect();
                r.push(a * 3 + c, &row);
            }
        }
        if !r.end_pass()? {
            break;
        }
    }
    let svd = r.finish()?;
    let f = Factors {
        k: svd.s.len(),
        s: svd.s.iter().map(|&x| x as f32).collect(),
        u: row_major(&svd.u),
        sv: row_major(&svd.sv),
    }
    .rounded(scalar_size);
    let ubo = Ubo {
        format: UboFormat::Fmf1,
        light: light_dirs(&model.layout),
        view: view_dirs(&model.layout),
        width: model.layout.width,
        height: model.layout.height,
        scalar_size,
        factors: vec![f],
        xml: String::new(),
    };
    let fit = compare(model, &ubo);
    Ok((ubo, fit))
}

/// Relative RMS difference between the model's and the container's linear RGB.
pub fn compare(model: &Model, ubo: &Ubo) -> ExportFit {
    let (w, h) = (model.layout.width, model.layout.height);
    let (mut e, mut t) = (0.0f64, 0.0f64);
    for a in 0..model.layout.n_angular() {
        let (l, v) = model.layout.pair(a);
        let tex = model.texture(a);
        for row in 0..h {
            for col in 0..w {
                let p = tex[row * w + col];
                let q = ubo.texel(l, v, col, row);
                for c in 0..3 {
                    e += f64::from(p[c] - q[c]).powi(2);
                    t += f64::from(p[c]).powi(2);
                }
            }
        }
    }
    ExportFit {
        terms: ubo.factors.iter().map(|f| f.k).max().unwrap_or(0),
        rel_rmse: (e / t.max(f64::MIN_POSITIVE)).sqrt(),
    }
}

/// `x` as a file of `scalar_size` stores it (2: rounded to f16; 4: as is), so the factors
/// held in memory are the ones written and read back, and every figure is of them.
fn stored(x: f32, scalar_size: u8) -> f32 {
    if scalar_size == 2 {
        half::f16::from_f32(x).to_f32()
    } else {
        x
    }
}

impl Factors {
    /// Rounds every value to what a file of `scalar_size` stores.
    fn rounded(mut self, scalar_size: u8) -> Self {
        for v in [&mut self.s, &mut self.u, &mut self.sv] {
            v.iter_mut().for_each(|x| *x = stored(*x, scalar_size));
        }
        self
    }
}

/// `||A C^T - U SV^T||_F^2` and `||A C^T||_F^2` in factored form (no m x n product):
/// $\|X\|^2 = \sum (A^T A) \circ (C^T C)$, $\langle X, Y \rangle = \sum (A^T U) \circ (C^T SV)$.
/// `f` holds `U` (m x k) and `SV` (n x k) row-major.
fn factored_err2(a: &DMatrix<f64>, c: &DMatrix<f64>, f: &Factors) -> (f64, f64) {
    use crate::linalg::at_b;
    let (m, n) = (a.nrows(), c.nrows());
    let u = DMatrix::<f64>::from_row_iterator(m, f.k, f.u.iter().map(|&x| f64::from(x)));
    let sv = DMatrix::<f64>::from_row_iterator(n, f.k, f.sv.iter().map(|&x| f64::from(x)));
    let xx = at_b(a, a).component_mul(&at_b(c, c)).sum();
    let xy = at_b(a, &u).component_mul(&at_b(c, &sv)).sum();
    let yy = at_b(&u, &u).component_mul(&at_b(&sv, &sv)).sum();
    ((xx - 2.0 * xy + yy).max(0.0), xx)
}

fn row_major(m: &DMatrix<f64>) -> Vec<f32> {
    let mut out = Vec::with_capacity(m.len());
    for r in 0..m.nrows() {
        for c in 0..m.ncols() {
            out.push(m[(r, c)] as f32);
        }
    }
    out
}

/// Channel `d` of the model as `A C^T` (A: angular x r, C: texels x r). A PCMF in a shared
/// basis is `[mu | W] [1 | a_j + A_j t_x]^T` (r = K + 1, not clusters x (terms + 1)): the same
/// values as its expanded parts, a smaller factored form for the SVD.
fn part_factors(model: &Model, d: usize) -> (DMatrix<f64>, DMatrix<f64>) {
    let (m, n) = (model.layout.n_angular(), model.layout.texels());
    let nl = model.layout.n_light();
    let parts = &model.channels[d].parts;
    if let (Some(sh), Some(cl)) = (&model.channels[d].shared, &model.clusters) {
        let k = sh.k;
        let a =
            DMatrix::<f64>::from_fn(m, k + 1, |r, j| f64::from(if j == 0 { sh.mean[r] } else { sh.w[r * k + j - 1] }));
        let mut c = DMatrix::<f64>::zeros(n, k + 1);
        for x in 0..n {
            let (j, col) = (cl[x] as usize, model.cluster_col[x] as usize);
            let (t, b) = (parts[j].k, &sh.cluster_basis[j]);
            let tx = &parts[j].sv[col * t..(col + 1) * t];
            c[(x, 0)] = 1.0;
            for i in 0..k {
                let mut v = f64::from(sh.cluster_mean[j][i]);
                for q in 0..t {
                    v += f64::from(b[i * t + q]) * f64::from(tx[q]);
                }
                c[(x, 1 + i)] = v;
            }
        }
        return (a, c);
    }
    let r: usize = parts.iter().map(|p| p.k + 1).sum();
    let mut a = DMatrix::<f64>::zeros(m, r);
    let mut c = DMatrix::<f64>::zeros(n, r);
    let mut off = 0;
    for (pi, p) in parts.iter().enumerate() {
        let cols: Vec<usize> = match &model.clusters {
            Some(cl) => (0..n).filter(|&x| cl[x] as usize == pi).collect(),
            None => (0..n).collect(),
        };
        for row in 0..m {
            if let Some(pr) = p.row_of(row, nl) {
                a[(row, off)] = f64::from(p.mean[pr]);
                for j in 0..p.k {
                    a[(row, off + 1 + j)] = f64::from(p.u[pr * p.k + j]);
                }
            }
        }
        for (ci, &x) in cols.iter().enumerate() {
            c[(x, off)] = 1.0;
            for j in 0..p.k {
                c[(x, off + 1 + j)] = f64::from(p.sv[ci * p.k + j]);
            }
        }
        off += p.k + 1;
    }
    (a, c)
}
