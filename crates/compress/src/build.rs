//! Streaming construction of the models: [`Builder`] takes rectified textures in any order,
//! once per pass, and holds only the sketches of [`crate::rsvd`].
//!
//! * FMF: per channel one [`StreamingRsvd`] over all measured rows (textures) and texels,
//!   each row centred by its own mean over the texels (the mean ABRDF, $\mu[a]$).
//! * PVMF: per channel and view one over that view's lights.
//! * PCMF: first an FMF of channel 0 with `cluster_terms` terms (its passes give every texel
//!   a coefficient vector), clustering of those vectors ([`crate::cluster`]), then per channel
//!   and cluster one over that cluster's texels; then `refine_iters` local-PCA iterations on
//!   the data ([`crate::refine`]: a reassignment pass, then the per-cluster models again).
//! * PCMF in a shared basis (`shared_basis: Some(K)`): per channel one FMF of `K` terms (the
//!   same passes as FMF), then, in memory, clustering of channel 0's coefficients and
//!   `shared_iters` local-PCA iterations on all channels' coefficients ([`crate::shared`]);
//!   no pass after the FMF's.
//!
//! Every pass must deliver every measured capture exactly once ([`Builder::push`] checks
//! indices, size, duplicates and finiteness, naming the capture), and [`Builder::end_pass`]
//! says whether another pass is needed. [`build`] drives a [`RowSource`] through all passes.

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cluster::{cluster, ClusterParams};
use crate::color::ColorModel;
use crate::error::{bad, CompressError, Result};
use crate::model::{Channel, Layout, Method, Model, Part, PartRows, Precision, SharedBasis};
use crate::refine::{ClusterModel, Reassign, RefineStep};
use crate::rsvd::{Real, RsvdParams, StreamingRsvd};

/// Everything that decides a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelParams {
    /// FMF, PVMF or PCMF (with its number of clusters).
    pub method: Method,
    /// Colour model of the three factorised channels.
    pub color: ColorModel,
    /// `eps` of the log colour model (radiance factor; 1 = a white reflector).
    pub log_eps: f32,
    /// Terms per channel (per view for PVMF, per cluster for PCMF).
    pub terms: [usize; 3],
    /// Oversampling of the randomized SVD.
    pub oversample: usize,
    /// Power iterations of the randomized SVD (two passes each).
    pub power_iters: usize,
    /// Rows per product batch.
    pub batch: usize,
    /// Seed of every random choice (test matrices, clustering).
    pub seed: u64,
    /// Precision of the stored factors.
    pub precision: Precision,
    /// PCMF: terms of the global basis the texels are clustered in.
    pub cluster_terms: usize,
    /// PCMF: local-PCA reassignment iterations in the clustering basis' coefficients.
    pub cluster_iters: usize,
    /// PCMF: local-PCA iterations on the data itself, after the first per-cluster models:
    /// each one pass that moves every texel to the cluster whose mean and basis reconstruct
    /// its ABRDF best (all channels, every measured row), then the per-cluster models again.
    #[serde(default = "ModelParams::default_refine_iters")]
    pub refine_iters: usize,
    /// PCMF in a shared basis: local-PCA iterations on the coefficients of every channel in
    /// the shared basis (in memory, no pass; [`crate::shared`]).
    #[serde(default = "ModelParams::default_shared_iters")]
    pub shared_iters: usize,
}

impl ModelParams {
    /// The defaults of `method`: YUV; FMF 32/16/16 terms, PVMF 8/4/4 per view, PCMF 8/4/4 per
    /// cluster; oversampling 10, one power iteration, f16 storage, seed 1; PCMF clusters in a
    /// 32-term basis with 10 local-PCA iterations, then 2 local-PCA iterations on the data.
    pub fn new(method: Method) -> Self {
        let terms = match method {
            Method::Fmf => [32, 16, 16],
            Method::Pvmf | Method::Pcmf { .. } => [8, 4, 4],
        };
        ModelParams {
            method,
            color: ColorModel::Yuv,
            log_eps: 1e-3,
            terms,
            oversample: 10,
            power_iters: 1,
            batch: 32,
            seed: 1,
            precision: Precision::F16,
            cluster_terms: 32,
            cluster_iters: 10,
            refine_iters: Self::default_refine_iters(),
            shared_iters: Self::default_shared_iters(),
        }
    }

