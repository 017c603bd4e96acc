//! Linear BTF models and their evaluation.
//!
//! The BTF of one colour channel is the matrix $B \in \mathbb{R}^{m \times n}$ with one row per
//! (light, view) pair, angular index $a = v\,n_L + l$ (light fastest, as in the Bonn files),
//! and one column per texel $x = \text{row}\cdot W + \text{col}$. Every model is a set of
//! *parts*, each an affine low-rank model of a block of $B$:
//!
//! $$B[a, x] \approx \mu_p[a] + \sum_{j<k} U_p[a, j]\,(SV)_p[x, j]$$
//!
//! * **FMF** (full matrix factorization): one part, all rows and texels.
//! * **PVMF** (per-view): one part per view $v$ over its $n_L$ rows.
//! * **PCMF** (per-cluster, local PCA): one part per cluster of texels $k(x)$, all rows.
//! * **PCMF in a shared basis** (`shared_basis: Some(K)`): PCMF whose cluster bases lie in
//!   the span of one angular basis $W \in \mathbb{R}^{m \times K}$ per channel (the first $K$
//!   FMF terms, with the FMF mean $\mu$): $\mu_j = \mu + W a_j$, $U_j = W A_j$, with
//!   $a_j \in \mathbb{R}^K$, $A_j \in \mathbb{R}^{K \times k}$ ([`SharedBasis`], built by
//!   [`crate::shared`]). Stored: $\mu$, $W$ once, $a_j, A_j$ per cluster, the texel
//!   coefficients; the parts' $\mu_j, U_j$ are expanded from them ([`SharedBasis::expand`]),
//!   so every decoding path treats the model as a PCMF.
//!
//! $\mu_p$ is the part's mean ABRDF (PCA centring). Pairs that were not measured (the rig
//! cannot reach them) get rows interpolated barycentrically from the measured lights of the
//! same view ([`Layout::fill_weights`]). Any direction pair is answered by interpolating the
//! angular factors over the samplings' triangulations
//! ($\tilde U = \sum_{i,j} w_i(v)\,w_j(l)\,U[v_i n_L + l_j]$, at most 9 rows), then one dot
//! product of length $k$ per texel and channel ([`Model::query`]).

use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use serde::{Deserialize, Serialize};

use crate::color::ColorModel;
use crate::error::{CompressError, Result};

/// Which linear model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Full matrix factorization.
    Fmf,
    /// Per-view matrix factorization.
    Pvmf,
    /// Per-cluster matrix factorization with this many clusters.
    Pcmf {
        /// Clusters of texels.
        clusters: usize,
        /// `Some(K)`: the cluster bases lie in a shared angular basis of `K` terms per
        /// channel ([`SharedBasis`]); `None`: each cluster stores its own angular basis.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        shared_basis: Option<usize>,
    },
}

impl Method {
    /// Short name (`fmf`, `pvmf`, `pcmf`).
    pub fn name(&self) -> &'static str {
        match self {
            Method::Fmf => "fmf",
            Method::Pvmf => "pvmf",
            Method::Pcmf { .. } => "pcmf",
        }
    }

    /// PCMF with its own angular basis per cluster.
    pub const fn pcmf(clusters: usize) -> Self {
        Method::Pcmf { clusters, shared_basis: None }
    }

    /// PCMF with its cluster bases in a shared angular basis of `basis` terms.
    pub const fn pcmf_shared(clusters: usize, basis: usize) -> Self {
        Method::Pcmf { clusters, shared_basis: Some(basis) }
    }

    /// PCMF: the terms of the shared angular basis, if any.
    pub fn shared_basis(&self) -> Option<usize> {
        match self {
            Method::Pcmf { shared_basis, .. } => *shared_basis,
            _ => None,
        }
    }

    /// A label with the parameters: `fmf`, `pvmf`, `pcmf-32`, `pcmf-32/w32`.
    pub fn label(&self) -> String {
        match self {
            Method::Pcmf { clusters, shared_basis: None } => format!("pcmf-{clusters}"),
            Method::Pcmf { clusters, shared_basis: Some(k) } => format!("pcmf-{clusters}/w{k}"),
            m => m.name().into(),
        }
    }
}

