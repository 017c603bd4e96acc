//! `btfrig bench compress`: linear BTF models on a simulated 81 x 81 BTF (docs/compression.md).
//!
//! The "measured" BTF is the renderer's ground truth (area-averaged over `--subsamples`^2
//! point samples per texel, as a radiance factor, exactly what the pipeline compares its
//! textures with) plus the sensor's noise at the level of a real capture: the rig's sensor
//! at the plans' auto exposure (a white reflector at 60 % of full scale), photon shot noise
//! and read noise per channel value, Gaussian, drawn from a generator seeded by (seed,
//! capture). It leaves out what rectification adds (interpolation blur, registration
//! error, demosaic correlation): a full 6480-capture pipeline run at 128 texels takes hours
//! here, and those errors are the pipeline's own figure (`texture_rel_rmse`), not the
//! compression's. Truths are cached in `target/bench-cache` (half floats, as datasets store
//! textures).

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use btfrig_compress::eval::{decode_throughput, ErrorSums};
use btfrig_compress::{build, file, ColorModel, Layout, Method, Model, ModelParams, Precision, RowSink, RowSource};
use btfrig_core::sampling::Sampling;
use btfrig_render::rig_scene::RigScene;
use half::f16;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use sha2::Digest;

/// How [`simulate`] samples a BTF.
#[derive(Debug, Clone, Copy)]
pub struct SimOptions {
    /// Texels per side.
    pub size: usize,
    /// Point samples per texel axis of the ground truth.
    pub subsamples: usize,
    /// Every how many Bonn directions is kept (1: all 81).
    pub every: usize,
    /// No progress lines on stderr.
    pub quiet: bool,
}

/// A simulated BTF: the truth (half floats per measured angular index) and the noise model.
pub struct SimBtf {
    /// Samplings, size, measured pairs.
    pub layout: Layout,
    /// Truth per angular index, RGB interleaved.
    pub truth: Vec<Option<Vec<f16>>>,
    /// Electrons of a white reflector (per channel value).
    pub white_e: f64,
    /// Read noise, electrons.
    pub read_e: f64,
    /// Noise seed.
    pub seed: u64,
}

impl SimBtf {
    /// The truth of angular index `a`.
    pub fn truth_row(&self, a: usize) -> Option<Vec<[f32; 3]>> {
        self.truth[a]
            .as_ref()
            .map(|t| t.chunks_exact(3).map(|c| [c[0].to_f32(), c[1].to_f32(), c[2].to_f32()]).collect())
    }

    /// The measured texture of angular index `a`: truth + shot and read noise.
    pub fn measured_row(&self, a: usize) -> Option<Vec<[f32; 3]>> {
        let mut t = self.truth_row(a)?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ a as u64);
        for p in &mut t {
            for v in p.iter_mut() {
                let sigma = ((f64::from(*v).max(0.0) * self.white_e + self.read_e * self.read_e).sqrt()) / self.white_e;
                let z: f64 = StandardNormal.sample(&mut rng);
                *v += (sigma * z) as f32;
            }
        }
        Some(t)
    }

    /// Bytes of the measured captures at half precision (the dataset's storage).
    pub fn raw_bytes(&self) -> usize {
        self.layout.n_measured() * self.layout.texels() * 3 * 2
    }
}

/// Feeds the measured (or true) textures, optionally only the pairs in `only`.
pub struct SimSource<'a> {
    /// The BTF.
    pub btf: &'a SimBtf,
    /// Noise added.
    pub measured: bool,
    /// Angular indices fed (`None`: every measured one).
    pub only: Option<&'a [bool]>,
}

impl RowSource for SimSource<'_> {
    fn for_each(&mut self, f: &mut RowSink<'_>) -> btfrig_compress::Result<()> {
        let rows: Vec<usize> = (0..self.btf.layout.n_angular())
            .filter(|&a| self.btf.layout.measured[a] && self.only.is_none_or(|o| o[a]))
            .collect();
        for chunk in rows.chunks(16) {
            let tex: Vec<Vec<[f32; 3]>> = chunk
                .par_iter()
                .map(|&a| {
                    if self.measured { self.btf.measured_row(a) } else { self.btf.truth_row(a) }.expect("measured")
                })
                .collect();
            for (&a, t) in chunk.iter().zip(&tex) {
                let (l, v) = self.btf.layout.pair(a);
                f(l as u32, v as u32, t)?;
            }
        }
        Ok(())
    }
}