    const fn default_refine_iters() -> usize {
        2
    }

    const fn default_shared_iters() -> usize {
        5
    }

    /// Checks every knob.
    pub fn validate(&self) -> Result<()> {
        for (c, &k) in self.terms.iter().enumerate() {
            if k == 0 || k > 1024 {
                return Err(bad(["terms[0]", "terms[1]", "terms[2]"][c], k, "1..=1024 per channel"));
            }
        }
        if let Method::Pcmf { clusters, .. } = self.method {
            if clusters == 0 || clusters > 4096 {
                return Err(bad("clusters", clusters, "1..=4096"));
            }
            if self.cluster_terms == 0 || self.cluster_terms > 1024 {
                return Err(bad("cluster_terms", self.cluster_terms, "1..=1024"));
            }
            if self.refine_iters > 20 {
                return Err(bad("refine_iters", self.refine_iters, "0..=20"));
            }
        }
        if let Some(k) = self.method.shared_basis() {
            let most = self.terms.iter().copied().max().unwrap_or(0);
            if k < most || k > 1024 {
                return Err(bad(
                    "shared_basis",
                    k,
                    format!("{most}..=1024 (at least the terms per cluster, {:?})", self.terms),
                ));
            }
            if self.shared_iters > 50 {
                return Err(bad("shared_iters", self.shared_iters, "0..=50"));
            }
        }
        if !(self.log_eps > 0.0 && self.log_eps <= 1.0) {
            return Err(bad("log_eps", self.log_eps, "(0, 1] (radiance factor)"));
        }
        RsvdParams { rank: 1, oversample: self.oversample, power_iters: self.power_iters, batch: self.batch, seed: 0 }
            .validate()
    }

    fn rsvd(&self, rank: usize, salt: u64) -> RsvdParams {
        RsvdParams {
            rank,
            oversample: self.oversample,
            power_iters: self.power_iters,
            batch: self.batch,
            seed: self.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(salt),
        }
    }

    /// Total passes over the data (PCMF: the clustering basis, the per-cluster models, and
    /// per refinement one assignment pass and the models again; PCMF in a shared basis: the
    /// FMF's).
    pub fn passes(&self) -> usize {
        let p = 2 + 2 * self.power_iters;
        match self.method {
            Method::Pcmf { shared_basis: Some(_), .. } => p,
            Method::Pcmf { .. } => 2 * p + self.refine_iters * (1 + p),
            _ => p,
        }
    }
}

struct PartBuilder<T: Real> {
    channel: usize,
    rows: PartRows,
    /// Texels of the part (PCMF), `None` = all.
    cols: Option<Vec<u32>>,
    /// Angular index -> compact row (`u32::MAX`: not in the part).
    rowmap: Vec<u32>,
    rsvd: StreamingRsvd<T>,
    mean: Vec<f64>,
    buf: Vec<T>,
}

impl<T: Real> PartBuilder<T> {
    fn new(layout: &Layout, channel: usize, rows: PartRows, cols: Option<Vec<u32>>, p: &RsvdParams) -> Result<Self> {
        let nl = layout.n_light();
        let mut rowmap = vec![u32::MAX; layout.n_angular()];
        let mut next = 0u32;
        for (a, slot) in rowmap.iter_mut().enumerate() {
            let inside = match rows {
                PartRows::All => true,
                PartRows::View(v) => a / nl == v,
            };
            if inside && layout.measured[a] {
                *slot = next;
                next += 1;
            }
        }
        let ncols = cols.as_ref().map_or(layout.texels(), Vec::len);
        let rsvd = StreamingRsvd::new(next as usize, ncols, p)?;
        Ok(PartBuilder {
            channel,
            rows,
            cols,
            rowmap,
            rsvd,
            mean: vec![0.0; next as usize],
            buf: vec![T::zero(); ncols],
        })
    }