/// The shape of a BTF: samplings, texture size, which pairs were measured.
#[derive(Debug, Clone)]
pub struct Layout {
    /// Light directions (a dome: the lights' directions in the rig frame, i.e. in the sample
    /// frame at turntable rotation 0; [`Layout::captures`] has each capture's).
    pub light: Sampling,
    /// View directions (a dome: each view's direction in the sample frame).
    pub view: Sampling,
    /// Texture width, texels.
    pub width: usize,
    /// Texture height, texels.
    pub height: usize,
    /// Per angular index `a = view * n_light + light`: measured.
    pub measured: Vec<bool>,
    /// A dome or camera array: the dataset's view ids and each capture's own directions in
    /// the sample frame; `None`: a gonioreflectometer's layout, capture `(l, v)` is exactly
    /// `(light[l], view[v])` and views are the dataset's view indices.
    pub captures: Option<CaptureDirections>,
}

/// The (light, view) directions of every capture of a dome or camera array, in the sample
/// frame. A dome's view is a camera at a turntable rotation, so a light's direction in the
/// sample frame depends on the view: the layout is not a product of two samplings.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureDirections {
    /// The dataset's view id of each view of the layout (a dome: `rotation x rig cameras +
    /// camera`); the layout holds only the measured views, in this order.
    pub view_ids: Vec<u32>,
    /// Per angular index, the light's direction in the sample frame.
    pub light: Vec<Direction>,
    /// Per angular index, the view's direction in the sample frame.
    pub view: Vec<Direction>,
}

impl Layout {
    /// A layout in which every pair is measured.
    pub fn full(light: Sampling, view: Sampling, width: usize, height: usize) -> Self {
        let m = light.len() * view.len();
        Layout { light, view, width, height, measured: vec![true; m], captures: None }
    }

    /// The (light, view) directions of angular index `a` in the sample frame.
    pub fn directions(&self, a: usize) -> (Direction, Direction) {
        match &self.captures {
            Some(c) => (c.light[a], c.view[a]),
            None => {
                let (l, v) = self.pair(a);
                (self.light.get(l), self.view.get(v))
            }
        }
    }

    /// The layout's view of the dataset's view id `id` (the same number on a gonio layout).
    pub fn view_of_id(&self, id: u32) -> Option<u32> {
        match &self.captures {
            Some(c) => c.view_ids.iter().position(|&v| v == id).map(|v| v as u32),
            None => ((id as usize) < self.n_view()).then_some(id),
        }
    }

    /// The dataset's view id of the layout's view `v`.
    pub fn view_id(&self, v: usize) -> u32 {
        self.captures.as_ref().map_or(v as u32, |c| c.view_ids[v])
    }

    /// Lights.
    pub fn n_light(&self) -> usize {
        self.light.len()
    }

    /// Views.
    pub fn n_view(&self) -> usize {
        self.view.len()
    }

    /// Angular rows `n_light * n_view`.
    pub fn n_angular(&self) -> usize {
        self.light.len() * self.view.len()
    }

    /// Texels per texture.
    pub fn texels(&self) -> usize {
        self.width * self.height
    }

    /// Measured pairs.
    pub fn n_measured(&self) -> usize {
        self.measured.iter().filter(|&&m| m).count()
    }

    /// Angular index of `(light, view)`.
    pub fn index(&self, light: usize, view: usize) -> usize {
        view * self.n_light() + light
    }

    /// `(light, view)` of angular index `a`.
    pub fn pair(&self, a: usize) -> (usize, usize) {
        (a % self.n_light(), a / self.n_light())
    }