pub fn bonn(every: usize) -> anyhow::Result<Sampling> {
    let b = Sampling::bonn81();
    if every == 1 {
        return Ok(b);
    }
    let d: Vec<_> = b.directions().iter().step_by(every).copied().collect();
    Ok(Sampling::from_list("bonn81-every", d)?)
}

/// Renders (or loads from the cache) the truth of `material` and returns the simulated BTF.
pub fn simulate(
    cfg: &btfrig_core::config::RigConfig,
    material: &btfrig_render::material::MaterialSpec,
    opts: SimOptions,
    seed: u64,
    cache: &Path,
) -> anyhow::Result<SimBtf> {
    let SimOptions { size, subsamples: k, every, quiet } = opts;
    let scene = RigScene::new(cfg, material)?;
    let (light, view) = (bonn(every)?, bonn(every)?);
    let mut layout = Layout::full(light.clone(), view.clone(), size, size);
    let sensor = scene.sensor();
    let full_e = f64::from(sensor.white_level(1.0) - sensor.black_level_dn) / sensor.dn_per_electron(1.0);
    let white_e = 0.6 * full_e;
    let read_e = sensor.read_noise_e;
    let key = format!("{cfg:?}|{material:?}|{size}|{k}|{every}");
    let hash: String = sha2::Sha256::digest(key.as_bytes()).iter().take(8).map(|b| format!("{b:02x}")).collect();
    std::fs::create_dir_all(cache).with_context(|| format!("cannot create {}", cache.display()))?;
    let path = cache.join(format!("compress-truth-{}-{size}-k{k}-e{every}-{hash}.f16", material.name));
    let m = layout.n_angular();
    let n = size * size;
    if let Ok(bytes) = std::fs::read(&path) {
        if bytes.len() == m + m * n * 6 || bytes.len() >= m {
            let mut truth = Vec::with_capacity(m);
            let mut off = m;
            let mut ok = true;
            for a in 0..m {
                if bytes[a] == 1 {
                    if bytes.len() < off + n * 6 {
                        ok = false;
                        break;
                    }
                    let row =
                        bytes[off..off + n * 6].chunks_exact(2).map(|c| f16::from_le_bytes([c[0], c[1]])).collect();
                    off += n * 6;
                    truth.push(Some(row));
                } else {
                    layout.measured[a] = false;
                    truth.push(None);
                }
            }
            if ok && off == bytes.len() {
                if !quiet {
                    eprintln!("truth     {} from cache {}", material.name, path.display());
                }
                return Ok(SimBtf { layout, truth, white_e, read_e, seed });
            }
            layout.measured.fill(true);
        }
    }
    let t = Instant::now();
    let scale = (scene.sensor().dn_per_electron(1.0) / scene.white_signal_dn(1.0, 1.0)) as f32;
    let mut truth = Vec::with_capacity(m);
    for a in 0..m {
        let (l, v) = layout.pair(a);
        match scene.gonio().ik(light.get(l), view.get(v)) {
            Ok(joints) => {
                let gt = scene.renderer().ground_truth(&scene.pose(&joints), size * k, size * k, None).box_average(k);
                truth
                    .push(Some(gt.data.iter().flat_map(|p| p.map(|c| f16::from_f32(c * scale))).collect::<Vec<f16>>()));
            }
            Err(_) => {
                layout.measured[a] = false;
                truth.push(None);
            }
        }
        if !quiet && a % 500 == 499 {
            eprintln!("truth     {}: {}/{m} pairs rendered, {:.0} s", material.name, a + 1, t.elapsed().as_secs_f64());
        }
    }
    let mut bytes = Vec::with_capacity(m + layout.n_measured() * n * 6);
    bytes.extend(truth.iter().map(|t| u8::from(t.is_some())));
    for row in truth.iter().flatten() {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(&path, &bytes).with_context(|| format!("cannot write {}", path.display()))?;
    if !quiet {
        eprintln!(
            "truth     {}: {m} pairs in {:.0} s, cached in {}",
            material.name,
            t.elapsed().as_secs_f64(),
            path.display()
        );
    }
    Ok(SimBtf { layout, truth, white_e, read_e, seed })
}

/// One benchmark row.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    /// Material name.
    pub material: String,
    /// Method label (PCMF with its clusters and refinement iterations).
    pub method: String,
    /// Colour model.
    pub color: String,
    /// Terms per channel.
    pub terms: [usize; 3],
    /// Model file size, bytes.
    pub file_bytes: usize,
    /// Factors plus cluster map ([`Model::payload_bytes`]): what the verdicts compare.
    pub payload_bytes: usize,
    /// Raw half-float captures / file size.
    pub ratio: f64,
    /// Build time, seconds.
    pub build_s: f64,
    /// Passes over the data.
    pub passes: usize,
    /// The builder's sketches at their peak, MB.
    pub builder_peak_mb: f64,
    /// Decode throughput at random direction pairs, Mtexel/s.
    pub decode_mtexel_s: f64,
    /// Relative RMSE of the decoded model against the noisy measured textures.
    pub rel_rmse_measured: f64,
    /// Relative RMSE against the noise-free ground truth.
    pub rel_rmse_truth: f64,
    /// PCMF: texels per cluster.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub cluster_sizes: Vec<usize>,
    /// PCMF: each local-PCA iteration on the data.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub refine: Vec<btfrig_compress::refine::RefineStep>,
    /// PCMF: errors of the clusters, smallest first (texels, vs measured, vs truth, noise).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub cluster_errors: Vec<ClusterError>,
}