    fn push(&mut self, a: usize, d: &[[f32; 3]]) {
        let r = self.rowmap[a];
        if r == u32::MAX {
            return;
        }
        let c = self.channel;
        let mut sum = 0.0f64;
        match &self.cols {
            None => {
                for (b, t) in self.buf.iter_mut().zip(d) {
                    *b = T::of_f32(t[c]);
                    sum += f64::from(t[c]);
                }
            }
            Some(cols) => {
                for (b, &x) in self.buf.iter_mut().zip(cols) {
                    let v = d[x as usize][c];
                    *b = T::of_f32(v);
                    sum += f64::from(v);
                }
            }
        }
        let mean = sum / self.buf.len().max(1) as f64;
        self.mean[r as usize] = mean;
        let m = T::of_f64(mean);
        for b in self.buf.iter_mut() {
            *b -= m;
        }
        let buf = std::mem::take(&mut self.buf);
        self.rsvd.push(r as usize, &buf);
        self.buf = buf;
    }

    fn memory_bytes(&self) -> usize {
        self.rsvd.memory_bytes()
            + self.buf.len() * std::mem::size_of::<T>()
            + self.rowmap.len() * 4
            + self.mean.len() * 8
            + self.cols.as_ref().map_or(0, |c| c.len() * 4)
    }
}

/// What the passes of the current phase feed.
enum Phase {
    /// PCMF: the clustering basis (one FMF part of channel 0).
    Basis,
    /// The model's parts (FMF, PVMF; PCMF per cluster).
    Parts,
    /// PCMF: a reassignment pass over the data ([`crate::refine`]).
    Assign(Box<Reassign>),
}

/// Streaming model builder (see the module documentation). `T`: the accumulation type of the
/// sketches (`f32` by default; `f64` for reference runs).
pub struct Builder<T: Real = f32> {
    layout: Layout,
    params: ModelParams,
    parts: Vec<PartBuilder<T>>,
    phase: Phase,
    /// PCMF: local-PCA iterations on the data still to do.
    refines_left: usize,
    refine_log: Vec<RefineStep>,
    clusters: Option<Vec<u16>>,
    /// PCMF in a shared basis: the finished channels (after the FMF passes).
    shared: Option<Vec<Channel>>,
    seen: Vec<bool>,
    pass: usize,
    peak_bytes: usize,
}