    /// Checks that `(light, view)` is a measured pair; its angular index.
    pub fn check(&self, light: u32, view: u32) -> Result<usize> {
        let (l, v) = (light as usize, view as usize);
        if l >= self.n_light() || v >= self.n_view() {
            return Err(CompressError::UnknownCapture {
                light,
                view,
                why: format!("allowed light 0..{}, view 0..{}", self.n_light(), self.n_view()),
            });
        }
        let a = self.index(l, v);
        if !self.measured[a] {
            return Err(CompressError::UnknownCapture {
                light,
                view,
                why: "the pair is not among the measured ones".into(),
            });
        }
        Ok(a)
    }

    /// For every unmeasured angular index, the measured indices and weights its row is
    /// interpolated from: barycentric weights of its light direction over the measured
    /// lights of its view; if that view has none, of its view direction over the measured
    /// views of its light; else the nearest measured pair.
    pub fn fill_weights(&self) -> Vec<(usize, Vec<(usize, f64)>)> {
        let nl = self.n_light();
        let mut out = Vec::new();
        let mut per_view: Vec<Option<(Vec<usize>, Option<Sampling>)>> = vec![None; self.n_view()];
        for a in 0..self.n_angular() {
            if self.measured[a] {
                continue;
            }
            let (l, v) = self.pair(a);
            let entry = per_view[v].get_or_insert_with(|| {
                let lights: Vec<usize> = (0..nl).filter(|&j| self.measured[self.index(j, v)]).collect();
                let dirs: Vec<Direction> = lights.iter().map(|&j| self.light.get(j)).collect();
                let s = if dirs.is_empty() { None } else { Sampling::from_list("measured", dirs).ok() };
                (lights, s)
            });
            if let (lights, Some(s)) = entry {
                let w = s.interpolate(self.light.get(l));
                out.push((a, w.iter().map(|(i, w)| (self.index(lights[i], v), w)).collect()));
                continue;
            }
            let views: Vec<usize> = (0..self.n_view()).filter(|&j| self.measured[self.index(l, j)]).collect();
            if !views.is_empty() {
                let dirs: Vec<Direction> = views.iter().map(|&j| self.view.get(j)).collect();
                if let Ok(s) = Sampling::from_list("measured", dirs) {
                    let w = s.interpolate(self.view.get(v));
                    out.push((a, w.iter().map(|(i, w)| (self.index(l, views[i]), w)).collect()));
                    continue;
                }
            }
            let (ld, vd) = (self.light.get(l), self.view.get(v));
            let best = (0..self.n_angular()).filter(|&b| self.measured[b]).min_by(|&x, &y| {
                let d = |b: usize| {
                    let (bl, bv) = self.pair(b);
                    ld.angle_to(self.light.get(bl)) + vd.angle_to(self.view.get(bv))
                };
                d(x).total_cmp(&d(y))
            });
            if let Some(b) = best {
                out.push((a, vec![(b, 1.0)]));
            }
        }
        out
    }
}

/// Which angular rows a part covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PartRows {
    /// Every angular index (FMF, PCMF); part row = angular index.
    All,
    /// The lights of one view (PVMF); part row = light index.
    View(usize),
}

/// One affine low-rank block of one channel (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// Rows covered.
    pub rows: PartRows,
    /// Terms.
    pub k: usize,
    /// Mean ABRDF, one value per part row.
    pub mean: Vec<f32>,
    /// Angular basis, part rows x k, row-major.
    pub u: Vec<f32>,
    /// Singular values (informational: `sv` already holds them).
    pub s: Vec<f32>,
    /// Texel coefficients `V S`, part columns x k, row-major.
    pub sv: Vec<f32>,
}

impl Part {
    /// Number of part rows.
    pub fn n_rows(&self) -> usize {
        self.mean.len()
    }

    /// Number of part columns (texels).
    pub fn n_cols(&self) -> usize {
        self.sv.len().checked_div(self.k).unwrap_or(0)
    }

    /// Part row of angular index `a` (`None`: not covered).
    #[inline]
    pub fn row_of(&self, a: usize, n_light: usize) -> Option<usize> {
        match self.rows {
            PartRows::All => Some(a),
            PartRows::View(v) => (a / n_light == v).then_some(a % n_light),
        }
    }