/// One cluster's share of a PCMF model's error.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ClusterError {
    /// Texels in the cluster.
    pub texels: usize,
    /// Relative RMSE of the decoded model against the noisy measured textures.
    pub rel_rmse_measured: f64,
    /// Relative RMSE against the noise-free ground truth.
    pub rel_rmse_truth: f64,
    /// Relative RMS of the measured data against the truth on the cluster's texels.
    pub noise: f64,
}

/// Per texel: squared error against measured, squared measured, against truth, squared
/// truth, squared noise (measured − truth).
pub fn texel_errors(model: &Model, btf: &SimBtf) -> Vec<[f64; 5]> {
    let n = btf.layout.texels();
    let rows: Vec<usize> = (0..btf.layout.n_angular()).filter(|&a| btf.layout.measured[a]).collect();
    rows.par_iter()
        .fold(
            || vec![[0.0f64; 5]; n],
            |mut acc, &a| {
                let d = model.texture(a);
                let (m, t) = (btf.measured_row(a).expect("measured"), btf.truth_row(a).expect("measured"));
                for x in 0..n {
                    for c in 0..3 {
                        let (dv, mv, tv) = (f64::from(d[x][c]), f64::from(m[x][c]), f64::from(t[x][c]));
                        let e = &mut acc[x];
                        e[0] += (dv - mv).powi(2);
                        e[1] += mv * mv;
                        e[2] += (dv - tv).powi(2);
                        e[3] += tv * tv;
                        e[4] += (mv - tv).powi(2);
                    }
                }
                acc
            },
        )
        .reduce(
            || vec![[0.0f64; 5]; n],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(&b) {
                    for i in 0..5 {
                        x[i] += y[i];
                    }
                }
                a
            },
        )
}