impl<T: Real> Builder<T> {
    /// A builder for a BTF of `layout`.
    pub fn new(layout: Layout, params: ModelParams) -> Result<Self> {
        params.validate()?;
        if layout.n_measured() == 0 {
            return Err(bad("measured captures", 0, "at least 1"));
        }
        if let Some(k) = params.method.shared_basis() {
            let most = max_shared_basis(&layout);
            if k > most {
                return Err(bad(
                    "shared_basis",
                    k,
                    format!(
                        "at most {most}: the FMF of {} measured captures x {} texels has no more terms (nor more \
                         than 1024)",
                        layout.n_measured(),
                        layout.texels()
                    ),
                ));
            }
        }
        let mut parts = Vec::new();
        let phase = if matches!(params.method, Method::Pcmf { .. }) { Phase::Basis } else { Phase::Parts };
        let refines_left = if matches!(params.method, Method::Pcmf { .. }) { params.refine_iters } else { 0 };
        match params.method {
            Method::Fmf => {
                for c in 0..3 {
                    parts.push(PartBuilder::new(
                        &layout,
                        c,
                        PartRows::All,
                        None,
                        &params.rsvd(params.terms[c], c as u64),
                    )?);
                }
            }
            Method::Pvmf => {
                for c in 0..3 {
                    for v in 0..layout.n_view() {
                        if (0..layout.n_light()).any(|l| layout.measured[layout.index(l, v)]) {
                            // 243 parts at once: small batches keep the buffers (batch x texels
                            // per part) below the sketches themselves.
                            let mut p = params.rsvd(params.terms[c], (c * 100_000 + v) as u64);
                            p.batch = p.batch.min(8);
                            parts.push(PartBuilder::new(&layout, c, PartRows::View(v), None, &p)?);
                        } else {
                            return Err(CompressError::Dataset {
                                dir: "<layout>".into(),
                                what: format!("PVMF needs at least one measured light per view; view {v} has none"),
                            });
                        }
                    }
                }
            }
            Method::Pcmf { shared_basis: Some(k), .. } => {
                for c in 0..3 {
                    parts.push(PartBuilder::new(&layout, c, PartRows::All, None, &params.rsvd(k, 7 + c as u64))?);
                }
            }
            Method::Pcmf { .. } => {
                parts.push(PartBuilder::new(&layout, 0, PartRows::All, None, &params.rsvd(params.cluster_terms, 7))?);
            }
        }
        let seen = vec![false; layout.n_angular()];
        let mut b = Builder {
            layout,
            params,
            parts,
            phase,
            refines_left,
            refine_log: Vec::new(),
            clusters: None,
            shared: None,
            seen,
            pass: 0,
            peak_bytes: 0,
        };
        b.peak_bytes = b.memory_bytes();
        Ok(b)
    }

    /// The layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The parameters.
    pub fn params(&self) -> &ModelParams {
        &self.params
    }

    /// Current pass, from 0.
    pub fn pass(&self) -> usize {
        self.pass
    }

    /// Total passes this model needs.
    pub fn passes(&self) -> usize {
        self.params.passes()
    }

    /// Bytes held now by the sketches and buffers.
    pub fn memory_bytes(&self) -> usize {
        self.parts.iter().map(PartBuilder::memory_bytes).sum::<usize>()
            + match &self.phase {
                Phase::Assign(r) => r.memory_bytes(),
                _ => 0,
            }
            + self.seen.len()
            + self.clusters.as_ref().map_or(0, |c| c.len() * 2)
    }

    /// Largest [`Builder::memory_bytes`] seen so far.
    pub fn peak_bytes(&self) -> usize {
        self.peak_bytes
    }

    /// PCMF: what each local-PCA iteration on the data did, so far.
    pub fn refine_log(&self) -> &[RefineStep] {
        &self.refine_log
    }

    /// PCMF: texels per cluster (after the clustering pass; empty before and for FMF, PVMF).
    pub fn cluster_sizes(&self) -> Vec<usize> {
        let Some(cl) = &self.clusters else { return Vec::new() };
        let mut n = vec![0usize; cl.iter().map(|&j| j as usize + 1).max().unwrap_or(0)];
        for &j in cl {
            n[j as usize] += 1;
        }
        n
    }

    /// True if capture `(light, view)` was pushed in the current pass.
    pub fn seen(&self, light: u32, view: u32) -> bool {
        let (l, v) = (light as usize, view as usize);
        l < self.layout.n_light() && v < self.layout.n_view() && self.seen[self.layout.index(l, v)]
    }

    /// Feeds the texture of capture `(light, view)` (row-major linear RGB, `width x height`).
    pub fn push(&mut self, light: u32, view: u32, texels: &[[f32; 3]]) -> Result<()> {
        let a = self.layout.check(light, view)?;
        if self.seen[a] {
            return Err(CompressError::DuplicateCapture { light, view, pass: self.pass + 1 });
        }
        let n = self.layout.texels();
        if texels.len() != n {
            return Err(CompressError::WrongTextureSize {
                light,
                view,
                got: texels.len(),
                expected: n,
                width: self.layout.width,
                height: self.layout.height,
            });
        }
        check_finite(light, view, texels, self.layout.width)?;
        let (color, eps) = (self.params.color, self.params.log_eps);
        let d: Vec<[f32; 3]> = texels.iter().map(|&t| color.forward(t, eps)).collect();
        match &mut self.phase {
            Phase::Assign(r) => r.push(a, &d),
            _ => self.parts.par_iter_mut().for_each(|p| p.push(a, &d)),
        }
        self.seen[a] = true;
        Ok(())
    }