    /// Value at part row `r`, part column `c`.
    #[inline]
    pub fn value(&self, r: usize, c: usize) -> f32 {
        let k = self.k;
        let u = &self.u[r * k..(r + 1) * k];
        let sv = &self.sv[c * k..(c + 1) * k];
        self.mean[r] + dot(u, sv)
    }
}

/// Dot product with eight independent accumulators, so the compiler can vectorise it (a
/// plain `sum()` of `f32` must keep its order and runs one lane at a time).
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..8 {
            acc[j] += x[j] * y[j];
        }
    }
    let mut s = 0.0f32;
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s + ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))
}

/// One colour channel of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// The parts (1 for FMF, one per view for PVMF, one per cluster for PCMF).
    pub parts: Vec<Part>,
    /// PCMF in a shared basis: the stored two-level angular factors; the parts' `mean` and
    /// `u` are [`SharedBasis::expand`]ed from them (not stored), their `s` and `sv` are.
    pub shared: Option<SharedBasis>,
}

impl Channel {
    /// A channel whose parts store their own angular factors.
    pub fn new(parts: Vec<Part>) -> Self {
        Channel { parts, shared: None }
    }

    /// Values stored for this channel (means, bases, coefficients, singular values; for a
    /// shared basis the two-level form, not the expanded parts).
    pub fn stored_values(&self) -> usize {
        match &self.shared {
            None => self.parts.iter().map(|p| p.mean.len() + p.u.len() + p.sv.len() + p.s.len()).sum(),
            Some(sh) => sh.stored_values() + self.parts.iter().map(|p| p.sv.len() + p.s.len()).sum::<usize>(),
        }
    }
}

/// The two-level angular factors of one channel of a PCMF in a shared basis (see the module
/// documentation): $\mu$ and $W$ once, $a_j$ and $A_j$ per cluster.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedBasis {
    /// Terms `K` of the shared basis.
    pub k: usize,
    /// Mean ABRDF $\mu$, one value per angular index.
    pub mean: Vec<f32>,
    /// Shared angular basis $W$, angular rows x `k`, row-major.
    pub w: Vec<f32>,
    /// Singular values of $W$'s FMF (informational), `k`.
    pub s: Vec<f32>,
    /// Per cluster, its mean in $W$'s coefficients $a_j$, `k` values.
    pub cluster_mean: Vec<Vec<f32>>,
    /// Per cluster, its basis in $W$'s coefficients $A_j$, `k` x terms, row-major.
    pub cluster_basis: Vec<Vec<f32>>,
}

impl SharedBasis {
    /// Stored values: $\mu$, $W$, its singular values, every $a_j$ and $A_j$.
    pub fn stored_values(&self) -> usize {
        self.mean.len()
            + self.w.len()
            + self.s.len()
            + self.cluster_mean.iter().map(Vec::len).sum::<usize>()
            + self.cluster_basis.iter().map(Vec::len).sum::<usize>()
    }

    /// Angular rows.
    pub fn n_rows(&self) -> usize {
        self.mean.len()
    }

    /// Terms of cluster `j`'s basis.
    pub fn terms(&self, j: usize) -> usize {
        self.cluster_basis[j].len().checked_div(self.k).unwrap_or(0)
    }

    /// Cluster `j`'s mean $\mu + W a_j$ and basis $W A_j$ (angular rows x terms, row-major),
    /// accumulated in f64 in a fixed order, so the builder and the file reader get the same
    /// bits. Cost: `rows * K * (terms + 1)` multiply-adds per cluster.
    pub fn expand(&self, j: usize) -> (Vec<f32>, Vec<f32>) {
        let (m, k, t) = (self.n_rows(), self.k, self.terms(j));
        let (a, b) = (&self.cluster_mean[j], &self.cluster_basis[j]);
        let mut mean = vec![0.0f32; m];
        let mut u = vec![0.0f32; m * t];
        let mut acc = vec![0.0f64; t];
        for r in 0..m {
            let w = &self.w[r * k..(r + 1) * k];
            let mut mu = f64::from(self.mean[r]);
            acc.fill(0.0);
            for i in 0..k {
                let wi = f64::from(w[i]);
                mu += wi * f64::from(a[i]);
                for (q, s) in acc.iter_mut().zip(&b[i * t..(i + 1) * t]) {
                    *q += wi * f64::from(*s);
                }
            }
            mean[r] = mu as f32;
            for (d, q) in u[r * t..(r + 1) * t].iter_mut().zip(&acc) {
                *d = *q as f32;
            }
        }
        (mean, u)
    }
}