/// Per cluster of a PCMF model, smallest cluster first.
pub fn cluster_errors(model: &Model, btf: &SimBtf) -> Vec<ClusterError> {
    let Some(cl) = &model.clusters else { return Vec::new() };
    let te = texel_errors(model, btf);
    let kc = cl.iter().map(|&j| j as usize + 1).max().unwrap_or(0);
    let mut sums = vec![(0usize, [0.0f64; 5]); kc];
    for (x, &j) in cl.iter().enumerate() {
        let (count, sum) = &mut sums[j as usize];
        *count += 1;
        for (s, e) in sum.iter_mut().zip(te[x]) {
            *s += e;
        }
    }
    let mut out: Vec<ClusterError> = sums
        .iter()
        .map(|(n, e)| ClusterError {
            texels: *n,
            rel_rmse_measured: (e[0] / e[1].max(f64::MIN_POSITIVE)).sqrt(),
            rel_rmse_truth: (e[2] / e[3].max(f64::MIN_POSITIVE)).sqrt(),
            noise: (e[4] / e[3].max(f64::MIN_POSITIVE)).sqrt(),
        })
        .collect();
    out.sort_by_key(|c| c.texels);
    out
}

/// Error of `model` against measured and truth in one pass (each texture decoded once).
pub fn errors(model: &Model, btf: &SimBtf) -> (ErrorSums, ErrorSums) {
    let rows: Vec<usize> = (0..btf.layout.n_angular()).filter(|&a| btf.layout.measured[a]).collect();
    rows.par_iter()
        .map(|&a| {
            let d = model.texture(a);
            let (mut em, mut et) = (ErrorSums::default(), ErrorSums::default());
            em.add(&d, &btf.measured_row(a).expect("measured"));
            et.add(&d, &btf.truth_row(a).expect("measured"));
            (em, et)
        })
        .reduce(
            || (ErrorSums::default(), ErrorSums::default()),
            |a, b| {
                (
                    ErrorSums { sq_err: a.0.sq_err + b.0.sq_err, sq_ref: a.0.sq_ref + b.0.sq_ref },
                    ErrorSums { sq_err: a.1.sq_err + b.1.sq_err, sq_ref: a.1.sq_ref + b.1.sq_ref },
                )
            },
        )
}

pub fn setting(method: Method, color: ColorModel, terms: [usize; 3]) -> ModelParams {
    let mut p = ModelParams::new(method);
    p.color = color;
    p.terms = terms;
    p.precision = Precision::F16;
    p
}

pub fn run_setting(name: &str, btf: &SimBtf, p: &ModelParams) -> anyhow::Result<(Model, Row)> {
    let (model, stats) = build::<f32>(btf.layout.clone(), p, &mut SimSource { btf, measured: true, only: None })?;
    let cluster_errors = cluster_errors(&model, btf);
    let bytes = file::encode(&model, serde_json::Value::Null).len();
    let (tput, _) = decode_throughput(&model, 24, 5);
    let (em, et) = errors(&model, btf);
    let row = Row {
        material: name.into(),
        method: match p.method {
            Method::Pcmf { clusters, shared_basis: None } => format!("pcmf-{clusters}/r{}", p.refine_iters),
            m => m.label(),
        },
        color: p.color.name().into(),
        terms: p.terms,
        file_bytes: bytes,
        payload_bytes: model.payload_bytes(),
        ratio: btf.raw_bytes() as f64 / bytes as f64,
        build_s: stats.total_s,
        passes: stats.passes,
        builder_peak_mb: stats.peak_bytes as f64 / 1e6,
        decode_mtexel_s: tput / 1e6,
        rel_rmse_measured: em.rel_rmse(),
        rel_rmse_truth: et.rel_rmse(),
        cluster_sizes: stats.cluster_sizes,
        refine: stats.refine,
        cluster_errors,
    };
    Ok((model, row))
}

/// Payload of an FMF with `k` terms per channel.
pub fn fmf_payload(k: usize, layout: &Layout, precision: Precision) -> usize {
    let (m, n) = (layout.n_angular(), layout.texels());
    3 * (m * (k + 1) + n * k + k) * precision.bytes()
}

/// FMF terms (same for the three channels) whose storage is at least `bytes` of payload.
pub fn fmf_terms_for(bytes: usize, layout: &Layout, precision: Precision) -> usize {
    (1..4096).find(|&k| fmf_payload(k, layout, precision) >= bytes).unwrap_or(4096)
}