    /// Ends a pass; `Ok(true)` if another pass over every capture is needed.
    pub fn end_pass(&mut self) -> Result<bool> {
        let missing: Vec<usize> =
            (0..self.layout.n_angular()).filter(|&a| self.layout.measured[a] && !self.seen[a]).collect();
        if !missing.is_empty() {
            let first = missing
                .iter()
                .take(5)
                .map(|&a| {
                    let (l, v) = self.layout.pair(a);
                    format!("(light {l}, view {v})")
                })
                .collect::<Vec<_>>()
                .join(", ");
            return Err(CompressError::MissingCaptures {
                pass: self.pass + 1,
                missing: missing.len(),
                expected: self.layout.n_measured(),
                first,
            });
        }
        self.peak_bytes = self.peak_bytes.max(self.memory_bytes());
        if matches!(self.phase, Phase::Assign(_)) {
            let Phase::Assign(r) = std::mem::replace(&mut self.phase, Phase::Parts) else { unreachable!() };
            let (assign, step) = r.finish(self.clusters.as_ref().expect("clusters before reassignment"));
            self.refine_log.push(step);
            self.pass += 1;
            self.seen.fill(false);
            self.start_parts(&assign)?;
            self.peak_bytes = self.peak_bytes.max(self.memory_bytes());
            return Ok(true);
        }
        let mut more = false;
        for p in &mut self.parts {
            more |= p.rsvd.end_pass()?;
        }
        self.pass += 1;
        self.seen.fill(false);
        self.peak_bytes = self.peak_bytes.max(self.memory_bytes());
        if !more && matches!(self.phase, Phase::Basis) && self.params.method.shared_basis().is_some() {
            self.finish_shared()?;
            self.phase = Phase::Parts;
            return Ok(false);
        }
        if !more && matches!(self.phase, Phase::Basis) {
            self.start_clusters()?;
            self.phase = Phase::Parts;
            self.peak_bytes = self.peak_bytes.max(self.memory_bytes());
            return Ok(true);
        }
        if !more && self.refines_left > 0 {
            self.refines_left -= 1;
            self.start_reassign()?;
            self.peak_bytes = self.peak_bytes.max(self.memory_bytes());
            return Ok(true);
        }
        Ok(more)
    }

    /// Finishes the per-cluster models and starts a reassignment pass with them.
    fn start_reassign(&mut self) -> Result<()> {
        let parts = std::mem::take(&mut self.parts);
        let rowmap = parts[0].rowmap.clone();
        let finished: Vec<(usize, ClusterModel)> = parts
            .into_par_iter()
            .map(|pb| {
                let svd = pb.rsvd.finish()?;
                Ok((pb.channel, ClusterModel { mean: pb.mean, u: svd.u }))
            })
            .collect::<Result<_>>()?;
        let mut models: Vec<Vec<ClusterModel>> = vec![Vec::new(), Vec::new(), Vec::new()];
        for (c, m) in finished {
            models[c].push(m);
        }
        // The rows of the accumulator's products: the rows of one batch of the sketches.
        let r = Reassign::new(rowmap, self.layout.texels(), &models, self.params.batch);
        self.phase = Phase::Assign(Box::new(r));
        Ok(())
    }