/// Numeric precision of a model's stored factors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Precision {
    /// IEEE binary16 (as the Bonn files): 2 bytes per value.
    F16,
    /// IEEE binary32.
    F32,
}

impl Precision {
    /// Bytes per stored value.
    pub fn bytes(self) -> usize {
        match self {
            Precision::F16 => 2,
            Precision::F32 => 4,
        }
    }
}

/// A built linear BTF model (see the module documentation).
#[derive(Debug, Clone)]
pub struct Model {
    /// The model kind.
    pub method: Method,
    /// Colour model of the channels.
    pub color: ColorModel,
    /// `eps` of the log colour model.
    pub log_eps: f32,
    /// Storage precision (the factors in memory are already rounded to it).
    pub precision: Precision,
    /// Samplings, size, measured pairs.
    pub layout: Layout,
    /// The three channels.
    pub channels: Vec<Channel>,
    /// PCMF: cluster of every texel.
    pub clusters: Option<Vec<u16>>,
    /// PCMF: column of every texel within its cluster's part.
    pub cluster_col: Vec<u32>,
}

impl Model {
    /// Computes `cluster_col` from `clusters` (call after changing `clusters`).
    pub fn index_clusters(&mut self) {
        self.cluster_col.clear();
        if let Some(c) = &self.clusters {
            let kc = c.iter().map(|&x| x as usize + 1).max().unwrap_or(0);
            let mut next = vec![0u32; kc];
            for &x in c {
                self.cluster_col.push(next[x as usize]);
                next[x as usize] += 1;
            }
        }
    }

    /// Terms per channel (of the first part).
    pub fn terms(&self) -> [usize; 3] {
        std::array::from_fn(|c| self.channels.get(c).and_then(|ch| ch.parts.first()).map_or(0, |p| p.k))
    }

    /// Stored values (means, bases, coefficients, singular values) over all channels; for a
    /// PCMF in a shared basis the two-level form ([`Channel::stored_values`]).
    pub fn stored_values(&self) -> usize {
        self.channels.iter().map(Channel::stored_values).sum()
    }

    /// Bytes of the factors at the model's precision plus the cluster map (2 bytes per
    /// texel): what storage comparisons use (the file adds a header, see [`crate::file`]).
    /// Singular values are counted at the precision too (the file holds them as f32: a few
    /// hundred bytes more).
    pub fn payload_bytes(&self) -> usize {
        self.stored_values() * self.precision.bytes() + self.clusters.as_ref().map_or(0, |c| 2 * c.len())
    }

    /// The stored channel values of texel `x` at angular index `a`.
    #[inline]
    pub fn channels_at(&self, a: usize, x: usize) -> [f32; 3] {
        let nl = self.layout.n_light();
        std::array::from_fn(|c| {
            let ch = &self.channels[c];
            match &self.clusters {
                Some(cl) => ch.parts[cl[x] as usize].value(a, self.cluster_col[x] as usize),
                None => ch.parts.iter().filter_map(|p| p.row_of(a, nl).map(|r| p.value(r, x))).sum(),
            }
        })
    }

    /// Linear RGB of texel `x` at measured (or filled) angular index `a`.
    pub fn texel(&self, a: usize, x: usize) -> [f32; 3] {
        self.color.inverse(self.channels_at(a, x), self.log_eps)
    }

    /// The whole texture of angular index `a` (row-major RGB).
    pub fn texture(&self, a: usize) -> Vec<[f32; 3]> {
        use rayon::prelude::*;
        (0..self.layout.texels()).into_par_iter().map(|x| self.texel(a, x)).collect()
    }