    /// PCMF in a shared basis: the FMF of every channel is done; clusters and fits the
    /// two-level model in memory ([`crate::shared`]).
    fn finish_shared(&mut self) -> Result<()> {
        let Method::Pcmf { clusters, .. } = self.params.method else { unreachable!("shared basis only for PCMF") };
        let fill = self.layout.fill_weights();
        let precision = self.params.precision;
        let parts = std::mem::take(&mut self.parts);
        let mut fmf: Vec<ChannelFmf> = parts
            .into_par_iter()
            .map(|pb| {
                let svd = pb.rsvd.finish()?;
                let (mut mean, mut u) = full_rows(&self.layout, &fill, pb.rows, &pb.rowmap, &pb.mean, &svd.u);
                for v in mean.iter_mut().chain(u.iter_mut()) {
                    *v = crate::shared::round(f64::from(*v), precision);
                }
                Ok((pb.channel, mean, u, svd.s.iter().map(|&s| s as f32).collect(), svd.sv))
            })
            .collect::<Result<_>>()?;
        fmf.sort_by_key(|f| f.0);
        let init = cluster(&fmf[0].4, &self.cluster_params(clusters));
        let coef: Vec<nalgebra::DMatrix<f64>> = fmf.iter().map(|f| f.4.clone()).collect();
        let fit = crate::shared::fit(&coef, &init, self.params.terms, self.params.shared_iters, precision);
        let mut channels = Vec::new();
        for ((_, mean, w, s, sv), cf) in fmf.into_iter().zip(fit.channels) {
            let sh = SharedBasis {
                k: sv.ncols(),
                mean,
                w,
                s,
                cluster_mean: cf.cluster_mean,
                cluster_basis: cf.cluster_basis,
            };
            let parts = (0..sh.cluster_mean.len())
                .zip(cf.s.into_iter().zip(cf.coef))
                .map(|(j, (s, coef))| {
                    let (mean, u) = sh.expand(j);
                    Part { rows: PartRows::All, k: sh.terms(j), mean, u, s, sv: coef }
                })
                .collect();
            channels.push(Channel { parts, shared: Some(sh) });
        }
        self.clusters = Some(fit.assign);
        self.shared = Some(channels);
        Ok(())
    }

    /// The clustering of both PCMF forms: k-means, then local-PCA iterations.
    fn cluster_params(&self, clusters: usize) -> ClusterParams {
        ClusterParams {
            clusters,
            terms: self.params.terms[0],
            kmeans_iters: 10,
            local_iters: self.params.cluster_iters,
            seed: self.params.seed,
        }
    }

    fn start_clusters(&mut self) -> Result<()> {
        let Method::Pcmf { clusters, .. } = self.params.method else { unreachable!("clustering only for PCMF") };
        let first = self.parts.pop().expect("the clustering part");
        let svd = first.rsvd.finish()?;
        let assign = cluster(&svd.sv, &self.cluster_params(clusters));
        self.start_parts(&assign)
    }

    /// The per-cluster parts of an assignment (labels from 0; empty clusters dropped).
    fn start_parts(&mut self, assign: &[u16]) -> Result<()> {
        let kc = assign.iter().map(|&j| j as usize + 1).max().unwrap_or(1);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); kc];
        for (x, &j) in assign.iter().enumerate() {
            members[j as usize].push(x as u32);
        }
        // An empty cluster (fewer distinct texels than clusters) is dropped by relabelling.
        let mut relabel = vec![u16::MAX; kc];
        let mut kept = Vec::new();
        for (j, m) in members.into_iter().enumerate() {
            if !m.is_empty() {
                relabel[j] = kept.len() as u16;
                kept.push(m);
            }
        }
        self.clusters = Some(assign.iter().map(|&j| relabel[j as usize]).collect());
        self.parts.clear();
        for c in 0..3 {
            for (j, cols) in kept.iter().enumerate() {
                let p = self.params.rsvd(self.params.terms[c], (1_000 + c * 10_000 + j) as u64);
                self.parts.push(PartBuilder::new(&self.layout, c, PartRows::All, Some(cols.clone()), &p)?);
            }
        }
        Ok(())
    }

    /// The model, after the last pass.
    pub fn finish(self) -> Result<Model> {
        if !matches!(self.phase, Phase::Parts) || self.pass < self.params.passes() {
            return Err(CompressError::State(format!("finish after {} of {} passes", self.pass, self.params.passes())));
        }
        let layout = self.layout;
        if let Some(channels) = self.shared {
            let mut model = Model {
                method: self.params.method,
                color: self.params.color,
                log_eps: self.params.log_eps,
                precision: self.params.precision,
                layout,
                channels,
                clusters: self.clusters,
                cluster_col: Vec::new(),
            };
            model.index_clusters();
            return Ok(model);
        }
        let fill = layout.fill_weights();
        let precision = self.params.precision;
        let built: Vec<(usize, Part)> = self
            .parts
            .into_par_iter()
            .map(|pb| {
                let svd = pb.rsvd.finish()?;
                let k = svd.s.len();
                let (mean, u) = full_rows(&layout, &fill, pb.rows, &pb.rowmap, &pb.mean, &svd.u);
                let ncols = svd.sv.nrows();
                let mut sv = vec![0.0f32; ncols * k];
                for x in 0..ncols {
                    for j in 0..k {
                        sv[x * k + j] = svd.sv[(x, j)] as f32;
                    }
                }
                let mut part = Part { rows: pb.rows, k, mean, u, s: svd.s.iter().map(|&s| s as f32).collect(), sv };
                if precision == Precision::F16 {
                    for v in part.mean.iter_mut().chain(part.u.iter_mut()).chain(part.sv.iter_mut()) {
                        *v = half::f16::from_f32(*v).to_f32();
                    }
                }
                Ok((pb.channel, part))
            })
            .collect::<Result<_>>()?;
        let mut channels = vec![Channel::new(Vec::new()), Channel::new(Vec::new()), Channel::new(Vec::new())];
        for (c, p) in built {
            channels[c].parts.push(p);
        }
        let mut model = Model {
            method: self.params.method,
            color: self.params.color,
            log_eps: self.params.log_eps,
            precision,
            layout,
            channels,
            clusters: self.clusters,
            cluster_col: Vec::new(),
        };
        model.index_clusters();
        Ok(model)
    }
}

/// The most terms a shared basis can have on `layout`: those of its FMF, at most the measured
/// captures and the texels (and 1024).
pub fn max_shared_basis(layout: &Layout) -> usize {
    layout.n_measured().min(layout.texels()).min(1024)
}

/// A part's mean and angular basis over all its rows (part rows x k, row-major) from the
/// measured rows of a finished sketch, unmeasured rows filled by `fill` (see
/// [`Layout::fill_weights`]).
fn full_rows(
    layout: &Layout,
    fill: &[(usize, Vec<(usize, f64)>)],
    rows: PartRows,
    rowmap: &[u32],
    measured_mean: &[f64],
    su: &nalgebra::DMatrix<f64>,
) -> (Vec<f32>, Vec<f32>) {
    let nl = layout.n_light();
    let k = su.ncols();
    let n_rows = match rows {
        PartRows::All => layout.n_angular(),
        PartRows::View(_) => nl,
    };
    let mut mean = vec![0.0f32; n_rows];
    let mut u = vec![0.0f32; n_rows * k];
    let mut known = vec![false; n_rows];
    let row_of = |a: usize| match rows {
        PartRows::All => Some(a),
        PartRows::View(v) => (a / nl == v).then_some(a % nl),
    };
    for (a, &r) in rowmap.iter().enumerate() {
        if r != u32::MAX {
            let pr = row_of(a).expect("mapped rows are in the part");
            mean[pr] = measured_mean[r as usize] as f32;
            for j in 0..k {
                u[pr * k + j] = su[(r as usize, j)] as f32;
            }
            known[pr] = true;
        }
    }
    for (a, weights) in fill.iter() {
        let Some(pr) = row_of(*a) else { continue };
        let ws: Vec<(usize, f64)> =
            weights.iter().filter_map(|&(b, w)| row_of(b).filter(|&r| known[r]).map(|r| (r, w))).collect();
        let total: f64 = ws.iter().map(|w| w.1).sum();
        if total <= 0.0 {
            continue;
        }
        let (mut m, mut row) = (0.0f64, vec![0.0f64; k]);
        for &(r, w) in &ws {
            m += w * f64::from(mean[r]);
            for j in 0..k {
                row[j] += w * f64::from(u[r * k + j]);
            }
        }
        mean[pr] = (m / total) as f32;
        for j in 0..k {
            u[pr * k + j] = (row[j] / total) as f32;
        }
    }
    (mean, u)
}