    /// A query for arbitrary directions: the interpolated angular factors, ready to evaluate
    /// any texel ([`Query::texel`], [`Query::texture`]).
    pub fn query(&self, view: Direction, light: Direction) -> Query<'_> {
        let nl = self.layout.n_light();
        let mut combos = Vec::with_capacity(9);
        if self.layout.captures.is_some() {
            // A dome's captures are no product of two triangulated samplings: the measured
            // capture nearest to the pair (summed angles in the sample frame).
            let d = |a: usize| {
                let (l, v) = self.layout.directions(a);
                light.angle_to(l) + view.angle_to(v)
            };
            let best = (0..self.layout.n_angular())
                .filter(|&a| self.layout.measured[a])
                .min_by(|&x, &y| d(x).total_cmp(&d(y)));
            combos.extend(best.map(|a| (a, 1.0f32)));
        } else {
            let wv = self.layout.view.interpolate(view);
            let wl = self.layout.light.interpolate(light);
            for (v, a) in wv.iter() {
                for (l, b) in wl.iter() {
                    if a * b > 0.0 {
                        combos.push((v * nl + l, (a * b) as f32));
                    }
                }
            }
        }
        let active: ActiveRows = self
            .channels
            .iter()
            .map(|ch| {
                ch.parts
                    .iter()
                    .map(|p| {
                        let mut mean = 0.0f32;
                        let mut u = vec![0.0f32; p.k];
                        let mut any = false;
                        for &(a, w) in &combos {
                            if let Some(r) = p.row_of(a, nl) {
                                any = true;
                                mean += w * p.mean[r];
                                for (d, s) in u.iter_mut().zip(&p.u[r * p.k..(r + 1) * p.k]) {
                                    *d += w * s;
                                }
                            }
                        }
                        any.then_some((mean, u))
                    })
                    .collect()
            })
            .collect();
        let listed = (0..3)
            .map(|c: usize| {
                let act: &Vec<Option<(f32, Vec<f32>)>> = &active[c];
                act.iter().enumerate().filter(|(_, a)| a.is_some()).map(|(i, _)| i).collect()
            })
            .collect();
        Query { model: self, active, listed }
    }
}

/// Per channel, per part: the interpolated mean and basis row, if the part has weight.
type ActiveRows = Vec<Vec<Option<(f32, Vec<f32>)>>>;

/// Interpolated angular factors of one (view, light) direction pair.
pub struct Query<'a> {
    model: &'a Model,
    /// Per channel, per part: interpolated mean and basis row, if the part has weight.
    active: ActiveRows,
    /// Per channel, the parts with weight.
    listed: Vec<Vec<usize>>,
}

impl Query<'_> {
    /// Linear RGB of texel `x`.
    #[inline]
    pub fn texel(&self, x: usize) -> [f32; 3] {
        let m = self.model;
        let d = std::array::from_fn(|c| {
            let ch = &m.channels[c];
            match &m.clusters {
                Some(cl) => {
                    let p = cl[x] as usize;
                    match &self.active[c][p] {
                        Some((mu, u)) => {
                            let k = ch.parts[p].k;
                            let col = m.cluster_col[x] as usize;
                            mu + dot(u, &ch.parts[p].sv[col * k..(col + 1) * k])
                        }
                        None => 0.0,
                    }
                }
                None => self.listed[c]
                    .iter()
                    .map(|&pi| {
                        let p = &ch.parts[pi];
                        let (mu, u) = self.active[c][pi].as_ref().expect("listed parts are active");
                        mu + dot(u, &p.sv[x * p.k..(x + 1) * p.k])
                    })
                    .sum(),
            }
        });
        m.color.inverse(d, m.log_eps)
    }

    /// The whole texture (row-major RGB).
    pub fn texture(&self) -> Vec<[f32; 3]> {
        use rayon::prelude::*;
        (0..self.model.layout.texels()).into_par_iter().map(|x| self.texel(x)).collect()
    }
}