/// Refuses a texture with a NaN or infinite texel, naming the capture and the texel.
pub fn check_finite(light: u32, view: u32, texels: &[[f32; 3]], width: usize) -> Result<()> {
    for (i, t) in texels.iter().enumerate() {
        for (c, &v) in t.iter().enumerate() {
            if !v.is_finite() {
                return Err(CompressError::NonFinite {
                    light,
                    view,
                    texel: i,
                    col: i % width.max(1),
                    row: i / width.max(1),
                    channel: c,
                    value: v,
                });
            }
        }
    }
    Ok(())
}

/// One channel's FMF, precision-rounded: `(channel, mean, basis U, singular values, SV)`
/// (see [`crate::rsvd::Svd`]).
type ChannelFmf = (usize, Vec<f32>, Vec<f32>, Vec<f32>, nalgebra::DMatrix<f64>);

/// The callback a [`RowSource`] feeds: `(light, view, texels)`.
pub type RowSink<'a> = dyn FnMut(u32, u32, &[[f32; 3]]) -> Result<()> + 'a;

/// Something that can deliver every measured capture of a BTF, once per call.
pub trait RowSource {
    /// Calls `f(light, view, texels)` once for every measured capture, in any order.
    fn for_each(&mut self, f: &mut RowSink<'_>) -> Result<()>;
}

/// What a build cost.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BuildStats {
    /// Passes over the data.
    pub passes: usize,
    /// Wall time of each pass, seconds (reading the source included).
    pub pass_s: Vec<f64>,
    /// Wall time of the whole build, seconds.
    pub total_s: f64,
    /// Peak bytes held by the builder.
    pub peak_bytes: usize,
    /// PCMF: texels per cluster of the model.
    pub cluster_sizes: Vec<usize>,
    /// PCMF: each local-PCA iteration on the data.
    pub refine: Vec<RefineStep>,
}

/// Builds a model from `source`, driving every pass.
pub fn build<T: Real>(layout: Layout, params: &ModelParams, source: &mut dyn RowSource) -> Result<(Model, BuildStats)> {
    let t0 = Instant::now();
    let mut b = Builder::<T>::new(layout, params.clone())?;
    let mut stats = BuildStats::default();
    loop {
        let t = Instant::now();
        source.for_each(&mut |l, v, tex| b.push(l, v, tex))?;
        let more = b.end_pass()?;
        stats.pass_s.push(t.elapsed().as_secs_f64());
        if !more {
            break;
        }
    }
    stats.passes = b.pass();
    stats.peak_bytes = b.peak_bytes();
    stats.cluster_sizes = b.cluster_sizes();
    stats.refine = b.refine_log().to_vec();
    let model = b.finish()?;
    stats.total_s = t0.elapsed().as_secs_f64();
    Ok((model, stats))
}

/// A BTF held in memory (tests, benchmarks): one texture per measured angular index.
pub struct MemorySource<'a> {
    /// The layout.
    pub layout: &'a Layout,
    /// Texture of each angular index (`None` where not measured).
    pub textures: &'a [Option<Vec<[f32; 3]>>],
}

impl RowSource for MemorySource<'_> {
    fn for_each(&mut self, f: &mut RowSink<'_>) -> Result<()> {
        for (a, t) in self.textures.iter().enumerate() {
            if let Some(t) = t {
                let (l, v) = self.layout.pair(a);
                f(l as u32, v as u32, t)?;
            }
        }
        Ok(())
    }
}
